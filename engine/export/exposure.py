"""Exposure statistics per level class: map area and number of buildings (END-style 5 dB classes).

Classes from levels L_0 < ... < L_n: [L_k, L_k+1) and [L_n, +inf); values below L_0 are counted in no
class (reported as ``below``). Area: each map node stands for one cell of dx x dy m^2 (the raster cell of
:mod:`.rasters`), NaN nodes and nodes inside ``exclude`` (a boolean mask, e.g. inside buildings) are not
counted. Buildings: one value per building (e.g. the maximum over its facade receivers, the most exposed
facade), NaN buildings counted as ``no_level``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from bentray.engine.export.isophones import DEFAULT_LEVELS_DB, check_levels

__all__ = ["class_index", "area_by_class", "buildings_by_class", "building_levels"]


def class_index(values: ArrayLike, levels: Sequence[float]) -> np.ndarray:
    """Class (int64, same shape) of each value: k for [L_k, L_k+1), n for >= L_n, -1 below L_0, -2 for NaN."""
    lv = np.asarray(check_levels(levels))
    v = np.asarray(values, dtype=np.float64)
    k = np.searchsorted(lv, v, side="right") - 1
    return np.where(np.isnan(v), -2, k).astype(np.int64)


def _labels(levels: Sequence[float]) -> list[dict[str, Any]]:
    lv = check_levels(levels)
    return [
        {"level_min": lo, "level_max": lv[k + 1] if k + 1 < len(lv) else None}
        for k, lo in enumerate(lv)  # fmt: skip
    ]


def area_by_class(
    level: ArrayLike, dxy: ArrayLike, levels: Sequence[float] = DEFAULT_LEVELS_DB, exclude: ArrayLike | None = None
) -> dict[str, Any]:
    """``{"classes": [{level_min, level_max, area_m2}], "below_m2", "no_level_m2", "cell_m2"}``."""
    v = np.asarray(level, dtype=np.float64)
    cell = float(np.prod(np.asarray(dxy, dtype=np.float64).reshape(2)))
    k = class_index(v, levels)
    if exclude is not None:
        k = np.where(np.asarray(exclude, dtype=bool), -3, k)
    classes = _labels(levels)
    for n, c in enumerate(classes):
        c["area_m2"] = cell * int(np.count_nonzero(k == n))
    return {
        "classes": classes,
        "below_m2": cell * int(np.count_nonzero(k == -1)),
        "no_level_m2": cell * int(np.count_nonzero(k == -2)),
        "cell_m2": cell,
    }


def buildings_by_class(building_level: ArrayLike, levels: Sequence[float] = DEFAULT_LEVELS_DB) -> dict[str, Any]:
    """``{"classes": [{level_min, level_max, buildings}], "below", "no_level"}`` from one level per building."""
    k = class_index(np.asarray(building_level, dtype=np.float64).reshape(-1), levels)
    classes = _labels(levels)
    for n, c in enumerate(classes):
        c["buildings"] = int(np.count_nonzero(k == n))
    return {"classes": classes, "below": int(np.count_nonzero(k == -1)), "no_level": int(np.count_nonzero(k == -2))}


def building_levels(receiver_level: ArrayLike, receiver_building: ArrayLike, n_buildings: int) -> np.ndarray:
    """(n_buildings,) maximum receiver level of each building (NaN receivers ignored; NaN if none)."""
    lv = np.asarray(receiver_level, dtype=np.float64).reshape(-1)
    b = np.asarray(receiver_building, dtype=np.int64).reshape(-1)
    out = np.full(n_buildings, -np.inf)
    ok = np.isfinite(lv)
    np.maximum.at(out, b[ok], lv[ok])
    return np.where(np.isfinite(out), out, np.nan)
