"""Job-file schema of media profiles (pydantic v2), one model per kind, and the bridge to the engine.

A profile in a job file is a JSON object with a ``kind`` discriminator and the constructor parameters of
the matching :mod:`bentray.engine.profiles` class, e.g. ``{"kind": "log", "c0": 340.0, "b": 1.0,
"z_g": 1.0}``. Defaults are the paper's values (docs/physics.md §7). Units: metres, m/s, kelvin,
rad/m. Validators only check (they never rewrite values); unknown keys are rejected.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, field_validator, model_validator

from bentray.engine.profiles import Profile, build_profile
from bentray.scenes.bounds import MAX_COORD_M, Coord, LengthVec3, Vec3

__all__ = [
    "HomogeneousSpec",
    "LinearCSpec",
    "LinearNSpec",
    "LinearN2Spec",
    "LogSpec",
    "MirageInferiorSpec",
    "MirageSuperiorSpec",
    "HotSpotSpec",
    "FluctuatingSpec",
    "TableSpec",
    "GridSpec",
    "ProfileSpec",
    "PROFILE_SPEC_ADAPTER",
    "profile_from_spec",
]

# Size-like parameters are bounded so that building the profile is bounded work: a few thousand modes,
# table rows and grid nodes per axis (the job body limit bounds the total), nesting of fluctuating bases.
MAX_SPEED_PARAM = 1.0e5  # m/s: c0, c_ref (the media check then asks for a physical range)
MAX_MODES = 4096
MAX_TABLE_ROWS = 100_000
MAX_GRID_NODES_PER_AXIS = 1024
MAX_INLINE_GRID_NODES = 1_000_000
MAX_PROFILE_NESTING = 4  # fluctuating bases within fluctuating bases
MAX_WAVENUMBER = 1.0e3  # rad/m (6 mm wavelength)
_Finite = Annotated[float, Field(ge=-1e12, le=1e12)]


class _ProfileSpecBase(BaseModel):
    """Common settings: unknown keys rejected, NaN/inf rejected for every float."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class _RefSpec(_ProfileSpecBase):
    """Kinds that carry their own reference speed (all but ``fluctuating``, which uses its base's)."""

    c_ref: float = Field(340.0, gt=0.0, le=MAX_SPEED_PARAM, description="Reference speed of n = c_ref / c (m/s).")


class HomogeneousSpec(_RefSpec):
    """Constant sound speed."""

    kind: Literal["homogeneous"] = "homogeneous"
    c0: float = Field(340.0, gt=0.0, le=MAX_SPEED_PARAM, description="Sound speed (m/s).")


class LinearCSpec(_RefSpec):
    """c = c0 + alpha z."""

    kind: Literal["linear_c"] = "linear_c"
    c0: float = Field(340.0, gt=0.0, le=MAX_SPEED_PARAM, description="Sound speed at z = 0 (m/s).")
    alpha: _Finite = Field(0.1, description="dc/dz (1/s).")


class LinearNSpec(_RefSpec):
    """n = n0 + alpha z, c = c_ref / n."""

    kind: Literal["linear_n"] = "linear_n"
    n0: float = Field(1.0, gt=0.0, le=1e3, description="Refractive index at z = 0.")
    alpha: _Finite = Field(0.02, description="dn/dz (1/m).")


class LinearN2Spec(_RefSpec):
    """n^2 = n0^2 + alpha z."""

    kind: Literal["linear_n2"] = "linear_n2"
    n0: float = Field(1.0, gt=0.0, le=1e3, description="Refractive index at z = 0.")
    alpha: _Finite = Field(0.01, description="d(n^2)/dz (1/m).")


class LogSpec(_RefSpec):
    """c = c0 + b ln(z/z_g + 1) (A-LD b = +1, A-LU b = -1)."""

    kind: Literal["log"] = "log"
    c0: float = Field(340.0, gt=0.0, le=MAX_SPEED_PARAM, description="Sound speed at the ground (m/s).")
    b: _Finite = Field(1.0, description="Log-profile strength (m/s); +1 downward (A-LD), -1 upward (A-LU).")
    z_g: float = Field(1.0, gt=0.0, le=MAX_COORD_M, description="Roughness length (m).")


class _MirageSpec(_RefSpec):
    mu0: float = Field(
        1.000233, gt=0.0, le=1e3, description="Refractive index at z = 0 (inferior) or far above (superior)."
    )
    mu1: _Finite = Field(0.4584, description="Refractive-index change scale (n^2 changes by mu1^2).")
    beta: _Finite = Field(2.303, description="Decay rate (1/m).")


class MirageInferiorSpec(_MirageSpec):
    """Light validation: n^2 = mu0^2 + mu1^2 (1 - exp(-beta z)), c = c_ref / n."""

    kind: Literal["mirage_inferior"] = "mirage_inferior"


class MirageSuperiorSpec(_MirageSpec):
    """Light validation: n^2 = mu0^2 + mu1^2 exp(-beta z), c = c_ref / n."""

    kind: Literal["mirage_superior"] = "mirage_superior"


class HotSpotSpec(_RefSpec):
    """A-HS: T = T_std(z) + (t_s - T_std(z_s)) exp(-d/d0), c = sqrt(gamma R T)."""

    kind: Literal["hot_spot"] = "hot_spot"
    center: Vec3 = Field((0.0, 0.0, 10.0), description="Hot-spot position (m).")
    t_s: float = Field(330.0, gt=0.0, le=1e4, description="Temperature at the hot spot (K).")
    d0: float = Field(50.0, gt=0.0, le=MAX_COORD_M, description="Drop-off length (m).")


class FluctuatingSpec(_ProfileSpecBase):
    """Base profile plus random Fourier-mode fluctuations (paper Eq. 7); c_ref comes from ``base``."""

    kind: Literal["fluctuating"] = "fluctuating"
    base: ProfileSpec = Field(default_factory=lambda: LogSpec(), description="Profile the modes add to.")
    rms: float = Field(0.5, ge=0.0, le=1e3, description="Spatial RMS of c_flu (m/s).")
    n_modes: int = Field(64, ge=1, le=MAX_MODES, description="Number of Fourier modes.")
    k_min: float = Field(2.0 * math.pi / 200.0, gt=0.0, le=MAX_WAVENUMBER, description="Smallest wavenumber (rad/m).")
    k_max: float = Field(2.0 * math.pi / 10.0, gt=0.0, le=MAX_WAVENUMBER, description="Largest wavenumber (rad/m).")
    spectrum: Literal["gaussian", "flat", "von_karman"] = "gaussian"
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Seed of numpy.random.default_rng.")

    @model_validator(mode="after")
    def _check_band(self) -> FluctuatingSpec:
        if not self.k_min < self.k_max:
            raise ValueError(f"k_min must be < k_max (got k_min={self.k_min}, k_max={self.k_max})")
        depth, base = 1, self.base
        while isinstance(base, FluctuatingSpec):
            depth, base = depth + 1, base.base
        if depth > MAX_PROFILE_NESTING:
            raise ValueError(f"fluctuating profiles nest {depth} deep; at most {MAX_PROFILE_NESTING}")
        return self


def _check_rows(name: str, values: list[float] | None) -> list[float] | None:
    if values is not None and len(values) < 2:
        raise ValueError(f"{name} needs at least 2 rows, got {len(values)}")
    return values


class TableSpec(_RefSpec):
    """Stratified table c(z): ``z`` plus exactly one of ``c``, ``temperature_k``, ``temperature_c``."""

    kind: Literal["table"] = "table"
    z: list[Coord] = Field(max_length=MAX_TABLE_ROWS, description="Heights (m), strictly increasing, at least 2 rows.")
    c: list[_Finite] | None = Field(None, max_length=MAX_TABLE_ROWS, description="Sound speed per row (m/s).")
    temperature_k: list[_Finite] | None = Field(None, max_length=MAX_TABLE_ROWS, description="Temperature per row (K).")
    temperature_c: list[_Finite] | None = Field(
        None, max_length=MAX_TABLE_ROWS, description="Temperature per row (deg C)."
    )
    interpolation: Literal["linear", "pchip"] = "pchip"

    @field_validator("z")
    @classmethod
    def _z_increasing(cls, v: list[float]) -> list[float]:
        _check_rows("z", v)
        if any(b <= a for a, b in zip(v[:-1], v[1:], strict=True)):
            raise ValueError("z must be strictly increasing")
        return v

    @field_validator("c")
    @classmethod
    def _c_positive(cls, v: list[float] | None) -> list[float] | None:
        _check_rows("c", v)
        if v is not None and any(x <= 0.0 for x in v):
            raise ValueError("c must be > 0 in every row")
        return v

    @field_validator("temperature_k")
    @classmethod
    def _tk_positive(cls, v: list[float] | None) -> list[float] | None:
        _check_rows("temperature_k", v)
        if v is not None and any(x <= 0.0 for x in v):
            raise ValueError("temperature_k must be > 0 K in every row")
        return v

    @field_validator("temperature_c")
    @classmethod
    def _tc_above_zero_k(cls, v: list[float] | None) -> list[float] | None:
        _check_rows("temperature_c", v)
        if v is not None and any(x <= -273.15 for x in v):
            raise ValueError("temperature_c must be above -273.15 deg C in every row")
        return v

    @model_validator(mode="after")
    def _one_column(self) -> TableSpec:
        cols = {"c": self.c, "temperature_k": self.temperature_k, "temperature_c": self.temperature_c}
        given = [k for k, v in cols.items() if v is not None]
        if len(given) != 1:
            raise ValueError(
                "table needs exactly one of c, temperature_k, temperature_c; got "
                + (", ".join(given) if given else "none")
            )
        n = len(cols[given[0]] or [])
        if n != len(self.z):
            raise ValueError(f"{given[0]} has {n} rows but z has {len(self.z)}")
        return self


class GridSpec(_RefSpec):
    """3D regular grid of c: either ``path`` (.npz or .vti; relative to the job's base_dir) or the
    inline arrays ``origin`` (m), ``spacing`` (m) and ``c`` (nested lists, shape (nx, ny, nz), m/s)."""

    kind: Literal["grid"] = "grid"
    path: str | None = Field(
        None, min_length=1, max_length=255, description="Grid file (.npz or .vti), relative to the job file."
    )
    origin: Vec3 | None = Field(None, description="Position of node c[0][0][0] (m).")
    spacing: LengthVec3 | None = Field(None, description="Node spacing along x, y, z (m).")
    c: list[list[list[_Finite]]] | None = Field(
        None, max_length=MAX_GRID_NODES_PER_AXIS, description="Sound speed at the nodes (m/s)."
    )

    @field_validator("path")
    @classmethod
    def _path_suffix(cls, v: str | None) -> str | None:
        if v is not None and any(ord(ch) < 32 for ch in v):
            raise ValueError("path must not contain control characters (NUL, newline, ...)")
        if v is not None and Path(v).suffix.lower() not in (".npz", ".vti"):
            raise ValueError(f"path must end in .npz or .vti, got {v!r}")
        return v

    @field_validator("spacing")
    @classmethod
    def _spacing_positive(cls, v: Vec3 | None) -> Vec3 | None:
        if v is not None and any(h <= 0.0 for h in v):
            raise ValueError(f"spacing must be > 0 along every axis, got {list(v)}")
        return v

    @field_validator("c")
    @classmethod
    def _c_box(cls, v: list[list[list[float]]] | None) -> list[list[list[float]]] | None:
        if v is None:
            return v
        nx = len(v)
        ny = len(v[0]) if nx else 0
        nz = len(v[0][0]) if ny else 0
        if any(len(row) != ny for row in v) or any(len(col) != nz for row in v for col in row):
            raise ValueError("c must be a rectangular (nx, ny, nz) nested list")
        if min(nx, ny, nz) < 2:
            raise ValueError(f"c needs at least 2 points along every axis, got shape ({nx}, {ny}, {nz})")
        if max(ny, nz) > MAX_GRID_NODES_PER_AXIS or nx * ny * nz > MAX_INLINE_GRID_NODES:
            raise ValueError(
                f"c has shape ({nx}, {ny}, {nz}); inline grids allow {MAX_GRID_NODES_PER_AXIS} nodes per axis and "
                f"{MAX_INLINE_GRID_NODES:,} in all (give a .npz file for more)"
            )
        if any(x <= 0.0 for row in v for col in row for x in col):
            raise ValueError("c must be > 0 everywhere")
        return v

    @model_validator(mode="after")
    def _path_or_arrays(self) -> GridSpec:
        arrays = {"origin": self.origin, "spacing": self.spacing, "c": self.c}
        if self.path is not None:
            extra = [k for k, v in arrays.items() if v is not None]
            if extra:
                raise ValueError(f"grid: give either path or origin/spacing/c, not both (also got {extra})")
        else:
            missing = [k for k, v in arrays.items() if v is None]
            if missing:
                raise ValueError(f"grid needs path, or all of origin, spacing, c (missing {missing})")
        return self


ProfileSpec = Annotated[
    HomogeneousSpec
    | LinearCSpec
    | LinearNSpec
    | LinearN2Spec
    | LogSpec
    | MirageInferiorSpec
    | MirageSuperiorSpec
    | HotSpotSpec
    | FluctuatingSpec
    | TableSpec
    | GridSpec,
    Field(discriminator="kind"),
]

FluctuatingSpec.model_rebuild()

PROFILE_SPEC_ADAPTER: TypeAdapter[Any] = TypeAdapter(ProfileSpec)


def profile_from_spec(spec: Any, base_dir: str | Path | None = None) -> Profile:
    """Engine profile from a validated spec model (or a plain dict, validated here).

    Relative grid paths are resolved against ``base_dir`` (normally the job file's folder; the current
    directory when None). Nested ``fluctuating`` bases are built recursively.
    """
    if isinstance(spec, dict):
        spec = PROFILE_SPEC_ADAPTER.validate_python(spec)
    if not isinstance(spec, _ProfileSpecBase):
        raise TypeError(f"expected a profile spec model or dict, got {type(spec).__name__}")
    if isinstance(spec, FluctuatingSpec):
        params = spec.model_dump(exclude={"kind", "base"})
        return build_profile("fluctuating", base=profile_from_spec(spec.base, base_dir), **params)
    if isinstance(spec, GridSpec):
        if spec.path is not None:
            path = Path(spec.path)
            if not path.is_absolute() and base_dir is not None:
                path = Path(base_dir) / path
            return build_profile("grid", path=str(path), c_ref=spec.c_ref)
        return build_profile("grid", origin=spec.origin, spacing=spec.spacing, c=spec.c, c_ref=spec.c_ref)
    params = spec.model_dump()
    kind = str(params.pop("kind"))  # every concrete spec has its Literal kind (the base declares none)
    if isinstance(spec, TableSpec):
        params = {k: v for k, v in params.items() if v is not None}
    return build_profile(kind, **params)
