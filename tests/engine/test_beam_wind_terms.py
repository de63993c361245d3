"""The wind's paraxial terms in closed form against central differences of the effective medium.

- paraxial.beam_wind_terms (beams: d m0/dgamma_k alone) and paraxial.wind_terms (trace(paraxial=True): d m0
  and the chord-middle gradient's d g/dgamma_k, through the wind speed's exact Hessian, wind.speed_hessian).
- Oracle: tests/reference/wind_fd.py, the same derivatives of the effective medium c + u.e by central
  differences (relative step WIND_FD_REL; its own rounding and O(h^2) truncation about 1e-7 relative; it was
  the engine's wind_terms until 2026-12). Random states in a log-law and a ridge wind for the three analytic
  curves, on the downwind, upwind and crosswind sides. Measured worst difference of d m0 relative to
  |g_cell| max|X_k|: 5e-8 to 9.8e-8, the central differences' own truncation (the log law's third
  derivative near the ground over the 5e-5 m step).
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.constants import CURVE_CODES
from bentray.engine.kernels import paraxial
from bentray.engine.wind import speed_hessian, wind_spec
from tests.reference import wind_fd

C_REF = 340.0
WINDS = {
    "log": {"u_star": 0.5, "z_g": 0.1, "direction_deg": 20.0},
    "ridge": {"u_star": 0.5, "z_g": 0.1, "direction_deg": 0.0, "height_m": 40.0, "half_width_m": 200.0},
}


def _cell_model(curve: str, z: float) -> tuple[float, np.ndarray]:
    """The cell's traced quantity at height z and its gradient (a downward log-like c profile)."""
    c = 340.0 + np.log(z + 1.0)
    dc = 1.0 / (z + 1.0)
    if curve == "parabolic":
        return (C_REF / c) ** 2, np.array([0.0, 0.0, -2.0 * C_REF**2 / c**3 * dc])
    if curve == "circular":
        return c, np.array([0.0, 0.0, dc])
    return C_REF / c, np.array([0.0, 0.0, -C_REF / c**2 * dc])


@pytest.mark.parametrize("kind", sorted(WINDS))
@pytest.mark.parametrize("curve", ["parabolic", "circular", "n_linear"])
def test_closed_form_wind_term_matches_the_central_differences(curve, kind):
    code, params = wind_spec(kind, WINDS[kind])
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(200):
        x = np.array([rng.uniform(-600.0, 600.0), rng.uniform(-100.0, 100.0), rng.uniform(0.3, 60.0)])
        az = rng.uniform(-np.pi, np.pi)
        e = np.array([np.cos(az), np.sin(az), 0.0])
        d = np.array([np.cos(0.1) * e[0], np.cos(0.1) * e[1], np.sin(0.1)])
        par = rng.normal(size=paraxial.PAR_SIZE) * np.array([30.0] * 6 + [0.5] * 6)
        m_raw, g_cell = _cell_model(curve, x[2])
        cc = CURVE_CODES[curve]
        seg_fd = np.zeros(paraxial.SEG_SIZE)
        seg_cf = np.zeros(paraxial.SEG_SIZE)
        paraxial.tangent_derivs(par, d, 1.0, seg_fd)
        paraxial.tangent_derivs(par, d, 1.0, seg_cf)
        planes = np.zeros((4, 4))
        neighbours = np.full(4, -9, dtype=np.int64)
        model = (m_raw, g_cell, planes, neighbours, 0.5, False, x.copy())
        wind_fd.wind_terms(cc, C_REF, (code, params, e), model, x, d, par, seg_fd, np.zeros(21))
        paraxial.beam_wind_terms(cc, C_REF, (code, params, e), m_raw, g_cell, x, par, seg_cf)
        scale = np.abs(g_cell).max() * np.abs(par[:6]).max() + 1e-6 * abs(m_raw)
        worst = max(worst, float(np.max(np.abs(seg_cf[6:8] - seg_fd[6:8])) / scale))
        assert np.all(seg_cf[8:14] == 0.0)
    print(curve, kind, worst)
    assert worst < 1e-6, worst


def _box_cell(x: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A cube of half-width ``half`` around x as face planes (mx, my, mz, h) and neighbour slots."""
    planes = np.zeros((6, 4))
    for i in range(3):
        for sign, f in ((1.0, 2 * i), (-1.0, 2 * i + 1)):
            planes[f, i] = sign
            planes[f, 3] = sign * x[i] + half
    return planes, np.zeros(6, dtype=np.int64)


@pytest.mark.parametrize("kind", sorted(WINDS))
@pytest.mark.parametrize("curve", ["parabolic", "circular", "n_linear"])
def test_closed_form_wind_terms_with_the_chord_middle_match_the_central_differences(curve, kind):
    """paraxial.wind_terms, d m0 and d g at the chord middle (which moves with X_k, D_k and the chord length),
    against the central-difference oracle (Richardson-extrapolated over two steps): d m0 within 1e-6 of
    |g_cell| max|X_k|, d g within 1e-7 of its own size (the larger |d g| of the pair, plus 1e-3 |g_cell|).
    Measured: d m0 1.5e-7..2.6e-7, the oracle's rounding at the smaller step amplified 5/3 by the
    extrapolation (without it, the single 5e-5 m step's truncation gave 2e-6 at 0.11 m above the ridge's
    surface, falling 4x per halving towards the closed form); d g 2e-9..9e-9."""
    code, params = wind_spec(kind, WINDS[kind])
    rng = np.random.default_rng(5)
    worst_m, worst_g = 0.0, 0.0
    for _ in range(200):
        x = np.array([rng.uniform(-600.0, 600.0), rng.uniform(-100.0, 100.0), rng.uniform(0.3, 60.0)])
        az = rng.uniform(-np.pi, np.pi)
        e = np.array([np.cos(az), np.sin(az), 0.0])
        el = rng.uniform(-0.3, 0.3)
        d = np.array([np.cos(el) * e[0], np.cos(el) * e[1], np.sin(el)])
        par = rng.normal(size=paraxial.PAR_SIZE) * np.array([30.0] * 6 + [0.5] * 6)
        half = min(0.25 * x[2], 5.0)
        planes, neighbours = _box_cell(x + rng.uniform(-0.5, 0.5, 3) * half, half)
        m_raw, g_cell = _cell_model(curve, x[2])
        mds = planes[:, :3] @ d
        ahead = [(planes[f, 3] - planes[f, :3] @ x) / mds[f] for f in range(6) if mds[f] > 0]
        x_mid = x + 0.5 * min(ahead) * d
        cc = CURVE_CODES[curve]
        seg_cf = np.zeros(paraxial.SEG_SIZE)
        paraxial.tangent_derivs(par, d, 1.0, seg_cf)
        # the oracle's step is WIND_FD_REL of the cell size it is given: 0.5 m and 0.25 m (5e-5 and 2.5e-5 m
        # steps), Richardson-extrapolated, so that its O(h^2) truncation near the ground (the log law's third
        # derivative: 2e-6 relative at 0.11 m above the ridge's surface, falling 4x per halving) is gone
        fd = []
        for cell_size in (0.5, 0.25):
            seg = np.zeros(paraxial.SEG_SIZE)
            paraxial.tangent_derivs(par, d, 1.0, seg)
            model = (m_raw, g_cell, planes, neighbours, cell_size, True, x_mid)
            wind_fd.wind_terms(cc, C_REF, (code, params, e), model, x, d, par, seg, np.zeros(21))
            fd.append(seg)
        seg_fd = (4.0 * fd[1] - fd[0]) / 3.0
        paraxial.wind_terms(cc, C_REF, (code, params, e), model, x, d, par, seg_cf)
        scale_m = np.abs(g_cell).max() * np.abs(par[:6]).max() + 1e-6 * abs(m_raw)
        worst_m = max(worst_m, float(np.max(np.abs(seg_cf[6:8] - seg_fd[6:8])) / scale_m))
        scale_g = max(np.abs(seg_fd[8:14]).max(), np.abs(seg_cf[8:14]).max()) + 1e-3 * np.abs(g_cell).max()
        worst_g = max(worst_g, float(np.max(np.abs(seg_cf[8:14] - seg_fd[8:14])) / scale_g))
        assert seg_cf[16] == 1.0
    print(curve, kind, worst_m, worst_g)
    assert worst_m < 1e-6 and worst_g < 1e-7, (worst_m, worst_g)


@pytest.mark.parametrize("kind", sorted(WINDS))
def test_wind_speed_hessian_matches_differences_of_its_gradient(kind):
    """wind.speed_hessian's second derivatives against central differences (step 1e-4 m) of the exact gradient
    (wind.speed_at), and its value and gradient equal speed_at's, over the ridge's slopes and in the layer below
    z_g: within 2e-6 relative to the largest second derivative."""
    from bentray.engine.wind import speed_at

    code, params = wind_spec(kind, WINDS[kind])
    z_g = float(params[1])
    rng = np.random.default_rng(0)
    worst = 0.0
    compared = 0
    for _ in range(300):
        x = np.array([rng.uniform(-600.0, 600.0), 0.0, rng.uniform(0.0, 60.0)])
        surface = float(params[4])
        if kind == "ridge":  # heights above the ridge's surface, some inside the layer below z_g
            surface += 40.0 * 200.0**2 / ((x[0] - params[7]) ** 2 + 200.0**2)
            x[2] = surface + rng.uniform(0.02, 60.0)
        out = np.array(speed_hessian(code, params, x))
        u, ux, uz = speed_at(code, params, x)
        assert out[0] == u and out[1] == ux and out[2] == uz
        h = 1e-4
        if abs(x[2] - surface - z_g) < 0.01 or x[2] - surface < 0.01:  # no difference across a branch edge
            continue

        def grad(y):
            return np.array(speed_at(code, params, y)[1:])

        gx = (grad(x + [h, 0, 0]) - grad(x - [h, 0, 0])) / (2 * h)
        gz = (grad(x + [0, 0, h]) - grad(x - [0, 0, h])) / (2 * h)
        fd = np.array([gx[0], gx[1], gz[1]])
        worst = max(worst, float(np.max(np.abs(fd - out[3:])) / (np.abs(out[3:]).max() + 1e-12)))
        compared += 1
    print(kind, compared, worst)
    assert compared > 250 and worst < 2e-6, worst
