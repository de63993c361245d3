"""Source directivity: a per-band table of level differences over directions around an axis.

``sources[i].directivity``::

    {"axis": [1, 0, 0],             # the 0-degree direction (world frame; normalised), default +z
     "reference": [0, 0, 1],        # azimuth 0 about the axis (optional; projected perpendicular to it)
     "polar_deg": [0, 45, 90, 135, 180],
     "azimuth_deg": [0, 90, 180, 270],       # optional: omitted = symmetric about the axis
     "levels_db": {"500": [0, -1, -3, -6, -10], ...}}   # (n_polar,) or (n_azimuth, n_polar) per band

``levels_db`` are the level differences Delta L(theta, phi) in dB that the source radiates in each
direction relative to an omnidirectional source of the same ``power_db`` (the Delta L_W,dir of CNOSSOS-EU
2.2.2 / ISO 9613-2's D_c); between the given angles they are interpolated linearly in dB (azimuth
periodically). The table is applied as given: bentray does not renormalise it to conserve power, and the
report gives the power change it implies per band (10 lg of the mean of 10^(Delta L / 10) over the
sphere), so a table that is not power-normalised is visible. Every band of the field (or receivers) must
be in the table.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["MAX_DIRECTIVITY_ANGLES", "DirectivitySpec", "launch_direction", "ray_amplitudes"]

MAX_DIRECTIVITY_ANGLES = 361  # per axis of the table (1-degree steps around a full turn)
_MAX_DB = 100.0  # |Delta L| beyond this is a unit mistake, not a loudspeaker


class DirectivitySpec(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    reference: tuple[float, float, float] | None = None
    polar_deg: list[float] = Field(min_length=2, max_length=MAX_DIRECTIVITY_ANGLES)
    azimuth_deg: list[float] | None = Field(default=None, min_length=2, max_length=MAX_DIRECTIVITY_ANGLES)
    levels_db: dict[str, list[float] | list[list[float]]] = Field(min_length=1, max_length=64)

    @model_validator(mode="after")
    def _check_table(self) -> DirectivitySpec:
        a = np.asarray(self.axis, float)
        if not np.linalg.norm(a) > 1e-9:
            raise ValueError("axis must be a non-zero vector")
        pol = np.asarray(self.polar_deg, float)
        if pol[0] != 0.0 or pol[-1] != 180.0 or np.any(np.diff(pol) <= 0):
            raise ValueError("polar_deg must increase strictly from 0 to 180 degrees")
        n_az = None
        if self.azimuth_deg is not None:
            az = np.asarray(self.azimuth_deg, float)
            if az[0] < 0.0 or az[-1] >= 360.0 or np.any(np.diff(az) <= 0):
                raise ValueError("azimuth_deg must increase strictly within [0, 360) degrees")
            n_az = az.size
            if self.reference is not None:
                r = np.asarray(self.reference, float)
                perp = r - a * (r @ a) / (a @ a)
                if not float(np.linalg.norm(perp)) > 1e-9 * max(float(np.linalg.norm(r)), 1.0):
                    raise ValueError("reference must not be parallel to the axis")
        for band, table in self.levels_db.items():
            arr = np.asarray(table, float)
            want = (pol.size,) if n_az is None else (n_az, pol.size)
            if arr.shape != want:
                raise ValueError(
                    f"levels_db[{band!r}] has shape {list(arr.shape)}; expected {list(want)} "
                    + ("(one value per polar angle)" if n_az is None else "(azimuths x polar angles)")
                )
            if not np.all(np.abs(arr) <= _MAX_DB):
                raise ValueError(f"levels_db[{band!r}] must lie within +-{_MAX_DB:g} dB")
        return self

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(axis, e1, e2): unit axis and two unit vectors perpendicular to it (azimuth 0 along e1)."""
        a = np.asarray(self.axis, float)
        a = a / np.linalg.norm(a)
        if self.reference is not None:
            r = np.asarray(self.reference, float)
        else:
            r = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = r - a * (r @ a)
        e1 /= np.linalg.norm(e1)
        return a, e1, np.cross(a, e1)

    def level_db(self, band: str, directions: np.ndarray) -> np.ndarray:
        """Delta L (dB) of ``band`` toward each of ``directions`` ((n, 3), world frame, any length)."""
        d = np.asarray(directions, float)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        a, e1, e2 = self.frame()
        polar = np.degrees(np.arccos(np.clip(d @ a, -1.0, 1.0)))
        table = np.asarray(self.levels_db[band], float)
        pol = np.asarray(self.polar_deg, float)
        if self.azimuth_deg is None:
            return np.asarray(np.interp(polar, pol, table), float)
        az = np.degrees(np.arctan2(d @ e2, d @ e1)) % 360.0
        azs = np.asarray(self.azimuth_deg, float)
        # periodic in azimuth: extend the table by the first azimuth + 360
        az_ext = np.concatenate([azs, [azs[0] + 360.0]])
        tab_ext = np.concatenate([table, table[:1]], axis=0)
        az = np.where(az < azs[0], az + 360.0, az)
        j = np.clip(np.searchsorted(az_ext, az, side="right") - 1, 0, azs.size - 1)
        t = (az - az_ext[j]) / (az_ext[j + 1] - az_ext[j])
        i = np.clip(np.searchsorted(pol, polar, side="right") - 1, 0, pol.size - 2)
        u = np.clip((polar - pol[i]) / (pol[i + 1] - pol[i]), 0.0, 1.0)
        lo = (1.0 - u) * tab_ext[j, i] + u * tab_ext[j, i + 1]
        hi = (1.0 - u) * tab_ext[j + 1, i] + u * tab_ext[j + 1, i + 1]
        return np.asarray((1.0 - t) * lo + t * hi, float)

    def power_change_db(self, band: str, n: int = 181) -> float:
        """10 lg of the mean of 10^(Delta L / 10) over the sphere (0: the table conserves power)."""
        th = np.linspace(0.0, math.pi, n)
        ph = np.linspace(0.0, 2.0 * math.pi, 2 * n)
        t, p = np.meshgrid(th, ph, indexing="ij")
        a, e1, e2 = self.frame()
        dirs = (
            np.cos(t)[..., None] * a + (np.sin(t) * np.cos(p))[..., None] * e1 + (np.sin(t) * np.sin(p))[..., None] * e2
        )
        lin = 10.0 ** (self.level_db(band, dirs.reshape(-1, 3)).reshape(t.shape) / 10.0)
        w = np.sin(t)
        return float(10.0 * math.log10(np.trapezoid(np.trapezoid(lin * w, ph, axis=1), th) / (4.0 * math.pi)))


def ray_amplitudes(spec: DirectivitySpec | None, labels: list[str], directions: np.ndarray) -> np.ndarray:
    """(n, F) pressure-amplitude factors 10^(Delta L / 20) of the launch ``directions`` (n, 3) per band
    label (ones when ``spec`` is None: an omnidirectional source)."""
    d = np.asarray(directions, float).reshape(-1, 3)
    if spec is None:
        return np.ones((d.shape[0], len(labels)))
    return (
        np.column_stack([10.0 ** (spec.level_db(b, d) / 20.0) for b in labels]) if labels else np.ones((d.shape[0], 0))
    )


def launch_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """(1, 3) unit launch direction (elevation above the horizontal, azimuth counter-clockwise from +x)."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([[math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]])
