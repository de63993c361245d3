"""The compiled Numerov row of the wavenumber integral (engine/acoustics/numerov_kernel.py).

Oracle: the numpy expression the integral used before (tests/reference/numerov_numpy.py), row by
row and through whole integrals (``ffp_field(..., row_step=numerov_row_numpy)``). Only the rounding may
differ (the kernel divides through the conjugate, numpy by Smith's algorithm), so:

- one row: every value within 4e-16 of the row's largest, and within 1e-15 of its two terms' size;
- whole integrals (an upward-refracting log profile over grass, source 3 m, receivers 0-10 m, 500 Hz):
  the reduced field psi within 1e-12 of its largest value; levels within 1e-9 dB where they lie within
  40 dB of the loudest point, and within 1e-4 dB everywhere (deep in the shadow the FFT's sum cancels
  to 1e-6 of its terms, and the rounding of either form grows by as much: 1e-6 to 1e-5 dB there on the
  consultant example's map).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bentray.engine.acoustics.ground import delany_bazley_impedance
from bentray.engine.acoustics.numerov_kernel import numerov_row
from bentray.engine.acoustics.wavenumber import ffp_field
from tests.reference.numerov_numpy import numerov_row_numpy


def _row_inputs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    k0 = 2.0 * math.pi * 1000.0 / 340.0
    kap = k0 + (np.arange(n) - n // 2) * (2.0 * k0 / n) - 1e-3j
    k2 = k0 * k0 * (1.0 + 0.02 * rng.standard_normal(3)) * (1.0 + 1j * rng.random(3))  # the absorbing layer too
    here = rng.standard_normal(n) + 1j * rng.standard_normal(n)
    last = rng.standard_normal(n) + 1j * rng.standard_normal(n)
    cc = (340.0 / 1000.0 / 12.0) ** 2 / 12.0
    return k2, kap * kap, cc, here, last


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_one_row_equals_the_numpy_expression(seed: int) -> None:
    k2, kap2, cc, here, last = _row_inputs(4099, seed)  # not a multiple of a vector width
    got = np.empty_like(here)
    want = np.empty_like(here)
    numerov_row(k2[0], k2[1], k2[2], kap2, cc, here, last, got)
    numerov_row_numpy(k2[0], k2[1], k2[2], kap2, cc, here, last, want)
    assert np.max(np.abs(got - want)) <= 4e-16 * np.max(np.abs(want))
    # each value to a few ulps of its terms' size (the two terms can cancel: then neither form has more digits)
    a = np.abs(2.0 * (1.0 - 5.0 * cc * (k2[0] - kap2)) * here) + np.abs((1.0 + cc * (k2[1] - kap2)) * last)
    scale = a / np.abs(1.0 + cc * (k2[2] - kap2))
    assert np.all(np.abs(got - want) <= 1e-15 * scale)


def test_whole_integrals_equal_the_numpy_rows() -> None:
    f, zs = 500.0, 3.0
    heights = np.array([0.0, 1.5, 4.0, 10.0])

    def c_of_h(h: np.ndarray) -> np.ndarray:  # upward refraction: a shadow beyond ~300 m at these heights
        return 340.0 - np.log1p(np.asarray(h, float))

    z = complex(delany_bazley_impedance(f, 2e5))
    ref = ffp_field(f, c_of_h, z, zs, heights, 900.0, 90.0, row_step=numerov_row_numpy)
    got = ffp_field(f, c_of_h, z, zs, heights, 900.0, 90.0)
    assert got.cells == ref.cells
    assert np.max(np.abs(got.psi - ref.psi)) <= 1e-12 * np.max(np.abs(ref.psi))
    r = np.linspace(20.0, 880.0, 200)
    for i in range(heights.size):
        lp_ref = 20.0 * np.log10(np.abs(ref.pressure(r, np.full(r.size, i))))
        lp_got = 20.0 * np.log10(np.abs(got.pressure(r, np.full(r.size, i))))
        loud = lp_ref > lp_ref.max() - 40.0
        assert np.max(np.abs(lp_got - lp_ref)[loud]) <= 1e-9
        assert np.max(np.abs(lp_got - lp_ref)) <= 1e-4
        assert lp_ref.min() < lp_ref.max() - 40.0  # the case reaches into the shadow (the loose bound is used)
