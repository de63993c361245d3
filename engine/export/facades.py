"""Facade receivers generated from the buildings, and levels at receiver points.

Receivers (the usual facade-map practice, e.g. CNOSSOS-EU / the German VBEB rule and the Dutch 'gevel'
points): along every wall of every footprint ring (exterior and courtyards), one receiver at the middle of
each of ``ceil(L / spacing)`` equal pieces of a wall of length L, ``distance`` metres in front of the wall
(outside the building, perpendicular to the wall at that point), at heights ``base + first_height +
k storey_height`` for every storey k whose receiver is below the roof. Receivers that would fall inside
(or within distance / 2 of) another building, or outside the map's ``bounds``, are dropped.
Frames: the footprints' plan coordinates (metres); z absolute (base from ``bases``, default the
footprint's ``base_z`` or 0).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bentray.engine.surfaces import Footprint
from bentray.scenes.gis_deps import require

__all__ = ["FacadeReceivers", "facade_receivers", "levels_at_points", "points_features", "write_points_csv"]


@dataclass
class FacadeReceivers:
    """points (N, 3) metres; ids (N,) str ``b<building>-r<ring>-e<edge>-p<piece>-s<storey>``; building (N,)
    int64 index into the footprint list; storey (N,) int64; normal (N, 2) unit outward wall normal."""

    points: NDArray[np.float64]
    ids: list[str]
    building: NDArray[np.int64]
    storey: NDArray[np.int64]
    normal: NDArray[np.float64]


def facade_receivers(
    footprints: Sequence[Footprint],
    *,
    spacing: float = 5.0,
    distance: float = 2.0,
    storey_height: float = 3.0,
    first_height: float = 1.5,
    bases: Sequence[float] | None = None,
    max_storeys: int | None = None,
) -> FacadeReceivers:
    """Facade receiver points of every building (see the module docstring).

    spacing : target distance between receivers along a wall (m, > 0); distance : in front of the wall
    (m, > 0); storey_height, first_height : receiver heights above the base (m); bases : ground z per
    footprint (default ``base_z`` or 0); max_storeys : cap per building (None: up to the roof).
    """
    shapely = require("shapely", "facade receivers")
    for name, value in (("spacing", spacing), ("distance", distance), ("storey_height", storey_height)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    if not (np.isfinite(first_height) and first_height >= 0):
        raise ValueError(f"first_height must be finite and >= 0, got {first_height!r}")
    polys = [shapely.Polygon(fp.polygon, [np.asarray(h) for h in fp.holes]) for fp in footprints]
    tree = shapely.STRtree(polys) if polys else None
    pts: list[list[float]] = []
    ids: list[str] = []
    bld: list[int] = []
    sto: list[int] = []
    nrm: list[list[float]] = []
    for b, fp in enumerate(footprints):
        base = float(bases[b]) if bases is not None else float(fp.base_z or 0.0)
        n_storeys = int(np.floor((fp.height_m - first_height) / storey_height)) + 1 if fp.height_m > first_height else 0
        if max_storeys is not None:
            n_storeys = min(n_storeys, max_storeys)
        rings = [np.asarray(fp.polygon, float)] + [np.asarray(h, float) for h in fp.holes]
        for r, ring in enumerate(rings):
            # exterior counter-clockwise, holes clockwise: the building is on the left of every edge, so the
            # outward (air-side) normal is the edge direction turned clockwise
            a, c = ring, np.roll(ring, -1, axis=0)
            for e in range(len(ring)):
                edge = c[e] - a[e]
                length = float(np.hypot(*edge))
                if length == 0.0:
                    continue
                n_out = np.array([edge[1], -edge[0]]) / length
                pieces = max(1, int(np.ceil(length / spacing - 1e-9)))
                for p in range(pieces):
                    xy = a[e] + (p + 0.5) / pieces * edge + distance * n_out
                    probe = shapely.Point(xy)
                    assert tree is not None
                    near = tree.query(probe, predicate="dwithin", distance=0.5 * distance)
                    if len(near):
                        continue  # in front of another wall (a neighbour, a courtyard corner): not a facade point
                    for s in range(n_storeys):
                        pts.append([float(xy[0]), float(xy[1]), base + first_height + s * storey_height])
                        ids.append(f"b{b}-r{r}-e{e}-p{p}-s{s}")
                        bld.append(b)
                        sto.append(s)
                        nrm.append([float(n_out[0]), float(n_out[1])])
    return FacadeReceivers(
        points=np.array(pts, dtype=np.float64).reshape(-1, 3),
        ids=ids,
        building=np.array(bld, dtype=np.int64),
        storey=np.array(sto, dtype=np.int64),
        normal=np.array(nrm, dtype=np.float64).reshape(-1, 2),
    )


def levels_at_points(
    values: ArrayLike, origin: ArrayLike, spacing: ArrayLike, points: ArrayLike
) -> NDArray[np.float64]:
    """Levels (N,) dB at points (N, 3) (the grid's frame, metres): trilinear in energy (10^(L/10)) over the
    8 nodes around each point; NaN outside the grid or where a surrounding node is NaN."""
    v = np.asarray(values, dtype=np.float64)
    o = np.asarray(origin, dtype=np.float64)
    s = np.asarray(spacing, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    shape = np.array(v.shape[:3])
    t = (p - o) / s
    inside = np.all((t >= 0) & (t <= shape - 1), axis=1)
    i0 = np.clip(np.floor(t).astype(np.int64), 0, np.maximum(shape - 2, 0))
    f = np.clip(t - i0, 0.0, 1.0)
    energy = np.power(10.0, v / 10.0)
    total = np.zeros(len(p))
    for corner in range(8):
        bits = np.array([(corner >> d) & 1 for d in range(3)])
        idx = np.minimum(i0 + bits, shape - 1)
        w = np.prod(np.where(bits == 1, f, 1.0 - f), axis=1)
        e = energy[idx[:, 0], idx[:, 1], idx[:, 2]]
        total += np.where(w > 0, w * e, 0.0)  # a NaN node with zero weight does not count
        inside &= ~((w > 0) & np.isnan(e))
    with np.errstate(divide="ignore"):
        level = 10.0 * np.log10(total)
    return np.where(inside, level, np.nan)


def points_features(
    points_xyz: ArrayLike, ids: Sequence[str], levels: dict[str, ArrayLike], extra: dict[str, ArrayLike] | None = None
) -> list[dict[str, Any]]:
    """GeoJSON Point features (x, y, z in the given coordinates) with ``id``, one property per level array
    (null for NaN) and per ``extra`` array."""
    p = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    cols = {k: np.asarray(v, dtype=np.float64) for k, v in levels.items()}
    more = {k: np.asarray(v) for k, v in (extra or {}).items()}
    out = []
    for n in range(len(p)):
        props: dict[str, Any] = {"id": ids[n]}
        props.update({k: (float(v[n]) if np.isfinite(v[n]) else None) for k, v in cols.items()})
        props.update({k: v[n].item() for k, v in more.items()})
        out.append(
            {"type": "Feature", "properties": props, "geometry": {"type": "Point", "coordinates": p[n].tolist()}}
        )
    return out


def write_points_csv(
    path: str | Path,
    points_xyz: ArrayLike,
    ids: Sequence[str],
    levels: dict[str, ArrayLike],
    extra: dict[str, ArrayLike] | None = None,
) -> Path:
    """CSV with columns id, x, y, z, the extra columns, then one column per level array (empty for NaN)."""
    p = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    cols = {k: np.asarray(v, dtype=np.float64) for k, v in levels.items()}
    more = {k: np.asarray(v) for k, v in (extra or {}).items()}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "x", "y", "z", *more, *cols])
        for n in range(len(p)):
            w.writerow(
                [ids[n], *(f"{c:.3f}" for c in p[n]), *(v[n].item() for v in more.values())]
                + [f"{v[n]:.2f}" if np.isfinite(v[n]) else "" for v in cols.values()]
            )
    return path
