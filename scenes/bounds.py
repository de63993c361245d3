"""Bounds shared by every job model: coordinates, lengths, counts (each says what it protects against).

Coordinates (metres, world frame) are finite and within +-:data:`MAX_COORD_M`: 10,000 km is beyond any
outdoor scene (a projected CRS in metres stays below 2e7 m only near its origin, so give coordinates
relative to a local origin), and it keeps every difference, product and square of coordinates that the
geometry code forms (extents, cross products, bounding-box cell counts) far from float64 overflow, so
no check can loop on an inf or NaN extent. Lengths are positive and at most ``2 * MAX_COORD_M``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field

__all__ = [
    "MAX_COORD_M",
    "MAX_LENGTH_M",
    "MIN_LENGTH_M",
    "Coord",
    "Length",
    "Vec2",
    "Vec3",
    "LengthVec3",
    "json_coordinate_problem",
]

MAX_COORD_M = 1.0e7  # |x|, |y|, |z| in metres
MAX_LENGTH_M = 2.0 * MAX_COORD_M  # a length between two bounded points
MIN_LENGTH_M = 1.0e-6  # a spacing or size below a micrometre is a unit mistake (and unbounded work)

Coord = Annotated[float, Field(ge=-MAX_COORD_M, le=MAX_COORD_M, allow_inf_nan=False)]
Length = Annotated[float, Field(gt=0.0, le=MAX_LENGTH_M, allow_inf_nan=False)]
Vec2 = tuple[Coord, Coord]
Vec3 = tuple[Coord, Coord, Coord]
LengthVec3 = tuple[Length, Length, Length]


def json_coordinate_problem(path: str | Path, limit: float = MAX_COORD_M) -> str | None:
    """Why the numbers of a GeoJSON file's ``coordinates`` arrays are not all finite and within
    +-``limit`` metres, or None. Iterative (no recursion limit); non-JSON text answers None (the
    reader reports it)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    stack: list[tuple[Any, bool]] = [(data, False)]
    while stack:
        value, in_coords = stack.pop()
        if isinstance(value, dict):
            stack.extend((v, k == "coordinates") for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((v, in_coords) for v in value)
        elif in_coords and isinstance(value, int | float) and not isinstance(value, bool):
            try:
                ok = math.isfinite(value) and abs(value) <= limit
            except OverflowError:  # an int too large for a float
                ok = False
            if not ok:
                shown = (
                    f"{value:.6g}" if isinstance(value, float) else f"{str(value)[:12]}... ({len(str(value))} digits)"
                )
                return (
                    f"coordinate {shown} is not within +-{limit:g} m (give coordinates in metres about a local origin)"
                )
    return None
