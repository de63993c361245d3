"""place_panels: every panel's texts (tick labels, axis labels, titles, colour bar and its extends) stay
inside the panel's cell of the figure and the colour bar never overlaps its axes (measured after drawing)."""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.preview_layout import place_panels

matplotlib = pytest.importorskip("matplotlib")
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402


def _figure(y_origin: float, title: str) -> tuple[Figure, list]:
    fig = Figure(figsize=(12.0, 4.5))
    FigureCanvasAgg(fig)
    axes = []
    for n, (ylabel, aspect) in enumerate([("y (m)", "equal"), ("z (m)", "auto")]):
        ax = fig.add_subplot(1, 2, n + 1)
        data = np.random.default_rng(n).normal(size=(20, 30)) * 10 - 60
        extent = (-250_000.0, -249_000.0, y_origin, y_origin + 500.0)
        im = ax.imshow(data, origin="lower", extent=extent, aspect=aspect)
        bar = fig.colorbar(im, cax=fig.add_axes((0.0, 0.0, 0.1, 1.0)), label="TL (dB)", extend="both")
        bar.ax.set_title("DIN 18005", fontsize=7)
        ax.set_xlabel("x (m)")
        ax.set_ylabel(ylabel)
        ax.set_title(f"panel {n}")
        axes.append(ax)
    if title:
        fig.suptitle(title)
    return fig, axes


@pytest.mark.parametrize(("y_origin", "title"), [(0.0, "job: title"), (-1_250_000.0, "")])
def test_panels_stay_in_their_cells(y_origin: float, title: str) -> None:
    fig, axes = _figure(y_origin, title)
    place_panels(fig, axes, title)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    for n, ax in enumerate(axes):
        bar = ax.images[0].colorbar
        cell = (n * width / 2, (n + 1) * width / 2)
        for box in (ax.get_tightbbox(renderer), bar.ax.get_tightbbox(renderer)):
            assert cell[0] - 0.5 <= box.x0 and box.x1 <= cell[1] + 0.5, (n, box, cell)
            assert -0.5 <= box.y0 and box.y1 <= height + 0.5, (n, box)
        assert ax.get_window_extent(renderer).x1 < bar.ax.get_window_extent(renderer).x0
        if title:  # the figure title above every axes title
            assert fig._suptitle.get_window_extent(renderer).y0 >= ax.title.get_window_extent(renderer).y1 - 0.5
