"""Isophones: level bands and lines of a 2D map (contourpy), as GeoJSON features.

Map (nx, ny) dB at nodes (x0 + i dx, y0 + j dy) in CRS metres; NaN nodes are masked (no contour crosses
them). Default levels 35, 40, ..., 80 dB (the 5 dB classes of noise maps, Directive 2002/49/EC).
Bands: [L_k, L_k+1) for consecutive levels plus [L_n, +inf) above the last, each a MultiPolygon (holes
included) with properties ``level_min``, ``level_max`` (null = open) and ``label``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from bentray.scenes.gis_deps import require

__all__ = ["DEFAULT_LEVELS_DB", "check_levels", "isophone_bands", "isophone_lines"]

DEFAULT_LEVELS_DB: tuple[float, ...] = tuple(float(v) for v in range(35, 81, 5))


def check_levels(levels: Sequence[float]) -> list[float]:
    """Finite, strictly increasing levels (at least one); ValueError otherwise."""
    out = [float(v) for v in levels]
    if not out or not all(np.isfinite(out)) or any(b <= a for a, b in zip(out, out[1:], strict=False)):
        raise ValueError(f"levels must be finite and strictly increasing, got {list(levels)}")
    return out


def _generator(level: ArrayLike, xy0: ArrayLike, dxy: ArrayLike, fill_type: Any = None, line_type: Any = None) -> Any:
    contourpy = require("contourpy", "isophones")
    v = np.asarray(level, dtype=np.float64)
    x0, y0 = np.asarray(xy0, dtype=np.float64).reshape(2)
    dx, dy = np.asarray(dxy, dtype=np.float64).reshape(2)
    x = x0 + dx * np.arange(v.shape[0])
    y = y0 + dy * np.arange(v.shape[1])
    z = np.ma.masked_invalid(v.T)
    kwargs: dict[str, Any] = {}
    if fill_type is not None:
        kwargs["fill_type"] = fill_type
    if line_type is not None:
        kwargs["line_type"] = line_type
    return contourpy.contour_generator(x, y, z, **kwargs)


def _label(lo: float, hi: float | None) -> str:
    return f">= {lo:g} dB" if hi is None else f"{lo:g}-{hi:g} dB"


def isophone_bands(
    level: ArrayLike, xy0: ArrayLike, dxy: ArrayLike, levels: Sequence[float] = DEFAULT_LEVELS_DB
) -> list[dict[str, Any]]:
    """GeoJSON MultiPolygon features, one per non-empty band (see the module docstring)."""
    contourpy = require("contourpy", "isophones")
    lv = check_levels(levels)
    v = np.asarray(level, dtype=np.float64)
    finite = v[np.isfinite(v)]
    if finite.size == 0:
        return []
    top = max(float(finite.max()), lv[-1]) + 1.0
    gen = _generator(v, xy0, dxy, fill_type=contourpy.FillType.OuterOffset)
    features = []
    for k, lo in enumerate(lv):
        hi = lv[k + 1] if k + 1 < len(lv) else None
        points, offsets = gen.filled(lo, top if hi is None else hi)
        polygons = []
        for pts, off in zip(points, offsets, strict=True):
            rings = [pts[off[r] : off[r + 1]].tolist() for r in range(len(off) - 1)]
            polygons.append([r if r[0] == r[-1] else r + [r[0]] for r in rings])
        if polygons:
            features.append(
                {
                    "type": "Feature",
                    "properties": {"level_min": lo, "level_max": hi, "label": _label(lo, hi)},
                    "geometry": {"type": "MultiPolygon", "coordinates": polygons},
                }
            )
    return features


def isophone_lines(
    level: ArrayLike, xy0: ArrayLike, dxy: ArrayLike, levels: Sequence[float] = DEFAULT_LEVELS_DB
) -> list[dict[str, Any]]:
    """GeoJSON MultiLineString features, one per level that has a contour (property ``level``)."""
    contourpy = require("contourpy", "isophones")
    gen = _generator(level, xy0, dxy, line_type=contourpy.LineType.Separate)
    features = []
    for lv in check_levels(levels):
        lines = [seg.tolist() for seg in gen.lines(lv) if len(seg) >= 2]
        if lines:
            features.append(
                {
                    "type": "Feature",
                    "properties": {"level": lv, "label": f"{lv:g} dB"},
                    "geometry": {"type": "MultiLineString", "coordinates": lines},
                }
            )
    return features
