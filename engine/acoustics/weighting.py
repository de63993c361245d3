"""Frequency weighting A (IEC 61672-1:2013, Annex E closed form) and octave-band frequencies.

The A-weighting in decibels is

    A(f) = 20 log10( f4^2 f^4 / ((f^2 + f1^2) (f^2 + f2^2)^(1/2) (f^2 + f3^2)^(1/2) (f^2 + f4^2)) ) - A1000

with the pole frequencies derived in the standard's Annex E from f_r = 1000 Hz, f_L = 10^1.5 Hz,
f_H = 10^3.9 Hz, D^2 = 1/2 and f_A = 10^2.45 Hz (f1 = 20.599 Hz, f2 = 107.65 Hz, f3 = 737.86 Hz,
f4 = 12194.2 Hz), and the normalisation constant A1000 = -2.000 dB (so that A(1 kHz) = 0.000 dB to
within 0.0004 dB, as in the standard).

Nominal versus exact frequencies: the standard's tabulated weightings (IEC 61672-1 Table 3) are the
closed form evaluated at the *exact* base-10 midband frequencies ``1000 * 10^(k/10)`` and rounded to
0.1 dB. At the nominal frequencies the rounding differs: A(125 Hz) = -16.19 dB (table -16.1, exact
125.89 Hz gives -16.10) and A(250 Hz) = -8.67 dB (table -8.6, exact 251.19 Hz gives -8.63). Band
calculations should therefore use :data:`OCTAVE_BANDS_EXACT_HZ` and label bands with
:data:`OCTAVE_BANDS_HZ`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "A1000_DB",
    "OCTAVE_BANDS_EXACT_HZ",
    "OCTAVE_BANDS_HZ",
    "a_weighting_db",
    "octave_band_exact_hz",
]

# Nominal octave-band midband frequencies (labels), Hz.
OCTAVE_BANDS_HZ: tuple[float, ...] = (63.0, 125.0, 250.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0)


def octave_band_exact_hz(nominal_hz: ArrayLike) -> np.ndarray:
    """Exact base-10 octave midband frequency ``1000 * 10^(0.3 k)`` nearest each nominal frequency (Hz)."""
    nominal = np.asarray(nominal_hz, dtype=np.float64)
    if not np.all(np.isfinite(nominal)) or np.any(nominal <= 0.0):
        raise ValueError("nominal_hz must be finite and > 0")
    k = np.round(np.log10(nominal / 1000.0) / 0.3)
    return 1000.0 * 10.0 ** (0.3 * k)


# Exact base-10 midband frequencies of OCTAVE_BANDS_HZ: 63.096, 125.89, 251.19, 501.19, 1000, 1995.3,
# 3981.1, 7943.3 Hz.
OCTAVE_BANDS_EXACT_HZ: tuple[float, ...] = tuple(float(f) for f in octave_band_exact_hz(OCTAVE_BANDS_HZ))

A1000_DB = -2.000  # normalisation constant of IEC 61672-1 (dB)


def _pole_frequencies() -> tuple[float, float, float, float]:
    """f1, f2, f3, f4 (Hz) from IEC 61672-1 Annex E, equations E.1 to E.6."""
    f_r, f_l, f_h = 1000.0, 10.0**1.5, 10.0**3.9
    d = math.sqrt(0.5)  # D, with D^2 = 1/2
    c = f_l**2 * f_h**2
    b = (f_r**2 + f_l**2 * f_h**2 / f_r**2 - d * (f_l**2 + f_h**2)) / (1.0 - d)
    root = math.sqrt(b * b - 4.0 * c)
    f1 = math.sqrt((-b - root) / 2.0)
    f4 = math.sqrt((-b + root) / 2.0)
    f_a = 10.0**2.45
    f2 = (3.0 - math.sqrt(5.0)) / 2.0 * f_a
    f3 = (3.0 + math.sqrt(5.0)) / 2.0 * f_a
    return f1, f2, f3, f4


_F1, _F2, _F3, _F4 = _pole_frequencies()


def a_weighting_db(frequency_hz: ArrayLike) -> np.ndarray:
    """A-weighting (dB) at the given frequencies, IEC 61672-1 closed form.

    Parameters
    ----------
    frequency_hz : array_like of float, any shape, Hz, every value > 0.

    Returns
    -------
    float64 ndarray with the shape of ``frequency_hz`` (a 0-d array for a scalar), dB; add it to a
    band level to get the A-weighted band level.
    """
    f = np.asarray(frequency_hz, dtype=np.float64)
    if not np.all(np.isfinite(f)) or np.any(f <= 0.0):
        raise ValueError("frequency_hz must be finite and > 0 everywhere")
    f2 = f * f
    log_num = math.log10(_F4**2) + 2.0 * np.log10(f2)
    log_den = np.log10(f2 + _F1**2) + 0.5 * np.log10(f2 + _F2**2) + 0.5 * np.log10(f2 + _F3**2) + np.log10(f2 + _F4**2)
    return 20.0 * (log_num - log_den) - A1000_DB
