"""The asymptotic series of the auxiliary Fresnel functions (engine/diffraction/kernels.py, x >= 6, the
faster path of the UTD transition function) against mpmath at 40 digits (g + i f from mpmath's C, S):
within 1e-15 of |g + i f| from x = 6 to 1e12 (measured 2026-12-02: <= 3.3e-16; the continued fraction
it replaces there: up to 4e-14), and C, S within 10 x 1e-16 (1 + x / 2) of scipy's (cephes) Fresnel
integrals (the rounding of the phase pi x^2 / 2 times f ~ 1 / (pi x))."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
from scipy.special import fresnel

from bentray.engine.diffraction.kernels import _X_ASYMPTOTIC, aux_fg, fresnel_cs, transition


def _exact_gf(x: float) -> complex:
    with mp.workdps(40):
        xm = mp.mpf(x)
        big_x = mp.pi * xm * xm / 2
        half_c = mp.mpf(1) / 2 - mp.fresnelc(xm)
        half_s = mp.mpf(1) / 2 - mp.fresnels(xm)
        g = half_c * mp.cos(big_x) + half_s * mp.sin(big_x)
        f = half_s * mp.cos(big_x) - half_c * mp.sin(big_x)
        return complex(float(g), float(f))


def test_asymptotic_aux_functions_against_mpmath() -> None:
    xs = np.concatenate([np.linspace(_X_ASYMPTOTIC, 40.0, 120), np.geomspace(40.0, 1e12, 40)])
    worst_fg = 0.0
    worst_cs = 0.0
    for x in xs:
        ref = _exact_gf(float(x))
        f, g = aux_fg(float(x))
        worst_fg = max(worst_fg, abs(complex(g, f) - ref) / abs(ref))
        if x < 1e4:  # beyond, cos and sin of pi x^2 / 2 carry no digits in float64
            c, s = fresnel_cs(float(x))
            s_ref, c_ref = fresnel(float(x))
            # both round the phase X = pi x^2 / 2 (error ~1e-16 X, times f ~ 1/(pi x)): scaled out
            tol = 1e-16 * (1.0 + math.pi * x * x / 2.0 / (math.pi * x))
            worst_cs = max(worst_cs, abs(c - c_ref) / tol, abs(s - s_ref) / tol)
    print(f"\n max |g + i f - mpmath| / |g + i f| {worst_fg:.1e}, max |C, S - scipy| / tol {worst_cs:.1f}")
    assert worst_fg < 1e-15
    assert worst_cs < 10.0


def test_transition_continuous_at_the_switch() -> None:
    big = math.pi * _X_ASYMPTOTIC**2 / 2.0  # X where u = sqrt(2 X / pi) reaches the switch
    lo = transition(big * (1 - 1e-12))
    hi = transition(big * (1 + 1e-12))
    assert abs(hi - lo) < 1e-12 * abs(hi)
    assert abs(abs(transition(1e6)) - 1.0) < 1e-6
