"""bentray lden on synthetic results: the period maps and Lden against the formulas, and its refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bentray.clients.cli import main
from bentray.engine.field_output import write_field_vti

rasterio = pytest.importorskip("rasterio")


def _result(tmp_path, name, level, origin=(0.0, 0.0, 0.0)):
    d = tmp_path / name
    write_field_vti(d / "field.vti", origin, (10.0, 10.0, 1.0), level.shape, {"spl_a": level})
    return d


def test_lden_maps_by_hand(tmp_path):
    rng = np.random.default_rng(1)
    fav, hom = 50 + 10 * rng.random((6, 4, 2)), 45 + 10 * rng.random((6, 4, 2))
    a, b = _result(tmp_path, "fav", fav), _result(tmp_path, "hom", hom)
    args = ["lden", "--condition", str(a), "0.5", "0.75", "1", "--condition", str(b), "0.5", "0.25", "0",
            "--z", "1", "--out", str(tmp_path / "out"), "--hours", "14,2,8"]  # fmt: skip
    assert main(args) == 0
    lf, lh = fav[:, :, 1], hom[:, :, 1]
    per = [10 * np.log10(p * 10 ** (lf / 10) + (1 - p) * 10 ** (lh / 10)) for p in (0.5, 0.75, 1.0)]
    hand = 10 * np.log10(
        (14 * 10 ** (per[0] / 10) + 2 * 10 ** ((per[1] + 5) / 10) + 8 * 10 ** ((per[2] + 10) / 10)) / 24
    )
    with rasterio.open(tmp_path / "out" / "map_lden.tif") as src:
        got = src.read(1).astype(np.float64)[::-1].T  # rows north first -> [i, j]
    np.testing.assert_allclose(got, hand, rtol=0, atol=1e-4)
    with rasterio.open(tmp_path / "out" / "map_lnight.asc") as src:
        np.testing.assert_allclose(src.read(1).astype(np.float64)[::-1].T, lf, rtol=0, atol=1e-5)
    assert math.isfinite(float(got.mean()))


def test_lden_refuses_bad_shares_and_different_grids(tmp_path, capsys):
    a = _result(tmp_path, "a", np.full((3, 3, 1), 50.0))
    b = _result(tmp_path, "b", np.full((3, 3, 1), 50.0), origin=(5.0, 0.0, 0.0))
    out = str(tmp_path / "out")
    assert main(["lden", "--condition", str(a), "0.5", "1", "1", "--z", "0", "--out", out]) == 1
    assert "day shares" in capsys.readouterr().err
    args = ["lden", "--condition", str(a), "0.5", "0.5", "0.5", "--condition", str(b), "0.5", "0.5", "0.5", "--z", "0",
            "--out", out]  # fmt: skip
    assert main(args) == 1
    assert "differs" in capsys.readouterr().err
