"""The Numerov row of the wavenumber integral as the numpy expression engine/acoustics/wavenumber.py used until
2026-12-05: the oracle of the compiled row (engine/acoustics/numerov_kernel.py; tests/shadows/test_numerov_kernel.py).
Same arguments as ``numerov_row``; numpy's complex division (Smith's algorithm)."""

from __future__ import annotations

import numpy as np


def numerov_row_numpy(k2_here, k2_last, k2_next, kap2: np.ndarray, cc: float, here, last, out: np.ndarray) -> None:
    """out = (2 (1 - 5 cc (k2_here - kap2)) here - (1 + cc (k2_last - kap2)) last) / (1 + cc (k2_next - kap2))."""
    out[:] = (2.0 * (1.0 - 5.0 * cc * (k2_here - kap2)) * here - (1.0 + cc * (k2_last - kap2)) * last) / (
        1.0 + cc * (k2_next - kap2)
    )
