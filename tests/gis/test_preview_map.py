"""preview.png as a map: the image is written at the expected size and shows the DIN 18005 class colours
of the levels it holds, the no-data colour and the buildings (pixel counts, not a visual judgement)."""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.field_output import (
    BUILDING_COLOUR,
    DIN_18005_CLASS_EDGES_DB,
    DIN_18005_COLOURS,
    _nice_length,
    write_preview_png,
)

matplotlib = pytest.importorskip("matplotlib")
from matplotlib.colors import to_rgb  # noqa: E402


def _count(img: np.ndarray, colour: str, tol: float = 1.5 / 255) -> int:
    rgb = np.asarray(to_rgb(colour))
    return int(np.count_nonzero(np.all(np.abs(img[:, :, :3] - rgb) <= tol, axis=2)))


def _field():
    origin, spacing, shape = np.array([0.0, 0.0, 0.0]), np.array([2.0, 2.0, 1.0]), (101, 61, 6)
    x = origin[0] + spacing[0] * np.arange(shape[0])
    level = 82.0 - 0.25 * x  # 82 dB at x = 0 down to 32 dB at x = 200: every class from > 80 to < 35
    values = np.broadcast_to(level[:, None, None], shape).copy()
    values[40:50, 5:15, :] = np.nan  # a hole with no value
    return origin, spacing, shape, values


def test_map_shows_every_class_colour_no_data_and_buildings(tmp_path):
    origin, spacing, shape, values = _field()
    building = [[120.0, 80.0], [150.0, 80.0], [150.0, 100.0], [120.0, 100.0]]
    out = write_preview_png(tmp_path / "preview.png", origin, spacing, shape, values, source_xyz=[10.0, 60.0, 2.0],
                            receiver_z=4.0, title="town: homogeneous", label="SPL (dB(A))", classes=True,
                            footprints=[building])  # fmt: skip
    img = matplotlib.image.imread(out)
    assert img.shape[:2] == (450, 1200)  # map + section, 600 x 450 px each
    counts = {c: _count(img, c) for c in DIN_18005_COLOURS}
    assert all(n > 50 for n in counts.values()), counts  # every class, < 35 and >= 80 included
    assert _count(img, BUILDING_COLOUR) > 100
    assert _count(img, "#FF0000") > 5  # the source star
    assert len(DIN_18005_COLOURS) == len(DIN_18005_CLASS_EDGES_DB) + 1


def test_map_keeps_equal_aspect(tmp_path):
    # a 200 m x 40 m map at equal aspect: the coloured area is about 5 times wider than high
    origin, spacing, shape = np.zeros(3), np.array([2.0, 2.0, 1.0]), (101, 21, 1)
    values = np.full(shape, 62.0)  # one class: 60-65 dB
    out = write_preview_png(tmp_path / "p.png", origin, spacing, shape, values, source_xyz=[10.0, 20.0, 2.0],
                            receiver_z=0.0, classes=True)  # fmt: skip
    img = matplotlib.image.imread(out)
    assert img.shape[:2] == (450, 600)
    rgb = np.asarray(to_rgb(DIN_18005_COLOURS[6]))
    mask = np.all(np.abs(img[:, :, :3] - rgb) <= 1.5 / 255, axis=2)
    # the colour bar has the same colour in a short band: keep the rows and columns mostly in the map
    per_row, per_col = mask.sum(axis=1), mask.sum(axis=0)
    height, width = np.count_nonzero(per_row > 0.5 * per_row.max()), np.count_nonzero(per_col > 0.5 * per_col.max())
    assert width / height == pytest.approx(202 / 42, rel=0.1)


def test_scale_bar_lengths():
    assert [_nice_length(v) for v in (200.0, 1000.0, 37.0, 12_000.0)] == [20.0, 200.0, 5.0, 2000.0]
