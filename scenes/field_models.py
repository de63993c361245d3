"""The ``field`` key of a job: the 3D grid where pressure / sound levels are accumulated.

Units: metres, hertz, percent, degrees Celsius, kilopascals. Grid values sit at grid points (VTK point
data); point (i, j, k) is at ``origin + (i, j, k) * spacing`` and owns the voxel of size ``spacing``
centred on it. A grid one point thick (e.g. shape [201, 1, 1]) is a receiver line.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from bentray.scenes.bounds import MAX_LENGTH_M, LengthVec3, Vec3

OCTAVE_BANDS_HZ: tuple[float, ...] = (63.0, 125.0, 250.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0)
# 50M points x 8 bands x 8 bytes x threads: a few GB at most; larger maps are split into tiles.
MAX_FIELD_POINTS = 50_000_000
# Coherent mode keeps 5 records per arrival group and point.
MAX_COHERENT_FIELD_POINTS = 5_000_000

_Count = Annotated[int, Field(ge=1, le=MAX_FIELD_POINTS)]


def band_label(frequency_hz: float) -> str:
    """Key of a band in ``power_db`` and in array names: '63', '1000', '31.5'."""
    return f"{frequency_hz:g}"


class FieldSpec(BaseModel):
    """Where and how to accumulate the field.

    ``mode``: "incoherent" (energy, noise maps; default) or "coherent" (complex pressure per
    frequency from arrival amplitudes and exact travel times; one source). ``humidity_percent``,
    ``temperature_c`` and ``pressure_kpa`` set ISO 9613-1 absorption (``absorption`` false: none).
    ``receiver_height_m``: height of the preview's horizontal slice above the ground.
    ``sample_fraction``: sub-interval length along the curves as a fraction of the smallest spacing
    (``method`` "voxels" only).
    ``method``: "beams" (default: geometric beams around paraxial rays, each ray's own spreading; modes
    coherent, incoherent, semicoherent) or "voxels" (the older ray-density estimate per voxel, kept as
    the bench's reference point; coherent and incoherent). ``chord_m``: beam chord length along the
    rays (default twice the smallest spacing within [1, 10] m); ``beam_min_width_m``: smallest beam
    half-width at caustics (default half a wavelength at the bands' geometric-mean frequency).
    ``incoherent_width``: beam widths of an incoherent map: "fresnel" (default) floors each beam's half-width
    at ``sqrt(lambda s / pi)``, the intensity half-width of the narrowest Gaussian beam that can reach arc
    length s (lambda of the highest band), returns the part spread below the ground through the ground's
    tangent plane, and keeps the amplitude factors (reflections, absorption) of the rays nearest each point:
    ray theory cannot place energy more finely, and where neighbouring rays no longer bound a tube (near-ground
    wind ducts) the map stays smooth (docs/physics.md §11); "tube": each ray's own tube (the coherent and
    semicoherent modes and the receivers always use it).
    ``heights``: "absolute" (world z) or "above_ground" (the map product: point (i, j, k) sits at
    ``origin_z + k * spacing_z`` above the ground under it, terrain included; beams only; field.vti then
    holds the grid in (x, y, height above ground)). ``refractive_shadow``: the creeping-wave stage
    (engine/shadow_stage.py): "auto" runs it when it needs at most SHADOW_AUTO_MAX_SOLVES mode solves
    (sources x bands x 5-degree azimuth bins with wind; each 0.3-10 s), "on" always, "off" never.
    ``wave_model``: the wave-field stage (engine/wave_stage.py: the wavenumber integral of the source column's
    profile at every point, exact for a range-independent scene, replacing the beams in its bands): "auto" runs
    it where it applies (flat ground of one material, no buildings, barriers, terrain or ground zones, a
    stratified profile, no wind or a log wind, omnidirectional sources, mode coherent or semicoherent) for the
    bands, lowest first, whose estimated cost fits scenes/cost.WAVE_AUTO_MAX_SECONDS; "on" for every band,
    refused (naming this field) where it cannot apply; "off": beams only. In mode "incoherent" (and for the
    receivers' incoherent columns) its band levels are band averages: the mean of |p|^2 over
    ``wave_band_points`` frequencies (Gauss nodes in ln f) across the ``wave_band`` ("octave", default, or
    "third_octave") centred on each frequency (docs/physics.md §18, "Band levels").
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    origin: Vec3
    spacing: LengthVec3
    shape: tuple[_Count, _Count, _Count]
    frequencies_hz: list[float] = Field(default_factory=lambda: list(OCTAVE_BANDS_HZ), min_length=1, max_length=64)
    mode: Literal["incoherent", "coherent", "semicoherent"] = "incoherent"
    method: Literal["beams", "voxels"] = "beams"
    heights: Literal["absolute", "above_ground"] = "absolute"
    chord_m: float | None = Field(default=None, ge=0.05, le=100.0)
    beam_min_width_m: float | None = Field(default=None, ge=1e-3, le=100.0)
    incoherent_width: Literal["fresnel", "tube"] = "fresnel"
    humidity_percent: float = Field(default=70.0, ge=0.0, le=100.0)
    temperature_c: float = Field(default=15.0, ge=-50.0, le=60.0)
    pressure_kpa: float = Field(default=101.325, gt=0.0, le=200.0)
    absorption: bool = True
    receiver_height_m: float = Field(default=4.0, ge=0.0, le=MAX_LENGTH_M)
    sample_fraction: float = Field(default=0.5, gt=0.0, le=2.0)
    refractive_shadow: Literal["auto", "on", "off"] = "auto"
    wave_model: Literal["auto", "on", "off"] = "auto"
    wave_band: Literal["octave", "third_octave"] = "octave"
    wave_band_points: int = Field(default=7, ge=1, le=31)

    @field_validator("spacing")
    @classmethod
    def _positive_spacing(cls, value: Vec3) -> Vec3:
        for axis, v in zip("xyz", value, strict=True):
            if not v > 0:
                raise ValueError(f"spacing along {axis} must be positive (got {v:g} m)")
        return value

    @field_validator("shape")
    @classmethod
    def _shape(cls, value: tuple[int, int, int]) -> tuple[int, int, int]:
        for axis, v in zip("xyz", value, strict=True):
            if v < 1:
                raise ValueError(f"shape along {axis} must be at least 1 (got {v})")
        n = math.prod(int(v) for v in value)  # Python ints: no int64 wrap-around
        if n > MAX_FIELD_POINTS:
            raise ValueError(
                f"{value[0]} x {value[1]} x {value[2]} = {n:,} points; the limit is "
                f"{MAX_FIELD_POINTS:,} per job (split the map into tiles)"
            )
        return value

    @model_validator(mode="after")
    def _method_modes(self) -> FieldSpec:
        if self.method == "voxels" and self.mode == "semicoherent":
            raise ValueError("mode 'semicoherent' needs method 'beams'")
        if self.method == "voxels" and self.heights == "above_ground":
            raise ValueError("heights 'above_ground' needs method 'beams'")
        return self

    @field_validator("frequencies_hz")
    @classmethod
    def _frequencies(cls, value: list[float]) -> list[float]:
        for f in value:
            if not 10.0 <= f <= 40_000.0:
                raise ValueError(f"frequency {f:g} Hz is outside 10 Hz .. 40 kHz")
        labels = [band_label(f) for f in value]
        if len(set(labels)) != len(labels):
            raise ValueError("frequencies must be distinct")
        return value

    @property
    def n_points(self) -> int:
        return math.prod(int(v) for v in self.shape)

    @property
    def labels(self) -> list[str]:
        return [band_label(f) for f in self.frequencies_hz]

    @property
    def upper_corner(self) -> np.ndarray:
        corner: np.ndarray = np.asarray(self.origin, float) + (np.asarray(self.shape) - 1) * np.asarray(
            self.spacing, float
        )
        return corner
