"""Media profiles: the sound speed c(x, y, z) that the media meshes sample (docs/physics.md §7).

Frames and units: world frame, metres, z up, ground at z = 0. Sound speed ``c`` in m/s, temperature in
kelvin, wavenumbers in rad/m. The acoustic refractive index is ``n = c_ref / c`` (dimensionless) with a
per-profile reference speed ``c_ref`` (default 340 m/s); the parabolic curve traces ``n^2``, the
circular curve ``c`` and the n-linear curve ``n`` (constants.CURVE_QUANTITY).

Every public method takes points ``xyz`` of shape ``(..., 3)`` (normally ``(N, 3)``) and returns
values of shape ``(...)`` or gradients of shape ``(..., 3)``, float64. All evaluation is vectorised
numpy; nothing loops over points (the fluctuation sum works through fixed-size blocks of points to
bound memory).

Each profile has a *native* quantity that it defines in closed form (``c`` for most, ``n`` for
``LinearN``, ``n^2`` for ``LinearN2`` and the mirages); the other quantities and their gradients follow
by the chain rule, so a native quantity is returned exactly as defined (``LinearN2.quantity("n2")`` is
linear in z to the last bit of one multiply-add).

Kinds (``Profile.kind``) and constructor defaults (the paper's values, docs/physics.md §7):

==================  ==============================================================================
homogeneous         ``Homogeneous(c0=340)``
linear_c            ``LinearC(c0=340, alpha=0.1)``: c = c0 + alpha z
linear_n            ``LinearN(n0=1, alpha=0.02)``: n = n0 + alpha z, c = c_ref / n
linear_n2           ``LinearN2(n0=1, alpha=0.01)``: n^2 = n0^2 + alpha z
log                 ``Log(c0=340, b=1, z_g=1)``: c = c0 + b ln(z/z_g + 1) (A-LD b=+1, A-LU b=-1)
mirage_inferior     ``MirageInferior(mu0=1.000233, mu1=0.4584, beta=2.303)`` (V-IM, light)
mirage_superior     ``MirageSuperior(...)`` (V-SM, light)
hot_spot            ``HotSpot(center=(0,0,10), t_s=330, d0=50)`` (A-HS)
fluctuating         ``Fluctuating(base, rms=0.5, n_modes=64, ...)`` (+F, paper Eq. 7)
table               ``Table(z, c | temperature_k | temperature_c, interpolation="pchip")``
grid                ``Grid(origin, spacing, c)`` / ``Grid.from_file(path)`` (.npz, .vti)
==================  ==============================================================================

Wind is not modelled yet: :meth:`Profile.effective_sound_speed` is the seam where it will enter.
"""

from __future__ import annotations

import inspect
import math
import os
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "GAMMA_AIR",
    "R_AIR",
    "FD_STEP_M",
    "FLUCTUATION_SPECTRA",
    "PROFILE_KINDS",
    "Profile",
    "Homogeneous",
    "LinearC",
    "LinearN",
    "LinearN2",
    "Log",
    "MirageInferior",
    "MirageSuperior",
    "HotSpot",
    "Fluctuating",
    "Table",
    "Grid",
    "build_profile",
    "speed_of_sound_from_temperature",
    "standard_temperature",
]

# Ratio of specific heats and specific gas constant of dry air (docs/physics.md §7).
GAMMA_AIR = 1.4
R_AIR = 287.05  # J/(kg K)
# 1976 US Standard Atmosphere, troposphere: T_std(z) = T_SEA_LEVEL_K + LAPSE_RATE_K_PER_M * z.
T_SEA_LEVEL_K = 288.15
LAPSE_RATE_K_PER_M = -0.0065
TROPOPAUSE_M = 11000.0

# Step of the central-difference gradient used only by profiles without a closed-form gradient
# (none of the built-in kinds; subclasses that do not override ``_grad_m`` get it). 1e-4 m keeps the
# truncation error (h^2/6 |m'''|) below 1e-8 relative for media varying on metre scales, and the
# rounding error (eps |m| / h) near 1e-12 relative.
FD_STEP_M = 1e-4

# Points are pushed through the fluctuation sum in blocks of this many, so the (block, n_modes)
# phase matrix stays a few MB whatever N is.
_FLUCTUATION_BLOCK = 16384

QUANTITIES = ("c", "n", "n2")

FloatArray = NDArray[np.float64]


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


def _positive(name: str, value: float) -> float:
    value = _finite(name, value)
    if value <= 0.0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    return value


def _as_points(xyz: ArrayLike) -> tuple[FloatArray, tuple[int, ...]]:
    """(..., 3) array-like -> ((N, 3) float64 C-contiguous, leading shape)."""
    p = np.asarray(xyz, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 3:
        raise ValueError(f"xyz must have shape (..., 3), got {p.shape}")
    lead = p.shape[:-1]
    return np.ascontiguousarray(p.reshape(-1, 3)), lead


def standard_temperature(z: ArrayLike) -> FloatArray:
    """1976 US Standard Atmosphere temperature (K) at height ``z`` (m), troposphere only.

    ``T_std(z) = 288.15 - 0.0065 z`` with z clamped to [0, 11000] m: the formula is the troposphere
    (valid to the tropopause at 11 km); heights below ground (rounding) use the ground value and heights
    above 11 km the tropopause value (216.65 K), so it is constant outside that interval.
    """
    zc = np.clip(np.asarray(z, dtype=np.float64), 0.0, TROPOPAUSE_M)
    return T_SEA_LEVEL_K + LAPSE_RATE_K_PER_M * zc


def speed_of_sound_from_temperature(temperature_k: ArrayLike) -> FloatArray:
    """Ideal-gas sound speed ``c = sqrt(gamma R T)`` (m/s) from temperature (K); gamma=1.4, R=287.05."""
    t = np.asarray(temperature_k, dtype=np.float64)
    return np.sqrt(GAMMA_AIR * R_AIR * t)


# =============================================================================================
# Base class
# =============================================================================================
class Profile:
    """Abstract media profile: sound speed ``c`` (m/s) as a function of world position (m).

    Attributes
    ----------
    kind : str
        Job-file kind string (``"log"``, ``"hot_spot"``...).
    c_ref : float
        Reference speed (m/s) of the refractive index ``n = c_ref / c``.
    stratified : bool
        True when c depends on z only, so a stack of horizontal slabs represents it exactly in x, y.

    Subclasses set ``_native`` (``"c"``, ``"n"`` or ``"n2"``) and implement ``_m(p)`` (values of the
    native quantity at ``(N, 3)`` points) and, where a closed form exists, ``_grad_m(p)`` (its
    gradient, ``(N, 3)``); the base class supplies central differences otherwise.
    """

    kind: ClassVar[str] = "abstract"
    _native: ClassVar[str] = "c"

    def __init__(self, c_ref: float = 340.0, stratified: bool = True) -> None:
        self.c_ref: float = _positive("c_ref", c_ref)
        self.stratified: bool = bool(stratified)

    # ----- subclass hooks -------------------------------------------------------------------
    def _m(self, p: FloatArray) -> FloatArray:
        raise NotImplementedError

    def _grad_m(self, p: FloatArray) -> FloatArray:
        """Central differences of ``_m`` with step ``FD_STEP_M`` along each world axis."""
        h = FD_STEP_M
        n = p.shape[0]
        offsets = np.eye(3) * h  # (3, 3)
        shifted = np.concatenate([p[None, :, :] + offsets[:, None, :], p[None, :, :] - offsets[:, None, :]])
        vals = self._m(shifted.reshape(-1, 3)).reshape(2, 3, n)
        return ((vals[0] - vals[1]) / (2.0 * h)).T.copy()

    # ----- conversions ----------------------------------------------------------------------
    def _evaluate(self, name: str, p: FloatArray, with_grad: bool) -> tuple[FloatArray, FloatArray | None]:
        if name not in QUANTITIES:
            raise ValueError(f"unknown quantity {name!r}; expected one of {QUANTITIES}")
        m = self._m(p)
        gm = self._grad_m(p) if with_grad else None
        native = self._native
        if name == native:
            return m, gm
        cr = self.c_ref
        # native -> (n, grad n)
        if native == "c":
            n = cr / m
            gn = None if gm is None else (-cr / (m * m))[:, None] * gm
        elif native == "n":
            n, gn = m, gm
        else:  # native n2
            n = np.sqrt(m)
            gn = None if gm is None else gm / (2.0 * n)[:, None]
        # (n, grad n) -> target
        if name == "n":
            return n, gn
        if name == "n2":
            return n * n, (None if gn is None else (2.0 * n)[:, None] * gn)
        c = cr / n
        return c, (None if gn is None else (-cr / (n * n))[:, None] * gn)

    # ----- public API -----------------------------------------------------------------------
    def sound_speed(self, xyz: ArrayLike) -> FloatArray:
        """Sound speed c (m/s) at world points ``xyz`` (m), shape (..., 3) -> (...)."""
        p, lead = _as_points(xyz)
        return self._evaluate("c", p, False)[0].reshape(lead)

    def sound_speed_gradient(self, xyz: ArrayLike) -> FloatArray:
        """grad c (1/s, i.e. m/s per m) in the world frame, shape (..., 3) -> (..., 3).

        Analytic for every built-in kind; central differences with step ``FD_STEP_M`` for subclasses
        that define no closed form.
        """
        p, lead = _as_points(xyz)
        g = self._evaluate("c", p, True)[1]
        assert g is not None
        return g.reshape(*lead, 3)

    def quantity(self, name: str, xyz: ArrayLike) -> FloatArray:
        """Traced quantity at ``xyz`` (m): ``"c"`` (m/s), ``"n"`` = c_ref/c or ``"n2"`` = n^2.

        Shape (..., 3) -> (...).
        """
        p, lead = _as_points(xyz)
        return self._evaluate(name, p, False)[0].reshape(lead)

    def quantity_gradient(self, name: str, xyz: ArrayLike) -> FloatArray:
        """World-frame gradient (per metre) of :meth:`quantity` ``name``; shape (..., 3) -> (..., 3).

        Chain rule from the native quantity: grad n = -c_ref/c^2 grad c, grad n^2 = 2 n grad n.
        """
        p, lead = _as_points(xyz)
        g = self._evaluate(name, p, True)[1]
        assert g is not None
        return g.reshape(*lead, 3)

    def refractive_index_gradient(self, xyz: ArrayLike) -> FloatArray:
        """grad n (1/m), shape (..., 3) -> (..., 3); the right-hand side of d/ds(n dx/ds) = grad n."""
        return self.quantity_gradient("n", xyz)

    def effective_sound_speed(self, xyz: ArrayLike, azimuth_unit: ArrayLike | None = None) -> FloatArray:
        """Effective sound speed (m/s) for rays launched along a horizontal azimuth.

        With wind ``u(x)`` (m/s) the standard effective-sound-speed approximation is
        ``c_eff = c + u . e`` with ``e`` the unit horizontal launch azimuth (docs/physics.md §7,
        A-UW/A-DW). No profile carries wind yet, so this returns :meth:`sound_speed` unchanged and
        allocates no wind arrays; ``azimuth_unit`` (shape (3,) or (..., 3), world frame) is only
        checked for shape. Wind profiles will override this method.
        """
        if azimuth_unit is not None:
            e = np.asarray(azimuth_unit, dtype=np.float64)
            if e.ndim == 0 or e.shape[-1] != 3:
                raise ValueError(f"azimuth_unit must have shape (3,) or (..., 3), got {e.shape}")
        return self.sound_speed(xyz)

    def describe(self) -> dict[str, Any]:
        """Kind and parameters, JSON-serializable (for reports)."""
        return {"kind": self.kind, "c_ref": self.c_ref, "stratified": self.stratified}

    def __repr__(self) -> str:
        d = self.describe()
        inner = ", ".join(f"{k}={v!r}" for k, v in d.items() if k != "kind")
        return f"{type(self).__name__}({inner})"


# =============================================================================================
# Validation profiles (exact solutions exist)
# =============================================================================================
class Homogeneous(Profile):
    """Constant sound speed ``c = c0`` (m/s)."""

    kind = "homogeneous"
    _native = "c"

    def __init__(self, c0: float = 340.0, c_ref: float = 340.0) -> None:
        super().__init__(c_ref=c_ref, stratified=True)
        self.c0 = _positive("c0", c0)

    def _m(self, p: FloatArray) -> FloatArray:
        return np.full(p.shape[0], self.c0)

    def _grad_m(self, p: FloatArray) -> FloatArray:
        return np.zeros_like(p)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "c0": self.c0}


class _LinearInZ(Profile):
    """Shared body of the three validation profiles that are linear in z in their native quantity:
    ``m_native = intercept + alpha z`` with ``intercept`` from the subclass's own parameter."""

    _param: ClassVar[str]  # name of the ground-value parameter ("c0" or "n0")

    def __init__(self, value: float, alpha: float, c_ref: float) -> None:
        super().__init__(c_ref=c_ref, stratified=True)
        setattr(self, self._param, _positive(self._param, value))
        self.alpha = _finite("alpha", alpha)

    def _intercept(self) -> float:
        return float(getattr(self, self._param))

    def _m(self, p: FloatArray) -> FloatArray:
        return self._intercept() + self.alpha * p[:, 2]

    def _grad_m(self, p: FloatArray) -> FloatArray:
        g = np.zeros_like(p)
        g[:, 2] = self.alpha
        return g

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), self._param: getattr(self, self._param), "alpha": self.alpha}


class LinearC(_LinearInZ):
    """c-linear profile ``c = c0 + alpha z`` (c0 m/s, alpha 1/s). Paper: alpha = 0.1 s^-1.

    Not guarded against c <= 0 (far below ground for alpha > 0); the tracer flags invalid media.
    """

    kind = "linear_c"
    _native = "c"
    _param = "c0"

    def __init__(self, c0: float = 340.0, alpha: float = 0.1, c_ref: float = 340.0) -> None:
        super().__init__(c0, alpha, c_ref)


class LinearN(_LinearInZ):
    """n-linear profile ``n = n0 + alpha z`` (alpha 1/m), ``c = c_ref / n``. Paper: alpha = 0.02 m^-1."""

    kind = "linear_n"
    _native = "n"
    _param = "n0"

    def __init__(self, n0: float = 1.0, alpha: float = 0.02, c_ref: float = 340.0) -> None:
        super().__init__(n0, alpha, c_ref)


class LinearN2(_LinearInZ):
    """n^2-linear profile ``n^2 = n0^2 + alpha z`` (alpha 1/m). Paper: alpha = 0.01 m^-1.

    ``quantity("n2")`` is returned exactly as ``n0^2 + alpha z``.
    """

    kind = "linear_n2"
    _native = "n2"
    _param = "n0"
    n0: float  # set by _LinearInZ.__init__

    def __init__(self, n0: float = 1.0, alpha: float = 0.01, c_ref: float = 340.0) -> None:
        super().__init__(n0, alpha, c_ref)

    def _intercept(self) -> float:
        return self.n0 * self.n0


class _Mirage(Profile):
    """Shared parameters of the light (visual) mirage validation profiles V-IM / V-SM.

    These are optical profiles: the paper defines them through the refractive index of light. So that
    the same engine traces them, the "sound speed" is defined as ``c = c_ref / n`` with the default
    ``c_ref = 340`` m/s; the ray paths depend on n only, travel times are in units of ``1/c_ref``.
    ``beta`` is in 1/m, mu0 and mu1 are dimensionless.
    """

    _native = "n2"

    def __init__(self, mu0: float = 1.000233, mu1: float = 0.4584, beta: float = 2.303, c_ref: float = 340.0) -> None:
        super().__init__(c_ref=c_ref, stratified=True)
        self.mu0 = _positive("mu0", mu0)
        self.mu1 = _finite("mu1", mu1)
        self.beta = _finite("beta", beta)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "mu0": self.mu0, "mu1": self.mu1, "beta": self.beta}


class MirageInferior(_Mirage):
    """Inferior mirage V-IM: ``n^2 = mu0^2 + mu1^2 (1 - exp(-beta z))`` (light; c = c_ref / n)."""

    kind = "mirage_inferior"

    def _m(self, p: FloatArray) -> FloatArray:
        return self.mu0 * self.mu0 + self.mu1 * self.mu1 * -np.expm1(-self.beta * p[:, 2])

    def _grad_m(self, p: FloatArray) -> FloatArray:
        g = np.zeros_like(p)
        g[:, 2] = self.mu1 * self.mu1 * self.beta * np.exp(-self.beta * p[:, 2])
        return g


class MirageSuperior(_Mirage):
    """Superior mirage V-SM: ``n^2 = mu0^2 + mu1^2 exp(-beta z)`` (light; c = c_ref / n)."""

    kind = "mirage_superior"

    def _m(self, p: FloatArray) -> FloatArray:
        return self.mu0 * self.mu0 + self.mu1 * self.mu1 * np.exp(-self.beta * p[:, 2])

    def _grad_m(self, p: FloatArray) -> FloatArray:
        g = np.zeros_like(p)
        g[:, 2] = -self.mu1 * self.mu1 * self.beta * np.exp(-self.beta * p[:, 2])
        return g


# =============================================================================================
# Acoustic profiles
# =============================================================================================
class Log(Profile):
    """Stratified log profile ``c = c0 + b ln(z/z_g + 1)`` (A-LD: b = +1 m/s, A-LU: b = -1 m/s).

    c0 (m/s) is the ground speed, z_g (m) the roughness length. Below ground (z < 0, reachable only by
    rounding) z is clamped to 0, so c = c0 and the gradient is 0 there (the exact derivative of what is
    evaluated). Above ground grad c = b / (z + z_g) e_z.
    """

    kind = "log"
    _native = "c"

    def __init__(self, c0: float = 340.0, b: float = 1.0, z_g: float = 1.0, c_ref: float = 340.0) -> None:
        super().__init__(c_ref=c_ref, stratified=True)
        self.c0 = _positive("c0", c0)
        self.b = _finite("b", b)
        self.z_g = _positive("z_g", z_g)

    def _m(self, p: FloatArray) -> FloatArray:
        z = np.maximum(p[:, 2], 0.0)
        return self.c0 + self.b * np.log1p(z / self.z_g)

    def _grad_m(self, p: FloatArray) -> FloatArray:
        z = p[:, 2]
        g = np.zeros_like(p)
        g[:, 2] = np.where(z >= 0.0, self.b / (np.maximum(z, 0.0) + self.z_g), 0.0)
        return g

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "c0": self.c0, "b": self.b, "z_g": self.z_g}


class HotSpot(Profile):
    """Hot spot A-HS: ``T = T_std(z) + (T_s - T_std(z_s)) exp(-d/d0)``, ``c = sqrt(gamma R T)``.

    ``center`` (m) is the hot-spot position (z_s its height), ``t_s`` (K) its temperature, ``d0`` (m)
    the drop-off length, d the distance to the centre, T_std the troposphere of the 1976 US Standard
    Atmosphere (:func:`standard_temperature`, z clamped to [0, 11000] m). So T = t_s at the centre and
    T -> T_std(z) far away. Defaults (our choice; the paper gives none): a 330 K source 10 m above
    the origin, 50 m drop-off.

    Gradient (analytic): ``grad T = T_std'(z) e_z - (T_s - T_std(z_s)) exp(-d/d0) / d0 * (x - x_s)/d``
    (the cone tip at d = 0 is given the zero subgradient), ``grad c = gamma R grad T / (2 c)``.
    T is not guarded against T <= 0 (needs t_s far below T_std); such media are flagged by the tracer.
    """

    kind = "hot_spot"
    _native = "c"

    def __init__(
        self,
        center: Sequence[float] = (0.0, 0.0, 10.0),
        t_s: float = 330.0,
        d0: float = 50.0,
        c_ref: float = 340.0,
    ) -> None:
        super().__init__(c_ref=c_ref, stratified=False)
        ctr = np.asarray(center, dtype=np.float64)
        if ctr.shape != (3,) or not np.all(np.isfinite(ctr)):
            raise ValueError(f"center must be 3 finite coordinates (m), got {center!r}")
        self.center: FloatArray = ctr
        self.t_s = _positive("t_s", t_s)
        self.d0 = _positive("d0", d0)
        self._dt = self.t_s - float(standard_temperature(ctr[2]))

    def temperature(self, xyz: ArrayLike) -> FloatArray:
        """Air temperature T (K) at world points (m), shape (..., 3) -> (...)."""
        p, lead = _as_points(xyz)
        return self._temperature(p).reshape(lead)

    def _temperature(self, p: FloatArray) -> FloatArray:
        d = np.linalg.norm(p - self.center, axis=1)
        return standard_temperature(p[:, 2]) + self._dt * np.exp(-d / self.d0)

    def _m(self, p: FloatArray) -> FloatArray:
        return speed_of_sound_from_temperature(self._temperature(p))

    def _grad_m(self, p: FloatArray) -> FloatArray:
        r = p - self.center
        d = np.linalg.norm(r, axis=1)
        e = np.exp(-d / self.d0)
        safe_d = np.where(d > 0.0, d, 1.0)
        coef = np.where(d > 0.0, -self._dt * e / (self.d0 * safe_d), 0.0)
        grad_t = coef[:, None] * r
        z = p[:, 2]
        grad_t[:, 2] += np.where((z >= 0.0) & (z <= TROPOPAUSE_M), LAPSE_RATE_K_PER_M, 0.0)
        t = standard_temperature(z) + self._dt * e
        c = speed_of_sound_from_temperature(t)
        return (GAMMA_AIR * R_AIR / (2.0 * c))[:, None] * grad_t

    def describe(self) -> dict[str, Any]:
        return {
            **super().describe(),
            "center": [float(v) for v in self.center],
            "t_s": self.t_s,
            "d0": self.d0,
        }


FLUCTUATION_SPECTRA = ("gaussian", "flat", "von_karman")


class Fluctuating(Profile):
    """Base profile plus random Fourier-mode fluctuations (paper Eq. 7, the "+F" media).

    ``c(x) = c_base(x) + sum_i G_i cos(k_i . x + phi_i)``, i = 1..n_modes.

    Mode construction (exactly, in this order, from ``rng = np.random.default_rng(seed)``):

    1. Magnitudes, stratified log-uniform over ``[k_min, k_max]`` (rad/m): the log band is cut into
       n_modes equal bins and one magnitude is drawn uniformly (in log k) inside each bin:
       ``u = rng.random(n_modes)``, ``|k_i| = k_min (k_max/k_min)^((i + u_i)/n_modes)``.
    2. Directions, isotropic on the unit sphere: ``cos_t = rng.uniform(-1, 1, n_modes)``,
       ``az = rng.uniform(0, 2 pi, n_modes)``.
    3. Phases ``phi = rng.uniform(0, 2 pi, n_modes)``.
    4. Amplitudes: each mode stands for its log-k bin, so its variance is proportional to
       ``w_i = E(|k_i|) |k_i|`` with E(k) the omnidirectional (3D isotropic, variance per unit |k|)
       spectrum; ``G_i = rms sqrt(2 w_i / sum_j w_j)``, hence ``sum G_i^2 / 2 = rms^2`` exactly: the
       spatial RMS of c_flu is ``rms`` (m/s). Spectra:

       - ``"gaussian"`` (default): Gaussian correlation function of length L,
         ``E(k) ~ k^2 exp(-k^2 L^2 / 4)``, with ``L = 2 / sqrt(k_min k_max)`` so E peaks at the
         band's geometric centre.
       - ``"von_karman"``: ``E(k) ~ k^2 (k^2 + k0^2)^(-11/6)`` with outer-scale wavenumber
         ``k0 = k_min``: Kolmogorov ``k^(-5/3)`` through the band.
       - ``"flat"``: equal amplitudes ``G_i = rms sqrt(2 / n_modes)`` (E(k) ~ 1/k).

    Same seed and parameters give the same field bit for bit. The gradient is analytic:
    ``grad c_flu = -sum_i G_i k_i sin(k_i . x + phi_i)``. ``stratified`` is always False and
    ``c_ref`` is the base profile's.
    """

    kind = "fluctuating"
    _native = "c"

    def __init__(
        self,
        base: Profile,
        rms: float = 0.5,
        n_modes: int = 64,
        k_min: float = 2.0 * math.pi / 200.0,
        k_max: float = 2.0 * math.pi / 10.0,
        spectrum: str = "gaussian",
        seed: int = 0,
    ) -> None:
        if not isinstance(base, Profile):
            raise ValueError(f"base must be a Profile, got {type(base).__name__}")
        super().__init__(c_ref=base.c_ref, stratified=False)
        self.base = base
        self.rms = _finite("rms", rms)
        if self.rms < 0.0:
            raise ValueError(f"rms must be >= 0, got {rms!r}")
        if int(n_modes) != n_modes or int(n_modes) < 1:
            raise ValueError(f"n_modes must be an integer >= 1, got {n_modes!r}")
        self.n_modes = int(n_modes)
        self.k_min = _positive("k_min", k_min)
        self.k_max = _positive("k_max", k_max)
        if not self.k_min < self.k_max:
            raise ValueError(f"k_min must be < k_max, got k_min={k_min!r}, k_max={k_max!r}")
        if spectrum not in FLUCTUATION_SPECTRA:
            raise ValueError(f"spectrum must be one of {FLUCTUATION_SPECTRA}, got {spectrum!r}")
        self.spectrum = spectrum
        if int(seed) != seed:
            raise ValueError(f"seed must be an integer, got {seed!r}")
        self.seed = int(seed)
        self.wavevectors, self.amplitudes, self.phases = self._draw_modes()

    def _draw_modes(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        m = self.n_modes
        rng = np.random.default_rng(self.seed)
        u = rng.random(m)
        log_ratio = math.log(self.k_max / self.k_min)
        kmag = self.k_min * np.exp(log_ratio * (np.arange(m) + u) / m)
        cos_t = rng.uniform(-1.0, 1.0, m)
        az = rng.uniform(0.0, 2.0 * math.pi, m)
        phases = rng.uniform(0.0, 2.0 * math.pi, m)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
        dirs = np.stack([sin_t * np.cos(az), sin_t * np.sin(az), cos_t], axis=1)
        wavevectors = kmag[:, None] * dirs

        if self.spectrum == "flat":
            log_w = np.zeros(m)
        elif self.spectrum == "gaussian":
            length = 2.0 / math.sqrt(self.k_min * self.k_max)
            log_w = 3.0 * np.log(kmag) - (kmag * length) ** 2 / 4.0
        else:  # von_karman
            k0 = self.k_min
            log_w = 3.0 * np.log(kmag) - (11.0 / 6.0) * np.log(kmag * kmag + k0 * k0)
        w = np.exp(log_w - np.max(log_w))
        amplitudes = self.rms * np.sqrt(2.0 * w / np.sum(w))
        return wavevectors, amplitudes, phases

    def fluctuation(self, xyz: ArrayLike) -> FloatArray:
        """c_flu (m/s) alone at world points (m), shape (..., 3) -> (...)."""
        p, lead = _as_points(xyz)
        return self._flu(p).reshape(lead)

    def _flu(self, p: FloatArray) -> FloatArray:
        out = np.empty(p.shape[0])
        for s in range(0, p.shape[0], _FLUCTUATION_BLOCK):  # blocks of points, bounded memory
            blk = p[s : s + _FLUCTUATION_BLOCK]
            out[s : s + _FLUCTUATION_BLOCK] = np.cos(blk @ self.wavevectors.T + self.phases) @ self.amplitudes
        return out

    def _flu_grad(self, p: FloatArray) -> FloatArray:
        out = np.empty_like(p)
        gk = self.amplitudes[:, None] * self.wavevectors  # (M, 3)
        for s in range(0, p.shape[0], _FLUCTUATION_BLOCK):
            blk = p[s : s + _FLUCTUATION_BLOCK]
            out[s : s + _FLUCTUATION_BLOCK] = -np.sin(blk @ self.wavevectors.T + self.phases) @ gk
        return out

    def _m(self, p: FloatArray) -> FloatArray:
        return self.base._evaluate("c", p, False)[0] + self._flu(p)

    def _grad_m(self, p: FloatArray) -> FloatArray:
        g = self.base._evaluate("c", p, True)[1]
        assert g is not None
        return g + self._flu_grad(p)

    def describe(self) -> dict[str, Any]:
        return {
            **super().describe(),
            "base": self.base.describe(),
            "rms": self.rms,
            "n_modes": self.n_modes,
            "k_min": self.k_min,
            "k_max": self.k_max,
            "spectrum": self.spectrum,
            "seed": self.seed,
        }


# =============================================================================================
# Tabulated media
# =============================================================================================
class Table(Profile):
    """Stratified table c(z): rows ``z`` (m, strictly increasing, >= 2) with exactly one of ``c`` (m/s),
    ``temperature_k`` (K) or ``temperature_c`` (deg C); temperatures become ``c = sqrt(gamma R T)``.

    ``interpolation="pchip"`` (default; scipy ``PchipInterpolator``: monotone, C1, reproduces the nodes)
    or ``"linear"``. Outside the table c is held constant at the end values and the gradient is 0;
    inside, the gradient is the interpolant's derivative (for "linear", at a node the slope of the
    segment above it).
    """

    kind = "table"
    _native = "c"

    def __init__(
        self,
        z: ArrayLike,
        c: ArrayLike | None = None,
        temperature_k: ArrayLike | None = None,
        temperature_c: ArrayLike | None = None,
        interpolation: str = "pchip",
        c_ref: float = 340.0,
    ) -> None:
        super().__init__(c_ref=c_ref, stratified=True)
        candidates = (("c", c), ("temperature_k", temperature_k), ("temperature_c", temperature_c))
        given = {k: v for k, v in candidates if v is not None}
        if len(given) != 1:
            raise ValueError(
                "table needs exactly one of c, temperature_k, temperature_c; got "
                + (", ".join(given) if given else "none")
            )
        ((source, values),) = given.items()
        zz = np.asarray(z, dtype=np.float64)
        vv = np.asarray(values, dtype=np.float64)
        if zz.ndim != 1 or zz.size < 2:
            raise ValueError(f"table z must be a 1D list of at least 2 rows, got shape {zz.shape}")
        if vv.shape != zz.shape:
            raise ValueError(f"table {source} must have the length of z ({zz.size}), got shape {vv.shape}")
        if not np.all(np.isfinite(zz)):
            raise ValueError("table z must be finite")
        if not np.all(np.diff(zz) > 0.0):
            raise ValueError("table z must be strictly increasing")
        if not np.all(np.isfinite(vv)):
            raise ValueError(f"table {source} must be finite")
        if source == "temperature_c":
            tk = vv + 273.15
        elif source == "temperature_k":
            tk = vv
        else:
            tk = None
        if tk is not None:
            if not np.all(tk > 0.0):
                raise ValueError(f"table {source} must be above absolute zero")
            cc = speed_of_sound_from_temperature(tk)
        else:
            cc = vv
        if not np.all(cc > 0.0):
            raise ValueError("table c must be > 0")
        if interpolation not in ("linear", "pchip"):
            raise ValueError(f"interpolation must be 'linear' or 'pchip', got {interpolation!r}")
        self.source = source
        self.interpolation = interpolation
        self.z: FloatArray = zz
        self.c: FloatArray = cc
        self._input_values: FloatArray = vv
        if interpolation == "pchip":
            from scipy.interpolate import PchipInterpolator

            self._pchip = PchipInterpolator(zz, cc, extrapolate=False)
            self._dpchip = self._pchip.derivative()
        self._slopes: FloatArray = np.diff(cc) / np.diff(zz)

    def _m(self, p: FloatArray) -> FloatArray:
        z = np.clip(p[:, 2], self.z[0], self.z[-1])
        if self.interpolation == "linear":
            return np.interp(z, self.z, self.c)
        return np.asarray(self._pchip(z), dtype=np.float64)

    def _grad_m(self, p: FloatArray) -> FloatArray:
        z = p[:, 2]
        inside = (z >= self.z[0]) & (z <= self.z[-1])
        zc = np.clip(z, self.z[0], self.z[-1])
        if self.interpolation == "linear":
            seg = np.clip(np.searchsorted(self.z, zc, side="right") - 1, 0, self.z.size - 2)
            dz = self._slopes[seg]
        else:
            dz = np.asarray(self._dpchip(zc), dtype=np.float64)
        g = np.zeros_like(p)
        g[:, 2] = np.where(inside, dz, 0.0)
        return g

    def describe(self) -> dict[str, Any]:
        return {
            **super().describe(),
            "interpolation": self.interpolation,
            "z": self.z.tolist(),
            self.source: self._input_values.tolist(),
        }


class Grid(Profile):
    """3D regular grid of c (m/s) with trilinear interpolation.

    ``origin`` (3,) m is the position of node ``c[0, 0, 0]``, ``spacing`` (3,) m the node spacing along
    x, y, z, ``c`` shape (nx, ny, nz) with node ``c[i, j, k]`` at ``origin + (i, j, k) * spacing``
    (at least 2 nodes per axis). ``temperature_k`` (K) may be given instead of ``c``.

    Points outside the grid box are clamped onto it (constant extension); the gradient is the exact
    gradient of the trilinear interpolant in the cell containing the point (the cell above on a node
    plane), with the component along any axis where the point lies strictly outside the box set to 0.
    ``stratified`` is True only when every (x, y) column holds the same c(z).
    """

    kind = "grid"
    _native = "c"

    def __init__(
        self,
        origin: ArrayLike,
        spacing: ArrayLike,
        c: ArrayLike | None = None,
        temperature_k: ArrayLike | None = None,
        c_ref: float = 340.0,
        source_path: str | None = None,
    ) -> None:
        o = np.asarray(origin, dtype=np.float64)
        h = np.asarray(spacing, dtype=np.float64)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError(f"grid origin must be 3 finite numbers (m), got shape {o.shape}")
        if h.shape != (3,) or not np.all(np.isfinite(h)):
            raise ValueError(f"grid spacing must be 3 finite numbers (m), got shape {h.shape}")
        if not np.all(h > 0.0):
            raise ValueError(f"grid spacing must be > 0 along every axis, got {h.tolist()}")
        if (c is None) == (temperature_k is None):
            raise ValueError("grid needs exactly one of c, temperature_k")
        name = "c" if c is not None else "temperature_k"
        arr = np.asarray(c if c is not None else temperature_k, dtype=np.float64)
        if arr.ndim != 3:
            raise ValueError(f"grid {name} must have shape (nx, ny, nz), got shape {arr.shape}")
        if min(arr.shape) < 2:
            raise ValueError(f"grid {name} needs at least 2 points along every axis, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"grid {name} contains NaN or infinite values")
        if not np.all(arr > 0.0):
            raise ValueError(f"grid {name} must be > 0 everywhere")
        cc = arr if c is not None else speed_of_sound_from_temperature(arr)
        stratified = bool(np.all(cc == cc[:1, :1, :]))
        super().__init__(c_ref=c_ref, stratified=stratified)
        self.origin: FloatArray = o
        self.spacing: FloatArray = h
        self.c: FloatArray = np.ascontiguousarray(cc)
        self.shape: tuple[int, int, int] = (int(cc.shape[0]), int(cc.shape[1]), int(cc.shape[2]))
        self.source_path = source_path

    @classmethod
    def from_file(cls, path: str | os.PathLike[str], c_ref: float = 340.0) -> Grid:
        """Load a grid from ``.npz`` or ``.vti``.

        ``.npz``: keys ``c`` (nx, ny, nz) m/s (or ``temperature_k`` in K instead), ``origin`` (3,) m and
        ``spacing`` (3,) m. ``.vti`` (VTK image data, read with pyvista): a point array named ``c`` or
        ``sound_speed`` (m/s); origin and spacing from the image (x-fastest point order).
        """
        p = os.fspath(path)
        suffix = os.path.splitext(p)[1].lower()
        if suffix not in (".npz", ".vti"):
            raise ValueError(f"grid file must be .npz or .vti, got {p!r}")
        if not os.path.isfile(p):
            raise ValueError(f"grid file not found: {p!r}")
        if suffix == ".npz":
            with np.load(p, allow_pickle=False) as data:
                keys = set(data.files)
                for key in ("origin", "spacing"):
                    if key not in keys:
                        raise ValueError(f"grid file {p!r} is missing key {key!r} (has {sorted(keys)})")
                if "c" in keys and "temperature_k" in keys:
                    raise ValueError(f"grid file {p!r} has both 'c' and 'temperature_k'; keep one")
                if "c" in keys:
                    return cls(data["origin"], data["spacing"], c=data["c"], c_ref=c_ref, source_path=p)
                if "temperature_k" in keys:
                    return cls(
                        data["origin"],
                        data["spacing"],
                        temperature_k=data["temperature_k"],
                        c_ref=c_ref,
                        source_path=p,
                    )
                raise ValueError(f"grid file {p!r} is missing key 'c' (or 'temperature_k'), has {sorted(keys)}")
        import pyvista

        mesh = pyvista.read(p)
        if not hasattr(mesh, "dimensions") or not hasattr(mesh, "spacing"):
            raise ValueError(f"grid file {p!r} is not VTK image data")
        names = list(mesh.point_data.keys())
        name = "c" if "c" in names else ("sound_speed" if "sound_speed" in names else None)
        if name is None:
            raise ValueError(f"grid file {p!r} has no point array 'c' or 'sound_speed' (has {names})")
        dims = tuple(int(d) for d in mesh.dimensions)
        values = np.asarray(mesh.point_data[name], dtype=np.float64)
        if values.ndim != 1 or values.size != dims[0] * dims[1] * dims[2]:
            raise ValueError(f"grid file {p!r}: array {name!r} has shape {values.shape}, expected {dims}")
        c = values.reshape(dims, order="F")
        return cls(np.asarray(mesh.origin), np.asarray(mesh.spacing), c=c, c_ref=c_ref, source_path=p)

    def _locate(self, p: FloatArray) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
        """Cell index (N, 3), local coordinates in [0, 1] (N, 3), inside-mask per axis (N, 3)."""
        nmax = np.asarray(self.shape, dtype=np.float64) - 1.0
        u = (p - self.origin) / self.spacing
        inside = (u >= 0.0) & (u <= nmax)
        u = np.clip(u, 0.0, nmax)
        idx = np.minimum(np.floor(u), nmax - 1.0)
        t = u - idx
        return idx.astype(np.int64), t, inside

    def _corners(self, idx: NDArray[np.int64]) -> FloatArray:
        """c at the 8 cell corners, shape (N, 2, 2, 2) indexed [di, dj, dk]."""
        i, j, k = idx[:, 0], idx[:, 1], idx[:, 2]
        c = self.c
        out = np.empty((idx.shape[0], 2, 2, 2))
        for di in (0, 1):
            for dj in (0, 1):
                for dk in (0, 1):
                    out[:, di, dj, dk] = c[i + di, j + dj, k + dk]
        return out

    def _m(self, p: FloatArray) -> FloatArray:
        idx, t, _ = self._locate(p)
        v = self._corners(idx)
        tx, ty, tz = t[:, 0, None, None], t[:, 1, None], t[:, 2]
        vx = v[:, 0] * (1.0 - tx) + v[:, 1] * tx  # (N, 2, 2) over (dj, dk)
        vy = vx[:, 0] * (1.0 - ty) + vx[:, 1] * ty  # (N, 2) over dk
        return vy[:, 0] * (1.0 - tz) + vy[:, 1] * tz

    def _grad_m(self, p: FloatArray) -> FloatArray:
        idx, t, inside = self._locate(p)
        v = self._corners(idx)
        tx, ty, tz = t[:, 0], t[:, 1], t[:, 2]
        # d/dtx: difference along i, then bilinear in (ty, tz)
        dx = v[:, 1] - v[:, 0]  # (N, 2, 2) over (dj, dk)
        dx = dx[:, 0] * (1.0 - ty[:, None]) + dx[:, 1] * ty[:, None]
        dx = dx[:, 0] * (1.0 - tz) + dx[:, 1] * tz
        dy = v[:, :, 1] - v[:, :, 0]  # (N, 2, 2) over (di, dk)
        dy = dy[:, 0] * (1.0 - tx[:, None]) + dy[:, 1] * tx[:, None]
        dy = dy[:, 0] * (1.0 - tz) + dy[:, 1] * tz
        dz = v[:, :, :, 1] - v[:, :, :, 0]  # (N, 2, 2) over (di, dj)
        dz = dz[:, 0] * (1.0 - tx[:, None]) + dz[:, 1] * tx[:, None]
        dz = dz[:, 0] * (1.0 - ty) + dz[:, 1] * ty
        g = np.stack([dx, dy, dz], axis=1) / self.spacing
        return np.where(inside, g, 0.0)

    def describe(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            **super().describe(),
            "origin": self.origin.tolist(),
            "spacing": self.spacing.tolist(),
            "shape": list(self.shape),
            "c_min": float(self.c.min()),
            "c_max": float(self.c.max()),
        }
        if self.source_path is not None:
            d["path"] = self.source_path
        return d


# =============================================================================================
# Factory
# =============================================================================================
PROFILE_KINDS: dict[str, type[Profile]] = {
    cls.kind: cls
    for cls in (
        Homogeneous,
        LinearC,
        LinearN,
        LinearN2,
        Log,
        MirageInferior,
        MirageSuperior,
        HotSpot,
        Fluctuating,
        Table,
        Grid,
    )
}


def build_profile(kind: str, **params: Any) -> Profile:
    """Build a profile from its kind string and constructor keyword arguments.

    ``fluctuating``: ``base`` is a :class:`Profile` or a dict ``{"kind": ..., **params}`` built
    recursively. ``grid``: either ``path`` (str, ``.npz``/``.vti``; relative paths are taken relative
    to the current directory, resolve them beforehand) or the arrays ``origin``, ``spacing``, ``c``
    (or ``temperature_k``). Raises ValueError for an unknown kind or unknown parameters.
    """
    if kind not in PROFILE_KINDS:
        raise ValueError(f"unknown profile kind {kind!r}; expected one of {sorted(PROFILE_KINDS)}")
    cls = PROFILE_KINDS[kind]
    params = dict(params)
    if cls is Fluctuating and isinstance(params.get("base"), dict):
        base = dict(params["base"])
        if "kind" not in base:
            raise ValueError("fluctuating base must be a dict with a 'kind' key")
        params["base"] = build_profile(base.pop("kind"), **base)
    if cls is Grid and "path" in params:
        path = params.pop("path")
        extra = set(params) - {"c_ref"}
        if extra:
            raise ValueError(f"grid: give either 'path' or arrays, not both (extra: {sorted(extra)})")
        return Grid.from_file(path, **params)
    allowed = set(inspect.signature(cls.__init__).parameters) - {"self", "source_path"}
    unknown = set(params) - allowed
    if unknown:
        raise ValueError(f"{kind}: unknown parameter(s) {sorted(unknown)}; allowed {sorted(allowed)}")
    return cls(**params)
