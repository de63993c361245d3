"""``bentray lden``: Lday, Levening, Lnight and Lden maps from the results of several conditions.

    bentray lden --condition RESULT_DIR DAY EVENING NIGHT [--condition ...]
                 (--z Z | --height H (--ground-z G | --terrain FILE)) [--array spl_a]
                 [--hours 12,4,8] [--penalties 0,5,10] [--format geotiff,asc,isophones]
                 [--levels 35,...,80] [--buildings FILE.geojson] [--facade-spacing 5] --out DIR

Each ``--condition`` is one finished job (a meteorological condition: profile + wind, with the emission
of the periods it stands for) and its occurrence in the day, evening and night (shares in [0, 1]); per
period the shares of all conditions sum to 1. A period's level is the energy mean of the condition maps
weighted by their shares (CNOSSOS-EU 2.5.5, :func:`bentray.engine.export.lden.combine_conditions`), and
Lden combines the three with the period lengths and penalties (:func:`bentray.engine.export.lden.lden`).
Per-period emission: give one job per emission and condition, each with zero shares in the periods it
does not stand for (e.g. a night-traffic job ``--condition night_h 0 0 0.5``).

Every condition's map is taken as in ``bentray export`` (``--z`` grid level, or ``--height`` above the
ground); all fields must share one grid and georeference. Files in ``--out``: ``map_<indicator>.tif`` /
``.asc`` (+ ``.prj``) for lday, levening, lnight, lden; ``isophones_lden.geojson``;
``facades_lden.geojson`` + ``.csv`` with ``--buildings`` (levels per facade receiver, per period and
Lden); ``lden.json`` (conditions, shares, hours, penalties, the map).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from bentray.clients.export_cli import format_list

__all__ = ["add_lden", "cmd_lden"]

INDICATORS = ("lday", "levening", "lnight")
LDEN_FORMATS = ("geotiff", "asc", "isophones")


def _numbers(count: int):  # type: ignore[no-untyped-def]
    def parse(text: str) -> list[float]:
        try:
            out = [float(v) for v in text.split(",") if v.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers, got {text!r}") from None
        if len(out) != count:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers, got {text!r}")
        return out

    return parse


_formats = format_list(LDEN_FORMATS)


def add_lden(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "lden",
        help="Lday / Levening / Lnight / Lden maps (and facade levels) from several conditions' results",
        description="Combine condition results by their occurrences into period levels and Lden.",
    )
    p.add_argument(
        "--condition",
        nargs=4,
        action="append",
        required=True,
        metavar=("RESULT_DIR", "DAY", "EVENING", "NIGHT"),
        help="a result directory and its occurrence (share) in the day, evening and night",
    )
    p.add_argument("--array", default="spl_a", help="point array of field.vti (default spl_a)")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--z", type=float, help="map on the grid level nearest this z (metres)")
    where.add_argument("--height", type=float, help="map at this height above the ground (metres)")
    ground = p.add_mutually_exclusive_group()
    ground.add_argument("--ground-z", type=float, help="flat ground z for --height (metres)")
    ground.add_argument("--terrain", help="terrain file in CRS coordinates for --height")
    p.add_argument("--hours", type=_numbers(3), default=[12.0, 4.0, 8.0], help="day,evening,night hours (12,4,8)")
    p.add_argument("--penalties", type=_numbers(3), default=[0.0, 5.0, 10.0], help="penalties in dB (0,5,10)")
    p.add_argument("--format", type=_formats, default=["geotiff", "asc"], help="geotiff,asc,isophones")
    p.add_argument("--levels", default=None, help="isophone levels in dB (default 35..80 step 5)")
    p.add_argument("--buildings", help="GeoJSON footprints (CRS coordinates): facade levels per period and Lden")
    p.add_argument("--facade-spacing", type=float, default=5.0, help="metres between facade receivers (default 5)")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=cmd_lden)


def _conditions(args: argparse.Namespace) -> list[tuple[Path, list[float]]]:
    from bentray.clients.cli import CommandError

    out = []
    for directory, *shares in args.condition:
        try:
            values = [float(v) for v in shares]
        except ValueError:
            raise CommandError(f"--condition {directory}: shares must be numbers, got {shares}") from None
        out.append((Path(directory), values))
    for k, period in enumerate(("day", "evening", "night")):
        total = sum(v[k] for _, v in out)
        if abs(total - 1.0) > 1e-9 or any(not 0.0 <= v[k] <= 1.0 for _, v in out):
            raise CommandError(f"the {period} shares of the conditions must lie in [0, 1] and sum to 1 (got {total:g})")
    return out


def _same_grid(grids: list[Any], dirs: list[Path]) -> None:
    from bentray.clients.cli import CommandError

    first = grids[0]
    for grid, d in zip(grids[1:], dirs[1:], strict=True):
        same = (
            grid.shape == first.shape
            and np.allclose(grid.origin, first.origin)
            and np.allclose(grid.spacing, first.spacing)
        )
        if not same or grid.frame != first.frame:
            raise CommandError(f"--condition {d}: its field grid or georeference differs from {dirs[0]}'s")


def _combine(levels: list[Any], shares: list[list[float]], hours: list[float], pen: list[float]) -> dict[str, Any]:
    """Period levels (energy mean weighted by the shares; zero-share conditions left out) and Lden."""
    from bentray.engine.export.lden import combine_conditions, lden

    out: dict[str, Any] = {}
    for k, name in enumerate(INDICATORS):
        used = [(lv, s[k]) for lv, s in zip(levels, shares, strict=True) if s[k] > 0]
        out[name] = combine_conditions([lv for lv, _ in used], [s for _, s in used])
    out["lden"] = lden(out["lday"], out["levening"], out["lnight"], hours=hours, penalties_db=pen)
    return out


def cmd_lden(args: argparse.Namespace) -> int:
    from bentray.clients.cli import CommandError
    from bentray.clients.export_cli import _buildings, _facades, _ground_fn
    from bentray.engine.export import geojson, isophones, rasters
    from bentray.engine.export.field_grid import read_result
    from bentray.engine.export.maps import level_map

    conditions = _conditions(args)
    grids = [read_result(d)[0] for d, _ in conditions]
    _same_grid(grids, [d for d, _ in conditions])
    if any(args.array not in g.arrays for g in grids):
        raise CommandError(f"--array {args.array!r} is missing from a condition's field.vti")
    if args.height is not None and args.ground_z is None and args.terrain is None:
        raise CommandError("--height needs the ground: --ground-z or --terrain")
    try:
        maps = [level_map(g, args.array, z=args.z, height=args.height, ground=_ground_fn(args)) for g in grids]
        shares = [s for _, s in conditions]
        result = _combine([m.level for m in maps], shares, args.hours, args.penalties)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    first, crs = maps[0], grids[0].frame.crs_wkt
    written: list[Path] = []
    for name, level in result.items():
        if "geotiff" in args.format:
            written.append(
                rasters.write_geotiff(out / f"map_{name}.tif", level, first.xy0, first.dxy, crs, band_name=name)
            )
        if "asc" in args.format:
            written.append(rasters.write_esri_ascii(out / f"map_{name}.asc", level, first.xy0, first.dxy, crs))
    if "isophones" in args.format:
        levels = isophones.check_levels(
            [float(v) for v in args.levels.split(",")] if args.levels else isophones.DEFAULT_LEVELS_DB
        )
        feats = isophones.isophone_bands(result["lden"], first.xy0, first.dxy, levels)
        written.append(geojson.write_geojson(out / "isophones_lden.geojson", feats, crs))
    if args.buildings:
        written += _facade_levels(args, grids, shares, out, _buildings(args), _facades)
    summary = {
        "array": args.array,
        "map": first.description,
        "conditions": [{"result": str(d), "day": s[0], "evening": s[1], "night": s[2]} for d, s in conditions],
        "hours": args.hours,
        "penalties_db": args.penalties,
    }
    (out / "lden.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    for path in [*written, out / "lden.json"]:
        print(path)
    return 0


def _facade_levels(
    args: argparse.Namespace, grids: list[Any], shares: list[list[float]], out: Path, footprints: Any, facades_fn: Any
) -> list[Path]:
    """Facade receivers of the buildings with each condition's level, combined per period and into Lden."""
    from bentray.engine.export import facades, geojson

    receivers = facades_fn(args, grids[0], footprints)
    local = grids[0].frame.to_local(receivers.points)
    per_condition = [facades.levels_at_points(g.level(args.array), g.origin, g.spacing, local) for g in grids]
    cols = _combine(per_condition, shares, args.hours, args.penalties)
    extra = {"building": receivers.building, "storey": receivers.storey}
    crs = grids[0].frame.crs_wkt
    feats = facades.points_features(receivers.points, receivers.ids, cols, extra)
    return [
        geojson.write_geojson(out / "facades_lden.geojson", feats, crs),
        facades.write_points_csv(out / "facades_lden.csv", receivers.points, receivers.ids, cols, extra),
    ]
