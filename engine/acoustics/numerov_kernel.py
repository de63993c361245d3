"""One Numerov row of the wavenumber integral (engine/acoustics/wavenumber.py), compiled.

The fast field program marches phi(z; kappa) row by row over N wavenumbers at once (N = 2^15-2^16 for a
km-scale map at 0.5-1 kHz, tens of thousands of rows). Per row and wavenumber, with f = k^2(z) - kappa^2
and cc = h^2 / 12,

    phi_new = (2 (1 - 5 cc f_here) phi_here - (1 + cc f_last) phi_last) / (1 + cc f_next).

As numpy expressions that row is about ten passes over N complex numbers with temporaries and a complex
division by Smith's algorithm: 7.7-9.8 ns per row and wavenumber (the consultant example's refractive
shadow: 12 s of its 26 s). :func:`numerov_row` does one pass in real arithmetic and divides through the
conjugate, (a + ib) / (c + id) = ((ac + bd) + i(bc - ad)) / (c^2 + d^2): 1.4-1.8 ns, a fifth of the time.
That division is safe here because the divisor 1 + cc (k^2 - kappa^2) stays near 1: kappa runs over
0..2 k0 and cc k0^2 = (2 pi / 12)^2 / 12 = 0.023 at the Numerov step lambda / 12, so c + id lies between
about 0.93 and 1.03 (the absorbing layer adds an imaginary part of at most 0.023 LAYER_STRENGTH); nothing
can overflow or underflow in c^2 + d^2. The result differs from numpy's (Smith's division, possibly fused
multiply-adds) by rounding only (tests/shadows/test_numerov_kernel.py, against the numpy row kept in
tests/reference/numerov_numpy.py): a row to 4e-16 of its largest value; levels to 1e-9 dB within 40 dB of
the loudest point and 1e-4 dB deep in a shadow, where the FFT's cancellation amplifies either form's
rounding (1.3e-5 dB at most on the consultant map).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from bentray.engine.constants import NJIT_FLAGS

__all__ = ["numerov_row"]


@nb.njit(**NJIT_FLAGS)
def numerov_row(
    k2_here: complex,
    k2_last: complex,
    k2_next: complex,
    kap2: np.ndarray,
    cc: float,
    here: np.ndarray,
    last: np.ndarray,
    out: np.ndarray,
) -> None:
    """out[i] = (2 (1 - 5 cc (k2_here - kap2[i])) here[i] - (1 + cc (k2_last - kap2[i])) last[i])
    / (1 + cc (k2_next - kap2[i])), i over the N wavenumbers.

    k2_* : k(z)^2 (1/m^2, complex in the absorbing layer) of the row marched from (here), the row before
    it (last) and the row being made (next); kap2 (N,) complex kappa^2 (1/m^2); cc = h^2 / 12 (m^2); here,
    last (N,) complex the two rows before; out (N,) complex, written (it must not be ``here`` or
    ``last``). Marching up: (k2[j], k2[j - 1], k2[j + 1]); down: (k2[j], k2[j + 1], k2[j - 1])."""
    hr, hi = k2_here.real, k2_here.imag
    lr, li = k2_last.real, k2_last.imag
    nr, ni = k2_next.real, k2_next.imag
    for i in range(kap2.size):
        kr = kap2[i].real
        ki = kap2[i].imag
        ar = 2.0 * (1.0 - 5.0 * cc * (hr - kr))
        ai = 2.0 * -(5.0 * cc * (hi - ki))
        br = 1.0 + cc * (lr - kr)
        bi = cc * (li - ki)
        cr = 1.0 + cc * (nr - kr)
        ci = cc * (ni - ki)
        pr = here[i].real
        pi = here[i].imag
        qr = last[i].real
        qi = last[i].imag
        num_r = (ar * pr - ai * pi) - (br * qr - bi * qi)
        num_i = (ar * pi + ai * pr) - (br * qi + bi * qr)
        inv = 1.0 / (cr * cr + ci * ci)
        out[i] = complex((num_r * cr + num_i * ci) * inv, (num_i * cr - num_r * ci) * inv)
