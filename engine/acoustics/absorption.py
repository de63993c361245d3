"""Atmospheric absorption of pure tones, ISO 9613-1:1993 (docs/physics.md §8).

The attenuation coefficient ``alpha`` (dB per metre of path) follows the standard's closed form: the
classical and rotational term plus the vibrational relaxation of oxygen and nitrogen, with relaxation
frequencies that depend on the molar concentration of water vapour ``h``. ``h`` comes from the relative
humidity through the standard's saturation-vapour-pressure formula (ISO 9613-1 Annex B):

    psat / pr = 10^C,   C = -6.8346 (T01 / T)^1.261 + 4.6151,    T01 = 273.16 K
    h = h_r (psat / pr) / (pa / pr)                                (h in %, h_r relative humidity in %)
    frO = (pa/pr) (24 + 4.04e4 h (0.02 + h) / (0.391 + h))
    frN = (pa/pr) (T/T0)^(-1/2) (9 + 280 h exp(-4.170 ((T/T0)^(-1/3) - 1)))
    alpha = 8.686 f^2 [ 1.84e-11 (pa/pr)^-1 (T/T0)^(1/2)
                        + (T/T0)^(-5/2) ( 0.01275 exp(-2239.1/T) / (frO + f^2/frO)
                                          + 0.1068 exp(-3352.0/T) / (frN + f^2/frN) ) ]      dB/m

with T0 = 293.15 K and pr = 101.325 kPa.

Octave bands: the standard's tables (ISO 9613-1 Table 1, ISO 9613-2 Table 2) are computed at the *exact*
midband frequencies ``1000 * 10^(0.3 k)`` Hz and labelled with the nominal ones (63, 125, ..., 8000).
The difference matters at high bands: at 8 kHz the exact midband is 7943 Hz and alpha(8000 Hz) is about
1.3 % larger than alpha(7943 Hz), which moves 20 C / 70 % from the table's 76.6 to 77.6 dB/km. Use
:data:`bentray.engine.acoustics.weighting.OCTAVE_BANDS_EXACT_HZ` to reproduce band values.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "REFERENCE_PRESSURE_KPA",
    "REFERENCE_TEMPERATURE_K",
    "TRIPLE_POINT_K",
    "absorption_db_per_m",
    "water_vapour_molar_percent",
]

REFERENCE_PRESSURE_KPA = 101.325  # pr: reference ambient atmospheric pressure (ISO 9613-1 clause 3)
REFERENCE_TEMPERATURE_K = 293.15  # T0: reference air temperature, 20 C
TRIPLE_POINT_K = 273.16  # T01: triple-point isotherm temperature (Annex B saturation formula)
_KELVIN = 273.15

# Input ranges accepted (the standard quotes its formulae as accurate to +-10 % for -20..50 C,
# 10..100 % humidity and pressures below 200 kPa; we accept a wider temperature range, as requested by
# the scene schema, and leave the accuracy statement to the caller).
_T_MIN_C, _T_MAX_C = -50.0, 60.0


def _check_scalar(name: str, value: float, lo: float, hi: float, lo_open: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real number, got {value!r}") from exc
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    below = x <= lo if lo_open else x < lo
    if below or x > hi:
        bracket = "(" if lo_open else "["
        raise ValueError(f"{name} must lie in {bracket}{lo}, {hi}], got {x}")
    return x


def water_vapour_molar_percent(temperature_c: float, humidity_percent: float, pressure_kpa: float) -> float:
    """Molar concentration of water vapour h (percent) from relative humidity, ISO 9613-1 Annex B.

    Parameters
    ----------
    temperature_c : air temperature, degrees Celsius.
    humidity_percent : relative humidity, percent (0..100).
    pressure_kpa : ambient atmospheric pressure, kPa.
    """
    t_k = temperature_c + _KELVIN
    c_exp = -6.8346 * (TRIPLE_POINT_K / t_k) ** 1.261 + 4.6151
    return humidity_percent * 10.0**c_exp / (pressure_kpa / REFERENCE_PRESSURE_KPA)


def absorption_db_per_m(
    frequency_hz: ArrayLike,
    temperature_c: float,
    humidity_percent: float,
    pressure_kpa: float = REFERENCE_PRESSURE_KPA,
) -> np.ndarray:
    """Pure-tone atmospheric attenuation coefficient, ISO 9613-1 (dB per metre).

    Parameters
    ----------
    frequency_hz : array_like of float, any shape, Hz, every value > 0.
    temperature_c : air temperature, degrees Celsius, in [-50, 60].
    humidity_percent : relative humidity, percent, in [0, 100].
    pressure_kpa : ambient pressure, kPa, > 0 (default 101.325).

    Returns
    -------
    alpha : float64 ndarray with the shape of ``frequency_hz``, dB/m (a 0-d array for a scalar input).
        The sound pressure level over a path of length L drops by ``alpha * L``.

    Raises
    ------
    ValueError naming the offending argument.
    """
    t_c = _check_scalar("temperature_c", temperature_c, _T_MIN_C, _T_MAX_C)
    h_r = _check_scalar("humidity_percent", humidity_percent, 0.0, 100.0)
    p_a = _check_scalar("pressure_kpa", pressure_kpa, 0.0, math.inf, lo_open=True)
    f = np.asarray(frequency_hz, dtype=np.float64)
    if not np.all(np.isfinite(f)) or np.any(f <= 0.0):
        raise ValueError("frequency_hz must be finite and > 0 everywhere")

    t_k = t_c + _KELVIN
    p_rel = p_a / REFERENCE_PRESSURE_KPA
    t_rel = t_k / REFERENCE_TEMPERATURE_K
    h = water_vapour_molar_percent(t_c, h_r, p_a)
    fr_o = p_rel * (24.0 + 4.04e4 * h * (0.02 + h) / (0.391 + h))
    fr_n = p_rel * t_rel**-0.5 * (9.0 + 280.0 * h * math.exp(-4.170 * (t_rel ** (-1.0 / 3.0) - 1.0)))
    f2 = f * f
    classical = 1.84e-11 / p_rel * math.sqrt(t_rel)
    oxygen = 0.01275 * math.exp(-2239.1 / t_k) / (fr_o + f2 / fr_o)
    nitrogen = 0.1068 * math.exp(-3352.0 / t_k) / (fr_n + f2 / fr_n)
    return 8.686 * f2 * (classical + t_rel**-2.5 * (oxygen + nitrogen))
