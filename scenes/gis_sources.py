"""Line sources (roads, railways as GeoJSON LineStrings with a power per metre) -> point sources.

Discretisation rule (ISO 9613-2:1996 clause 4: an extended source may be replaced by a point source at its
centre when the distance to the receiver exceeds twice the source's largest dimension): each line is cut
into pieces whose length is at most half the distance from the piece's centre to the *nearest* receiver,
and at most ``max_piece_m``, and at least ``min_piece_m`` (no infinite refinement for a receiver on the
line). Pieces are found by bisection of each LineString segment, so pieces near receivers are short and
far ones long. Each piece becomes a point source at its midpoint with sound power
``L_W = L_W' + 10 lg(length / 1 m)`` per band: the pieces' powers sum to the line's, ``L_W' + 10 lg(L)``.

Heights: a piece's z is the line's z (3D coordinates, interpolated) or ``height_above_ground_m``
(GeoJSON property or argument) above ``ground(xy)`` (a callable returning ground z per point, metres).
Without ``ground`` a piece keeps ``height_above_ground_m`` and its job source is ``{"position": [x, y],
"height_above_ground_m": h}``: the job resolves it against the scene's terrain (or flat ground) when it
is prepared, in whatever frame the job is in (a CRS job's line in CRS coordinates included).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = ["PointSource", "discretise_line", "read_line_sources_geojson", "total_power_db"]

# Bisection depth cap: 2^40 pieces of a segment is far below any min_piece_m of a real line.
_MAX_DEPTH = 40


@dataclass
class PointSource:
    """One piece of a line source: ``position`` (3,) metres, ``power_db`` per band (dB re 1 pW),
    ``length_m`` of the piece, ``line`` (index of the feature) and ``name``; ``height_above_ground_m``
    when the z is left to the job (position z is then NaN)."""

    position: tuple[float, float, float]
    power_db: dict[str, float]
    length_m: float
    line: int
    name: str
    height_above_ground_m: float | None = None

    def as_job_source(self) -> dict[str, Any]:
        """The job-file ``sources`` entry (``position``, ``power_db``, ``name``; ``height_above_ground_m``
        with a 2D position when the job resolves the height)."""
        if self.height_above_ground_m is not None and math.isnan(self.position[2]):
            return {
                "position": list(self.position[:2]),
                "height_above_ground_m": self.height_above_ground_m,
                "power_db": dict(self.power_db),
                "name": self.name,
            }
        return {"position": list(self.position), "power_db": dict(self.power_db), "name": self.name}


def _pieces(
    a: NDArray[np.float64], b: NDArray[np.float64], nearest: Callable[[NDArray[np.float64]], float],
    min_piece: float, max_piece: float,
) -> list[tuple[float, float]]:  # fmt: skip
    """Parameter intervals (t0, t1) of segment a-b (3D) obeying the rule (see the module docstring)."""
    length = float(np.linalg.norm(b[:2] - a[:2]))
    if length == 0.0:
        return []
    out: list[tuple[float, float]] = []
    stack = [(0.0, 1.0, 0)]
    while stack:
        t0, t1, depth = stack.pop()
        piece = (t1 - t0) * length
        mid = a + 0.5 * (t0 + t1) * (b - a)
        split = piece > max_piece or (piece > 0.5 * nearest(mid) and piece > min_piece)
        if split and piece / 2 >= min_piece * (1 - 1e-12) and depth < _MAX_DEPTH:
            tm = 0.5 * (t0 + t1)
            stack += [(tm, t1, depth + 1), (t0, tm, depth + 1)]
        else:
            out.append((t0, t1))
    return sorted(out)


def discretise_line(
    coords: ArrayLike,
    power_db_per_m: Mapping[str, float],
    receivers: ArrayLike,
    *,
    min_piece_m: float = 1.0,
    max_piece_m: float = 100.0,
    height_above_ground_m: float | None = None,
    ground: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    line: int = 0,
    name: str = "line",
) -> list[PointSource]:
    """Point sources of one polyline (k >= 2 vertices, (k, 2) or (k, 3) metres).

    receivers : (R, 3) or (R, 2) receiver positions (the rule's distances are 3D when both are 3D);
    power_db_per_m : dB re 1 pW per metre, per band label; height_above_ground_m with ``ground``
    (callable xy (N, 2) -> z (N,); without it the job resolves the height), or z from 3D coordinates
    (exactly one). 0 < min_piece_m <= max_piece_m.
    """
    p = np.asarray(coords, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] < 2 or p.shape[1] not in (2, 3) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: a line needs at least 2 finite [x, y] or [x, y, z] vertices")
    if not (0 < min_piece_m <= max_piece_m and math.isfinite(max_piece_m)):
        raise ValueError(f"need 0 < min_piece_m <= max_piece_m, got {min_piece_m!r}, {max_piece_m!r}")
    if (height_above_ground_m is None) == (p.shape[1] != 3):
        raise ValueError(f"{name}: give either 3D coordinates or height_above_ground_m (exactly one)")
    if height_above_ground_m is not None and not (math.isfinite(height_above_ground_m) and height_above_ground_m > 0):
        raise ValueError(f"{name}: height_above_ground_m must be > 0, got {height_above_ground_m!r}")
    if not power_db_per_m or not all(math.isfinite(v) for v in power_db_per_m.values()):
        raise ValueError(f"{name}: power_db_per_m must map band labels to finite dB values")
    r = np.asarray(receivers, dtype=np.float64)
    r = r.reshape(-1, r.shape[-1]) if r.size else np.zeros((0, 3))
    # distances in 3D when receivers and line are both 3D; in plan otherwise (a lower bound: finer pieces)
    dims = 3 if r.shape[1] == 3 and height_above_ground_m is None else 2
    tree = cKDTree(r[:, :dims]) if len(r) else None

    def nearest(q: NDArray[np.float64]) -> float:
        return math.inf if tree is None else float(tree.query(q[:dims])[0])

    p3 = p if p.shape[1] == 3 else np.column_stack([p, np.zeros(len(p))])
    out: list[PointSource] = []
    for s in range(len(p3) - 1):
        a, b = p3[s], p3[s + 1]
        for t0, t1 in _pieces(a, b, nearest, min_piece_m, max_piece_m):
            mid = a + 0.5 * (t0 + t1) * (b - a)
            length = (t1 - t0) * float(np.linalg.norm(b[:2] - a[:2]))
            if height_above_ground_m is not None:
                ground_z = math.nan if ground is None else float(np.asarray(ground(mid[None, :2]))[0])
                mid[2] = ground_z + height_above_ground_m
            power = {k: float(v) + 10.0 * math.log10(length) for k, v in power_db_per_m.items()}
            pos = (float(mid[0]), float(mid[1]), float(mid[2]))
            out.append(PointSource(pos, power, length, line, f"{name} {len(out)}", height_above_ground_m))
    return out


def read_line_sources_geojson(
    path: str | Path,
    receivers: ArrayLike,
    *,
    ground: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    min_piece_m: float = 1.0,
    max_piece_m: float = 100.0,
) -> list[PointSource]:
    """GeoJSON FeatureCollection of LineString / MultiLineString features with ``power_db_per_m`` (an
    object: band label -> dB re 1 pW/m) and ``height_above_ground_m`` (or 3D coordinates) -> point sources.
    Errors are ValueError naming ``features.<i>``."""
    path = Path(path)
    data = json.loads(path.read_text(encoding="utf-8"))
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list):
        raise ValueError(f"{path}: expected a GeoJSON FeatureCollection")
    out: list[PointSource] = []
    for i, feature in enumerate(features):
        label = f"{path}: features.{i}"
        geom = feature.get("geometry") if isinstance(feature, dict) else None
        props = (feature.get("properties") if isinstance(feature, dict) else None) or {}
        kind = geom.get("type") if isinstance(geom, dict) else None
        if kind not in ("LineString", "MultiLineString"):
            raise ValueError(f"{label}: geometry must be a LineString or MultiLineString, got {kind!r}")
        power = props.get("power_db_per_m")
        if not isinstance(power, dict) or not all(isinstance(v, int | float) for v in power.values()):
            raise ValueError(f"{label}: power_db_per_m must be an object of band label -> dB re 1 pW/m")
        height = props.get("height_above_ground_m")
        assert isinstance(geom, dict)
        lines = [geom["coordinates"]] if kind == "LineString" else geom["coordinates"]
        for part, coords in enumerate(lines):
            try:
                out += discretise_line(
                    coords, power, receivers, min_piece_m=min_piece_m, max_piece_m=max_piece_m,
                    height_above_ground_m=None if height is None else float(height), ground=ground, line=i,
                    name=str(props.get("name", f"features.{i}")) + (f" part {part}" if kind != "LineString" else ""),
                )  # fmt: skip
            except ValueError as exc:
                text = str(exc)
                # discretise_line names the piece itself ("features.3: ..." for an unnamed feature)
                prefix = f"features.{i}"
                raise ValueError(f"{path}: {text}" if text.startswith(prefix) else f"{label}: {text}") from None
    return out


def total_power_db(sources: Sequence[PointSource], band: str) -> float:
    """Energy sum (dB re 1 pW) of the pieces' powers in one band."""
    return 10.0 * math.log10(sum(10.0 ** (s.power_db[band] / 10.0) for s in sources))
