"""The lean kernel's four-lane advance stage (engine/kernels/lane_advance4.py) against the scalar helpers.

Oracle: parabolic.travel_time, parabolic.state_at and parabolic.arc_length, one lane at a time (the code the
generic kernel runs). ``advance4`` must give the same dt, position, unit tangent and (for lanes it does not
flag) arc length *bit for bit*, and flag exactly the lanes whose arc length parabolic.arc_length takes with
its 4-point rule or the closed form (half-turning ratio e above ARC_E3, or a nan test), on lanes spread over
the 2-point, 3-point and flagged ranges, on special values (+-0, nan, +-inf, huge and tiny numbers), and in a
hypothesis search over single lanes.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bentray.engine.kernels import parabolic
from bentray.engine.kernels.lane_advance4 import advance4

C_REF = 340.0


@nb.njit(cache=False)
def _run(lf, lx, out_vec, out_sca, masks):
    """Lanes in groups of four: advance4 into out_vec (dt, xn (3), dn (3), ds), the helpers into out_sca."""
    n = lf.shape[0]
    lxn = np.empty((n, 3))
    ldn = np.empty((n, 3))
    lds = np.full(n, np.nan)
    for first in range(0, n - 3, 4):
        masks[first // 4] = advance4(lf, lx, lxn, ldn, lds, first, C_REF)
    xn = np.empty(3)
    dn = np.empty(3)
    for k in range(n):
        out_vec[k, 0] = lf[k, 11]
        out_vec[k, 1:4] = lxn[k]
        out_vec[k, 4:7] = ldn[k]
        out_vec[k, 7] = lds[k]
        g = (lf[k, 1], lf[k, 2], lf[k, 3])
        p0 = (lf[k, 4], lf[k, 5], lf[k, 6])
        out_sca[k, 0] = parabolic.travel_time(lf[k, 0], lf[k, 7], lf[k, 8], lf[k, 10], C_REF)
        parabolic.state_at(lx[k], p0, g, lf[k, 10], xn, dn)
        out_sca[k, 1:4] = xn
        out_sca[k, 4:7] = dn
        out_sca[k, 7] = parabolic.arc_length(p0, g, lf[k, 10])


def _lanes(
    m0: np.ndarray, g: np.ndarray, p0: np.ndarray, sigma: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    n = m0.size
    lf = np.zeros((n, 12))
    lf[:, 0] = m0
    lf[:, 1:4] = g
    lf[:, 4:7] = p0
    with np.errstate(all="ignore"):
        lf[:, 7] = g[:, 0] * p0[:, 0] + g[:, 1] * p0[:, 1] + g[:, 2] * p0[:, 2]
        lf[:, 8] = g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1] + g[:, 2] * g[:, 2]
    lf[:, 10] = sigma
    return lf, np.ascontiguousarray(x)


def _check(lf: np.ndarray, lx: np.ndarray) -> np.ndarray:
    """Compare; returns the flagged lanes (bool (n,)) of the complete groups of four."""
    n = lf.shape[0] - lf.shape[0] % 4
    lf, lx = np.ascontiguousarray(lf[:n]), np.ascontiguousarray(lx[:n])
    out_vec = np.empty((n, 8))
    out_sca = np.empty((n, 8))
    masks = np.zeros(n // 4, dtype=np.int64)
    _run(lf, lx, out_vec, out_sca, masks)
    flagged = ((masks[:, None] >> np.arange(4)[None, :]) & 1).astype(bool).ravel()
    same = (out_vec == out_sca) | (np.isnan(out_vec) & np.isnan(out_sca))
    same &= np.signbit(out_vec) == np.signbit(out_sca)
    same[flagged, 7] = True  # a flagged lane's length is the caller's to take
    bad = ~same.all(axis=1)
    assert not bad.any(), (
        f"{int(bad.sum())} of {n} lanes differ; first {np.argmax(bad)}: {out_vec[bad][0]} vs {out_sca[bad][0]}"
    )
    # flagged exactly where arc_length leaves the 2- and 3-point rules (e above ARC_E3 or a nan test)
    p0, g, sigma = lf[:, 4:7], lf[:, 1:4], lf[:, 10]
    with np.errstate(all="ignore"):
        mm = (p0[:, 0] * p0[:, 0] + p0[:, 1] * p0[:, 1]) + p0[:, 2] * p0[:, 2]
        q = 0.0625 * ((g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1]) + g[:, 2] * g[:, 2]) * sigma * sigma
        expect = ~((q <= parabolic.ARC_Q2 * mm) | (q <= parabolic.ARC_Q3 * mm))
    assert np.array_equal(flagged, expect)
    return flagged


def test_lanes_across_the_quadrature_ranges() -> None:
    rng = np.random.default_rng(3)
    n = 40_000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    m0 = rng.uniform(0.8, 1.2, size=n)
    p0 = d * np.sqrt(m0)[:, None]
    g = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-9, -2, size=(n, 1))
    g[rng.random(n) < 0.05] = 0.0
    # sigma spread so that e = |g| sigma / (4 |p_mid|) covers the 2-point, 3-point and flagged ranges
    e = 10.0 ** rng.uniform(-7, -1, size=n)
    sigma = 4.0 * e / np.maximum(np.linalg.norm(g, axis=1), 1e-12)
    sigma[rng.random(n) < 0.02] = 0.0
    x = rng.normal(size=(n, 3)) * 1e3
    lf, lx = _lanes(m0, g, p0, sigma, x)
    flagged = _check(lf, lx)
    assert 0 < flagged.sum() < 0.5 * flagged.size


SPECIAL = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 5e-324, 1e-160, 1e150, -1e300, 1.0, -3.0])


def test_special_values() -> None:
    rng = np.random.default_rng(5)
    n = 20_000
    lf, lx = _lanes(
        rng.uniform(0.5, 2.0, n), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.uniform(0, 10, n),
        rng.normal(size=(n, 3)),
    )  # fmt: skip
    for arr in (lf[:, :11], lx):
        hit = rng.random(arr.shape) < 0.1
        arr[hit] = rng.choice(SPECIAL, size=int(hit.sum()))
    _check(lf, lx)


_value = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-5.0, 5.0), st.sampled_from([0.0, -0.0]))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(row=st.lists(_value, min_size=11, max_size=11), x=st.lists(_value, min_size=3, max_size=3))
def test_any_lane(row, x) -> None:
    lf = np.zeros((4, 12))
    lf[:, :11] = row
    lx = np.tile(np.array(x), (4, 1))
    lf[1:, 10] *= 0.5  # the other three lanes: the same lane with shorter steps
    _check(lf, lx)
