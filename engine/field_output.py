"""Writers for the 3D sound field on a regular grid: VTK ImageData (.vti) and a PNG preview.

Grid convention (both writers): node (i, j, k) of a grid with ``shape = (nx, ny, nz)`` lies at
``origin + (i dx, j dy, k dz)`` (metres, world frame, z up); node arrays are numpy arrays of shape
``(nx, ny, nz)`` (or ``(nx, ny, nz, n_components)``) indexed ``[i, j, k]`` in C order. VTK stores point
data with x fastest (point id ``i + nx (j + ny k)``); :func:`write_field_vti` does that reordering.

Files are written to a temporary file in the destination folder and moved into place with
``os.replace``, so a failed write never leaves a partial file. pyvista and matplotlib are imported
lazily; the PNG writer uses ``matplotlib.figure.Figure`` with the Agg canvas directly and never touches
pyplot or the global backend.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import os
import tempfile
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
    """Yield a temporary path in ``path``'s folder (same suffix, so writers pick the format); replace on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
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
    import pyvista as pv

    o, s, shp = _check_grid(origin, spacing, shape)
    if not point_arrays:
        raise ValueError("point_arrays must hold at least one array")
    grid = pv.ImageData(dimensions=shp, spacing=tuple(s), origin=tuple(o))
    for name, values in point_arrays.items():
        if not isinstance(name, str) or not name:
            raise ValueError("point array names must be non-empty strings")
        grid.point_data[name] = _vtk_order(name, values, shp)
    for name, value in (field_data or {}).items():
        if not isinstance(name, str) or not name:
            raise ValueError("field data names must be non-empty strings")
        grid.field_data[name] = _field_value(name, value)
    path = Path(path)
    with _atomic_path(path, path.suffix or ".vti") as tmp:
        grid.save(str(tmp), binary=True)
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


def _panel(
    fig: Any,
    ax: Any,
    axis_u: np.ndarray,
    axis_v: np.ndarray,
    data: np.ndarray,
    u_label: str,
    v_label: str,
    norm: Any,
    label: str,
) -> None:
    """Draw one slice: an image if both axes have >= 2 nodes, a line if one has 1, a point if both."""
    masked = np.ma.masked_invalid(data)
    nu, nv = data.shape
    if nu >= 2 and nv >= 2:
        du, dv = axis_u[1] - axis_u[0], axis_v[1] - axis_v[0]
        extent = (axis_u[0] - du / 2, axis_u[-1] + du / 2, axis_v[0] - dv / 2, axis_v[-1] + dv / 2)
        im = ax.imshow(
            masked.T, origin="lower", extent=extent, aspect="auto", norm=norm, cmap="viridis", interpolation="nearest"
        )
        fig.colorbar(im, ax=ax, label=label, extend="both")
        ax.set_xlabel(u_label)
        ax.set_ylabel(v_label)
        return
    if nu >= 2 or nv >= 2:
        x, y, xl = (axis_u, masked[:, 0], u_label) if nu >= 2 else (axis_v, masked[0, :], v_label)
    else:
        x, y, xl = axis_u, masked[:, 0], u_label
    ax.plot(x, y, marker="." if len(x) < 50 else None, color="C0")
    ax.set_xlabel(xl)
    ax.set_ylabel(label)
    ax.grid(True, alpha=0.3)


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
) -> Path:
    """Write a two-panel PNG preview of a field in dB, atomically.

    Panels: the horizontal x-y slice at the z-node nearest ``receiver_z`` and the vertical x-z slice at
    the y-node nearest the source (:func:`preview_slice_indices`), one shared colour scale with a colour
    bar in dB. NaN and +-inf are left blank. A slice one node thick along an axis is drawn as a line plot;
    a panel whose slice is contained in the other one (nz == 1: the x-z slice is a row of the x-y slice;
    ny == 1: the x-y slice is a row of the x-z slice) is dropped, so a receiver line of shape (n, 1, 1)
    gives one line plot.

    Parameters
    ----------
    values : (nx, ny, nz) float, dB, C order indexed [i, j, k] (see the module docstring).
    source_xyz : (3,) float, metres, world frame (marked on the panels).
    receiver_z : height of the horizontal slice, metres.
    db_range : the colour scale spans [top - db_range, top], top the 99.5th percentile of the finite values
        shown (values above saturate); None: down to the smallest finite value.
    ground_z, receiver_height : over terrain, the ground height (nx, ny) metres under each grid column
        and the receiver height above it: the horizontal panel then follows the terrain (the node nearest
        ground + receiver_height in each column; blank where that is outside the grid) and the vertical
        panel draws the ground line.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    o, s, shp = _check_grid(origin, spacing, shape)
    v = np.asarray(values, dtype=np.float64)
    if v.shape != shp:
        raise ValueError(f"values must have shape {shp}, got {v.shape}")
    src = np.asarray(source_xyz, dtype=np.float64)
    k, j = preview_slice_indices(o, s, shp, src, receiver_z)
    axes = [o[d] + s[d] * np.arange(shp[d]) for d in range(3)]
    horizontal = v[:, :, k]  # (nx, ny)
    vertical = v[:, j, :]  # (nx, nz)
    ground = None
    if ground_z is not None and receiver_height is not None:
        ground = np.asarray(ground_z, dtype=np.float64).reshape(shp[0], shp[1])
        horizontal = terrain_following_slice(v, o, s, ground, float(receiver_height))
    panels = []
    if not (shp[1] == 1 and shp[2] > 1):
        panels.append(("h", horizontal))
    if shp[2] > 1:
        panels.append(("v", vertical))

    shown = np.concatenate([p[1].ravel() for p in panels])
    finite = shown[np.isfinite(shown)]
    if finite.size:
        # The 99.5th percentile rather than the maximum: the field is singular at the source, and one
        # near-source node would otherwise push everything else to the bottom of the scale.
        vmax = float(np.percentile(finite, PREVIEW_TOP_PERCENTILE))
        vmin = float(finite.min()) if db_range is None else max(float(finite.min()), vmax - float(db_range))
        if vmin == vmax:
            vmin, vmax = vmin - 1.0, vmax + 1.0
    else:
        vmin, vmax = 0.0, 1.0
    norm = Normalize(vmin=vmin, vmax=vmax)

    fig = Figure(figsize=(6.0 * len(panels), 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    for n, (kind, data) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), n + 1)
        if kind == "h":
            _panel(fig, ax, axes[0], axes[1], data, "x (m)", "y (m)", norm, label)
            ax.set_title(
                f"{receiver_height:.3g} m above the ground"
                if ground is not None
                else f"horizontal slice z = {axes[2][k]:.3g} m"
            )
            if shp[0] > 1 and shp[1] > 1:
                ax.plot([src[0]], [src[1]], marker="*", color="red", markersize=10, linestyle="none")
        else:
            _panel(fig, ax, axes[0], axes[2], data, "x (m)", "z (m)", norm, label)
            ax.set_title(f"vertical slice y = {axes[1][j]:.3g} m")
            if shp[0] > 1 and shp[2] > 1:
                ax.plot([src[0]], [src[2]], marker="*", color="red", markersize=10, linestyle="none")
                if ground is not None:
                    ax.plot(axes[0], ground[:, j], color="black", linewidth=1.2)
                else:
                    ax.axhline(axes[2][k], color="white", linewidth=0.8, linestyle="--")
        if not finite.size:
            ax.text(0.5, 0.5, "no finite values", transform=ax.transAxes, ha="center", va="center")
    if title:
        fig.suptitle(title)
    path = Path(path)
    with _atomic_path(path, ".png") as tmp:
        fig.savefig(str(tmp), format="png", dpi=100)
    return path
