"""Noise indicators as pure functions on level arrays (dB, any shape, broadcast together).

Lden (EU Environmental Noise Directive 2002/49/EC, Annex I; CNOSSOS-EU, Directive (EU) 2015/996):

    Lden = 10 lg( (t_d 10^(L_day/10) + t_e 10^((L_evening + 5)/10) + t_n 10^((L_night + 10)/10)) / 24 )

with period lengths t_d + t_e + t_n = 24 h (default 12, 4, 8 h; member states may shift them, e.g.
14/2/8) and penalties 0 / 5 / 10 dB (configurable).

Meteorological combination (CNOSSOS-EU section 2.5.5, the long-term level of a period):

    L_LT = 10 lg( p 10^(L_F/10) + (1 - p) 10^(L_H/10) )

p the occurrence of sound-propagation-favourable conditions in the period, L_F and L_H the favourable and
homogeneous levels; :func:`combine_conditions` generalises it to any number of conditions with shares that
sum to 1. NaN levels propagate (a point not reached stays NaN); a level of -inf is zero energy.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["DEFAULT_PERIOD_HOURS", "DEFAULT_PENALTIES_DB", "energy_sum", "combine_conditions", "lden", "period_level"]

DEFAULT_PERIOD_HOURS = (12.0, 4.0, 8.0)  # day, evening, night (Directive 2002/49/EC Annex I)
DEFAULT_PENALTIES_DB = (0.0, 5.0, 10.0)
_SHARE_TOL = 1e-9


def _energy(level_db: ArrayLike) -> NDArray[np.float64]:
    return np.power(10.0, np.asarray(level_db, dtype=np.float64) / 10.0)


def _level(energy: NDArray[np.float64]) -> NDArray[np.float64]:
    with np.errstate(divide="ignore"):
        return np.asarray(10.0 * np.log10(energy), dtype=np.float64)


def energy_sum(levels_db: Sequence[ArrayLike], weights: Sequence[float] | None = None) -> NDArray[np.float64]:
    """10 lg(sum_i w_i 10^(L_i/10)) in dB; weights default to 1 (an incoherent sum of sources)."""
    if len(levels_db) == 0:
        raise ValueError("energy_sum needs at least one level array")
    w = [1.0] * len(levels_db) if weights is None else [float(v) for v in weights]
    if len(w) != len(levels_db):
        raise ValueError(f"{len(levels_db)} level arrays but {len(w)} weights")
    if any(not np.isfinite(v) or v < 0 for v in w):
        raise ValueError(f"weights must be finite and >= 0, got {w}")
    total = sum(v * _energy(level) for v, level in zip(w, levels_db, strict=True))
    return _level(np.asarray(total, dtype=np.float64))


def combine_conditions(levels_db: Sequence[ArrayLike], occurrences: Sequence[float]) -> NDArray[np.float64]:
    """Long-term level (dB) of one period from the levels under several meteorological conditions.

    levels_db : one array per condition (e.g. [L_favourable, L_homogeneous]); occurrences : the share of
    the period each condition holds, each in [0, 1], summing to 1 (within 1e-9). CNOSSOS-EU:
    ``combine_conditions([L_F, L_H], [p, 1 - p])``.
    """
    occ = [float(p) for p in occurrences]
    if any(not (0.0 <= p <= 1.0) for p in occ):
        raise ValueError(f"occurrences must lie in [0, 1], got {occ}")
    if abs(sum(occ) - 1.0) > _SHARE_TOL:
        raise ValueError(f"occurrences must sum to 1, got {sum(occ):.12g}")
    return energy_sum(levels_db, occ)


def period_level(
    favourable_db: ArrayLike, homogeneous_db: ArrayLike, favourable_occurrence: float
) -> NDArray[np.float64]:
    """CNOSSOS-EU long-term level of a period: p favourable, 1 - p homogeneous (dB)."""
    p = float(favourable_occurrence)
    return combine_conditions([favourable_db, homogeneous_db], [p, 1.0 - p])


def lden(
    day_db: ArrayLike,
    evening_db: ArrayLike,
    night_db: ArrayLike,
    *,
    hours: Sequence[float] = DEFAULT_PERIOD_HOURS,
    penalties_db: Sequence[float] = DEFAULT_PENALTIES_DB,
) -> NDArray[np.float64]:
    """Day-evening-night level (dB) from the three period levels (dB, broadcastable arrays).

    hours : (t_day, t_evening, t_night), each > 0, summing to 24 (within 1e-9 h);
    penalties_db : added to each period's level before the energy average (default 0, 5, 10 dB).
    """
    h = [float(v) for v in hours]
    pen = [float(v) for v in penalties_db]
    if len(h) != 3 or len(pen) != 3:
        raise ValueError("hours and penalties_db need 3 values each (day, evening, night)")
    if any(not (np.isfinite(v) and v > 0) for v in h) or abs(sum(h) - 24.0) > _SHARE_TOL * 24:
        raise ValueError(f"period hours must be > 0 and sum to 24, got {h}")
    if not all(np.isfinite(pen)):
        raise ValueError(f"penalties must be finite, got {pen}")
    levels = [
        np.asarray(day_db, float) + pen[0],
        np.asarray(evening_db, float) + pen[1],
        np.asarray(night_db, float) + pen[2],
    ]
    return energy_sum(levels, [v / 24.0 for v in h])
