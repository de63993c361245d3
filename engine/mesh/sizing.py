"""Cell-size rules for the media mesh (docs/physics.md §6).

Two rules, both offered, the default chosen by measurement (README, benchmark):

- ``gradient`` (the paper's rule, Sec. 4.2): eps = |grad k| d^2 / 4 with k the normalised slowness
  n = c_ref / c (dimensionless), so d = sqrt(4 eps / |grad n|); eps is in metres.
- ``curvature`` (error-controlled): d such that linear interpolation of the traced quantity m across
  a cell errs by at most delta * |m| (delta relative). Its estimate is d = sqrt(8 delta |m| / |m''|);
  for layers the error is checked directly on the candidate layer instead of trusting a
  finite-difference second derivative, so kinks in tabulated profiles are handled too.

Near the ground the log profile needs millimetre layers and metre-scale ones aloft: the layering
grades vertically, it never shrinks cells isotropically.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# Interior points used to measure a candidate layer's interpolation error (Chebyshev-like spread so
# both the middle and the quarter points, where curvature errors peak, are seen).
_CHECK_FRACTIONS = np.array([0.05, 0.15, 0.3, 0.5, 0.7, 0.85, 0.95])
# Largest number of layers a job may ask for; beyond it the tolerance is unreasonable.
MAX_LAYERS = 2_000_000
# Layers may grow by at most this factor from one to the next (keeps the grading smooth).
MAX_GROWTH = 2.0


def _interp_error(m_at_z: Callable[[np.ndarray], np.ndarray], z: float, d: float, m_lo: float, m_hi: float) -> float:
    zz = z + d * _CHECK_FRACTIONS
    exact = m_at_z(zz)
    linear = m_lo + (m_hi - m_lo) * _CHECK_FRACTIONS
    return float(np.max(np.abs(exact - linear)))


def curvature_layers(
    z0: float,
    z1: float,
    m_at_z: Callable[[np.ndarray], np.ndarray],
    *,
    delta: float,
    d_min: float,
    d_max: float,
) -> np.ndarray:
    """Layer boundaries on [z0, z1] so that linear interpolation of m errs by <= delta * max|m|."""
    if not (z1 > z0):
        raise ValueError("z1 must be above z0")
    probe = m_at_z(np.linspace(z0, z1, 257))
    tol = float(delta) * float(np.max(np.abs(probe)))
    levels = [float(z0)]
    z = float(z0)
    m_lo = float(m_at_z(np.array([z]))[0])
    d = min(d_max, z1 - z0)
    while z < z1:
        d = min(d * MAX_GROWTH, d_max, z1 - z)
        while True:
            m_hi = float(m_at_z(np.array([z + d]))[0])
            err = _interp_error(m_at_z, z, d, m_lo, m_hi)
            if err <= tol or d <= d_min:
                break
            d = max(d_min, d * max(0.1, 0.9 * np.sqrt(tol / err)))
        z_next = z + d
        if z1 - z_next < min(d_min, 1e-9 * max(1.0, abs(z1))) or z_next > z1:
            z_next = z1
            m_hi = float(m_at_z(np.array([z1]))[0])
        levels.append(z_next)
        if len(levels) > MAX_LAYERS:
            raise ValueError(f"the sizing rule asks for more than {MAX_LAYERS} layers; raise delta or d_min_m")
        z = z_next
        m_lo = m_hi
    return np.asarray(levels)


def gradient_layers(
    z0: float,
    z1: float,
    n_at_z: Callable[[np.ndarray], np.ndarray],
    *,
    epsilon: float,
    d_min: float,
    d_max: float,
) -> np.ndarray:
    """Layer boundaries from the paper's rule d = sqrt(4 eps / |dn/dz|), evaluated mid-layer."""
    if not (z1 > z0):
        raise ValueError("z1 must be above z0")

    def spacing(zc: float) -> float:
        h = 1e-6 * max(1.0, abs(zc))
        lo = max(z0, zc - h)
        hi = min(z1, zc + h)
        vals = n_at_z(np.array([lo, hi]))
        grad = abs(float(vals[1] - vals[0])) / (hi - lo)
        if grad == 0.0:
            return d_max
        return float(np.clip(np.sqrt(4.0 * epsilon / grad), d_min, d_max))

    levels = [float(z0)]
    z = float(z0)
    d_prev = d_max
    while z < z1:
        d = min(spacing(z), d_prev * MAX_GROWTH, z1 - z)
        d = min(spacing(z + 0.5 * d), d_prev * MAX_GROWTH, z1 - z)
        d = max(d, min(d_min, z1 - z))
        z_next = z1 if z1 - (z + d) < 1e-9 * max(1.0, abs(z1)) else z + d
        levels.append(z_next)
        if len(levels) > MAX_LAYERS:
            raise ValueError(f"the sizing rule asks for more than {MAX_LAYERS} layers; raise epsilon or d_min_m")
        z = z_next
        d_prev = d
    return np.asarray(levels)


def relative_error_1d(
    z_levels: np.ndarray,
    m_at_z: Callable[[np.ndarray], np.ndarray],
    n_from_m: Callable[[np.ndarray], np.ndarray],
    n_points: int = 20001,
) -> float:
    """Eq. 14 of the paper on a fine input grid in z: ||n_G - n~_G|| / ||n_G||.

    The grid is geometric near the bottom (where stratified profiles curve most) and uniform above.
    """
    z = np.asarray(z_levels, float)
    z0, z1 = z[0], z[-1]
    span = z1 - z0
    geo = z0 + np.geomspace(1e-6 * span, span, n_points // 2)
    grid = np.unique(np.concatenate([np.linspace(z0, z1, n_points // 2), geo]))
    m_exact = m_at_z(grid)
    m_nodes = m_at_z(z)
    m_interp = np.interp(grid, z, m_nodes)
    n_exact = n_from_m(m_exact)
    n_interp = n_from_m(m_interp)
    return float(np.linalg.norm(n_exact - n_interp) / np.linalg.norm(n_exact))


# Most nodes of the regular sizing grid on which 3D target spacings are computed (the paper's
# "input grid"): 1e6 nodes keep the evaluation under a second for analytic profiles.
SIZING_GRID_MAX_NODES = 1_000_000


def sizing_grid_spacing(
    values_at: Callable[[np.ndarray], np.ndarray],
    n_at: Callable[[np.ndarray], np.ndarray],
    domain_min: np.ndarray,
    domain_max: np.ndarray,
    *,
    rule: str,
    tolerance: float,
    d_min: float,
    d_max: float,
    grid_step: float | None = None,
) -> Callable[[np.ndarray], np.ndarray]:
    """Target spacing d(x) computed once on a regular grid, then interpolated (paper, Sec. 4.2).

    The profile is sampled on a grid of step ``grid_step`` (default: the larger of d_min / 2 and the
    step that keeps SIZING_GRID_MAX_NODES nodes); first and second derivatives come from central
    differences of those samples (np.gradient), so tabulated and gridded profiles are sized from
    their own data. rule "curvature": d = sqrt(8 delta |m| / lambda_max(Hessian m)); rule
    "gradient": d = sqrt(4 eps / |grad n|). Each node then takes the minimum over its 3x3x3
    neighbourhood so that interpolation never widens a fine region. Returns a vectorised callable
    xyz (N, 3) -> d (N,), clamped to [d_min, d_max].
    """
    from scipy.interpolate import RegularGridInterpolator
    from scipy.ndimage import minimum_filter

    lo = np.asarray(domain_min, float)
    hi = np.asarray(domain_max, float)
    ext = hi - lo
    step = (
        grid_step
        if grid_step is not None
        else max(0.5 * d_min, float(np.prod(ext) / SIZING_GRID_MAX_NODES) ** (1.0 / 3.0))
    )
    shape = [int(np.clip(np.ceil(e / step), 2, 400)) + 1 for e in ext]
    axes = [np.linspace(lo[i], hi[i], shape[i]) for i in range(3)]
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if rule == "gradient":
        n = n_at(mesh).reshape(shape)
        grads = np.gradient(n, *axes, edge_order=2)
        gmag = np.sqrt(sum(g * g for g in grads))
        with np.errstate(divide="ignore"):
            d = np.sqrt(4.0 * tolerance / gmag)
    elif rule == "curvature":
        m = values_at(mesh).reshape(shape)
        first = np.gradient(m, *axes, edge_order=2)
        hess = np.empty(tuple(shape) + (3, 3))
        for i in range(3):
            second = np.gradient(first[i], *axes, edge_order=2)
            for j in range(3):
                hess[..., i, j] = second[j]
        hess = 0.5 * (hess + np.swapaxes(hess, -1, -2))
        lam = np.abs(np.linalg.eigvalsh(hess)).max(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.sqrt(8.0 * tolerance * np.abs(m) / lam)
    else:
        raise ValueError(f"unknown sizing rule {rule!r}")
    d = np.clip(np.nan_to_num(d, nan=d_max, posinf=d_max), d_min, d_max)
    d = minimum_filter(d, size=3, mode="nearest")
    interp = RegularGridInterpolator(axes, d, method="linear", bounds_error=False, fill_value=None)

    def spacing(xyz: np.ndarray) -> np.ndarray:
        p = np.clip(np.atleast_2d(np.asarray(xyz, float)), lo, hi)
        return np.clip(interp(p), d_min, d_max)

    return spacing
