"""Trace a handful of rays of one case with the CPU kernels and with the CUDA kernel, print the comparison.

Run as ``NUMBA_ENABLE_CUDASIM=1 python -m tests.gpu.sim_compare CASE`` (tests/gpu/test_cuda_simulator.py does, in a
subprocess, so that the simulator flag stays out of the rest of the suite), or on a device without the flag
(tests/gpu/test_cuda_device.py). Prints one JSON object: the case, the device the CUDA path used, and per ray
whether the final states are bit-identical, the largest position / direction / time / length difference
relative to the path length, and the counts of both sides.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

import bentray  # noqa: F401  (numba cache folder before numba loads)
from bentray.engine.mesh.fcc import fcc_resample
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.mesh.tets import build_tet_mesh
from bentray.engine.wind import wind_spec

REPO = Path(__file__).resolve().parents[2]
C_REF = 340.0


def _fan(source, el_deg, az_deg):
    el, az = np.meshgrid(np.radians(el_deg), np.radians(az_deg), indexing="ij")
    el, az = el.ravel(), az.ravel()
    d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return np.tile(np.asarray(source, float), (len(d), 1)), d


def _log_n2(z):
    c = 340.0 + 1.0 * np.log(np.asarray(z, float) / 1.0 + 1.0)
    return (C_REF / c) ** 2


def case_slabs():
    """A-LD (log profile, b = +1) on 24 horizontal slabs, parabolic curve, ground reflections, no wind."""
    lo, hi = np.array([-50.0, -50.0, 0.0]), np.array([4000.0, 50.0, 400.0])
    z = np.concatenate([[0.0], np.geomspace(0.5, 400.0, 23)])
    mesh = build_slab_mesh(lo, hi, z, _log_n2)
    o, d = _fan([0.0, 0.0, 1.5], [-20.0, -3.0, 1.0, 4.0, 12.0], [0.0])
    return dict(mesh=mesh, curve="parabolic", o=o, d=d, cells=locate_in_slabs(z, o), t=12.0, refl=20, wind=None)


def case_slabs_circular_wind():
    """linear_c slabs traced with the circular curve, a log-law wind blowing along +x (up- and downwind rays)."""
    lo, hi = np.array([-3000.0, -50.0, 0.0]), np.array([3000.0, 50.0, 600.0])
    z = np.linspace(0.0, 600.0, 13)
    mesh = build_slab_mesh(lo, hi, z, lambda zz: 340.0 - 0.05 * np.asarray(zz, float))
    o, d = _fan([0.0, 0.0, 2.0], [-4.0, 2.0, 8.0], [0.0, 180.0])
    wind = wind_spec("log", {"u_star": 0.6, "z_g": 0.1, "direction_deg": 0.0})
    return dict(mesh=mesh, curve="circular", o=o, d=d, cells=locate_in_slabs(z, o), t=8.0, refl=20, wind=wind)


def case_tets():
    """A stratified n^2 = 1 + 0.004 z on an FCC tetrahedral mesh (18 m), 3D fan, ground reflections."""
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([200.0, 160.0, 120.0])
    pts = fcc_resample(lo, hi, lambda x: np.full(len(x), 18.0), d_min=18.0, d_max=18.0)
    tm = build_tet_mesh(lo, hi, pts, lambda x: 1.0 + 0.004 * x[:, 2], spacing=lambda x: np.full(len(x), 18.0))
    from bentray.engine.mesh.cells import locate_points

    o, d = _fan([37.0, 41.0, 9.5], [-25.0, -6.0, 10.0], [10.0, 55.0])
    cells = locate_points(tm.cells, o[:1])
    return dict(mesh=tm.cells, curve="parabolic", o=o, d=d, cells=np.repeat(cells, len(o)), t=1.5, refl=8, wind=None)


def case_terrain():
    """The example hill (scenes/examples/hill.asc) as a terrain-following mesh, A-LD above the ground, a log-law
    wind, parabolic curve, reflections off the terrain."""
    from bentray.engine import stages
    from bentray.scenes.schema import Job

    job = Job.model_validate(
        {
            "name": "sim-terrain",
            "scene": {
                "domain": {"min": [-400, -300, 0], "max": [300, 300, 120]},
                "terrain": {"file": str(REPO / "scenes" / "examples" / "hill.asc")},
            },
            "profile": {"kind": "log", "b": 1.0},
            "wind": {"kind": "log", "u_star": 0.4, "z_g": 0.1, "direction_deg": 30.0},
            "sources": [{"position": [-300.0, -20.0, 12.0]}],
            "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 2.0, "max_reflections": 10},
        }
    )
    log = stages.StageLog()
    profile, wind = stages.stage_profile(job, REPO, log)
    surfaces = stages.stage_scene(job, REPO, log)
    profile = stages.stage_profile_heights(job, profile, surfaces, log)
    media = stages.stage_mesh(job, profile, surfaces, wind, log)
    o, d = _fan([-300.0, -20.0, 12.0], [-10.0, -2.0, 3.0], [0.0, 20.0])
    cells = np.repeat(media.locate(o[:1]), len(o))
    return dict(mesh=media.mesh, curve="parabolic", o=o, d=d, cells=cells, t=2.0, refl=10, wind=wind)


CASES = {
    "slabs": case_slabs,
    "slabs_circular_wind": case_slabs_circular_wind,
    "tets": case_tets,
    "terrain": case_terrain,
}


def compare(name: str) -> dict:
    from bentray.engine.gpu.tracer import trace_cuda
    from bentray.engine.tracer import trace

    c = CASES[name]()
    kw = dict(max_time_s=c["t"], max_reflections=c["refl"], wind=c["wind"])
    cpu = trace(c["mesh"], c["curve"], C_REF, c["o"], c["d"], c["cells"], record_reflections=True, **kw)
    gpu, timings = trace_cuda(c["mesh"], c["curve"], C_REF, c["o"], c["d"], c["cells"], **kw)
    scale = np.maximum(cpu.length_m, 1.0)
    rays = []
    for i in range(len(c["o"])):
        a = np.concatenate([cpu.position[i], cpu.direction[i], [cpu.time_s[i], cpu.length_m[i]]])
        b = np.concatenate([gpu.position[i], gpu.direction[i], [gpu.time_s[i], gpu.length_m[i]]])
        counts_cpu = [int(cpu.status[i]), int(cpu.reflections[i]), int(cpu.crossings[i]), int(cpu.nudges[i])]
        counts_gpu = [int(gpu.status[i]), int(gpu.reflections[i]), int(gpu.crossings[i]), int(gpu.nudges[i])]
        rays.append(
            {
                "identical": bool(np.array_equal(a, b)) and counts_cpu == counts_gpu,
                "position_rel": float(np.max(np.abs(cpu.position[i] - gpu.position[i])) / scale[i]),
                "direction": float(np.max(np.abs(cpu.direction[i] - gpu.direction[i]))),
                "time_s": float(abs(cpu.time_s[i] - gpu.time_s[i])),
                "length_rel": float(abs(cpu.length_m[i] - gpu.length_m[i]) / scale[i]),
                "counts_cpu": counts_cpu,
                "counts_gpu": counts_gpu,
                "first_reflection_material_equal": bool(
                    cpu.reflections[i] == 0 or cpu.reflection_material[i, 0] == gpu.reflection_material[i, 0]
                ),
            }
        )
    from bentray.engine.gpu.device import cuda_status

    return {"case": name, "device": cuda_status()[1], "timings_s": timings, "rays": rays}


def compare_render() -> dict:
    """A 12 x 9 V-IM render (engine/render; slabs at delta 1e-5) with solver.device cpu and cuda: identical states."""
    from bentray.engine.render.image import render_job
    from bentray.scenes.schema import Job

    spec = json.loads((REPO / "scenes" / "examples" / "mirage-inferior.json").read_text())
    spec["camera"].update({"width": 12, "height": 9, "look_at": [400, 0, -150]})
    out = {}
    for dev in ("cpu", "cuda"):
        job = Job.model_validate({**spec, "solver": {"device": dev, "delta": 1e-5}})  # coarser slabs: fewer steps
        out[dev] = render_job(job, REPO)
    a, b = out["cpu"], out["cuda"]
    return {
        "case": "render",
        "devices": [a.stats["device"], b.stats["device"]],
        "identical": bool(np.array_equal(a.position, b.position) and np.array_equal(a.direction, b.direction)),
        "hit_equal": bool(np.array_equal(a.hit, b.hit)),
        "surface": a.stats["surface"],
        "sky": a.stats["sky"],
    }


def compare_run() -> dict:
    """``run_job`` of the A-LD fan example (5 rays, 5 reflections, outputs report) with solver.device cpu and
    cuda (engine/batches.py sends the batches to the CUDA kernel): identical final states."""
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    spec = json.loads((REPO / "scenes" / "examples" / "a-ld-fan.json").read_text())
    spec["rays"].update({"elevation_deg": {"min": -20, "max": 20, "count": 5}, "max_reflections": 5})
    spec["outputs"] = ["report"]
    res = {}
    for dev in ("cpu", "cuda"):
        job = Job.model_validate({**spec, "solver": {**spec["solver"], "device": dev}})
        res[dev] = run_job(job, REPO).trace
    a, b = res["cpu"], res["cuda"]
    same = all(
        np.array_equal(getattr(a, k), getattr(b, k))
        for k in ("position", "direction", "time_s", "length_m", "status", "reflections", "crossings", "nudges")
    )
    return {"case": "run", "identical": bool(same), "reflections": int(a.reflections.sum()), "rays": a.n_rays}


if __name__ == "__main__":
    special = {"render": compare_render, "run": compare_run}
    print(json.dumps(special[sys.argv[1]]() if sys.argv[1] in special else compare(sys.argv[1])))
