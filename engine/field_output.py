"""Writers for the 3D sound field on a regular grid: VTK ImageData (.vti) and a PNG preview.

Grid convention (both writers): node (i, j, k) of a grid with ``shape = (nx, ny, nz)`` lies at
``origin + (i dx, j dy, k dz)`` (metres, world frame, z up); node arrays are numpy arrays of shape
``(nx, ny, nz)`` (or ``(nx, ny, nz, n_components)``) indexed ``[i, j, k]`` in C order. VTK stores point
data with x fastest (point id ``i + nx (j + ny k)``); :func:`write_field_vti` does that reordering.

Files are written to a temporary file in the destination folder and moved into place with
``os.replace``, so a failed write never leaves a partial file. VTK (:mod:`bentray.engine.vti_writer`)
and matplotlib are imported lazily; the PNG writer uses ``matplotlib.figure.Figure`` with the Agg canvas
directly and never touches pyplot or the global backend; its panels are placed by
:func:`bentray.engine.preview_layout.place_panels`.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import os
import secrets
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "FieldDataValue",
    "nearest_index",
    "preview_slice_indices",
    "terrain_following_slice",
    "write_field_vti",
    "write_preview_png",
]

FieldDataValue = str | float | int | Sequence[str] | Sequence[float]

# Default dynamic range of the preview colour scale (dB below the largest finite value shown).
PREVIEW_DB_RANGE = 60.0
# Top of the preview colour scale: this percentile of the finite values shown (higher values saturate).
PREVIEW_TOP_PERCENTILE = 99.5


@contextlib.contextmanager
def _atomic_path(path: str | Path, suffix: str) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder (same suffix, so writers pick the format); replace on success.

    The temporary file is created with mode 0o666 less the umask, as ``open`` would create ``path`` itself
    (``tempfile.mkstemp``'s 0o600 made field.vti and preview.png unreadable to the group beside a 0o644
    report.json: a web server or a colleague reading the results folder could not open them)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = path.parent / f".{path.stem}.{secrets.token_hex(8)}.tmp{suffix}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # another writer's name (1 in 2^64): draw again
            continue
        os.close(fd)
        break
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def _check_grid(
    origin: ArrayLike, spacing: ArrayLike, shape: Sequence[int]
) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    o = np.asarray(origin, dtype=np.float64)
    s = np.asarray(spacing, dtype=np.float64)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise ValueError(f"origin must be 3 finite numbers, got {origin!r}")
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise ValueError(f"spacing must be 3 finite numbers > 0, got {spacing!r}")
    shp = tuple(int(n) for n in shape)
    if len(shp) != 3 or any(n < 1 for n in shp) or any(int(n) != n for n in shape):
        raise ValueError(f"shape must be 3 integers >= 1, got {shape!r}")
    return o, s, (shp[0], shp[1], shp[2])


def _vtk_order(name: str, values: ArrayLike, shape: tuple[int, int, int]) -> np.ndarray:
    """(nx, ny, nz[, c]) C-order array -> (nx*ny*nz[, c]) with x fastest (VTK point order)."""
    a = np.asarray(values)
    if a.shape[:3] != shape or a.ndim not in (3, 4):
        raise ValueError(f"point array {name!r} must have shape {shape} or {shape} + (n_components,), got {a.shape}")
    if a.ndim == 3:
        return np.ascontiguousarray(a.transpose(2, 1, 0)).reshape(-1)
    return np.ascontiguousarray(a.transpose(2, 1, 0, 3)).reshape(-1, a.shape[3])


def _field_value(name: str, value: FieldDataValue) -> np.ndarray | str | list[str]:
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        raise ValueError(f"field data {name!r}: booleans are not supported, write 'true'/'false' or 0/1")
    if isinstance(value, (int, float)) or isinstance(value, numbers.Real):  # numpy scalars are Real too
        return np.array([float(value)])
    items = list(value)
    if items and all(isinstance(v, str) for v in items):
        return [str(v) for v in items]
    try:
        arr = np.asarray(items, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"field data {name!r} must be a string, a number or a list of either") from exc
    if arr.ndim != 1:
        raise ValueError(f"field data {name!r} must be a flat list")
    return arr


def write_field_vti(
    path: str | Path,
    origin: ArrayLike,
    spacing: ArrayLike,
    shape: Sequence[int],
    point_arrays: Mapping[str, ArrayLike],
    field_data: Mapping[str, FieldDataValue] | None = None,
) -> Path:
    """Write a regular-grid field as VTK ImageData (.vti), atomically.

    Parameters
    ----------
    path : destination file (the ``.vti`` suffix is expected by VTK readers).
    origin : (3,) float, metres, world frame: position of node (0, 0, 0).
    spacing : (3,) float > 0, metres: dx, dy, dz.
    shape : (nx, ny, nz) node counts, each >= 1.
    point_arrays : name -> array of shape (nx, ny, nz) or (nx, ny, nz, n_components), C order, indexed
        [i, j, k]; value [i, j, k] belongs to the node at ``origin + (i dx, j dy, k dz)``. Stored as VTK
        point data with their own dtype (float64 stays float64).
    field_data : name -> str, number or list of str / numbers: units and conventions, e.g.
        ``{"spl_units": "dB re 20 uPa", "time_convention": "exp(-i w t)", "frequency_hz": 500.0}``.

    Returns
    -------
    The destination path.
    """
    from bentray.engine.vti_writer import write_image_data

    o, s, shp = _check_grid(origin, spacing, shape)
    if not point_arrays:
        raise ValueError("point_arrays must hold at least one array")
    points = {}
    for name, values in point_arrays.items():
        if not isinstance(name, str) or not name:
            raise ValueError("point array names must be non-empty strings")
        points[name] = _vtk_order(name, values, shp)
    fields = {}
    for name, value in (field_data or {}).items():
        if not isinstance(name, str) or not name:
            raise ValueError("field data names must be non-empty strings")
        fields[name] = _field_value(name, value)
    path = Path(path)
    with _atomic_path(path, path.suffix or ".vti") as tmp:  # lz4: README job 0.18 s vs 0.98 s zlib, 2.8 vs 2.5 MB
        write_image_data(tmp, shp, s, o, points, fields)
    return path


# ---------------------------------------------------------------------------------------------
# PNG preview
# ---------------------------------------------------------------------------------------------
def nearest_index(origin: float, spacing: float, n: int, value: float) -> int:
    """Index of the grid node ``origin + i spacing`` (0 <= i < n) nearest ``value``, clamped to the grid.

    Ties (a value exactly half-way) go to the lower index.
    """
    if n < 1 or not spacing > 0.0:
        raise ValueError("need n >= 1 and spacing > 0")
    if not math.isfinite(value):
        raise ValueError(f"value must be finite, got {value}")
    i = math.ceil((value - origin) / spacing - 0.5)
    return min(max(i, 0), n - 1)


def preview_slice_indices(
    origin: ArrayLike, spacing: ArrayLike, shape: Sequence[int], source_xyz: ArrayLike, receiver_z: float
) -> tuple[int, int]:
    """(k, j) of the preview slices: the horizontal slice at the z-node nearest ``receiver_z`` and the
    vertical x-z slice at the y-node nearest the source's y. Positions in metres, world frame."""
    o, s, shp = _check_grid(origin, spacing, shape)
    src = np.asarray(source_xyz, dtype=np.float64)
    if src.shape != (3,):
        raise ValueError(f"source_xyz must have shape (3,), got {src.shape}")
    k = nearest_index(o[2], s[2], shp[2], float(receiver_z))
    j = nearest_index(o[1], s[1], shp[1], float(src[1]))
    return k, j


def terrain_following_slice(
    values: np.ndarray, origin: ArrayLike, spacing: ArrayLike, ground_z: np.ndarray, height: float
) -> np.ndarray:
    """(nx, ny) values at the z-node nearest ``ground_z[i, j] + height`` in each grid column (NaN where
    that node is outside the grid). values (nx, ny, nz); origin, spacing (3,) metres; ground_z (nx, ny)."""
    o = np.asarray(origin, dtype=np.float64)
    s = np.asarray(spacing, dtype=np.float64)
    nx, ny, nz = values.shape
    kk = np.rint((np.asarray(ground_z, dtype=np.float64) + height - o[2]) / s[2]).astype(np.int64)
    inside = (kk >= 0) & (kk < nz)
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    return np.where(inside, values[ii, jj, np.clip(kk, 0, nz - 1)], np.nan)


# DIN 18005-2:1991 colours of the 5 dB classes (< 35, 35-40, ..., 75-80, >= 80 dB), as NoiseModelling
# encodes them (Docs/styles/style_din_18005-2.sld); ISO 1996-2:1987 gave the same scheme. Greens below
# 45 dB, yellow-brown-orange 45-60, reds 60-70, violet and blues from 70.
DIN_18005_CLASS_EDGES_DB: tuple[float, ...] = tuple(float(v) for v in range(35, 81, 5))
DIN_18005_COLOURS: tuple[str, ...] = (
    "#B7CE8E", "#1D8435", "#0E4C3C", "#ECD721", "#9F6F2C", "#EF7926",
    "#C71932", "#8D1A27", "#88497B", "#18558C", "#134367",
)  # fmt: skip
NO_DATA_COLOUR = "#FFFFFF"  # no value (no beam reached the point, inside a solid, outside the grid)
BUILDING_COLOUR = "#8C8C8C"


def _scale(finite: np.ndarray, db_range: float | None, classes: bool) -> tuple[Any, Any, list[float] | None]:
    """(norm, cmap, class edges or None): DIN 18005 classes of 5 dB for levels, else a continuous
    viridis scale spanning [top - db_range, top], top the 99.5th percentile (the source node is singular)."""
    from matplotlib.colors import BoundaryNorm, ListedColormap, Normalize

    if classes:
        edges = list(DIN_18005_CLASS_EDGES_DB)
        cmap = ListedColormap(DIN_18005_COLOURS[1:-1]).with_extremes(
            under=DIN_18005_COLOURS[0], over=DIN_18005_COLOURS[-1], bad=NO_DATA_COLOUR
        )
        return BoundaryNorm(edges, cmap.N), cmap, edges
    if finite.size:
        vmax = float(np.percentile(finite, PREVIEW_TOP_PERCENTILE))
        vmin = float(finite.min()) if db_range is None else max(float(finite.min()), vmax - float(db_range))
        if vmin == vmax:
            vmin, vmax = vmin - 1.0, vmax + 1.0
    else:
        vmin, vmax = 0.0, 1.0
    from matplotlib import colormaps

    return Normalize(vmin=vmin, vmax=vmax), colormaps["viridis"].with_extremes(bad=NO_DATA_COLOUR), None


def _image(
    fig: Any, ax: Any, u: np.ndarray, v: np.ndarray, data: np.ndarray, style: Any, label: str, equal: bool
) -> Any:
    """An image of ``data`` (nu, nv) on node axes u, v (each node a cell) with its colour bar."""
    norm, cmap, edges = style
    du = u[1] - u[0] if len(u) > 1 else 1.0
    dv = v[1] - v[0] if len(v) > 1 else 1.0
    extent = (u[0] - du / 2, u[-1] + du / 2, v[0] - dv / 2, v[-1] + dv / 2)
    im = ax.imshow(np.ma.masked_invalid(data).T, origin="lower", extent=extent, norm=norm, cmap=cmap,
                   interpolation="nearest", aspect="equal" if equal else "auto")  # fmt: skip
    bar = fig.colorbar(im, cax=fig.add_axes((0.0, 0.0, 0.1, 1.0)), label=label, extend="both")  # placed by place_panels
    if edges is not None:
        bar.set_ticks(edges)
        bar.ax.set_title("DIN 18005", fontsize=7)
    return extent


def _line(ax: Any, x: np.ndarray, y: np.ndarray, x_label: str, label: str) -> None:
    ax.plot(x, np.ma.masked_invalid(y), marker="." if len(x) < 50 else None, color="C0")
    ax.set_xlabel(x_label)
    ax.set_ylabel(label)
    ax.grid(True, alpha=0.3)


def _nice_length(span: float) -> float:
    """A 1-2-5 x 10^n length near a fifth of ``span`` (metres) for the scale bar."""
    target = max(span / 5.0, 1e-9)
    base = 10.0 ** math.floor(math.log10(target))
    return float(max(m * base for m in (1.0, 2.0, 5.0) if m * base <= target))


def _scale_bar(ax: Any, extent: tuple[float, float, float, float]) -> None:
    """A black bar of a round length in the lower-left corner of a plan view, labelled in m / km."""
    x0, x1, y0, y1 = extent
    length = _nice_length(x1 - x0)
    bx, by = x0 + 0.05 * (x1 - x0), y0 + 0.06 * (y1 - y0)
    ax.plot([bx, bx + length], [by, by], color="black", linewidth=3, solid_capstyle="butt")
    text = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m"
    ax.text(bx + length / 2, by + 0.02 * (y1 - y0), text, ha="center", va="bottom", fontsize=8)


def _map_overlays(ax: Any, x: np.ndarray, y: np.ndarray, data: np.ndarray, edges: list[float] | None,
                  ground: np.ndarray | None, footprints: Sequence[ArrayLike]) -> list[Any]:  # fmt: skip
    """Isophones (black lines at the class edges), terrain contours (brown, dashed) and buildings on a plan
    view; returns the legend handles they add."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon

    handles: list[Any] = []
    finite = np.isfinite(data)
    if edges is not None and len(x) > 1 and len(y) > 1 and finite.sum() > 3:
        inside = [e for e in edges if np.nanmin(data) < e < np.nanmax(data)]
        if inside:
            ax.contour(x, y, np.ma.masked_invalid(data).T, levels=inside, colors="black", linewidths=0.6)
            handles.append(Line2D([], [], color="black", linewidth=0.6, label="isophones (5 dB)"))
    if ground is not None and len(x) > 1 and len(y) > 1 and np.ptp(ground) > 0:
        ax.contour(x, y, ground.T, levels=8, colors="#7F4F24", linewidths=0.5, linestyles="dashed")
        handles.append(Line2D([], [], color="#7F4F24", linewidth=0.5, linestyle="--", label="terrain contours"))
    for ring in footprints:
        xy = np.asarray(ring, dtype=np.float64)[:, :2]
        ax.add_patch(Polygon(xy, closed=True, facecolor=BUILDING_COLOUR, edgecolor="black", linewidth=0.6))
    if len(footprints):
        handles.append(Patch(facecolor=BUILDING_COLOUR, edgecolor="black", label="buildings"))
    return handles


def _plan_panel(fig: Any, ax: Any, axes: list[np.ndarray], data: np.ndarray, style: Any, label: str,
                src: np.ndarray, ground: np.ndarray | None, footprints: Sequence[ArrayLike]) -> None:  # fmt: skip
    """The horizontal panel as a map: equal aspect, classes, overlays, scale bar, source and a legend
    (no-data included). A line or a point when the grid is one node thick."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    x, y = axes[0], axes[1]
    if len(x) < 2 or len(y) < 2:
        _line(ax, x if len(x) >= 2 else y, data[:, 0] if len(x) >= 2 else data[0, :],
              "x (m)" if len(x) >= 2 else "y (m)", label)  # fmt: skip
        return
    extent = _image(fig, ax, x, y, data, style, label, equal=True)
    handles = _map_overlays(ax, x, y, data, style[2], ground, footprints)
    ax.plot([src[0]], [src[1]], marker="*", color="red", markersize=11, markeredgecolor="black", linestyle="none")
    handles.append(Line2D([], [], marker="*", color="red", markeredgecolor="black", linestyle="none", label="source"))
    handles.append(Patch(facecolor=NO_DATA_COLOUR, edgecolor="black", label="no value"))
    _scale_bar(ax, extent)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(handles=handles, loc="upper right", fontsize=7, framealpha=0.85)


def _section_panel(fig: Any, ax: Any, axes: list[np.ndarray], data: np.ndarray, style: Any, label: str,
                   src: np.ndarray, ground: np.ndarray | None, j: int, z_slice: float) -> None:  # fmt: skip
    """The vertical x-z panel at the source's y: the ground line (terrain) or the slice height."""
    x, z = axes[0], axes[2]
    if len(x) < 2:
        _line(ax, z, data[0, :], "z (m)", label)
        return
    _image(fig, ax, x, z, data, style, label, equal=False)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title(f"vertical slice y = {axes[1][j]:.3g} m")
    ax.plot([src[0]], [src[2]], marker="*", color="red", markersize=10, linestyle="none")
    if ground is not None:
        ax.plot(x, ground[:, j], color="black", linewidth=1.2)
    else:
        ax.axhline(z_slice, color="black", linewidth=0.8, linestyle="--")


def write_preview_png(
    path: str | Path,
    origin: ArrayLike,
    spacing: ArrayLike,
    shape: Sequence[int],
    values: ArrayLike,
    *,
    source_xyz: ArrayLike,
    receiver_z: float,
    title: str = "",
    label: str = "SPL (dB)",
    db_range: float | None = PREVIEW_DB_RANGE,
    ground_z: ArrayLike | None = None,
    receiver_height: float | None = None,
    classes: bool = False,
    footprints: Sequence[ArrayLike] = (),
) -> Path:
    """Write a PNG preview of a field in dB, atomically: a map (x-y) and a vertical section (x-z).

    The map is the horizontal slice at the z-node nearest ``receiver_z`` (over terrain, ``ground_z`` (nx,
    ny) and ``receiver_height``: the node nearest ground + height in each column) at equal aspect, with
    a scale bar, the source (red star), terrain contours, ``footprints`` (plan rings (n, 2), metres) and a
    legend that includes "no value" (white: NaN / inf, no beam reached the point). ``classes`` (levels
    such as SPL): 5 dB classes 35 ... 80 dB in the DIN 18005-2:1991 colours (``DIN_18005_COLOURS``) with
    isophones at the class edges; otherwise a continuous viridis scale over ``db_range`` dB below the
    99.5th percentile (None: down to the smallest finite value; TL arrays). The section is the x-z slice
    at the y-node nearest the source (:func:`preview_slice_indices`). A panel one node thick is a line
    plot; one contained in the other (nz == 1, or ny == 1) is dropped. ``title``: the figure's title
    (one per job: a sweep names the value in it). values (nx, ny, nz) dB [i, j, k]; positions metres.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from bentray.engine.preview_layout import place_panels

    o, s, shp = _check_grid(origin, spacing, shape)
    v = np.asarray(values, dtype=np.float64)
    if v.shape != shp:
        raise ValueError(f"values must have shape {shp}, got {v.shape}")
    src = np.asarray(source_xyz, dtype=np.float64)
    k, j = preview_slice_indices(o, s, shp, src, receiver_z)
    axes = [o[d] + s[d] * np.arange(shp[d]) for d in range(3)]
    horizontal, ground = v[:, :, k], None
    if ground_z is not None and receiver_height is not None:
        ground = np.asarray(ground_z, dtype=np.float64).reshape(shp[0], shp[1])
        horizontal = terrain_following_slice(v, o, s, ground, float(receiver_height))
    panels = ([("h", horizontal)] if not (shp[1] == 1 and shp[2] > 1) else []) + (
        [("v", v[:, j, :])] if shp[2] > 1 else []
    )
    shown = np.concatenate([p[1].ravel() for p in panels])
    finite = shown[np.isfinite(shown)]
    style = _scale(finite, db_range, classes)
    fig = Figure(figsize=(6.0 * len(panels), 4.5))
    FigureCanvasAgg(fig)
    panel_axes = []
    for n, (kind, data) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), n + 1)
        panel_axes.append(ax)
        if kind == "h":
            _plan_panel(fig, ax, axes, data, style, label, src, ground, footprints)
            where = f"{receiver_height:.3g} m above the ground" if ground is not None else f"z = {axes[2][k]:.3g} m"
            ax.set_title(f"map at {where}")
        else:
            _section_panel(fig, ax, axes, data, style, label, src, ground, j, float(axes[2][k]))
        if not finite.size:
            ax.text(0.5, 0.5, "no finite values", transform=ax.transAxes, ha="center", va="center")
    if title:
        fig.suptitle(title)
    place_panels(fig, panel_axes, title)  # margins from the texts drawn; constrained layout cost 0.2 s more
    path = Path(path)
    with _atomic_path(path, ".png") as tmp:
        fig.savefig(str(tmp), format="png", dpi=100)
    return path
