"""The one-band creeping-layer rate that engine/diffraction/leg_shadow.py computed until 2026-12-05 (morning): the
oracle of its lockstep form ``layer_rates`` (tests/shadows/test_leg_shadow.py). Same fixed point, one band at a
time, one ``c_of_h`` call per step."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bentray.engine.diffraction import leg_shadow as ls


def layer_rate_scalar(
    c_of_h: Callable[[np.ndarray], np.ndarray], frequency_hz: float, flow_resistivity: float | None
) -> float:
    """Im kappa_1 (1/m) of the least attenuated creeping mode over the column's own layer (module docstring
    of engine/diffraction/leg_shadow.py); 0 where c does not decrease over the layer."""
    c0 = float(np.asarray(c_of_h(np.array([0.0])), float)[0])
    k0 = 2.0 * math.pi * frequency_hz / c0
    table = ls._root_table(float(frequency_hz), flow_resistivity)
    delta, a = 1.0, math.nan
    for _ in range(ls.LAYER_ITERATIONS):
        drop = c0 - float(np.asarray(c_of_h(np.array([delta])), float)[0])
        if not drop > 0.0:
            return 0.0
        a = 2.0 * drop / (c0 * delta)
        ell = (k0 * k0 * a) ** (1.0 / 3.0)
        if table is None:
            w = ls._rigid_root()
        else:
            v = table(math.log(min(max((k0 / a) ** (1.0 / 3.0), ls._U_MIN), ls._U_MAX)))
            w = complex(v[0], v[1])
        new = abs(w) / ell
        if abs(new - delta) <= 1e-6 * delta:
            break
        delta = min(new, ls.H_MAX_M)
    return float(ls.creeping_rate(frequency_hz, np.array([a]), np.array([c0]), flow_resistivity)[0])
