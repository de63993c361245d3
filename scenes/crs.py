"""Coordinate reference systems (pyproj) and the local frame the engine works in.

A scene's plan coordinates are metres of a *projected* CRS (``scene.crs``: an EPSG code such as 32632 or
``"EPSG:32632"``, or a WKT string). The engine works in metres near zero: :func:`choose_local_origin`
picks an offset (x0, y0) from the input's bounds, every plan coordinate is shifted by it before meshing
(x_local = x_crs - x0), and the outputs carry ``{"crs": WKT, "local_origin": [x0, y0]}`` back so the
exports can place them in the CRS again. Geographic CRSs (degrees) are refused: project the data first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bentray.scenes.gis_deps import require

__all__ = ["LOCAL_ORIGIN_STEP_M", "CrsError", "LocalFrame", "parse_crs", "choose_local_origin", "crs_errors"]

# The local origin is the input's lower-left corner rounded down to whole kilometres: local coordinates then
# lie in [0, extent + 1 km), small enough that float64 keeps ~1e-12 m resolution, and the offset is a round
# number a person can read back (500000, 5400000).
LOCAL_ORIGIN_STEP_M = 1000.0


class CrsError(ValueError):
    """``scene.crs`` is not a known, projected, metric coordinate reference system."""


def parse_crs(value: int | str) -> Any:
    """A pyproj CRS from an EPSG code (int or ``"EPSG:n"``) or WKT / PROJ text; raises CrsError unless it is
    projected with metre axes."""
    pyproj = require("pyproj", "scene.crs")
    text = f"EPSG:{value}" if isinstance(value, int) and not isinstance(value, bool) else value
    if not isinstance(text, str) or not text.strip():
        raise CrsError(f"crs must be an EPSG code or WKT text, got {value!r}")
    try:
        crs = pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as exc:
        raise CrsError(f"unknown CRS {str(value)[:80]!r}: {exc}") from None
    if not crs.is_projected:
        raise CrsError(
            f"CRS {crs.name!r} is not projected (its axes are {', '.join(a.unit_name for a in crs.axis_info)}); "
            "give plan coordinates in metres of a projected CRS (e.g. UTM, EPSG:326xx)"
        )
    units = {a.unit_name for a in crs.axis_info[:2]}
    if units != {"metre"}:
        raise CrsError(f"CRS {crs.name!r} has axis units {sorted(units)}; bentray needs metres")
    return crs


def crs_errors(
    crs: int | str | None, local_origin: tuple[float, float] | None, builtin: str | None
) -> list[tuple[tuple[str], str]]:
    """(location in ``scene``, reason) for the Scene validator: a CRS that pyproj does not know or that is not
    projected in metres, a local_origin without a CRS, a CRS on a builtin (local-metre) scene."""
    errors: list[tuple[tuple[str], str]] = []
    if crs is not None:
        if builtin is not None:
            errors.append((("crs",), f"builtin scene {builtin!r} is in local metres; remove crs"))
        try:
            parse_crs(crs)
        except CrsError as exc:
            errors.append((("crs",), str(exc)))
    elif local_origin is not None:
        errors.append((("local_origin",), "local_origin only applies with a crs"))
    return errors


def choose_local_origin(xy_min: ArrayLike, step: float = LOCAL_ORIGIN_STEP_M) -> tuple[float, float]:
    """The local origin (x0, y0), metres: the input's lower-left corner ``xy_min`` (2,) rounded down to a
    multiple of ``step``. Inputs already near zero (|x|, |y| < step) keep (0, 0)."""
    lo = np.asarray(xy_min, dtype=np.float64).reshape(2)
    if not np.all(np.isfinite(lo)):
        raise ValueError(f"xy_min must be finite, got {lo.tolist()}")
    out = tuple(0.0 if abs(v) < step else math.floor(v / step) * step for v in lo.tolist())
    return float(out[0]), float(out[1])


@dataclass(frozen=True)
class LocalFrame:
    """The engine's frame: x_local = x_crs - origin[0], y_local = y_crs - origin[1], z unchanged (metres).

    crs_wkt : WKT2 of the projected CRS, or None for a scene in plain local metres (no CRS).
    """

    origin: tuple[float, float] = (0.0, 0.0)
    crs_wkt: str | None = None

    @classmethod
    def from_scene(cls, crs: int | str | None, xy_min: ArrayLike) -> LocalFrame:
        """Frame for a scene with ``scene.crs`` (None: no CRS, no shift) and input lower-left corner xy_min."""
        if crs is None:
            return cls()
        return cls(origin=choose_local_origin(xy_min), crs_wkt=parse_crs(crs).to_wkt())

    def to_local(self, xy: ArrayLike) -> NDArray[np.float64]:
        """(N, 2) or (N, 3) CRS coordinates -> local (a copy; z untouched)."""
        p = np.array(xy, dtype=np.float64)
        p[..., 0] -= self.origin[0]
        p[..., 1] -= self.origin[1]
        return p

    def to_crs(self, xy: ArrayLike) -> NDArray[np.float64]:
        """(N, 2) or (N, 3) local coordinates -> CRS (a copy; z untouched)."""
        p = np.array(xy, dtype=np.float64)
        p[..., 0] += self.origin[0]
        p[..., 1] += self.origin[1]
        return p

    def as_dict(self) -> dict[str, Any]:
        """``{"crs": WKT or None, "local_origin": [x0, y0]}`` for report.json (what the exports read)."""
        return {"crs": self.crs_wkt, "local_origin": [self.origin[0], self.origin[1]]}

    def vti_field_data(self) -> dict[str, Any]:
        """Field data for field.vti (ParaView shows it in the Information panel): ``crs_wkt`` (WKT2, ASCII),
        ``crs_epsg`` (the code, when the CRS has one; needs pyproj), ``local_origin_m`` [x0, y0] and
        ``georeference`` (the rule in words). Empty for a scene in local metres without a CRS."""
        if self.crs_wkt is None:
            return {}
        # VTK string arrays are ASCII: non-ASCII characters only occur in quoted names and remarks of a
        # WKT (area of use "6°E to 12°E"), so replacing them keeps the CRS the same
        wkt = self.crs_wkt.replace("\u00b0", " deg").encode("ascii", "replace").decode("ascii")
        out: dict[str, Any] = {"crs_wkt": wkt, "local_origin_m": [self.origin[0], self.origin[1]]}
        try:
            epsg = parse_crs(self.crs_wkt).to_epsg()
        except (CrsError, ImportError):
            epsg = None
        if epsg is not None:
            out["crs_epsg"] = float(epsg)
        out["georeference"] = (
            "grid x, y are local metres: x_crs = x + local_origin_m[0], y_crs = y + local_origin_m[1] "
            "in the CRS of crs_wkt; z unchanged"
        )
        return out

    @classmethod
    def from_vti_field_data(cls, field_data: Any) -> LocalFrame | None:
        """The frame of a field.vti's field data (see :meth:`vti_field_data`), None when it has none."""
        if "crs_wkt" not in field_data:
            return None
        wkt = field_data["crs_wkt"]
        wkt = str(wkt if isinstance(wkt, str) else np.asarray(wkt).ravel()[0])
        origin = (
            np.asarray(field_data["local_origin_m"], dtype=np.float64).ravel()
            if "local_origin_m" in field_data
            else np.zeros(2)
        )
        return cls(origin=(float(origin[0]), float(origin[1])), crs_wkt=wkt)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LocalFrame:
        """Inverse of :meth:`as_dict`."""
        origin = data.get("local_origin") or [0.0, 0.0]
        if len(origin) != 2 or not all(isinstance(v, int | float) and math.isfinite(v) for v in origin):
            raise ValueError(f"local_origin must be 2 finite numbers, got {origin!r}")
        crs = data.get("crs")
        return cls(origin=(float(origin[0]), float(origin[1])), crs_wkt=None if crs is None else str(crs))
