"""The oracle of the paraxial tests (tests/engine/test_paraxial.py, test_paraxial_curves.py): central
differences of launches, traced by the same tracer without any paraxial arithmetic in the difference."""

from __future__ import annotations

from typing import Any

import numpy as np

from bentray.engine.constants import STATUS_EXITED
from bentray.engine.tracer import trace
from bentray.engine.wind import check_wind
from bentray.scenes.schema import Job

H = 1e-6  # rad, launch-angle step of the central differences


def _directions(el: np.ndarray, az: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def launch_derivative_errors(
    job: Job, media: Any, profile: Any, wind: Any, src: np.ndarray, el_deg: np.ndarray, az_deg: np.ndarray
) -> dict:
    """Worst relative difference between the derivatives a trace carries (``job.solver.curve`` on ``media``)
    and Richardson-extrapolated central differences of launches (steps H and H/2: truncation O(H^4); a
    plain central difference is O(H^2), 1e-4 relative near a caustic at H = 1e-6), over the rays whose
    neighbours took the same path. Errors relative to |X_k| (near a caustic, 10 % of the ray's length) and
    to |P_k|."""
    el0 = np.radians(el_deg)
    az0 = np.radians(az_deg)
    n = el0.size
    steps = [H, -H, H / 2, -H / 2]
    els = np.concatenate([el0] + [el0 + h for h in steps] + [el0] * 4)
    azs = np.concatenate([az0] + [az0] * 4 + [az0 + h for h in steps])
    dirs = _directions(els, azs)
    origins = np.repeat(src[None], dirs.shape[0], axis=0)
    cells = media.locate(src[None])
    assert cells[0] >= 0
    res = trace(
        media.mesh,
        job.solver.curve,
        profile.c_ref,
        origins,
        dirs,
        np.full(dirs.shape[0], cells[0]),
        max_time_s=job.rays.max_time_s,
        max_reflections=job.rays.max_reflections,
        paraxial=True,
        wind=check_wind(wind) if wind is not None else None,
    )
    par = res.paraxial
    assert par is not None
    p_vec = res.direction * par[:, 12:13]
    blocks = [slice(k * n, (k + 1) * n) for k in range(9)]
    same = res.status[blocks[0]] == STATUS_EXITED
    for b in blocks[1:]:
        same &= (res.crossings[b] == res.crossings[blocks[0]]) & (res.reflections[b] == res.reflections[blocks[0]])
        same &= res.status[b] == STATUS_EXITED

    def richardson(values: np.ndarray, first: int) -> np.ndarray:
        d_h = (values[blocks[first]] - values[blocks[first + 1]]) / (2 * H)
        d_h2 = (values[blocks[first + 2]] - values[blocks[first + 3]]) / H
        return (4.0 * d_h2 - d_h) / 3.0

    worst_x = 0.0
    worst_p = 0.0
    for k, first in enumerate((1, 5)):
        fd_x = richardson(res.position, first)
        fd_p = richardson(p_vec, first)
        x_k = par[blocks[0], 3 * k : 3 * k + 3]
        p_k = par[blocks[0], 6 + 3 * k : 9 + 3 * k]
        scale_x = np.maximum(np.linalg.norm(x_k, axis=1), 0.1 * res.length_m[blocks[0]])
        err_x = np.linalg.norm(fd_x - x_k, axis=1) / scale_x
        err_p = np.linalg.norm(fd_p - p_k, axis=1) / np.maximum(np.linalg.norm(p_k, axis=1), 1e-2)
        worst_x = max(worst_x, float(np.max(err_x[same], initial=0.0)))
        worst_p = max(worst_p, float(np.max(err_p[same], initial=0.0)))
    return {
        "compared": int(same.sum()),
        "rays": n,
        "worst_rel": max(worst_x, worst_p),
        "worst_x": worst_x,
        "worst_p": worst_p,
        "reflections": int(res.reflections[blocks[0]][same].sum()),
        "crossings": int(res.crossings[blocks[0]][same].sum()),
    }
