"""Layer-sizing probe on A-LD: worst position error against layers and crossings for alternative slab rules.

Question (issue 18): can a layer rule that bounds the ray's position error, instead of the n^2
interpolation error, reach a worst relative position error of 1e-4 on A-LD with far fewer layers than
the curvature rule (engine/mesh/sizing.py)? The probe traces the case's fan with the parabolic curve on
slab meshes whose boundaries come from the curvature rule at several delta, or from a power law
h(z) = k z_g u^p, u = z / z_g + 1 (layer thickness h in metres, z height above the ground in metres), and
reports layers, crossings per ray and the worst / median relative position error against
baselines_probe.reference_positions (DOP853, rtol 1e-13). No timing: layers and crossings only.

Error argument (docs/physics.md §6 material). In sigma (d sigma = ds / n) a ray in a stratified medium keeps
a = n cos(theta) and has p_z^2 = m(z) - a^2, m = n^2. Linear interpolation of m over a layer of thickness h
adds e(z) with 0 <= e <= h^2 m'' / 8 for convex m (the log profile with b > 0). A ray turning at z_t moves its
apex by dz_t = e(z_t) / |m'| and, from the turning layer and the convergent sum over the layers below it,
its range per turn by dX ~ C a h^(3/2) m'' / |m'|^(3/2) (C = O(0.1), set by where z_t falls in its layer).
For the log profile |m'| ~ 2 b / (c0 u z_g), m'' ~ 2 b / (c0 u^2 z_g^2), so dX ~ C' (h / z_g)^(3/2) u^(-1/2) z_g,
while the cycle length is X ~ 2 sqrt(2 pi c0 / b) u z_g for u >> 1. A ray with many turns in its path
(the ground duct) errs relatively by dX / X ~ (h / (u z_g))^(3/2): constant for h proportional to u, which is
what the curvature rule already gives (h = sqrt(8 delta |m| / m'') ~ u). A ray that turns once (cycle at
least its path, e.g. A-LD's +-8 degree rays turning near 70 m) errs absolutely by dX ~ h^(3/2) u^(-1/2):
equalising that needs h ~ u^(1/3), finer aloft than now. Either way, bounding the position error never asks
for thicker layers than h ~ u; p < 1 (e.g. h ~ sqrt(u)) refines aloft and costs layers and crossings for
the same worst error, p > 1 crowds the ground where the ducted rays cross most layers.

``python -m bentray.engine.bench.sizing_probe`` prints the rows (91 rays; about a minute after compilation).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from bentray.engine.bench.baselines_probe import CASES, StratifiedCase, reference_positions
from bentray.engine.bench.common import fan
from bentray.engine.mesh.sizing import MAX_LAYERS, curvature_layers
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.tracer import trace

__all__ = ["power_law_levels", "curvature_levels", "sizing_rows", "format_sizing_rows"]


def power_law_levels(z_lo: float, z_hi: float, k: float, p: float, z_g: float = 1.0) -> np.ndarray:
    """Layer boundaries (L + 1,) m on [z_lo, z_hi] with thickness h = k z_g u^p, u = (z - z_lo) / z_g + 1,
    evaluated at the layer's middle (one fixed-point pass); a last sliver under 1e-6 of the column joins its
    neighbour."""
    if not (z_hi > z_lo) or k <= 0.0:
        raise ValueError("need z_hi > z_lo and k > 0")

    def h_at(z: float) -> float:
        return k * z_g * ((z - z_lo) / z_g + 1.0) ** p

    levels = [float(z_lo)]
    while levels[-1] < z_hi:
        z = levels[-1]
        h = h_at(z + 0.5 * h_at(z))
        levels.append(min(float(z_hi), z + h))
        if len(levels) > MAX_LAYERS:
            raise ValueError("too many layers; raise k")
    if len(levels) > 2 and levels[-1] - levels[-2] < 1e-6 * (z_hi - z_lo):
        levels.pop(-2)
    return np.asarray(levels)


def _m_at_z(case: StratifiedCase) -> Callable[[np.ndarray], np.ndarray]:
    prof = case.profile()

    def m_at_z(z: np.ndarray) -> np.ndarray:
        z = np.atleast_1d(np.asarray(z, float))
        return prof.quantity("n2", np.column_stack([np.zeros_like(z), np.zeros_like(z), z]))

    return m_at_z


def curvature_levels(case: StratifiedCase, delta: float, d_min: float = 1e-5) -> np.ndarray:
    """The curvature rule's boundaries for the case's column (what build_media uses for its slabs)."""
    lo, hi = case.domain_min[2], case.domain_max[2]
    return curvature_layers(lo, hi, _m_at_z(case), delta=delta, d_min=d_min, d_max=hi - lo)


def sizing_rows(
    case: StratifiedCase,
    levels: Sequence[tuple[str, np.ndarray]],
    count: int = 91,
    ref: np.ndarray | None = None,
    *,
    elevations_deg: np.ndarray | None = None,
    rtol: float = 1e-13,
) -> list[dict[str, Any]]:
    """Trace rays with the parabolic curve on each (label, z_levels) slab mesh of the case.

    Rays: the case's fan of ``count`` rays, or the given elevations (degrees, azimuth 0) from its source.
    ``ref`` (rays, 3): reference end points, computed (DOP853 at ``rtol``) when None. Returns one dict per
    mesh: label, layers, crossings_per_ray, error_max, error_median (relative position error
    |x - x_ref| / (c_ref t)), worst (the three worst elevations in degrees with their errors).
    """
    el = np.linspace(*case.elevation_range_deg, count) if elevations_deg is None else np.asarray(elevations_deg)
    origins, dirs = fan(case.source, el)
    ref = reference_positions(dirs, rtol=rtol, case=case) if ref is None else ref
    lo, hi = np.asarray(case.domain_min, float), np.asarray(case.domain_max, float)
    m_at_z = _m_at_z(case)
    out = []
    for label, z in levels:
        mesh = build_slab_mesh(lo, hi, z, m_at_z)
        res = trace(mesh, "parabolic", case.c_ref, origins, dirs, locate_in_slabs(z, origins),
                    max_time_s=case.t_end, max_reflections=case.max_reflections)  # fmt: skip
        err = np.linalg.norm(res.position - ref, axis=1) / case.norm_m
        worst = np.argsort(err)[::-1][:3]
        out.append(
            {
                "label": label,
                "layers": len(z) - 1,
                "crossings_per_ray": float(res.crossings.mean()),
                "error_max": float(err.max()),
                "error_median": float(np.median(err)),
                "worst": [(float(el[i]), float(err[i])) for i in worst],
            }
        )
    return out


def format_sizing_rows(rows: Sequence[dict[str, Any]]) -> str:
    """A markdown table of sizing_rows."""
    lines = ["| rule | layers | crossings/ray | worst error | median error | worst rays (el deg: error) |"]
    lines.append("|" + " --- |" * 6)
    for r in rows:
        worst = ", ".join(f"{e:+.0f}: {v:.1e}" for e, v in r["worst"])
        lines.append(
            f"| {r['label']} | {r['layers']} | {r['crossings_per_ray']:.0f} | {r['error_max']:.2e} | "
            f"{r['error_median']:.1e} | {worst} |"
        )
    return "\n".join(lines)


def default_levels(case: StratifiedCase) -> list[tuple[str, np.ndarray]]:
    """The probe's meshes: curvature delta 1e-5 .. 3e-7 and power laws p = 1/3, 1/2, 3/4, 1, 5/4, 3/2."""
    lo, hi = case.domain_min[2], case.domain_max[2]
    z_g = case.params.get("z_g", 1.0)
    out = [(f"curvature delta={d:g}", curvature_levels(case, d)) for d in (1e-5, 3e-6, 2e-6, 1e-6, 3e-7)]
    grid = {1 / 3: (0.2, 0.1, 0.05), 0.5: (0.14, 0.07, 0.035), 0.75: (0.07, 0.035), 1.0: (0.04, 0.03, 0.02),
            1.25: (0.02, 0.01), 1.5: (0.01, 0.005)}  # fmt: skip
    for p, ks in grid.items():
        out += [(f"h = {k:g} u^{p:.2f}", power_law_levels(lo, hi, k, p, z_g)) for k in ks]
    return out


if __name__ == "__main__":  # pragma: no cover
    case = CASES["A-LD"]
    print(format_sizing_rows(sizing_rows(case, default_levels(case))))
