"""The job contract: one pydantic v2 model tree for a ray-tracing job (file, CLI and HTTP alike).

Units: metres, seconds, degrees (angles carry ``_deg``), Pa s/m^2 for flow resistivity.
Every model forbids unknown keys and rejects NaN/inf. Validators only check; they never rewrite
input values (derived values are properties, e.g. :attr:`Solver.effective_sizing`).

Entry points: :func:`load_job` (JSON file -> :class:`Job`), :func:`parse_job_text` (JSON text -> Job)
and :func:`format_validation_error` (pydantic error -> ``field.path: reason`` lines, the text of the
CLI's exit-2 message and of the service's HTTP 422 body).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_serializer,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from bentray.engine.errors import BentrayError
from bentray.scenes.bounds import MAX_LENGTH_M, MIN_LENGTH_M, Coord, Vec3
from bentray.scenes.camera_models import Camera
from bentray.scenes.condition_models import (
    MAX_CONDITIONS,
    MAX_EMISSION_GROUPS,
    Condition,
    PeriodOffsets,
    Periods,
    occurrence_errors,
)
from bentray.scenes.crs import crs_errors
from bentray.scenes.directivity_models import DirectivitySpec
from bentray.scenes.field_models import MAX_COHERENT_FIELD_POINTS, FieldSpec
from bentray.scenes.ground_zones import GroundZonesSpec
from bentray.scenes.library.registry import BUILTIN_SCENES as _REGISTRY
from bentray.scenes.profile_models import ProfileSpec
from bentray.scenes.receiver_models import (
    AUTO_EIGENRAY_PAIRS,
    MAX_EIGENRAY_PAIRS,
    MAX_RECEIVERS,
    EigenraySpec,
    Receiver,
)
from bentray.scenes.scene_models import BuildingsSpec, MaterialSpec, TerrainSpec, material_reference_errors
from bentray.scenes.turbulence_models import TurbulenceSpec
from bentray.scenes.wind_models import WindSpec

__all__ = [
    "BUILTIN_SCENES",
    "MAX_TOTAL_RAYS",
    "AngleRange",
    "Domain",
    "ElevationRange",
    "Ground",
    "Job",
    "JobFileError",
    "Rays",
    "Scene",
    "Solver",
    "Source",
    "Top",
    "format_validation_error",
    "load_job",
    "parse_job_json",
    "parse_job_text",
]

# Limits (each one says what it protects against).
MAX_DOMAIN_EXTENT_M = 1.0e6  # 1000 km: beyond any outdoor-acoustics scene; catches unit mistakes (mm, km)
MIN_DOMAIN_EXTENT_M = 1.0e-3  # 1 mm: a thinner box cannot be meshed meaningfully
BASELINE_CURVES = ("euler", "euler_adaptive", "rk4", "dopri5")
# Rays per trace batch (the unit of progress, of scale-out tasks and of the field's summation order).
# Measured (engine/bench/scaling_dask.py): a batch costs 1-2 ms locally and 5-27 ms on Dask beyond its rays
# (+ ~0.2 s per 1e6 field points x 8 bands); 10,000 rays keep that under 1 % for rays of >= 0.3 ms while a
# 100k-ray job still spreads over 10 tasks and a batch's sampled paths stay ~160 MB (50,000: 800 MB).
DEFAULT_BATCH_RAYS = 10_000
MAX_TOTAL_RAYS = 10_000_000  # sources x elevations x azimuths; keeps one job's arrays to a few GB
MAX_SOURCES = 10_000
MAX_TIME_S = 3600.0
MAX_REFLECTIONS = 100_000
MAX_STEPS = 1_000_000_000  # cell crossings per ray (a ray that needs more is stuck)
MAX_PATH_SAMPLES = 10_000  # samples per recorded ray path (each costs ~100 B per ray in memory)
MAX_ANGLE_DEG = 3600.0  # azimuths are periodic; ten turns is more than any fan needs
MAX_POWER_DB = 250.0  # sound power level re 1 pW (a rocket launch is ~200 dB)
MAX_JSON_DEPTH = 64  # nesting of the job JSON (the deepest valid job is ~10 levels)
MAX_JSON_INT_DIGITS = 100  # digits of one JSON integer (no valid field needs more than 20)
BUILTIN_SCENES: tuple[str, ...] = tuple(_REGISTRY)
_NAME_RE = r"^[A-Za-z0-9._-]{1,100}$"


class JobFileError(BentrayError, ValueError):
    """A job file that cannot be read or is not valid JSON (schema errors raise ValidationError)."""


def _fail(errors: list[tuple[tuple[str | int, ...], str, Any]], title: str) -> None:
    """Raise a ValidationError whose entries sit at the given field locations (relative to the model).

    Raised inside a validator, pydantic prefixes the locations with the model's own location, so
    ``sources.0.position`` checked in :class:`Job` still names the offending field.
    """
    line_errors = [
        {
            "type": PydanticCustomError("value_error", "{reason}", {"reason": reason}),
            "loc": loc,
            "input": value,
        }
        for loc, reason, value in errors
    ]
    raise ValidationError.from_exception_data(title=title, line_errors=line_errors)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


_AXES = ("x", "y", "z")


# ---------------------------------------------------------------------------------------------
# Scene
# ---------------------------------------------------------------------------------------------
class Domain(_Model):
    """Axis-aligned box ``[min, max]`` in metres; z is up and ``min[2]`` is the flat ground height."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _check_box(self) -> Domain:
        errors = []
        for axis, (lo, hi) in enumerate(zip(self.min, self.max, strict=True)):
            name = _AXES[axis]
            extent = hi - lo
            if hi <= lo:
                errors.append((("max", axis), f"max {name} ({hi:g}) must be greater than min {name} ({lo:g})", hi))
            elif not MIN_DOMAIN_EXTENT_M <= extent <= MAX_DOMAIN_EXTENT_M:
                errors.append(
                    (
                        ("max", axis),
                        f"domain extent along {name} is {extent:g} m; allowed range is "
                        f"{MIN_DOMAIN_EXTENT_M:g} m to {MAX_DOMAIN_EXTENT_M:g} m",
                        hi,
                    )
                )
        if errors:
            _fail(errors, "Domain")
        return self

    @property
    def extent(self) -> np.ndarray:
        return np.asarray(self.max, dtype=np.float64) - np.asarray(self.min, dtype=np.float64)

    def contains(self, point: Vec3) -> bool:
        """Strictly inside the box (a point on a face is ambiguous for the ray's start cell)."""
        return all(lo < p < hi for p, lo, hi in zip(point, self.min, self.max, strict=True))


class Ground(_Model):
    """The domain's bottom face. ``flow_resistivity`` in Pa s/m^2 (> 0); None means acoustically rigid."""

    kind: Literal["flat"] = "flat"
    flow_resistivity: float | None = Field(default=None, gt=0, le=1e12)


class Top(_Model):
    """The domain's top face: rays leave through an open top or reflect specularly."""

    kind: Literal["open", "reflect"] = "open"


class Scene(_Model):
    """The solid world: a domain box, flat ground or terrain, buildings/barriers, ground materials.

    ``builtin`` names a generated scene (``bentray scenes`` lists them) that brings its own domain,
    terrain, buildings and materials; ``domain`` may then be omitted (or given to crop it). Otherwise
    ``domain`` is required and ``terrain`` / ``buildings`` / ``materials`` are optional.
    ``ground.flow_resistivity`` is the material of flat ground; terrain uses ``terrain.material``.
    """

    domain: Domain | None = None
    ground: Ground = Field(default_factory=Ground)
    top: Top = Field(default_factory=Top)
    builtin: str | None = None
    resolution: Literal["medium", "high"] = "medium"
    terrain: TerrainSpec | None = None
    buildings: BuildingsSpec | None = None
    # ground materials by plan-view zone (scenes/ground_zones.py): flow resistivity, CNOSSOS G or a material
    ground_zones: GroundZonesSpec | None = None
    # projected CRS of every plan coordinate (EPSG code or WKT); the engine works relative to local_origin
    # (default: the domain's lower-left corner rounded down to 1 km), see scenes/gis_frame.py
    crs: int | str | None = None
    local_origin: tuple[float, float] | None = None
    materials: list[MaterialSpec] = Field(default_factory=list, max_length=256)
    # "above_ground": the profile's z is the height above the local ground (terrain, or the domain
    # bottom); "absolute": world z (the paper's c(z); keep domain.min z at 0 for stratified laws)
    profile_heights: Literal["above_ground", "absolute"] = "above_ground"

    @field_validator("builtin")
    @classmethod
    def _known_builtin(cls, value: str | None) -> str | None:
        if value is not None and value not in BUILTIN_SCENES:
            raise ValueError(f"unknown builtin scene {value!r}; known scenes: {', '.join(BUILTIN_SCENES)}")
        return value

    @model_validator(mode="after")
    def _check_scene(self) -> Scene:
        errors: list[tuple[tuple[str | int, ...], str, Any]] = []
        if self.builtin is None and self.domain is None:
            errors.append((("domain",), "a domain is required unless the scene is builtin", None))
        if self.builtin is not None:
            for key in ("terrain", "buildings", "ground_zones"):
                if getattr(self, key) is not None:
                    errors.append(
                        ((key,), f"builtin scene {self.builtin!r} brings its own {key}; remove one of them", None)
                    )
        errors.extend((loc, why, None) for loc, why in crs_errors(self.crs, self.local_origin, self.builtin))
        if self.terrain is not None and self.ground.flow_resistivity is not None:
            errors.append(
                (
                    ("ground", "flow_resistivity"),
                    "with terrain, give the ground material as scene.terrain.material (defined in scene.materials)",
                    self.ground.flow_resistivity,
                )
            )
        errors.extend(
            (loc, reason, None)
            for loc, reason in material_reference_errors(self.terrain, self.buildings, self.materials)
        )
        files: list[tuple[tuple[str | int, ...], str | None]] = []
        if self.terrain is not None:
            files.append((("terrain", "file"), self.terrain.file))
        if self.buildings is not None:
            files.append((("buildings", "file"), self.buildings.file))
            files += [(("buildings", "obstacles", i, "file"), ob.file) for i, ob in enumerate(self.buildings.obstacles)]
        for loc, name in files:
            if name is not None and (len(name) > 255 or any(ord(ch) < 32 for ch in name)):
                errors.append(
                    (loc, "a file name of at most 255 characters without control characters (NUL, ...)", name)
                )
        if errors:
            _fail(errors, "Scene")
        return self

    @property
    def box(self) -> Domain:
        """The effective domain: ``domain`` if given, else the builtin scene's."""
        if self.domain is not None:
            return self.domain
        assert self.builtin is not None
        scene = _builtin(self.builtin, self.resolution)
        return Domain(min=scene.domain_min, max=scene.domain_max)

    @property
    def has_surfaces(self) -> bool:
        """True when the scene has terrain, buildings or a builtin with surfaces (a conforming mesh)."""
        if self.terrain is not None or self.buildings is not None or self.ground_zones is not None:
            return True
        if self.builtin is not None:
            surf = _builtin(self.builtin, self.resolution).surfaces
            return surf.terrain is not None or bool(surf.footprints) or bool(surf.obstacles)
        return False


@functools.lru_cache(maxsize=16)
def _builtin(name: str, resolution: str):
    from bentray.scenes.library.registry import get_builtin

    return get_builtin(name, resolution)


# ---------------------------------------------------------------------------------------------
# Sources and rays
# ---------------------------------------------------------------------------------------------
class Source(_Model):
    """Point source. ``power_db``: optional sound power level per band label (dB re 1 pW).

    ``position`` [x, y, z] (absolute z, metres) or [x, y] with ``height_above_ground_m`` (exactly one of the
    two; the z is resolved against the terrain, or the flat ground, when the job is prepared)."""

    position: tuple[Coord, ...] = Field(min_length=2, max_length=3)  # [x, y, z] or [x, y]
    height_above_ground_m: float | None = Field(default=None, gt=0, lt=10_000)
    power_db: dict[str, Annotated[float, Field(ge=-MAX_POWER_DB, le=MAX_POWER_DB)]] | None = Field(
        default=None, max_length=64
    )
    name: str | None = Field(default=None, max_length=100)
    period_offsets_db: PeriodOffsets | None = None  # emission per period re power_db (jobs with conditions)
    directivity: DirectivitySpec | None = None  # level differences over directions (scenes/directivity_models.py)

    @model_validator(mode="after")
    def _one_height(self) -> Source:
        if (len(self.position) == 3) == (self.height_above_ground_m is not None):
            raise ValueError(
                "give position [x, y, z] (absolute z) or position [x, y] with height_above_ground_m (exactly one)"
            )
        return self


class AngleRange(_Model):
    """``count`` evenly spaced angles from ``min`` to ``max`` inclusive, in degrees."""

    min: float = Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)
    max: float = Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)
    count: int = Field(ge=1, le=10**12)  # the product is checked against MAX_TOTAL_RAYS

    @model_validator(mode="after")
    def _check_range(self) -> AngleRange:
        if self.count == 1 and self.min != self.max:
            _fail(
                [
                    (
                        ("max",),
                        f"count is 1, so min and max must be equal (got min={self.min:g}, max={self.max:g}); "
                        "use count >= 2 for a range",
                        self.max,
                    )
                ],
                type(self).__name__,
            )
        if self.count > 1 and not self.max > self.min:
            _fail(
                [
                    (
                        ("max",),
                        f"with count={self.count}, max ({self.max:g}) must be greater than min ({self.min:g})",
                        self.max,
                    )
                ],
                type(self).__name__,
            )
        return self

    def values(self) -> np.ndarray:
        """The angles in degrees, float64, shape (count,)."""
        return np.linspace(self.min, self.max, self.count, dtype=np.float64)


class ElevationRange(AngleRange):
    """Elevation angles above the horizontal, within [-90, 90] degrees."""

    min: float = Field(ge=-90.0, le=90.0)
    max: float = Field(ge=-90.0, le=90.0)


def _single_azimuth() -> AngleRange:
    return AngleRange(min=0.0, max=0.0, count=1)


class Rays(_Model):
    """Launch fan (per source) and per-ray stopping limits."""

    elevation_deg: ElevationRange
    azimuth_deg: AngleRange = Field(default_factory=_single_azimuth)
    max_time_s: float = Field(gt=0, le=MAX_TIME_S)
    max_reflections: int = Field(ge=0, le=MAX_REFLECTIONS)
    max_steps: int = Field(default=10_000_000, ge=1, le=MAX_STEPS)
    # None: record sampled paths when 'paths' is an output, or for 'rays' when the job has at most
    # DEFAULT_PATH_RAYS rays (engine.run._wants_paths); true / false: always / never
    record_paths: bool | None = None

    @property
    def rays_per_source(self) -> int:
        return self.elevation_deg.count * self.azimuth_deg.count


# ---------------------------------------------------------------------------------------------
# Solver
# ---------------------------------------------------------------------------------------------
class Solver(_Model):
    """How the medium is represented and meshed, and which analytic curve the rays follow.

    ``sizing``: "curvature" (relative tolerance ``delta``) or "gradient" (the paper's rule with
    parameter ``epsilon``). Giving ``epsilon`` without ``sizing`` selects the gradient rule; read
    :attr:`effective_sizing`, not ``sizing``. Serialisation writes the effective rule as ``sizing``
    so a dumped job reloads with the same meaning (the reloaded model then stores ``sizing`` =
    "gradient" explicitly, so compare solvers by dump or by ``effective_sizing``, not with ``==``).
    """

    curve: Literal["parabolic", "circular", "n_linear", "euler", "euler_adaptive", "rk4", "dopri5"] = "parabolic"
    representation: Literal["auto", "uniform", "slabs", "tets"] = "auto"
    sizing: Literal["curvature", "gradient"] = "curvature"
    # sizing tolerances: below 1e-12 the layers are rounding noise; above 1 (epsilon: 10) no refinement
    epsilon: float | None = Field(default=None, ge=1e-12, le=10.0)
    delta: float | None = Field(default=None, ge=1e-12, le=1.0)
    d_min_m: float | None = Field(default=None, ge=MIN_LENGTH_M, le=MAX_LENGTH_M)
    d_max_m: float | None = Field(default=None, ge=MIN_LENGTH_M, le=MAX_LENGTH_M)
    gradient: Literal["lsq", "green_gauss"] = "lsq"
    path_samples: int = Field(default=400, ge=2, le=MAX_PATH_SAMPLES)
    # numerical baselines (engine/baselines): fixed step / first step in metres of arc, local error
    # tolerance of the adaptive ones, and the media they integrate (the mesh's linear model, or the
    # closed-form profile)
    step_m: float | None = Field(default=None, ge=MIN_LENGTH_M, le=1e5)
    tolerance: float | None = Field(default=None, ge=1e-14, lt=1)
    media: Literal["mesh", "exact"] | None = None
    batch_rays: int = Field(default=DEFAULT_BATCH_RAYS, ge=1, le=MAX_TOTAL_RAYS)
    # where the analytic traversal runs: "cuda" needs numba-cuda and a device (the gpu extra), "auto" picks
    # cuda when a device is present and the job is large enough (engine/gpu/device.py, AUTO_MIN_RAYS)
    device: Literal["cpu", "cuda", "auto"] = "cpu"

    @property
    def is_baseline(self) -> bool:
        """True for the numerical integrators (euler, euler_adaptive, rk4, dopri5)."""
        return self.curve in BASELINE_CURVES

    @property
    def mesh_curve(self) -> str:
        """The analytic curve whose traced quantity the media mesh carries (baselines: parabolic, n^2)."""
        return "parabolic" if self.is_baseline else self.curve

    @property
    def effective_sizing(self) -> Literal["curvature", "gradient"]:
        if self.epsilon is not None and "sizing" not in self.model_fields_set:
            return "gradient"
        return self.sizing

    @field_serializer("sizing")
    def _serialize_sizing(self, value: str) -> str:
        return self.effective_sizing

    @model_validator(mode="after")
    def _check_consistency(self) -> Solver:
        errors = []
        sizing = self.effective_sizing
        if sizing == "curvature" and self.epsilon is not None:
            errors.append(
                (
                    ("epsilon",),
                    "epsilon is the gradient rule's parameter but sizing is 'curvature'; "
                    "use delta with sizing 'curvature', or set sizing to 'gradient'",
                    self.epsilon,
                )
            )
        if sizing == "gradient" and self.delta is not None:
            errors.append(
                (
                    ("delta",),
                    "delta is the curvature rule's tolerance but sizing is 'gradient'; "
                    "use epsilon with sizing 'gradient', or set sizing to 'curvature'",
                    self.delta,
                )
            )
        if not self.is_baseline:
            for key in ("step_m", "tolerance", "media"):
                if getattr(self, key) is not None:
                    errors.append(
                        (
                            (key,),
                            f"{key} applies to the numerical baselines "
                            f"({', '.join(BASELINE_CURVES)}), not to curve {self.curve!r}",
                            getattr(self, key),
                        )
                    )
        elif self.tolerance is not None and self.curve not in ("euler_adaptive", "dopri5"):
            errors.append(
                (
                    ("tolerance",),
                    f"{self.curve} takes fixed steps (step_m); tolerance applies to euler_adaptive and dopri5",
                    self.tolerance,
                )
            )
        if self.d_min_m is not None and self.d_max_m is not None and self.d_min_m > self.d_max_m:
            errors.append(
                (
                    ("d_max_m",),
                    f"d_max_m ({self.d_max_m:g}) must be greater than or equal to d_min_m ({self.d_min_m:g})",
                    self.d_max_m,
                )
            )
        if errors:
            _fail(errors, "Solver")
        return self


# ---------------------------------------------------------------------------------------------
# Job
# ---------------------------------------------------------------------------------------------
OutputName = Literal["rays", "paths", "mesh", "report", "field"]


class Job(_Model):
    name: str = Field(pattern=_NAME_RE)
    scene: Scene
    profile: ProfileSpec
    wind: WindSpec | None = None
    turbulence: TurbulenceSpec | None = None  # scattering into refractive shadows; off by default
    sources: list[Source] = Field(min_length=1, max_length=MAX_SOURCES)
    rays: Rays
    solver: Solver = Field(default_factory=Solver)
    outputs: list[OutputName] = Field(default_factory=lambda: ["rays", "report"], min_length=1, max_length=16)
    field: FieldSpec | None = None
    receivers: list[Receiver] = Field(default_factory=list, max_length=MAX_RECEIVERS)
    eigenrays: EigenraySpec = Field(default_factory=EigenraySpec)
    conditions: list[Condition] = Field(default_factory=list, max_length=MAX_CONDITIONS)
    periods: Periods = Field(default_factory=Periods)
    camera: Camera | None = None  # bentray render: a pinhole camera through the media mesh (camera_models.py)

    @field_validator("name")
    @classmethod
    def _not_only_dots(cls, value: str) -> str:
        if set(value) == {"."}:
            raise ValueError("name must contain a letter, digit, '_' or '-' (not only dots)")
        return value

    @property
    def n_rays(self) -> int:
        """Total rays: sources x elevations x azimuths."""
        return len(self.sources) * self.rays.rays_per_source

    @model_validator(mode="after")
    def _check_job(self) -> Job:
        errors = []
        domain = self.scene.box
        for i, source in enumerate(self.sources):
            p = source.position
            if len(p) == 2:  # height above the ground: z resolved at job preparation
                p = (p[0], p[1], float(domain.min[2]) + float(source.height_above_ground_m or 0.0))
            if not p[2] > domain.min[2]:
                errors.append(
                    (
                        ("sources", i, "position"),
                        f"source z={p[2]:g} m is not above the ground (domain min z={domain.min[2]:g} m)",
                        p,
                    )
                )
            elif not domain.contains(p):
                errors.append(
                    (
                        ("sources", i, "position"),
                        f"source at ({p[0]:g}, {p[1]:g}, {p[2]:g}) is not strictly inside the domain "
                        f"[{', '.join(f'{v:g}' for v in domain.min)}] to "
                        f"[{', '.join(f'{v:g}' for v in domain.max)}]",
                        p,
                    )
                )
        seen: set[str] = set()
        for i, rec in enumerate(self.receivers):
            if rec.id in seen:
                errors.append((("receivers", i, "id"), f"receiver id {rec.id!r} is used twice", rec.id))
            seen.add(rec.id)
            x, y = rec.horizontal
            inside_xy = domain.min[0] < x < domain.max[0] and domain.min[1] < y < domain.max[1]
            where = "position" if rec.position is not None else "xy"
            if not inside_xy:
                errors.append(
                    (("receivers", i, where), f"receiver ({x:g}, {y:g}) is not inside the domain's x-y extent", None)
                )
            elif rec.position is not None and not (domain.min[2] < rec.position[2] < domain.max[2]):
                errors.append(
                    (
                        ("receivers", i, "position"),
                        f"receiver z={rec.position[2]:g} m is outside the domain's z range "
                        f"({domain.min[2]:g}, {domain.max[2]:g}) (at or below the ground, or above the top)",
                        None,
                    )
                )
        pairs = len(self.receivers) * len(self.sources)
        if self.eigenrays.enabled == "on" and pairs > MAX_EIGENRAY_PAIRS:
            errors.append(
                (
                    ("eigenrays", "enabled"),
                    f"an eigenray search for {pairs} source-receiver pairs is over the limit of "
                    f"{MAX_EIGENRAY_PAIRS}; use 'auto' (searches up to {AUTO_EIGENRAY_PAIRS} pairs) or fewer receivers",
                    self.eigenrays.enabled,
                )
            )
        if self.receivers and self.field is not None and self.field.method != "beams":
            errors.append(
                (
                    ("receivers",),
                    "receiver levels come from beams; field.method 'voxels' cannot give them in the same job",
                    None,
                )
            )
        if self.receivers and self.solver.is_baseline:
            errors.append(
                (
                    ("receivers",),
                    f"receiver levels use paraxial beams of the analytic curves (parabolic, circular, n_linear), "
                    f"not the numerical baseline solver.curve {self.solver.curve!r}",
                    None,
                )
            )
        if self.field is not None and self.field.wave_model == "on":
            from bentray.scenes.cost import wave_blockers

            for why in wave_blockers(self):
                errors.append((("field", "wave_model"), f"'on' cannot apply: {why}", self.field.wave_model))
        if self.field is not None and self.field.method == "beams" and self.solver.is_baseline:
            errors.append(
                (
                    ("field", "method"),
                    f"beam fields use the paraxial rays of the analytic curves; solver.curve is the numerical "
                    f"baseline {self.solver.curve!r} (use field.method 'voxels' or an analytic curve)",
                    None,
                )
            )
        n_rays = self.n_rays
        if n_rays > MAX_TOTAL_RAYS:
            errors.append(
                (
                    ("rays",),
                    f"{len(self.sources)} sources x {self.rays.elevation_deg.count} elevations x "
                    f"{self.rays.azimuth_deg.count} azimuths = {n_rays:,} rays; the limit is "
                    f"{MAX_TOTAL_RAYS:,} rays per job",
                    n_rays,
                )
            )
        errors.extend(self._field_errors())
        errors.extend(self._baseline_errors())
        errors.extend(self._condition_errors())
        errors.extend(self._directivity_errors())
        if errors:
            _fail(errors, "Job")
        return self

    def _directivity_errors(self) -> list[tuple[tuple[str | int, ...], str, Any]]:
        """A directivity table must cover every band the job computes; beams carry it (not voxels)."""
        errors: list[tuple[tuple[str | int, ...], str, Any]] = []
        for i, src in enumerate(self.sources):
            spec = src.directivity
            if spec is None:
                continue
            if self.field is not None and self.field.method != "beams":
                errors.append(
                    (
                        ("sources", i, "directivity"),
                        "directivity needs field.method 'beams' (voxels do not carry it)",
                        None,
                    )
                )
            if self.field is not None:
                labels = self.field.labels
            elif src.power_db is not None:
                labels = list(src.power_db)
            else:
                labels = []
            missing = [b for b in labels if b not in spec.levels_db]
            if missing:
                errors.append(
                    (
                        ("sources", i, "directivity", "levels_db"),
                        f"missing band(s) {', '.join(missing)} Hz of the job's bands; give a table per band",
                        None,
                    )
                )
        return errors

    def _condition_errors(self) -> list[tuple[tuple[str | int, ...], str, Any]]:
        """Conditions need levels to combine: sources with power_db and a field or receivers."""
        errors: list[tuple[tuple[str | int, ...], str, Any]] = []
        if not self.conditions:
            for i, src in enumerate(self.sources):
                if src.period_offsets_db is not None:
                    errors.append(
                        (
                            ("sources", i, "period_offsets_db"),
                            "per-period emission is combined over 'conditions'; this job lists none (give at least "
                            "one condition with its occurrences)",
                            None,
                        )
                    )
            return errors
        errors.extend(occurrence_errors(self.conditions))
        if any(src.power_db is None for src in self.sources):
            errors.append((("conditions",), "conditions combine sound levels: every source needs power_db", None))
        if self.field is None and not self.receivers:
            errors.append((("conditions",), "conditions combine levels of a field or of receivers; give one", None))
        if self.solver.is_baseline:
            errors.append((("conditions",), "numerical baselines give no levels; use an analytic curve", None))
        groups = {s.period_offsets_db.as_tuple() if s.period_offsets_db else (0.0, 0.0, 0.0) for s in self.sources}
        if len(groups) > MAX_EMISSION_GROUPS:
            errors.append(
                (
                    ("sources",),
                    f"{len(groups)} different period_offsets_db; at most {MAX_EMISSION_GROUPS} emission groups "
                    "per job (sources with the same offsets share one)",
                    None,
                )
            )
        return errors

    def _baseline_errors(self) -> list[tuple[tuple[str | int, ...], str, Any]]:
        """What the numerical baselines do not support (they are measured, not production, solvers)."""
        solver = self.solver
        if not solver.is_baseline:
            return []
        errors: list[tuple[tuple[str | int, ...], str, Any]] = []
        why = f"solver.curve {solver.curve!r} (a numerical baseline)"
        if self.wind is not None:
            errors.append((("wind",), f"{why} integrates the profile without wind; use an analytic curve", None))
        if self.field is not None:
            errors.append((("field",), f"{why} does not accumulate fields; use an analytic curve", None))
        if solver.media == "exact" and self.scene.has_surfaces:
            errors.append(
                (
                    ("solver", "media"),
                    "'exact' media know flat ground only; use 'mesh' with terrain or buildings",
                    solver.media,
                )
            )
        return errors

    def _field_errors(self) -> list[tuple[tuple[str | int, ...], str, Any]]:
        """Consistency of ``field`` with outputs, domain, fan and source powers."""
        errors: list[tuple[tuple[str | int, ...], str, Any]] = []
        spec = self.field
        powered = [i for i, src in enumerate(self.sources) if src.power_db is not None]
        if spec is None:
            if "field" in self.outputs:
                errors.append((("field",), "outputs include 'field' but no field grid is given", None))
            return errors
        if "field" not in self.outputs:
            errors.append((("outputs",), "a field grid is given but 'field' is not in outputs", self.outputs))
        domain = self.scene.box
        lo, hi = np.asarray(spec.origin, float), spec.upper_corner
        for axis, name in enumerate(_AXES):
            if lo[axis] < domain.min[axis] or hi[axis] > domain.max[axis]:
                errors.append(
                    (
                        ("field", "origin"),
                        f"grid spans {name} = {lo[axis]:g} .. {hi[axis]:g} m, outside the domain "
                        f"{domain.min[axis]:g} .. {domain.max[axis]:g} m",
                        spec.origin,
                    )
                )
        for key, rng in (("elevation_deg", self.rays.elevation_deg), ("azimuth_deg", self.rays.azimuth_deg)):
            # beams take a one-azimuth (vertical) fan; elevation always needs a step, voxels both
            if rng.count < 2 and (spec.method == "voxels" or key == "elevation_deg"):
                errors.append(
                    (
                        ("rays", key, "count"),
                        "a voxel field needs a 3D fan (count >= 2): each ray carries the power of its launch solid "
                        "angle; beams need at least 2 elevations",
                        rng.count,
                    )
                )
        if spec.mode == "coherent":
            if len(self.sources) != 1:
                errors.append(
                    (
                        ("field", "mode"),
                        "coherent mode sums the arrivals of one source; "
                        f"got {len(self.sources)} sources (use one job per source, or 'incoherent')",
                        spec.mode,
                    )
                )
            if spec.n_points > MAX_COHERENT_FIELD_POINTS:
                errors.append(
                    (
                        ("field", "shape"),
                        f"coherent mode allows at most {MAX_COHERENT_FIELD_POINTS:,} points (got {spec.n_points:,})",
                        spec.shape,
                    )
                )
        if powered and len(powered) != len(self.sources):
            i = next(i for i in range(len(self.sources)) if i not in powered)
            errors.append(
                (
                    ("sources", i, "power_db"),
                    "some sources give power_db and this one does not; give it for every source or none",
                    None,
                )
            )
        labels = spec.labels
        for i in powered:
            given = self.sources[i].power_db or {}
            missing = [b for b in labels if b not in given]
            extra = [b for b in given if b not in labels]
            if missing:
                errors.append(
                    (
                        ("sources", i, "power_db"),
                        f"missing band(s) {', '.join(missing)} Hz of field.frequencies_hz",
                        given,
                    )
                )
            if extra:
                errors.append(
                    (
                        ("sources", i, "power_db"),
                        f"band(s) {', '.join(extra)} are not in field.frequencies_hz ({', '.join(labels)})",
                        given,
                    )
                )
        return errors


# ---------------------------------------------------------------------------------------------
# Loading and error text
# ---------------------------------------------------------------------------------------------
def _no_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    result: dict[str, Any] = {}
    for key, value in pairs:
        if key in result:
            raise JobFileError(f"duplicate key {key!r} in a JSON object")
        result[key] = value
    return result


def _reject_constant(name: str) -> Any:
    raise JobFileError(f"{name} is not valid JSON (non-finite numbers are not allowed)")


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_JSON_INT_DIGITS:
        raise JobFileError(f"an integer of {digits:,} digits; no job field takes more than {MAX_JSON_INT_DIGITS}")
    return int(text)


def _json_depth_problem(data: Any) -> str | None:
    """Why ``data`` nests deeper than :data:`MAX_JSON_DEPTH` (iterative: no recursion), or None."""
    stack: list[tuple[Any, int]] = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, dict | list):
            if depth > MAX_JSON_DEPTH:
                return f"the JSON nests deeper than {MAX_JSON_DEPTH} levels"
            items = value.values() if isinstance(value, dict) else value
            stack.extend((item, depth + 1) for item in items)
    return None


def parse_job_json(text: str, origin: str = "<job>") -> Any:
    """The one JSON reader of jobs: text -> plain data, or :class:`JobFileError` with the reason.

    Refuses what :func:`json.loads` would accept but no job needs and what makes later stages fail
    or spin: duplicate keys, NaN/Infinity, integers of more than :data:`MAX_JSON_INT_DIGITS` digits,
    nesting deeper than :data:`MAX_JSON_DEPTH` (RecursionError included), NUL characters.
    """
    if not isinstance(text, str):
        raise JobFileError(f"{origin}: the job must be JSON text")
    try:
        data = json.loads(
            text, object_pairs_hook=_no_duplicate_keys, parse_constant=_reject_constant, parse_int=_bounded_int
        )
    except json.JSONDecodeError as exc:
        raise JobFileError(f"{origin}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except JobFileError as exc:
        raise JobFileError(f"{origin}: {exc}") from None
    except RecursionError:
        raise JobFileError(f"{origin}: the JSON nests deeper than {MAX_JSON_DEPTH} levels") from None
    except (ValueError, OverflowError, MemoryError) as exc:  # e.g. int digit limits of the json module
        raise JobFileError(f"{origin}: invalid JSON: {' '.join(str(exc).split())[:200]}") from None
    problem = _json_depth_problem(data)
    if problem is not None:
        raise JobFileError(f"{origin}: {problem}")
    return data


def parse_job_text(text: str, origin: str = "<job>") -> Job:
    """Parse JSON text into a :class:`Job`.

    Raises :class:`JobFileError` for invalid JSON (message with line and column, see
    :func:`parse_job_json`) and ``pydantic.ValidationError`` for a schema violation (render it with
    :func:`format_validation_error`).
    """
    data = parse_job_json(text, origin)
    try:
        return Job.model_validate(data)
    except RecursionError:  # pydantic's own guard normally answers first
        raise JobFileError(f"{origin}: the job nests too deeply") from None


def load_job(path: str | Path) -> Job:
    """Read and validate a job file (UTF-8 JSON); errors as in :func:`parse_job_text`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise JobFileError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise JobFileError(f"{path}: cannot read job file: {exc.strerror or exc}") from None
    return parse_job_text(text, origin=str(path))


def _format_loc(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(part) for part in loc) if loc else "job"


def format_validation_error(exc: ValidationError) -> str:
    """One ``field.path: reason`` line per error, e.g.
    ``rays.elevation_deg.count: Input should be greater than or equal to 1``.

    A pure function of the error (no trailing newline); a root-level error is reported as ``job``.
    Errors inside the discriminated ``profile`` union carry the matched kind, as pydantic reports
    them (``profile.log.c0: Input should be greater than 0``).
    """
    lines = []
    for error in exc.errors(include_url=False):
        message = error["msg"]
        if error["type"] == "value_error" and "error" in error.get("ctx", {}):
            message = str(error["ctx"]["error"])  # drop pydantic's "Value error, " prefix
        lines.append(f"{_format_loc(tuple(error['loc']))}: {message}")
    return "\n".join(lines)
