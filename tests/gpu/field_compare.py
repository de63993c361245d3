"""Run a small beam-field job with ``solver.device`` cpu and cuda and print how far the fields differ.

Run as ``NUMBA_ENABLE_CUDASIM=1 python -m tests.gpu.field_compare CASE`` (tests/gpu/test_cuda_field_simulator.py
does, in a subprocess), or on a device without the flag (tests/gpu/test_cuda_device.py). Prints one JSON object:
the case, the devices used, whether the ray states are bit-identical, and per field kind (the grid, the
receivers) the largest relative difference of the linear levels (|p|^2 per band and the incoherent energies,
10^(-TL/10)), the largest difference of the levels in dB, of the coherent pressures relative to their largest
magnitude, of the beam weights, and whether the beam hit counts and the points reached are equal.

Cases (A-LD: the log profile b = +1 over flat ground on slabs; a ground reflection, soft ground):
``slab_coherent`` and ``slab_incoherent`` (a field grid and two receivers), ``slab_semicoherent_directivity``
(semicoherent, a directional source) and ``terrain`` (the example hill, heights above the ground, a log-law wind,
incoherent). The fans are small (about fifty rays): the simulator runs each thread in Python.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import bentray  # noqa: F401  (numba cache folder before numba loads)

REPO = Path(__file__).resolve().parents[2]


def _slab_job(mode: str, directivity: bool = False) -> dict[str, Any]:
    src: dict[str, Any] = {"position": [0.0, 0.0, 2.0], "power_db": {"250": 100.0, "1000": 100.0}}
    if directivity:
        src["directivity"] = {
            "axis": [1.0, 0.0, 0.0],
            "polar_deg": [0.0, 60.0, 120.0, 180.0],
            "levels_db": {"250": [0.0, -3.0, -8.0, -12.0], "1000": [0.0, -5.0, -12.0, -20.0]},
        }
    return {
        "name": f"gpu-field-{mode}",
        "scene": {
            "domain": {"min": [-20, -40, 0], "max": [320, 40, 120]},
            "ground": {"kind": "flat", "flow_resistivity": 200_000.0},
        },
        "profile": {"kind": "log", "b": 1.0},
        "sources": [src],
        "rays": {
            "elevation_deg": {"min": -30.0, "max": 20.0, "count": 18},
            "azimuth_deg": {"min": -6.0, "max": 6.0, "count": 3},
            "max_time_s": 0.6,
            "max_reflections": 2,
        },
        "field": {
            "origin": [20.0, -4.0, 1.5],
            "spacing": [12.0, 4.0, 3.0],
            "shape": [16, 3, 2],
            "frequencies_hz": [250.0, 1000.0],
            "mode": mode,
        },
        "receivers": [
            {"id": "near", "position": [60.0, 0.5, 1.5]},
            {"id": "far", "position": [170.0, -1.0, 4.0]},
        ],
        "outputs": ["field", "report"],
    }


def _terrain_job() -> dict[str, Any]:
    return {
        "name": "gpu-field-terrain",
        "scene": {
            "domain": {"min": [-400, -300, 0], "max": [300, 300, 120]},
            "terrain": {"file": str(REPO / "scenes" / "examples" / "hill.asc")},
        },
        "profile": {"kind": "log", "b": 1.0},
        "wind": {"kind": "log", "u_star": 0.4, "z_g": 0.1, "direction_deg": 30.0},
        "sources": [{"position": [-300.0, -20.0, 12.0], "power_db": {"500": 100.0}}],
        "rays": {
            "elevation_deg": {"min": -10.0, "max": 10.0, "count": 21},
            "azimuth_deg": {"min": -12.0, "max": 12.0, "count": 5},
            "max_time_s": 0.7,
            "max_reflections": 2,
        },
        "field": {
            "origin": [-240.0, -30.0, 4.0],
            "spacing": [20.0, 5.0, 1.0],
            "shape": [10, 5, 1],
            "frequencies_hz": [500.0],
            "mode": "incoherent",
            "heights": "above_ground",
            "receiver_height_m": 4.0,
        },
        "outputs": ["field", "report"],
    }


CASES = {
    "slab_coherent": lambda: _slab_job("coherent"),
    "slab_incoherent": lambda: _slab_job("incoherent"),
    "slab_semicoherent_directivity": lambda: _slab_job("semicoherent", directivity=True),
    "terrain": _terrain_job,
}


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| / max(|a|, |b|) over the entries where either is non-zero and finite (0 if none)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b) & ((a != 0) | (b != 0))
    if not ok.any():
        return 0.0
    return float(np.max(np.abs(a[ok] - b[ok]) / np.maximum(np.abs(a[ok]), np.abs(b[ok]))))


def _db(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.max(np.abs(a[ok] - b[ok]))) if ok.any() else 0.0


def _compare_arrays(a: dict[str, np.ndarray], b: dict[str, np.ndarray], tl: list[str], p: list[str]) -> dict:
    out: dict[str, Any] = {"names": sorted(a), "same_names": sorted(a) == sorted(b)}
    out["levels_rel"] = max([_rel(10.0 ** (-a[k] / 10.0), 10.0 ** (-b[k] / 10.0)) for k in tl] or [0.0])
    out["levels_db"] = max([_db(a[k], b[k]) for k in tl] or [0.0])
    out["nan_equal"] = all(np.array_equal(np.isnan(a[k]), np.isnan(b[k])) for k in tl)
    p_rel = 0.0
    for k in p:
        scale = max(float(np.nanmax(np.abs(a[k]))), 1e-300)
        p_rel = max(p_rel, float(np.nanmax(np.abs(a[k] - b[k]))) / scale)
    out["pressure_rel_to_max"] = p_rel
    out["differ"] = sorted(k for k in a if not np.array_equal(a[k], b[k], equal_nan=True))
    return out


def compare(name: str) -> dict:
    import bentray.engine.gpu.tracer as gpu_tracer
    from bentray.engine.gpu.device import cuda_status
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    calls: list[int] = []  # rays per trace_cuda call: proves the cuda run went through the device kernel
    real = gpu_tracer.trace_cuda

    def counted(*args: Any, **kw: Any) -> Any:
        calls.append(int(np.asarray(args[3]).reshape(-1, 3).shape[0]))
        assert kw.get("beams") is not None
        return real(*args, **kw)

    gpu_tracer.trace_cuda = counted  # type: ignore[assignment]
    spec = CASES[name]()
    res = {}
    seconds = {}
    for dev in ("cpu", "cuda"):
        job = Job.model_validate({**spec, "solver": {**spec.get("solver", {}), "device": dev}})
        t0 = time.perf_counter()
        res[dev] = run_job(job, REPO)
        seconds[dev] = time.perf_counter() - t0
    a, b = res["cpu"], res["cuda"]
    ta, tb = a.trace, b.trace
    states_identical = all(
        np.array_equal(getattr(ta, k), getattr(tb, k))
        for k in ("position", "direction", "time_s", "length_m", "status", "reflections", "crossings", "nudges")
    )
    fa, fb = a.field.arrays, b.field.arrays
    tl = [k for k in fa if k.startswith("tl_") or k.startswith("spl_")]
    pk = [k for k in fa if k.startswith("p_re_") or k.startswith("p_im_")]
    grid = _compare_arrays(fa, fb, tl, pk)
    grid["hits_equal"] = bool(np.array_equal(fa["beam_hits"], fb["beam_hits"]))
    grid["weight_rel"] = _rel(fa["beam_weight"], fb["beam_weight"])
    grid["points"] = int(fa["beam_hits"].size)
    grid["points_reached"] = int(np.count_nonzero(fa["beam_hits"] > 0))
    out: dict[str, Any] = {
        "case": name,
        "device": cuda_status()[1],
        "device_calls": calls,
        "rays": int(ta.n_rays),
        "reflections": int(ta.reflections.sum()),
        "states_identical": bool(states_identical),
        "grid": grid,
        "seconds": seconds,
    }
    if a.receivers is not None and b.receivers is not None:
        cols = [c for c in a.receivers.columns if c != "id"]
        ra = {c: np.array([r[c] for r in a.receivers.rows], float) for c in cols}
        rb = {c: np.array([r[c] for r in b.receivers.rows], float) for c in cols}
        lv = [c for c in cols if c.startswith("tl_") or c.startswith("spl_")]
        rec = _compare_arrays(ra, rb, lv, [])
        rec["hits_equal"] = bool(np.array_equal(ra["beam_hits"], rb["beam_hits"]))
        rec["hits"] = [int(h) for h in ra["beam_hits"]]
        out["receivers"] = rec
    return out


def compare_bench_field() -> dict:
    """The bench's field case (engine/bench/gpu.py ``_field_rows``) on 60 rays for 0.5 s: CPU and CUDA rows."""
    from bentray.engine.bench import gpu
    from bentray.engine.gpu.device import cuda_status

    gpu._KW["max_time_s"] = 0.5  # (this process only) a short trace: the simulator runs each thread in Python
    rows = gpu._field_rows(gpu._field_case(60), 1, 0.0, cuda_status()[1])
    return {"case": "bench_field", "rows": rows}


if __name__ == "__main__":
    print(json.dumps(compare_bench_field() if sys.argv[1] == "bench_field" else compare(sys.argv[1])))
