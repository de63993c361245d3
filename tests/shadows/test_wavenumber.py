"""The wavenumber integral (engine/acoustics/wavenumber.py) in homogeneous air, where the field is known
exactly: the image source over rigid ground and the exact complex-image-line solution over grass
(tests/reference/image_source.py, independent code). Its stratified-medium checks against the GFPE are in
tests/shadows/test_shadow_gfpe.py."""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.acoustics.ground import delany_bazley_impedance
from bentray.engine.acoustics.wavenumber import ffp_cells, ffp_field
from tests.reference import image_source

RANGES = np.array([30.0, 80.0, 200.0, 450.0, 800.0])
HOMOGENEOUS = lambda z: np.full(np.shape(z), 343.0)  # noqa: E731 - image_source's default c0


@pytest.mark.parametrize(("f", "zs"), [(100.0, 2.0), (250.0, 1.0), (100.0, 0.5)])
def test_rigid_ground_is_the_image_source(f, zs):
    heights = [0.0, 1.5, 4.0]
    got = ffp_field(f, HOMOGENEOUS, None, zs, heights, 1000.0, 100.0)
    for i, zr in enumerate(heights):
        ref = image_source.pressure(f, zs, RANGES, [zr])[:, 0]
        p = got.pressure(RANGES, np.full(RANGES.size, i))
        np.testing.assert_allclose(20 * np.log10(np.abs(p) / np.abs(ref)), 0.0, atol=0.2)


def test_grass_is_the_exact_solution():
    f, zs, zr = 250.0, 2.0, 1.5
    z = complex(delany_bazley_impedance(f, 200_000.0))
    got = ffp_field(f, HOMOGENEOUS, z, zs, [zr], 1000.0, 100.0).pressure(RANGES, np.zeros(RANGES.size, int))
    ref = image_source.exact_pressure(f, zs, RANGES, [zr], 200_000.0)[:, 0]
    np.testing.assert_allclose(20 * np.log10(np.abs(got) / np.abs(ref)), 0.0, atol=0.2)


def test_bad_arguments_and_the_cost_measure():
    with pytest.raises(ValueError, match="z_top"):
        ffp_field(100.0, HOMOGENEOUS, None, 2.0, [50.0], 1000.0, 40.0)
    with pytest.raises(ValueError, match="frequency_hz"):
        ffp_field(-1.0, HOMOGENEOUS, None, 2.0, [1.5], 1000.0, 100.0)
    assert ffp_field(100.0, HOMOGENEOUS, None, 2.0, [1.5], 1000.0, 100.0).cells == ffp_cells(
        100.0, 343.0, 2.0, 1000.0, 100.0
    )
    assert ffp_cells(200.0, 343.0, 2.0, 1000.0, 100.0) > 3.9 * ffp_cells(100.0, 343.0, 2.0, 1000.0, 100.0)


def test_receivers_tens_of_metres_above_the_source_stay_finite():
    """Evanescent wavenumbers grow like exp(sqrt(kappa^2 - k^2) z) over the stored heights: at 646 Hz in a
    log profile, receivers up to 36 m made both recursions overflow and the whole field nan (a job's band map
    came out nan). Oracle: the same integral with the low receivers alone (nothing above 16 m to grow over)
    must give their pressures unchanged, and every pressure must be finite."""
    c = lambda z: 340.0 + np.log1p(np.asarray(z, float))  # noqa: E731 - the log profile, b = 1 m/s, z_g = 1 m
    heights = np.array([1.0, 6.0, 11.0, 16.0, 21.0, 26.0, 31.0, 36.0])
    r = np.array([20.0, 60.0, 150.0])
    for f in (646.0, 694.0):
        full = ffp_field(f, c, None, 1.5, heights, 191.1, 92.0)
        low = ffp_field(f, c, None, 1.5, heights[:4], 191.1, 92.0)
        assert np.all(np.isfinite(full.psi))
        p_full = np.array([full.pressure(r, np.full(r.size, i)) for i in range(heights.size)])
        p_low = np.array([low.pressure(r, np.full(r.size, i)) for i in range(4)])
        np.testing.assert_allclose(p_full[:4], p_low, rtol=1e-9)
        assert np.all(np.abs(p_full) > 0.0)


def test_renormalising_with_a_receiver_on_every_row_keeps_the_low_receivers():
    """400 receivers from 1 to 36 m put a stored row at every height the marches renormalise at, so the row a
    march carries on from is a stored row itself (dividing the stored rows in place divided it twice: 13 %
    off). Oracle as above: the receivers up to 16 m alone."""
    c = lambda z: 340.0 + np.log1p(np.asarray(z, float))  # noqa: E731
    dense = np.linspace(1.0, 36.0, 400)
    low = dense[dense <= 16.0]
    r = np.array([20.0, 60.0, 150.0])
    full = ffp_field(646.0, c, None, 1.5, dense, 191.1, 92.0)
    alone = ffp_field(646.0, c, None, 1.5, low, 191.1, 92.0)
    assert np.all(np.isfinite(full.psi))
    p_full = np.array([full.pressure(r, np.full(r.size, i)) for i in range(low.size)])
    p_alone = np.array([alone.pressure(r, np.full(r.size, i)) for i in range(low.size)])
    np.testing.assert_allclose(p_full, p_alone, rtol=1e-9)


def test_receivers_far_above_the_source_leave_the_source_rows_alive():
    """The night-noise-map example (log profile, source 2 m up, receivers to 57.5 m, 500 m map, z_top 135 m): at
    575-694 Hz the upward recursion, marched to the top receiver, renormalised its evanescent wavenumbers by
    factors so large that their rows at the source underflowed to 0, the Wronskian there became 0 / 0 and the
    band's whole spectrum nan (the example's 500 Hz map: 203,788 of 204,020 points without a level). Only the
    rows at and below the source are read from that recursion. Oracle: finite everywhere, and the receivers up
    to 16 m give the pressures they give alone (where nothing grows beyond double precision)."""
    c = lambda z: 340.0 + np.log1p(np.asarray(z, float))  # noqa: E731 - the example's profile
    heights = np.arange(0.5, 58.0, 3.0)
    r = np.array([50.0, 200.0, 600.0])
    for f in (575.0, 694.0):
        full = ffp_field(f, c, None, 2.0, heights, 707.2, 135.0)
        low = ffp_field(f, c, None, 2.0, heights[heights <= 16.0], 707.2, 135.0)
        assert np.all(np.isfinite(full.psi)), f
        n_low = low.heights_m.size
        p_full = np.array([full.pressure(r, np.full(r.size, i)) for i in range(n_low)])
        p_low = np.array([low.pressure(r, np.full(r.size, i)) for i in range(n_low)])
        np.testing.assert_allclose(p_full, p_low, rtol=1e-9)
