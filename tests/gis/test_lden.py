"""Lden and the meteorological combination against hand computations (scalar formulas, 1e-9 dB)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bentray.engine.export.lden import combine_conditions, energy_sum, lden, period_level


def test_lden_equal_penalised_levels_is_that_level():
    # Ld = 60, Le + 5 = 60, Ln + 10 = 60: every period contributes 10^6, Lden = 60 exactly
    assert float(lden(60.0, 55.0, 50.0)) == pytest.approx(60.0, abs=1e-9)


def test_lden_matches_the_directive_formula():
    ld, le, ln = 65.0, 62.0, 57.0
    hand = 10 * math.log10((12 * 10 ** (65 / 10) + 4 * 10 ** ((62 + 5) / 10) + 8 * 10 ** ((57 + 10) / 10)) / 24)
    assert float(lden(ld, le, ln)) == pytest.approx(hand, abs=1e-9)
    # 14 / 2 / 8 hours and custom penalties
    hand2 = 10 * math.log10((14 * 10**6.5 + 2 * 10 ** ((62 + 3) / 10) + 8 * 10 ** ((57 + 8) / 10)) / 24)
    assert float(lden(ld, le, ln, hours=(14, 2, 8), penalties_db=(0, 3, 8))) == pytest.approx(hand2, abs=1e-9)
    # arrays broadcast elementwise
    out = lden(np.array([60.0, 65.0]), np.array([55.0, 62.0]), np.array([50.0, 57.0]))
    np.testing.assert_allclose(out, [60.0, hand], rtol=0, atol=1e-9)


def test_meteorological_combination_cnossos():
    p, lf, lh = 0.35, 61.0, 55.5
    hand = 10 * math.log10(p * 10 ** (lf / 10) + (1 - p) * 10 ** (lh / 10))
    assert float(period_level(lf, lh, p)) == pytest.approx(hand, abs=1e-9)
    three = combine_conditions([60.0, 57.0, 50.0], [0.5, 0.3, 0.2])
    hand3 = 10 * math.log10(0.5 * 1e6 + 0.3 * 10**5.7 + 0.2 * 1e5)
    assert float(three) == pytest.approx(hand3, abs=1e-9)
    assert float(energy_sum([50.0, 50.0])) == pytest.approx(50.0 + 10 * math.log10(2), abs=1e-9)
    assert np.isnan(combine_conditions([np.nan, 50.0], [0.5, 0.5]))  # an unreached point stays unknown


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: lden(60, 55, 50, hours=(12, 4, 7)), "sum to 24"),
        (lambda: lden(60, 55, 50, hours=(12, 4)), "3 values"),
        (lambda: combine_conditions([60, 50], [0.5, 0.6]), "sum to 1"),
        (lambda: combine_conditions([60, 50], [1.5, -0.5]), r"\[0, 1\]"),
    ],
)
def test_bad_arguments(call, match):
    with pytest.raises(ValueError, match=match):
        call()
