"""Error against run time for the numerical baselines and the analytic tracer on stratified cases.

Cases (:data:`CASES`; docs/physics.md §7): V-IM, V-SM (mirages, light; 0.3 s at c_ref = 340 m/s, about
100 m of range, domain [-50, 200] x [-50, 50] x [0, 200] m) and A-LU, A-LD (log profile, b = -1 / +1,
z_g = 1 m; 10 s, domain [-50, 4000] x [-50, 50] x [0, 2600] m); source at 1.5 m, elevations -45..45
degrees (91 rays; 13 in quick mode), azimuth 0, flat reflecting ground, at most 50 reflections.

Reference: scipy DOP853 at rtol 1e-13 on the ray equations in sigma (d sigma = ds/n: dx = p, dp = n grad n,
dt = n^2/c_ref), each profile and its gradient written out here (no engine code), ground events
located by scipy and reflected (p_z -> -p_z). (The time-parametrised oracle of tests/reference scatters
by ~1e-4 m on the ray trapped in the ground duct at elevation 0; this one is stable to 1e-8 m there.)

Each row: method, media, setting, error (worst and median relative position error |x - x_ref| / (c_ref t)
over the rays), trace time (best of ``repeats`` warm runs: Numba compilation and mesh builds excluded),
and per ray the accepted steps, right-hand-side evaluations, restarts and rejected steps (numerical
methods) or cell crossings (analytic tracer). ``python -c "from bentray.engine.bench.baselines_probe import
probe; print(probe(quick=True))"`` runs the A-LD rows; :func:`run_rows` runs any case.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from scipy.integrate import solve_ivp

from bentray.engine.baselines.exact_media import exact_media_spec
from bentray.engine.baselines.trace_numerical import trace_numerical
from bentray.engine.bench.common import best_time, fan
from bentray.engine.media import Media, build_media
from bentray.engine.profiles import Profile, build_profile
from bentray.engine.tracer import trace
from bentray.scenes.schema import Solver

__all__ = [
    "probe",
    "run_rows",
    "reference_positions",
    "StratifiedCase",
    "CASES",
    "A_LD",
    "format_rows",
    "ANALYTIC_CURVES",
]


@dataclass(frozen=True)
class StratifiedCase:
    """A stratified validation case: profile kind and parameters, source, fan, time and domain (metres)."""

    key: str
    kind: str
    params: dict[str, float]
    t_end: float
    domain_min: tuple[float, float, float]
    domain_max: tuple[float, float, float]
    source: tuple[float, float, float] = (0.0, 0.0, 1.5)
    c_ref: float = 340.0
    max_reflections: int = 50
    elevation_range_deg: tuple[float, float] = (-45.0, 45.0)

    @property
    def norm_m(self) -> float:
        """Error normalisation c_ref t (m): the path length scale of the relative error, docs/physics.md §1."""
        return self.c_ref * self.t_end

    def profile(self) -> Profile:
        return build_profile(self.kind, c_ref=self.c_ref, **self.params)

    def fan(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        return fan(self.source, np.linspace(*self.elevation_range_deg, count))

    def n_and_dndz(self) -> Callable[[float], tuple[float, float]]:
        """n(z) and dn/dz, written out from docs/physics.md §7 (independent of engine/profiles.py)."""
        cr = self.c_ref
        p = self.params
        if self.kind == "log":
            c0, b, z_g = p.get("c0", 340.0), p["b"], p.get("z_g", 1.0)

            def log_n(z: float) -> tuple[float, float]:
                # the profile's own formula continued a little below the ground (only DOP853 stages go there)
                z = max(z, -0.5 * z_g)
                c = c0 + b * math.log1p(z / z_g)
                return cr / c, -cr * b / ((z + z_g) * c * c)

            return log_n
        mu0, mu1, beta = p.get("mu0", 1.000233), p.get("mu1", 0.4584), p.get("beta", 2.303)
        sign = 1.0 if self.kind == "mirage_inferior" else -1.0

        def mirage_n(z: float) -> tuple[float, float]:
            e = math.exp(-beta * z)
            n2 = mu0 * mu0 + mu1 * mu1 * ((1.0 - e) if sign > 0 else e)
            n = math.sqrt(n2)
            return n, sign * mu1 * mu1 * beta * e / (2.0 * n)

        return mirage_n


_ACOUSTIC_DOMAIN = ((-50.0, -50.0, 0.0), (4000.0, 50.0, 2600.0))
_VISUAL_DOMAIN = ((-50.0, -50.0, 0.0), (200.0, 50.0, 200.0))
CASES: dict[str, StratifiedCase] = {
    "V-IM": StratifiedCase(
        "V-IM", "mirage_inferior", {"mu0": 1.000233, "mu1": 0.4584, "beta": 2.303}, 0.3, *_VISUAL_DOMAIN
    ),
    "V-SM": StratifiedCase(
        "V-SM", "mirage_superior", {"mu0": 1.000233, "mu1": 0.4584, "beta": 2.303}, 0.3, *_VISUAL_DOMAIN
    ),
    "A-LU": StratifiedCase("A-LU", "log", {"c0": 340.0, "b": -1.0, "z_g": 1.0}, 10.0, *_ACOUSTIC_DOMAIN),
    "A-LD": StratifiedCase("A-LD", "log", {"c0": 340.0, "b": 1.0, "z_g": 1.0}, 10.0, *_ACOUSTIC_DOMAIN),
}

# Backwards-compatible view of the A-LD case (the probe's original constants).
A_LD: dict[str, Any] = {
    "c0": 340.0,
    "b": 1.0,
    "z_g": 1.0,
    "c_ref": 340.0,
    "source": (0.0, 0.0, 1.5),
    "t_end": 10.0,
    "domain_min": (-50.0, -50.0, 0.0),
    "domain_max": (4000.0, 50.0, 2600.0),
    "max_reflections": 50,
}

# (method, media, setting) rows; setting is step_m for euler / rk4, tolerance for the adaptive methods,
# delta (slab sizing) for the analytic tracer. "+renorm" rows rescale |p| = n after every step.
FULL_ROWS = [
    ("euler", "exact", 4.0),
    ("euler", "exact", 1.0),
    ("euler", "exact", 0.25),
    ("euler_adaptive", "exact", 1e-4),
    ("euler_adaptive", "exact", 1e-6),
    ("euler_adaptive", "exact", 1e-8),
    ("rk4", "exact", 4.0),
    ("rk4", "exact", 1.0),
    ("rk4", "exact", 0.25),
    ("rk4+renorm", "exact", 1.0),
    ("dopri5", "exact", 1e-6),
    ("dopri5", "exact", 1e-8),
    ("dopri5", "exact", 1e-10),
    ("dopri5", "exact", 1e-12),
    ("dopri5+renorm", "exact", 1e-8),
    ("rk4", "mesh", 1.0),
    ("dopri5", "mesh", 1e-8),
    ("dopri5", "mesh", 1e-10),
    ("analytic", "mesh", 1e-6),
    ("analytic", "mesh", 1e-8),
    ("analytic", "mesh", 1e-9),
]
QUICK_ROWS = [
    ("euler", "exact", 1.0),
    ("euler_adaptive", "exact", 1e-6),
    ("rk4", "exact", 1.0),
    ("dopri5", "exact", 1e-8),
    ("dopri5", "mesh", 1e-8),
    ("analytic", "mesh", 1e-8),
]
# The mesh rows use the analytic tracer's default slab mesh for the parabolic curve (delta 1e-8).
MESH_DELTA = 1e-8
# Analytic method names -> curve kind.
ANALYTIC_CURVES = {"analytic": "parabolic", "analytic_circular": "circular", "analytic_n_linear": "n_linear"}


def _fan(count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    el = np.linspace(-45.0, 45.0, count)
    o, d = CASES["A-LD"].fan(count)
    return o, d, el


def reference_positions(directions: np.ndarray, rtol: float = 1e-13, case: StratifiedCase | None = None) -> np.ndarray:
    """Final positions (n, 3) m of the case's rays (default A-LD) from its source after t_end, DOP853 in sigma."""
    case = CASES["A-LD"] if case is None else case
    n_and_dnz = case.n_and_dndz()
    cr, t_end = case.c_ref, case.t_end

    def rhs(_s: float, y: np.ndarray) -> list[float]:
        n, dnz = n_and_dnz(y[2])
        return [y[3], y[4], y[5], 0.0, 0.0, n * dnz, n * n / cr]

    def ground(_s: float, y: np.ndarray) -> float:
        return y[2]

    def time_up(_s: float, y: np.ndarray) -> float:
        return y[6] - t_end

    ground.terminal, ground.direction = True, -1  # type: ignore[attr-defined]
    time_up.terminal, time_up.direction = True, 1  # type: ignore[attr-defined]
    out = np.empty((len(directions), 3))
    src = np.asarray(case.source, float)
    for i, d in enumerate(np.asarray(directions, float)):
        n0 = n_and_dnz(src[2])[0]
        y = np.concatenate([src, n0 * d / np.linalg.norm(d), [0.0]])
        s = 0.0
        for _ in range(10_000):
            sol = solve_ivp(rhs, (s, 1e7), y, method="DOP853", rtol=rtol, atol=rtol * 1e-3, events=[ground, time_up])
            y, s = sol.y[:, -1].copy(), float(sol.t[-1])
            if sol.t_events[1].size or not sol.t_events[0].size:
                break
            y[2], y[5] = 0.0, -y[5]
        out[i] = y[:3]
    return out


class MeshCache:
    """Slab media of one case built once per (curve, delta); ``build_s`` records each build's wall time."""

    def __init__(self, case: StratifiedCase) -> None:
        self.case = case
        self.profile = case.profile()
        self._meshes: dict[tuple[str, float], Media] = {}
        self.build_s: dict[tuple[str, float], float] = {}

    def get(self, curve: str, delta: float) -> Media:
        key = (curve, float(delta))
        if key not in self._meshes:
            lo = np.asarray(self.case.domain_min, float)
            hi = np.asarray(self.case.domain_max, float)
            med = build_media(self.profile, curve, Solver(curve=curve, delta=delta), lo, hi)
            self._meshes[key] = med
            self.build_s[key] = float(med.stats.get("build_time_s", math.nan))
        return self._meshes[key]


@dataclass(frozen=True)
class _RowInputs:
    """What every row of one ``run_rows`` call shares: the case, its fan (origins, dirs (n, 3)), the
    meshes, the timing (best of ``repeats``, more runs up to ``min_total_s`` seconds) and the keyword
    arguments every trace_numerical call takes (``common``)."""

    case: StratifiedCase
    origins: np.ndarray
    dirs: np.ndarray
    meshes: MeshCache
    repeats: int
    min_total_s: float
    common: dict[str, Any]


def _analytic_row(inp: _RowInputs, name: str, setting: float, row: dict[str, Any]) -> tuple[float, Any]:
    """Time the analytic tracer (curve ANALYTIC_CURVES[name]) on the case's slab mesh at delta = setting,
    compiled outside the timing; fills the row's setting / cells / crossings / steps columns. Returns
    (best trace time s, TraceResult)."""
    case, origins, dirs = inp.case, inp.origins, inp.dirs
    curve = ANALYTIC_CURVES[name]
    med = inp.meshes.get(curve, setting)
    cells = med.locate(origins)
    row.update(
        {"setting": f"delta={setting:g}", "tolerance": float(setting), "cells": med.mesh.n_cells, "curve": curve}
    )

    def run() -> Any:
        return trace(med.mesh, curve, case.c_ref, origins, dirs, cells, max_time_s=case.t_end,
                     max_reflections=case.max_reflections)  # fmt: skip

    trace(med.mesh, curve, case.c_ref, origins[:1], dirs[:1], cells[:1], max_time_s=1e-3 * case.t_end,
          max_reflections=1)  # fmt: skip  # compile outside the timing
    elapsed, result = best_time(run, inp.repeats, inp.min_total_s)
    row["crossings_per_ray"] = float(result.crossings.mean())
    row["steps_per_ray"] = float(result.steps.mean())
    return elapsed, result


def _numerical_row(inp: _RowInputs, name: str, media: str, setting: float, row: dict[str, Any]) -> tuple[float, Any]:
    """Time a numerical baseline (``method[+renorm]``; setting = step in metres for euler / rk4, else the
    tolerance) on ``exact`` or ``mesh`` media (the parabolic slab mesh at MESH_DELTA), compiled outside
    the timing; fills the row's setting / cells / steps / evaluations / restarts / rejected columns.
    Returns (best trace time s, TraceResult)."""
    case, origins, dirs = inp.case, inp.origins, inp.dirs
    method, _, renorm = name.partition("+")
    kw = dict(inp.common, renormalize=bool(renorm))
    if method in ("euler", "rk4"):
        kw["step_m"] = setting
        row["setting"] = f"step={setting:g} m"
    else:
        kw["tolerance"] = setting
        row["setting"] = f"tol={setting:g}"
    row["tolerance"] = float(setting)
    if media == "mesh":
        med = inp.meshes.get("parabolic", MESH_DELTA)
        kw.update(mesh=med.mesh, quantity=med.quantity, start_cells=med.locate(origins))
        row["cells"] = med.mesh.n_cells
    else:
        kw["exact_spec"] = exact_media_spec(inp.meshes.profile)
    stats: dict[str, np.ndarray] = {}
    warm = dict(kw, origins=origins[:1], directions=dirs[:1], max_time_s=1e-3 * case.t_end)
    if "start_cells" in kw:
        warm["start_cells"] = kw["start_cells"][:1]
    trace_numerical(method, media, **warm)  # compile outside the timing

    def run_numerical() -> Any:
        return trace_numerical(method, media, stats=stats, **kw)

    elapsed, (result, restarts) = best_time(run_numerical, inp.repeats, inp.min_total_s)
    row.update(
        {
            "steps_per_ray": float(result.steps.mean()),
            "evaluations_per_ray": float(stats["evaluations"].mean()),
            "restarts_per_ray": float(restarts.mean()),
            "rejected_per_ray": float(stats["rejected"].mean()),
        }
    )
    return elapsed, result


def _error_columns(case: StratifiedCase, result: Any, ref: np.ndarray, elapsed: float) -> dict[str, Any]:
    """Worst and median relative position error |x - x_ref| / (c_ref t) (inf when an end point is not
    finite), the trace time (s) and the rays by status."""
    err = np.linalg.norm(result.position - ref, axis=1) / case.norm_m
    finite = bool(np.all(np.isfinite(result.position)))
    return {
        "error_max": float(np.max(err)) if finite else math.inf,
        "error_median": float(np.median(err)) if finite else math.inf,
        "trace_time_s": elapsed,
        "status": result.status_counts(),
        "finite": finite,
    }


def run_rows(
    case: StratifiedCase,
    rows: Sequence[tuple[str, str, float]],
    count: int,
    repeats: int,
    *,
    ref: np.ndarray | None = None,
    meshes: MeshCache | None = None,
    min_total_s: float = 0.0,
) -> list[dict[str, Any]]:
    """Run ``(method, media, setting)`` rows on ``case`` with ``count`` rays; see the module docstring.

    method: ``analytic`` (parabolic), ``analytic_circular``, ``analytic_n_linear`` (setting: slab delta), or a
    numerical method of trace_numerical with an optional ``+renorm`` (setting: step in metres for euler /
    rk4, tolerance for euler_adaptive / dopri5). media: ``exact`` or ``mesh`` (the parabolic slab mesh at
    MESH_DELTA for numerical rows). ``ref`` (count, 3): reference end points (computed when None).
    Each row is timed ``repeats`` times at least, more (up to 50) while the runs add up to ``min_total_s``.
    """
    origins, dirs = case.fan(count)
    if ref is None:
        ref = reference_positions(dirs, case=case)
    common = {
        "c_ref": case.c_ref,
        "origins": origins,
        "directions": dirs,
        "max_time_s": case.t_end,
        "max_reflections": case.max_reflections,
        "domain_min": np.asarray(case.domain_min, float),
        "domain_max": np.asarray(case.domain_max, float),
    }
    meshes = MeshCache(case) if meshes is None else meshes
    inp = _RowInputs(case, origins, dirs, meshes, repeats, min_total_s, common)
    out: list[dict[str, Any]] = []
    for name, media, setting in rows:
        row: dict[str, Any] = {
            "case": case.key,
            "method": name,
            "media": media,
            "rays": count,
            "threads": numba.get_num_threads(),
        }
        if name in ANALYTIC_CURVES:
            elapsed, result = _analytic_row(inp, name, setting, row)
        else:
            elapsed, result = _numerical_row(inp, name, media, setting, row)
        row.update(_error_columns(case, result, ref, elapsed))
        out.append(row)
    return out


def probe(quick: bool = False) -> list[dict[str, Any]]:
    """Rows of error against trace time on A-LD (module docstring). ``quick``: 13 rays, 6 rows, 1 run."""
    return run_rows(CASES["A-LD"], QUICK_ROWS if quick else FULL_ROWS, 13 if quick else 91, 1 if quick else 3)


def format_rows(rows: list[dict[str, Any]]) -> str:
    """A markdown table of probe rows."""
    head = (
        "| method | media | setting | worst error | median error | trace time | steps (crossings)/ray | "
        "evals/ray | restarts/ray |"
    )
    lines = [head, "|" + " --- |" * 9]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['media']} | {r['setting']} | {r['error_max']:.1e} | {r['error_median']:.1e} | "
            f"{r['trace_time_s']:.3f} s | {r.get('crossings_per_ray', r.get('steps_per_ray', 0)):.0f} | "
            f"{r.get('evaluations_per_ray', float('nan')):.0f} | {r.get('restarts_per_ray', float('nan')):.1f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(format_rows(probe(quick="--quick" in sys.argv)))
