"""Turbulent scattering into refractive shadows: the engineering level of the heuristic model.

    dL_s = 25 + 10 lg(gamma_T) + 3 lg(f / 1000 Hz) + 10 lg(R / 100 m)   dB re the free field at R,
    gamma_T = C_T^2 / T0^2 + (22/3) C_v^2 / c0^2   (m^-2/3),

the scattered level in a shadow zone relative to the free-field level at the same distance R (L'Esperance,
Herzog, Daigle and Nicolas 1992, Applied Acoustics 37:111, "Heuristic model for outdoor sound propagation
based on an extension of the geometrical ray theory in the case of a linear sound speed profile", whose
shadow-zone term is an empirical fit to Daigle's shadow-zone data; taken over by Nord2000, Plovsing, DELTA
AV 1106/07, for its scattering zone). gamma_T is 4 C_n^2 with the effective index structure parameter of
moving media C_n^2 = C_T^2 / (4 T0^2) + (22/12) C_v^2 / c0^2 (Ostashev; Wilson), the combination that
sets the scattering cross-section; the +10 lg(R/100 m) makes the scattered energy fall as 1/R, not 1/R^2.
The constants could not be read in the primary documents from this project's sources (see docs/physics.md
"Refractive shadows" for what was checked); the 22/3 ratio is consistent with the Ostashev/Wilson C_n^2.

T0 = c0^2 / (gamma R_air) (gamma = 1.4, R_air = 287.05 J/(kg K)): the temperature of the ground sound speed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["gamma_t", "scattered_energy", "scattered_level_db"]

_GAMMA_AIR = 1.4
_R_AIR = 287.05  # J/(kg K)


def gamma_t(c_t2: float, c_v2: float, c0: float) -> float:
    """gamma_T (m^-2/3) = C_T^2/T0^2 + (22/3) C_v^2/c0^2, T0 = c0^2/(1.4 * 287.05) (c0 in m/s)."""
    if not (c_t2 >= 0 and c_v2 >= 0 and c0 > 0):
        raise ValueError("C_T^2, C_v^2 must be >= 0 and c0 > 0")
    t0 = c0 * c0 / (_GAMMA_AIR * _R_AIR)
    return c_t2 / t0**2 + (22.0 / 3.0) * c_v2 / c0**2


def scattered_level_db(
    frequency_hz: ArrayLike, distance_m: ArrayLike, c_t2: float, c_v2: float, c0: float
) -> np.ndarray:
    """dL_s (dB re the free field at the same distance), broadcast over frequency (Hz) and distance (m);
    -inf when gamma_T = 0."""
    g = gamma_t(c_t2, c_v2, c0)
    f = np.asarray(frequency_hz, float)
    r = np.asarray(distance_m, float)
    with np.errstate(divide="ignore"):
        return 25.0 + 10.0 * np.log10(g) + 3.0 * np.log10(f / 1000.0) + 10.0 * np.log10(r / 100.0)


def scattered_energy(frequency_hz: ArrayLike, distance_m: ArrayLike, c_t2: float, c_v2: float, c0: float) -> np.ndarray:
    """Scattered |p|^2 re the free field at 1 m: 10^(dL_s/10) / R^2 (R the source-point distance, m)."""
    r = np.asarray(distance_m, float)
    return 10.0 ** (scattered_level_db(frequency_hz, r, c_t2, c_v2, c0) / 10.0) / (r * r)
