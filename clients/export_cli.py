"""``bentray export``: noise-map files from a finished field (``RESULT_DIR/field.vti``).

    bentray export RESULT_DIR --format geotiff,asc,isophones,isolines,facades,exposure
                   [--array spl_a] (--z Z | --height H (--ground-z G | --terrain FILE))
                   [--levels 35,40,...,80] [--buildings FILE.geojson] [--crs EPSG|WKT --origin X0 Y0]
                   [--out DIR]

The map is the field's ``--array`` on the grid level nearest ``--z``, or ``--height`` metres above the
ground (``--ground-z`` constant, or the ``--terrain`` file in CRS coordinates), energy-linear between the
grid levels. Georeference: ``report.json["georeference"]`` when the job wrote one, else ``--crs`` and
``--origin`` (the local origin the engine's coordinates are relative to; default 0 0), else none.
Files (in ``--out``, default RESULT_DIR/export): ``map_<array>.tif``, ``map_<array>.asc`` + ``.prj``,
``isophones_<array>.geojson`` (bands), ``isolines_<array>.geojson``, ``facades.geojson`` + ``facades.csv``
(receivers 2 m in front of every facade of ``--buildings``, per storey), ``exposure.json`` (map area per
class, buildings per class by their most exposed facade receiver), ``receivers.geojson`` + ``.csv``
(levels at the Point features of ``--receivers``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["FORMATS", "add_export", "cmd_export"]

FORMATS = ("geotiff", "asc", "isophones", "isolines", "facades", "exposure", "receivers")


def _levels(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"levels must be comma-separated numbers, got {text!r}") from None


def format_list(allowed: tuple[str, ...] | list[str]) -> Callable[[str], list[str]]:
    """An argparse ``type`` for a comma-separated list of names out of ``allowed`` (an ArgumentTypeError
    naming the unknown ones otherwise)."""

    def parse(text: str) -> list[str]:
        out = [v.strip() for v in text.split(",") if v.strip()]
        bad = [v for v in out if v not in allowed]
        if bad or not out:
            raise argparse.ArgumentTypeError(f"unknown format(s) {bad or text!r}; choose from {', '.join(allowed)}")
        return out

    return parse


_formats = format_list(FORMATS)


def add_export(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "export",
        help="write GeoTIFF / ASCII grid / isophones / facade levels / exposure from a field result",
        description="Noise-map exports of RESULT_DIR/field.vti (see `bentray export --help`).",
    )
    p._negative_number_matcher = __import__("re").compile(r"^-\.?\d")
    p.add_argument("result", help="result directory holding field.vti (and report.json)")
    p.add_argument("--format", required=True, type=_formats, help=f"comma-separated: {', '.join(FORMATS)}")
    p.add_argument(
        "--array", default=None, help="point array of field.vti (default spl_a; l_den for a job with conditions)"
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument("--z", type=float, help="map on the grid level nearest this z (metres)")
    where.add_argument("--height", type=float, help="map at this height above the ground (metres)")
    ground = p.add_mutually_exclusive_group()
    ground.add_argument("--ground-z", type=float, help="flat ground z for --height (metres)")
    ground.add_argument("--terrain", help="terrain file (asc, npz, obj, ...) in CRS coordinates for --height")
    p.add_argument("--levels", type=_levels, default=None, help="isophone / class levels in dB (default 35..80 step 5)")
    p.add_argument("--buildings", help="GeoJSON footprints (CRS coordinates) for facades and exposure")
    p.add_argument("--facade-spacing", type=float, default=5.0, help="metres between facade receivers (default 5)")
    p.add_argument(
        "--receivers",
        help="GeoJSON Point features (CRS coordinates; z from the third coordinate, else --height above the "
        "ground) for --format receivers",
    )
    p.add_argument("--crs", help="CRS of the outputs when report.json has none (EPSG code or WKT)")
    p.add_argument("--origin", type=float, nargs=2, metavar=("X0", "Y0"), help="local origin in the CRS (metres)")
    p.add_argument("--out", help="output directory (default RESULT_DIR/export)")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from bentray.clients.cli import CommandError
    from bentray.engine.export.field_grid import read_result
    from bentray.engine.export.isophones import DEFAULT_LEVELS_DB, check_levels
    from bentray.scenes.crs import LocalFrame, parse_crs

    frame = None
    if args.crs is not None or args.origin is not None:
        crs_value: int | str | None = args.crs
        if isinstance(crs_value, str) and crs_value.isdigit():
            crs_value = int(crs_value)
        wkt = parse_crs(crs_value).to_wkt() if crs_value is not None else None
        origin = tuple(args.origin) if args.origin is not None else (0.0, 0.0)
        frame = LocalFrame(origin=(float(origin[0]), float(origin[1])), crs_wkt=wkt)
    grid, _report = read_result(args.result, frame)
    if args.array is None:
        args.array = "l_den" if "l_den" in grid.arrays else "spl_a"
    if args.array not in grid.arrays:
        raise CommandError(f"--array {args.array!r}: field.vti has {', '.join(sorted(grid.arrays))}")
    levels = check_levels(args.levels if args.levels is not None else DEFAULT_LEVELS_DB)
    out = Path(args.out) if args.out else Path(args.result) / "export"
    out.mkdir(parents=True, exist_ok=True)
    needs_map = [f for f in args.format if f not in ("facades", "receivers")]
    written: list[Path] = []
    lmap = None
    if needs_map:
        if args.z is None and args.height is None:
            raise CommandError("give --z or --height for the map")
        lmap = _map(args, grid)
    footprints = (
        _buildings(args) if ("facades" in args.format or ("exposure" in args.format and args.buildings)) else None
    )
    if "facades" in args.format and footprints is None:
        raise CommandError("--format facades needs --buildings FILE.geojson")
    receivers = None
    if footprints is not None:
        receivers = _facades(args, grid, footprints)
    if "receivers" in args.format:
        if args.receivers is None:
            raise CommandError("--format receivers needs --receivers FILE.geojson")
        written += _write_receivers(args, grid, out)
    for fmt in args.format:
        if fmt != "receivers":
            written += _write(fmt, args, grid, lmap, levels, out, footprints, receivers)
    for path in written:
        print(path)
    return 0


def _write_receivers(args: argparse.Namespace, grid: Any, out: Path) -> list[Path]:
    """Levels at the points of a GeoJSON file -> receivers.geojson and receivers.csv."""
    from bentray.clients.cli import CommandError
    from bentray.engine.export import facades, geojson

    try:
        data = json.loads(Path(args.receivers).read_text(encoding="utf-8"))
        features = data["features"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CommandError(f"--receivers {args.receivers}: not a readable GeoJSON FeatureCollection ({exc})") from None
    pts, ids = [], []
    for i, f in enumerate(features):
        geom = f.get("geometry") if isinstance(f, dict) else None
        c = geom.get("coordinates") if isinstance(geom, dict) and geom.get("type") == "Point" else None
        if not isinstance(c, list) or len(c) not in (2, 3) or not all(isinstance(v, int | float) for v in c):
            raise CommandError(f"--receivers {args.receivers}: features.{i}: expected a Point [x, y] or [x, y, z]")
        if len(c) == 2 and args.height is None:
            raise CommandError(f"--receivers: features.{i} has no z: give --height (above the ground) for 2D points")
        pts.append([float(v) for v in c] if len(c) == 3 else [float(c[0]), float(c[1]), np.nan])
        props = f.get("properties") or {}
        ids.append(str(props.get("id", props.get("name", f"features.{i}"))))
    p = np.array(pts, dtype=np.float64).reshape(-1, 3)
    flat = np.isnan(p[:, 2])
    if np.any(flat):
        ground = _ground_fn(args)
        if ground is None:
            raise CommandError("--height needs the ground: --ground-z or --terrain")
        gz = np.asarray(ground(p[flat, :2]), dtype=np.float64) if callable(ground) else float(ground)
        p[flat, 2] = gz + float(args.height)
    levels: dict[str, Any] = {
        args.array: facades.levels_at_points(grid.level(args.array), grid.origin, grid.spacing, grid.frame.to_local(p))
    }
    crs = grid.frame.crs_wkt
    return [
        geojson.write_geojson(out / "receivers.geojson", facades.points_features(p, ids, levels), crs),
        facades.write_points_csv(out / "receivers.csv", p, ids, levels),
    ]


def _ground_fn(args: argparse.Namespace) -> Any:
    if args.terrain is None:
        return args.ground_z
    from bentray.scenes.geometry import terrain_height_at
    from bentray.scenes.terrain_io import read_terrain

    terrain = read_terrain(args.terrain)
    return lambda xy: terrain_height_at(terrain, xy)


def _map(args: argparse.Namespace, grid: Any) -> Any:
    from bentray.engine.export.maps import level_map

    return level_map(grid, args.array, z=args.z, height=args.height, ground=_ground_fn(args))


def _buildings(args: argparse.Namespace) -> Any:
    from bentray.scenes.terrain_io import read_footprints_geojson

    if args.buildings is None:
        return None
    # exports need no acoustic materials: accept every material name the file uses
    try:
        data = json.loads(Path(args.buildings).read_text(encoding="utf-8"))
        names = {str(f["properties"]["material"]) for f in data["features"] if "material" in (f["properties"] or {})}
    except (OSError, ValueError, KeyError, TypeError):
        names = set()  # the reader reports what is wrong with the file
    return read_footprints_geojson(args.buildings, materials={"rigid": 0, **dict.fromkeys(names, 0)})


def _facades(args: argparse.Namespace, grid: Any, footprints: Any) -> Any:
    from bentray.engine.export.facades import facade_receivers

    ground = _ground_fn(args)
    if callable(ground):
        from bentray.scenes.scene_models import footprint_bases

        bases = footprint_bases(None, footprints, 0.0)
        for k, fp in enumerate(footprints):
            if fp.base_z is None:
                bases[k] = float(np.nanmin(ground(np.asarray(fp.polygon))))
    else:
        flat = float(ground) if ground is not None else float(grid.origin[2])
        bases = np.array([flat if fp.base_z is None else fp.base_z for fp in footprints])
    return facade_receivers(footprints, spacing=args.facade_spacing, bases=bases.tolist())


def _write(
    fmt: str, args: argparse.Namespace, grid: Any, lmap: Any, levels: list[float], out: Path, footprints: Any,
    receivers: Any,
) -> list[Path]:  # fmt: skip
    from bentray.engine.export import exposure, facades, geojson, isophones, rasters

    stem = f"{args.array}"
    crs = grid.frame.crs_wkt
    if fmt == "geotiff":
        return [
            rasters.write_geotiff(
                out / f"map_{stem}.tif", lmap.level, lmap.xy0, lmap.dxy, crs, band_name=lmap.description
            )
        ]
    if fmt == "asc":
        path = rasters.write_esri_ascii(out / f"map_{stem}.asc", lmap.level, lmap.xy0, lmap.dxy, crs)
        return [path] + ([path.with_suffix(".prj")] if crs else [])
    if fmt == "isophones":
        feats = isophones.isophone_bands(lmap.level, lmap.xy0, lmap.dxy, levels)
        return [geojson.write_geojson(out / f"isophones_{stem}.geojson", feats, crs)]
    if fmt == "isolines":
        feats = isophones.isophone_lines(lmap.level, lmap.xy0, lmap.dxy, levels)
        return [geojson.write_geojson(out / f"isolines_{stem}.geojson", feats, crs)]
    local = grid.frame.to_local(receivers.points) if receivers is not None else None
    rec_levels = (
        facades.levels_at_points(grid.level(args.array), grid.origin, grid.spacing, local)
        if local is not None
        else None
    )
    if fmt == "facades":
        cols: dict[str, Any] = {args.array: rec_levels}
        extra = {"building": receivers.building, "storey": receivers.storey}
        feats = facades.points_features(receivers.points, receivers.ids, cols, extra)
        return [
            geojson.write_geojson(out / "facades.geojson", feats, crs),
            facades.write_points_csv(out / "facades.csv", receivers.points, receivers.ids, cols, extra),
        ]
    if fmt == "exposure":
        inside = None
        result: dict[str, Any] = {"array": args.array, "map": lmap.description, "levels_db": levels}
        if footprints is not None:
            from bentray.engine.export.maps import node_xy_crs
            from bentray.scenes.gis_geometry import footprint_polygon, points_in_polygon

            xy = node_xy_crs(grid).reshape(-1, 2)
            inside = np.zeros(len(xy), dtype=bool)
            for fp in footprints:
                inside |= points_in_polygon(footprint_polygon(fp), xy)
            inside = inside.reshape(grid.shape[:2])
            assert rec_levels is not None
            per_building = exposure.building_levels(rec_levels, receivers.building, len(footprints))
            result["buildings"] = exposure.buildings_by_class(per_building, levels)
        result["area"] = exposure.area_by_class(lmap.level, lmap.dxy, levels, exclude=inside)
        path = out / "exposure.json"
        path.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
        return [path]
    raise AssertionError(fmt)
