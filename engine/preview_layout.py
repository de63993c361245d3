"""A fixed layout for preview.png's panels, measured from the few texts that set the margins.

matplotlib's constrained layout measured every tick label of every axes two or three times before the
figure was drawn (about 0.2 s of the README job's 0.4 s preview). Here each panel's margins come from
its tick labels' widths (the strings the axes' own locators and formatters will draw) and the label and
title heights, measured once each with the canvas's renderer; panels sit side by side in equal cells of
the figure, each with its colour bar (full panel height, on its right) when it has an image.

Sizes are in inches (figure size) and pixels (renderer) as named; positions in figure fractions.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["place_panels"]

PAD_IN = 0.06  # between a text and its neighbour, and around the figure's edge
BAR_WIDTH_IN = 0.2  # colour bar width
BAR_GAP_IN = 0.12  # between an axes and its colour bar
EXTEND_FRACTION = 0.05  # matplotlib's default length of a colour bar's extend triangle, as a fraction of the bar


def _text_px(renderer: Any, texts: Sequence[str], size: Any) -> tuple[float, float]:
    """(largest width, largest height + descent) of ``texts`` at font ``size``, pixels (0, 0 for none)."""
    from matplotlib.font_manager import FontProperties

    prop = FontProperties(size=size)
    width = height = 0.0
    for text in texts:
        if text:
            w, h, d = renderer.get_text_width_height_descent(text, prop, ismath=False)
            width, height = max(width, w), max(height, h + d)
    return width, height


def _tick_labels(axis: Any) -> list[str]:
    """The major tick labels ``axis`` will draw for its current view limits (no drawing)."""
    lo, hi = sorted(axis.get_view_interval())
    locs = [loc for loc in axis.get_major_locator()() if lo <= loc <= hi]
    return list(axis.get_major_formatter().format_ticks(locs))


def _tick_extent_px(axis: Any, renderer: Any) -> float:
    """Tick length + pad + widest (y axis) or tallest (x axis) tick label, pixels."""
    from matplotlib import rcParams

    if axis.axis_name == "y":
        w, _ = _text_px(renderer, _tick_labels(axis), rcParams["ytick.labelsize"])
        return (rcParams["ytick.major.size"] + rcParams["ytick.major.pad"]) / 72.0 * renderer.dpi + w
    _, h = _text_px(renderer, _tick_labels(axis), rcParams["xtick.labelsize"])
    return (rcParams["xtick.major.size"] + rcParams["xtick.major.pad"]) / 72.0 * renderer.dpi + h


def place_panels(fig: Any, axes: Sequence[Any], title: str) -> None:
    """Position ``axes`` (one per panel, left to right) in equal cells of ``fig``; an axes showing an
    image with a colour bar (``fig.colorbar(image, cax=...)``) gets that bar on its right, as tall as
    the panel. Margins fit the tick labels, axis labels, axes titles and the figure's ``title``."""
    from matplotlib import rcParams

    renderer = fig.canvas.get_renderer()
    dpi = renderer.dpi
    fig_w, fig_h = fig.get_size_inches()
    cell_w = fig_w / len(axes)
    _, sup_h = _text_px(renderer, [title], rcParams["figure.titlesize"])
    for n, ax in enumerate(axes):
        bar = ax.images[0].colorbar if ax.images else None
        _, title_h = _text_px(renderer, [ax.get_title()], rcParams["axes.titlesize"])
        _, xlabel_h = _text_px(renderer, [ax.get_xlabel()], rcParams["axes.labelsize"])
        _, ylabel_h = _text_px(renderer, [ax.get_ylabel()], rcParams["axes.labelsize"])
        label_pad = rcParams["axes.labelpad"] / 72.0 * dpi
        title_pad = rcParams["axes.titlepad"] / 72.0 * dpi
        left_px = ylabel_h + label_pad + _tick_extent_px(ax.yaxis, renderer)
        bottom_px = xlabel_h + label_pad + _tick_extent_px(ax.xaxis, renderer)
        top_px = (sup_h + PAD_IN * dpi if title else 0.0) + (title_h + title_pad if ax.get_title() else 0.0)
        right_in = PAD_IN
        if bar is not None:
            bar_title = bar.ax.get_title()
            _, bar_title_h = _text_px(renderer, [bar_title], bar.ax.title.get_fontsize())
            _, bar_label_h = _text_px(renderer, [bar.ax.get_ylabel()], rcParams["axes.labelsize"])
            bar_right_px = _tick_extent_px(bar.ax.yaxis, renderer) + label_pad + bar_label_h
            top_px = max(top_px, bar_title_h + title_pad + (sup_h + PAD_IN * dpi if title else 0.0))
            right_in += bar_right_px / dpi + BAR_WIDTH_IN + BAR_GAP_IN
        x0 = n * cell_w + PAD_IN + left_px / dpi
        x1 = (n + 1) * cell_w - right_in
        y0 = PAD_IN + bottom_px / dpi
        y1 = fig_h - PAD_IN - top_px / dpi
        ax.set_position((x0 / fig_w, y0 / fig_h, (x1 - x0) / fig_w, (y1 - y0) / fig_h))
        if bar is not None:  # the extend triangles are drawn outside the bar's axes: keep them in the panel
            ext = (bar.extend in ("both", "min")) + (bar.extend in ("both", "max"))
            frac = EXTEND_FRACTION * (y1 - y0) / (1.0 + ext * EXTEND_FRACTION)
            b0 = y0 + frac * (bar.extend in ("both", "min"))
            b1 = y1 - frac * (bar.extend in ("both", "max"))
            bar.ax.set_position(((x1 + BAR_GAP_IN) / fig_w, b0 / fig_h, BAR_WIDTH_IN / fig_w, (b1 - b0) / fig_h))
