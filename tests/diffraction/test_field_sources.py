"""engine/field_sources.py: the combine API (replace, blend, add, inside solids) and the codes."""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine import field_sources as fs


def _arrays(rel: np.ndarray, powered: np.ndarray | None = None) -> dict[str, np.ndarray]:
    out = {f"tl_{lab}hz": -10 * np.log10(np.where(rel[f] > 0, rel[f], np.nan)) for f, lab in enumerate(("500", "1000"))}
    if powered is not None:
        for f, lab in enumerate(("500", "1000")):
            out[f"spl_{lab}hz"] = 10 * np.log10(powered[f] / 1e-12)
        out["spl_a"] = np.zeros(rel.shape[1])
    return out


LABELS = ["500", "1000"]
A_W = np.array([-3.2, 0.0])


def test_replace_blend_add_and_codes() -> None:
    beams = np.array([[1e-4, 1e-4, 0.0, 1e-4, 1e-4], [1e-4, 1e-4, 0.0, 1e-4, 1e-4]])
    arrays = _arrays(beams)
    model = np.full((2, 5), 1e-6)
    w = np.array([[0.0, 1.0, 1.0, 0.5, 0.0]] * 2)
    code = fs.combine(arrays, LABELS, A_W, [fs.Contribution(fs.DIFFRACTED, model, w)], coherent=False)
    tl = arrays["tl_500hz"]
    assert tl[0] == pytest.approx(40.0) and tl[1] == pytest.approx(60.0) and tl[2] == pytest.approx(60.0)
    assert tl[3] == pytest.approx(-10 * np.log10(0.5e-4 + 0.5e-6))
    assert list(code) == [fs.GEOMETRIC, fs.DIFFRACTED, fs.DIFFRACTED, fs.COMBINATION, fs.GEOMETRIC]
    # a second kind (code 3) added on top where its mask is set: energies add
    extra = fs.Contribution(fs.REFRACTIVE_SHADOW, np.full((2, 5), 1e-6), np.array([[0, 0, 0, 0, 1.0]] * 2), mode="add")
    code = fs.combine(arrays, LABELS, A_W, [extra], coherent=False)
    assert arrays["tl_500hz"][4] == pytest.approx(-10 * np.log10(1e-4 + 1e-6))
    assert code[4] == fs.COMBINATION and code[1] == fs.GEOMETRIC  # (now an input level: geometric)


def test_inside_solid_is_nan_and_code_zero_and_spl() -> None:
    rel = np.full((2, 3), 1e-4)
    powered = rel * 1e-3
    arrays = _arrays(rel, powered)
    solid = np.array([False, True, False])
    c = fs.Contribution(fs.DIFFRACTED, np.full((2, 3), 1e-6), np.ones((2, 3)), powered=np.full((2, 3), 1e-9))
    code = fs.combine(arrays, LABELS, A_W, [c], coherent=False, inside_solid=solid)
    assert np.isnan(arrays["tl_500hz"][1]) and np.isnan(arrays["spl_1000hz"][1]) and code[1] == fs.NONE
    assert arrays["spl_500hz"][0] == pytest.approx(30.0)  # 1e-9 W/m^2
    expected_a = 10 * np.log10(10 ** ((30 - 3.2) / 10) + 10 ** (30 / 10))
    assert arrays["spl_a"][0] == pytest.approx(expected_a)
    assert fs.counts(code, solid) == {
        "none": 1, "geometric": 0, "diffracted": 2, "refractive_shadow": 0, "combination": 0, "wave": 0,
        "inside_solid": 1,
    }  # fmt: skip


def test_coherent_pressures_blend() -> None:
    arrays = _arrays(np.full((2, 2), 1.0))
    for lab in LABELS:
        arrays[f"p_re_{lab}hz"] = np.array([1.0, 1.0])
        arrays[f"p_im_{lab}hz"] = np.array([0.0, 0.0])
    c = fs.Contribution(fs.DIFFRACTED, np.full((2, 2), 0.25), np.array([[1.0, 0.5]] * 2), p=np.full((2, 2), -0.5 + 0j))
    fs.combine(arrays, LABELS, A_W, [c], coherent=True)
    assert arrays["p_re_500hz"][0] == pytest.approx(-0.5) and arrays["p_re_500hz"][1] == pytest.approx(0.25)
    assert arrays["tl_500hz"][1] == pytest.approx(-20 * np.log10(0.25))
