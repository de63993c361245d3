"""The beams' closed-form wind term d m0/dgamma_k (kernels/paraxial.beam_wind_terms) against wind_terms.

Oracle: paraxial.wind_terms, which takes the same derivative of the effective medium c + u.e at x by central
differences (relative step WIND_FD_REL; its own rounding and O(h^2) truncation about 1e-7 relative). Random
states in a log-law and a ridge wind for the three analytic curves, on the downwind, upwind and crosswind
sides; the chord-middle gradient terms (which beams drop) are not compared. Measured worst difference of d m0
relative to |g_cell| max|X_k|: 5e-8 to 9.8e-8, the central differences' own truncation (u''' of the log
law near the ground over the 5e-5 m step).
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.constants import CURVE_CODES
from bentray.engine.kernels import paraxial
from bentray.engine.wind import wind_spec

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
        paraxial.wind_terms(cc, C_REF, (code, params, e), model, x, d, par, seg_fd, np.zeros(21))
        paraxial.beam_wind_terms(cc, C_REF, (code, params, e), m_raw, g_cell, x, par, seg_cf, np.zeros(12))
        scale = np.abs(g_cell).max() * np.abs(par[:6]).max() + 1e-6 * abs(m_raw)
        worst = max(worst, float(np.max(np.abs(seg_cf[6:8] - seg_fd[6:8])) / scale))
        assert np.all(seg_cf[8:14] == 0.0)
    print(curve, kind, worst)
    assert worst < 1e-6, worst
