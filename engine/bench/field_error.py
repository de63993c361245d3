"""Field error against run time: beams (several fan sizes) and the voxel ray-density method.

Case "image": homogeneous air (340 m/s) over rigid ground, source at 2 m, receiver line at 1.5 m from
10 m to 1 km (1 m spacing), 500 Hz, coherent. Reference: the image-source pressure
``exp(ikR1)/R1 + exp(ikR2)/R2`` (acoustics.ground.image_source_pressure). Error: mean and largest
|level difference| (dB) outside the interference dips (points where the reference is more than 6 dB below
the energy sum), and the fraction of points without a value.

Case "gfpe": A-LD downward log profile (b = +1) over grass (200 kPa s/m^2), source 2 m, receivers 1.5 m,
20 m - 1 km, 500 Hz, against the repository's GFPE oracle (tests/reference/gfpe.py; only in a source
checkout: the case says "skipped" where the tests package is not importable).

Time: the job's trace stage (seconds, warm, the field accumulated inside it) and its field finalisation,
on the bench's timing threads (one: see common.TIMING_THREADS).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bentray.engine.bench.common import Plot, Section, Series, Table, on_timing_threads

FREQ = 500.0
C0 = 340.0
ZS, ZR = 2.0, 1.5


def _image_job(n_el: int, n_az: int, method: str) -> dict[str, Any]:
    az = 2.0 if method == "beams" else 3.0
    return {
        "name": f"field-image-{method}-{n_el}x{n_az}",
        "scene": {"domain": {"min": [-20, -60, 0], "max": [1020, 60, 120]}, "ground": {"kind": "flat"}},
        "profile": {"kind": "homogeneous", "c0": C0},
        "sources": [{"position": [0.0, 0.0, ZS]}],
        "rays": {
            "elevation_deg": {"min": -45.0 if method == "beams" else -22.0, "max": 15.0, "count": n_el},
            "azimuth_deg": {"min": -az, "max": az, "count": n_az},
            "max_time_s": 3.1,
            "max_reflections": 2,
        },
        "field": {
            "origin": [10.0, 0.0, ZR],
            "spacing": [1.0, 1.0, 1.0],
            "shape": [991, 1, 1],
            "frequencies_hz": [FREQ],
            "absorption": False,
            "mode": "coherent",
            "method": method,
        },
        "outputs": ["field", "report"],
    }


def _gfpe_job(n_el: int) -> dict[str, Any]:
    return {
        "name": f"field-gfpe-{n_el}",
        "scene": {
            "domain": {"min": [-20, -20, 0], "max": [1020, 20, 300]},
            "ground": {"kind": "flat", "flow_resistivity": 200_000.0},
        },
        "profile": {"kind": "log", "c0": C0, "b": 1.0, "z_g": 1.0},
        "sources": [{"position": [0.0, 0.0, ZS]}],
        "rays": {
            "elevation_deg": {"min": -30.0, "max": 30.0, "count": n_el},
            "azimuth_deg": {"min": 0.0, "max": 0.0, "count": 1},
            "max_time_s": 3.2,
            "max_reflections": 8,
        },
        "field": {
            "origin": [20.0, 0.0, ZR],
            "spacing": [2.0, 1.0, 1.0],
            "shape": [491, 1, 1],
            "frequencies_hz": [FREQ],
            "absorption": False,
            "mode": "coherent",
            "wave_model": "off",  # this section times the beams (the wave stage would replace them here)
        },
        "outputs": ["field", "report"],
    }


def _run(spec: dict[str, Any], repeats: int) -> tuple[Any, float]:
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    job = Job.model_validate(spec)
    best = np.inf
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = run_job(job)
        timings = out.report["timings_s"]
        t = float(timings.get("trace", np.nan)) + float(timings.get("field_finalize", 0.0))
        best = min(best, t if np.isfinite(t) else time.perf_counter() - t0)
    return out, best


def image_errors(tl: np.ndarray) -> dict[str, float]:
    """Mean / max |dB| outside dips and the no-value fraction of a TL line against the image source."""
    from bentray.engine.acoustics.ground import image_source_intensity_ratio, image_source_pressure

    x = 10.0 + np.arange(991)
    rec = np.column_stack([x, np.zeros_like(x), np.full_like(x, ZR)])
    src = np.array([0.0, 0.0, ZS])
    ref = -20 * np.log10(np.abs(image_source_pressure(src, rec, FREQ, None, c=C0)))
    energy = -10 * np.log10(image_source_intensity_ratio(src, rec, FREQ, None, c=C0))
    ok = (ref - energy < 6.0) & np.isfinite(tl)
    err = np.abs(tl - ref)[ok]
    return {
        "mean_db": float(err.mean()) if err.size else np.nan,
        "max_db": float(err.max()) if err.size else np.nan,
        "no_value": float(np.mean(~np.isfinite(tl))),
    }


def paraxial_cost(quick: bool) -> Table:
    """Trace time with the paraxial state carried (``paraxial=True``) against the same trace without it, same
    rays, rounds interleaved in one process (best of each), on the desert terrain mesh: the parabolic curve,
    the circular curve (its own mesh, constant grad c per cell) and the parabolic curve with a log-law wind
    (u* 0.4 m/s, z_g 0.05 m, toward +x). ``ratio``: against what a job without the state runs (the lean kernel for
    the plain parabolic trace, kernels/lean.py); ``ratio_generic``: against the same trace on the generic kernel
    (the state's own cost)."""
    from bentray.engine.bench.scene_meshes import build_scene_mesh
    from bentray.engine.tracer import trace
    from bentray.engine.wind import wind_spec

    table = Table(
        "paraxial_cost",
        "Cost of carrying the paraxial state (one thread)",
        ["case", "rays", "crossings", "plain_s", "generic_plain_s", "paraxial_s", "ratio", "ratio_generic"],
    )
    rounds = 2 if quick else 5
    n = 1000 if quick else 4000
    cases: list[tuple[str, str, bool]] = [("desert", "parabolic", False), ("desert", "circular", False)]
    cases.append(("desert", "parabolic", True))
    for name, curve, windy in cases:
        sc = build_scene_mesh(name, n, curve=curve)
        kw: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 3}
        if windy:
            ground_z = float(sc.origins[0, 2]) - 10.0  # the log law's zero about the source's ground
            kw["wind"] = wind_spec("log", {"u_star": 0.4, "z_g": 0.05, "direction_deg": 0.0, "ground_z_m": ground_z})
        args = (sc.mesh, curve, 340.0, sc.origins, sc.directions, sc.start_cells)
        # "plain": what a job without paraxial state runs (the lean kernel when it applies); "generic": the same
        # trace on the generic kernel, so the paraxial state's own cost is the ratio to it
        variants: dict[str, dict[str, Any]] = {
            "plain": {},
            "generic": {"kernel": "generic"},
            "paraxial": {"paraxial": True},
        }
        best = dict.fromkeys(variants, np.inf)
        res = trace(*args, **kw)
        for extra in variants.values():
            trace(*args, **{**kw, **extra})
        for r in range(rounds):
            order = list(variants) if r % 2 == 0 else list(variants)[::-1]
            for key in order:
                t0 = time.perf_counter()
                trace(*args, **{**kw, **variants[key]})
                best[key] = min(best[key], time.perf_counter() - t0)
        label = name if curve == "parabolic" and not windy else f"{name} {curve}" + (" wind" if windy else "")
        table.add(
            case=label,
            rays=int(sc.origins.shape[0]),
            crossings=int(res.crossings.sum()),
            plain_s=round(best["plain"], 4),
            generic_plain_s=round(best["generic"], 4),
            paraxial_s=round(best["paraxial"], 4),
            ratio=round(best["paraxial"] / best["plain"], 3),
            ratio_generic=round(best["paraxial"] / best["generic"], 3),
        )
    return table


@on_timing_threads
def run(quick: bool) -> Section:
    repeats = 1 if quick else 2
    beam_fans = [(121, 5), (301, 5)] if quick else [(61, 5), (121, 5), (301, 5), (601, 5), (1201, 5)]
    voxel_fans = [(425, 91)] if quick else [(212, 45), (425, 91), (850, 181)]
    table = Table(
        "field_error",
        "Field error against run time (coherent, 500 Hz)",
        ["case", "method", "rays", "mean_db", "max_db", "no_value", "seconds"],
    )
    series: dict[str, list[tuple[float, float]]] = {}
    for method, fans in (("beams", beam_fans), ("voxels", voxel_fans)):
        for n_el, n_az in fans:
            out, secs = _run(_image_job(n_el, n_az, method), repeats)
            e = image_errors(out.field.arrays[f"tl_{FREQ:g}hz"].ravel())
            table.add(
                case="image",
                method=method,
                rays=n_el * n_az,
                seconds=round(secs, 4),
                **{k: round(v, 3) for k, v in e.items()},
            )
            series.setdefault(f"image, {method}", []).append((secs, e["mean_db"]))
    gfpe_tl: Callable[..., np.ndarray] | None
    try:
        from tests.reference.gfpe import gfpe_tl
    except ImportError:  # an installed package without the repository's tests: the case is skipped
        gfpe_tl = None
    if gfpe_tl is not None:
        xs = 20.0 + 2.0 * np.arange(491)
        ref = gfpe_tl(lambda z: C0 + np.log(z + 1.0), FREQ, ZS, xs, np.array([ZR]), flow_resistivity=200_000.0)[:, 0]
        from scipy.ndimage import median_filter

        dips = ref - median_filter(ref, size=25, mode="nearest") >= 6.0
        for n_el in [301, 1201] if quick else [151, 301, 601, 1201, 2401]:
            out, secs = _run(_gfpe_job(n_el), repeats)
            tl = out.field.arrays[f"tl_{FREQ:g}hz"].ravel()
            w = out.field.arrays["beam_weight"].ravel()
            ok = (w >= 0.5) & ~dips
            d = np.abs(tl - ref)[ok]
            table.add(
                case="gfpe A-LD grass",
                method="beams",
                rays=n_el,
                mean_db=round(float(d.mean()), 3),
                max_db=round(float(d.max()), 3),
                no_value=round(float(np.mean(~np.isfinite(tl))), 3),
                seconds=round(secs, 4),
            )
            series.setdefault("gfpe A-LD, beams", []).append((secs, float(d.mean())))
    sec = Section("field_error", "Field error against run time")
    sec.text.append(
        "Coherent 500 Hz levels against independent references: the image source over rigid ground "
        "(receiver line 10 m - 1 km at 1.5 m, source 2 m) and the GFPE oracle for the A-LD log profile over "
        "grass. Beams: geometric beams around paraxial rays (docs/physics.md §11); voxels: the older "
        "ray-density estimate. Mean |dB| outside interference dips; seconds: trace + field stages, warm, "
        "one thread."
    )
    if gfpe_tl is None:
        sec.text.append(
            "The GFPE case was skipped: its oracle lives in the repository's tests package "
            "(tests/reference/gfpe.py), which this interpreter cannot import; run the bench from a source "
            "checkout with `python -m bentray.clients.cli bench ...` in the repository root."
        )
    sec.tables.append(table)
    sec.tables.append(paraxial_cost(quick))
    panel = {
        "title": "mean |error| outside dips against trace + field time",
        "xlabel": "seconds",
        "ylabel": "mean |error| (dB)",
        "xlog": True,
        "ylog": True,
        "series": [Series(k, [p[0] for p in v], [p[1] for p in v]) for k, v in series.items()],
    }
    sec.plots.append(Plot("field_error", "Field error against run time", [panel]))
    return sec
