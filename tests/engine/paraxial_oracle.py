"""The oracle of the paraxial tests (tests/engine/test_paraxial.py, test_paraxial_curves.py): central
differences of launches, traced by the same tracer without any paraxial arithmetic in the difference."""

from __future__ import annotations

from typing import Any

import numpy as np

from bentray.engine.constants import STATUS_EXITED
from bentray.engine.media import build_media, build_terrain_media
from bentray.engine.stages import load_surfaces
from bentray.engine.tracer import trace
from bentray.engine.wind import check_wind
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.schema import Job
from bentray.scenes.wind_models import wind_from_spec

H = 1e-6  # rad, launch-angle step of the central differences (also H/2 and H/4)
CONVERGED = 1e-6  # relative |R1 - R2| above which the central differences do not resolve a derivative


def paraxial_job(
    profile: dict, curve: str, representation: str, *, terrain: str | None = None, wind: dict | None = None
) -> Job:
    """The paraxial tests' job: source 2 m over flat reflecting ground in a 620 x 400 x 150 m box (or a
    built-in terrain scene), the given profile, curve, media representation and optional wind."""
    scene: dict = {"domain": {"min": [-20, -200, 0], "max": [600, 200, 150]}, "ground": {"kind": "flat"}}
    if terrain is not None:
        scene = {"builtin": terrain}
    spec = {
        "name": "paraxial",
        "scene": scene,
        "profile": profile,
        "sources": [{"position": [0.0, 0.0, 2.0]}],
        "rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 30.0, "max_reflections": 20},
        "solver": {"curve": curve, "representation": representation},
        "outputs": ["report"],
    }
    if wind is not None:
        spec["wind"] = wind
    return Job.model_validate(spec)


def job_media(job: Job) -> tuple[Any, Any, Any]:
    """(media, profile, wind) of a paraxial_job: terrain media for a terrain scene, else the flat media."""
    profile = profile_from_spec(job.profile)
    lo = np.asarray(job.scene.box.min, float)
    hi = np.asarray(job.scene.box.max, float)
    wind = wind_from_spec(job.wind) if job.wind is not None else None
    surfaces = load_surfaces(job)
    curve = job.solver.curve
    if surfaces is not None:
        media = build_terrain_media(profile, curve, job.solver, lo, hi, surfaces, top=job.scene.top.kind)
    else:
        media = build_media(profile, curve, job.solver, lo, hi, ground="reflect", top=job.scene.top.kind, wind=wind)
    return media, profile, wind


def compare(job: Job, src: np.ndarray, el_deg: np.ndarray, az_deg: np.ndarray) -> dict:
    """Carried derivatives against central differences of launches (launch_derivative_errors)."""
    media, profile, wind = job_media(job)
    return launch_derivative_errors(job, media, profile, wind, src, el_deg, az_deg)


def _directions(el: np.ndarray, az: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def launch_derivative_errors(
    job: Job, media: Any, profile: Any, wind: Any, src: np.ndarray, el_deg: np.ndarray, az_deg: np.ndarray
) -> dict:
    """Worst relative difference between the derivatives a trace carries (``job.solver.curve`` on ``media``)
    and Richardson-extrapolated central differences of launches, over the rays whose neighbours took the
    same path. Errors relative to |X_k| (near a caustic, 10 % of the ray's length) and to |P_k|.

    Two Richardson estimates, R1 from the steps (H, H/2) and R2 from (H/2, H/4) (truncation O(H^4); a
    plain central difference is O(H^2), 1e-4 relative near a caustic at H = 1e-6). The carried
    derivatives are compared with R1 (R2 carries twice its rounding noise: measured up to 2e-7 relative
    after 1,000-10,000 crossings). A ray counts as compared only when its neighbours have its crossing
    and reflection counts *and* R1 and R2 agree to CONVERGED: a neighbour that passes an edge or vertex
    on the other side (another cell sequence with the same counts, e.g. two cells instead of one short
    one) straddles a kink of the traced map (the piecewise-linear medium's gradient jumps), and its
    central difference mixes two one-sided derivatives; the two estimates then differ by about the
    contamination of the worse one (measured: the n-linear curve on tets, el 0.5, az 20 deg, whose az +H
    neighbour takes two cells for one 0.6 mm cell 411 m out: |R1 - R2| = 1.4e-3, and the carried
    derivatives agree with the clean R2 to 9e-9). The filter reads only traced positions and slownesses,
    never the carried derivatives, so it cannot hide an error in them; a kink it misses fails the test.
    ``unresolved`` counts the rays it leaves out; ``oracle_gap`` is the largest |R1 - R2| (relative)
    among the compared rays; ``ray_err`` / ``ray_gap`` are per ray (every ray, compared or not)."""
    el0 = np.radians(el_deg)
    az0 = np.radians(az_deg)
    n = el0.size
    steps = [H, -H, H / 2, -H / 2, H / 4, -H / 4]
    m = len(steps)
    els = np.concatenate([el0] + [el0 + h for h in steps] + [el0] * m)
    azs = np.concatenate([az0] + [az0] * m + [az0 + h for h in steps])
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
    blocks = [slice(k * n, (k + 1) * n) for k in range(1 + 2 * m)]
    same = res.status[blocks[0]] == STATUS_EXITED
    for b in blocks[1:]:
        same &= (res.crossings[b] == res.crossings[blocks[0]]) & (res.reflections[b] == res.reflections[blocks[0]])
        same &= res.status[b] == STATUS_EXITED
    same_path = same.copy()

    def richardson(values: np.ndarray, first: int, h: float) -> np.ndarray:
        d_h = (values[blocks[first]] - values[blocks[first + 1]]) / (2 * h)
        d_h2 = (values[blocks[first + 2]] - values[blocks[first + 3]]) / h
        return (4.0 * d_h2 - d_h) / 3.0

    worst_x = 0.0
    worst_p = 0.0
    gap = 0.0
    errs = []
    for k, first in enumerate((1, 1 + m)):
        x_k = par[blocks[0], 3 * k : 3 * k + 3]
        p_k = par[blocks[0], 6 + 3 * k : 9 + 3 * k]
        scale_x = np.maximum(np.linalg.norm(x_k, axis=1), 0.1 * res.length_m[blocks[0]])
        scale_p = np.maximum(np.linalg.norm(p_k, axis=1), 1e-2)
        for values, carried, scale in ((res.position, x_k, scale_x), (p_vec, p_k, scale_p)):
            r1 = richardson(values, first, H)
            r2 = richardson(values, first + 2, H / 2)
            gap_k = np.linalg.norm(r1 - r2, axis=1) / scale
            same &= gap_k < CONVERGED
            errs.append((np.linalg.norm(r1 - carried, axis=1) / scale, gap_k, values is res.position))
    for err, gap_k, is_x in errs:
        worst = float(np.max(err[same], initial=0.0))
        if is_x:
            worst_x = max(worst_x, worst)
        else:
            worst_p = max(worst_p, worst)
        gap = max(gap, float(np.max(gap_k[same], initial=0.0)))
    return {
        "compared": int(same.sum()),
        "unresolved": int(same_path.sum() - same.sum()),
        "oracle_gap": gap,
        "ray_err": np.max([e[0] for e in errs], axis=0).tolist(),
        "ray_gap": np.max([e[1] for e in errs], axis=0).tolist(),
        "rays": n,
        "worst_rel": max(worst_x, worst_p),
        "worst_x": worst_x,
        "worst_p": worst_p,
        "reflections": int(res.reflections[blocks[0]][same].sum()),
        "crossings": int(res.crossings[blocks[0]][same].sum()),
    }
