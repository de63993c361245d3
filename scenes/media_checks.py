"""Physical checks of a job's medium before any mesh is built: sound speed and wind where the mesh samples.

bentray traces sound in air. A profile whose sound speed leaves :data:`C_MIN_M_S` .. :data:`C_MAX_M_S`
anywhere in the domain (a log profile with b = -1e6 goes negative, ``linear_c`` with c0 = 1e308 is not
air, a grid with a 10x checkerboard is a medium the curve model was never meant for) is refused with the
profile field to change, instead of being traced to a "successful" nonsense result. The range is that of
air from -150 deg C to +1,000 deg C with margin (c = 20.05 sqrt(T): 222 .. 714 m/s), widened so that
the light-validation mirages (c = c_ref / n with c_ref = 340) and steep textbook gradients still pass.
Within the domain the ratio of the largest to the smallest sound speed is at most :data:`MAX_CONTRAST`
(so a 10x checkerboard of speeds that are each in range is refused too). A wind must stay well below the
sound speed: ``|u| <= MAX_MACH * c`` at every sampled point.

Where the mesh samples: a lattice of :data:`LATTICE` points per axis over the domain box (edges
included, plus the hot spot centre), at the heights the profile is evaluated at (the height above the
ground from 0 to the domain's z extent for ``profile_heights = "above_ground"``, world z otherwise), and
every node of a grid profile. Monotone laws (linear, log, mirages, tables) take their extremes at the
lattice's end points, so for them the check is exact; fluctuating and hot-spot media are sampled.
Pure numpy; bounded work (a few thousand profile evaluations plus one pass over a grid's nodes).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["C_MAX_M_S", "C_MIN_M_S", "LATTICE", "MAX_MACH", "media_problems"]

C_MIN_M_S = 100.0
C_MAX_M_S = 1000.0
MAX_MACH = 0.3  # |u| / c: beyond this the effective-sound-speed model (c + u . e) is no longer good
MAX_CONTRAST = 3.0  # max c / min c over the domain: air from -150 deg C to +1,000 deg C is 3.2x
LATTICE = 17

# The parameter named when the speed at the reference point is wrong, and when its variation is.
_LEVEL_FIELD = {
    "homogeneous": "c0",
    "linear_c": "c0",
    "linear_n": "n0",
    "linear_n2": "n0",
    "log": "c0",
    "mirage_inferior": "mu0",
    "mirage_superior": "mu0",
    "hot_spot": "t_s",
    "fluctuating": "base",
    "table": "z",
    "grid": "c",
}
_SLOPE_FIELD = {
    "linear_c": "alpha",
    "linear_n": "alpha",
    "linear_n2": "alpha",
    "log": "b",
    "mirage_inferior": "mu1",
    "mirage_superior": "mu1",
    "hot_spot": "t_s",
    "fluctuating": "rms",
}


def _lattice(lo: np.ndarray, hi: np.ndarray, n: int = LATTICE) -> np.ndarray:
    axes = [np.linspace(lo[k], hi[k], n) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _table_field(spec: Any) -> str:
    for key in ("c", "temperature_k", "temperature_c"):
        if getattr(spec, key, None) is not None:
            return key
    return "z"


def _where(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in p) + ") m"


def media_problems(job: Any, base_dir: str | Path | None = None, prefix: str = "profile") -> list[str]:
    """``field.path: reason`` lines for a job whose medium is not air-like (empty when it is).

    job : a validated :class:`bentray.scenes.schema.Job`; base_dir : folder of relative grid paths.
    A profile that cannot be built (an unreadable grid, NaN or c <= 0 nodes) is one line naming the
    field with the reader's reason.
    """
    from bentray.scenes.profile_models import GridSpec, TableSpec, profile_from_spec

    spec = job.profile
    kind = spec.kind
    try:
        profile = profile_from_spec(spec, base_dir)
    except Exception as exc:  # the engine's readers raise ValueError, OSError, BentrayError ...
        field = "path" if isinstance(spec, GridSpec) and spec.path is not None else _LEVEL_FIELD.get(kind, "kind")
        return [f"{prefix}.{field}: {' '.join(str(exc).split()) or type(exc).__name__}"]
    box = job.scene.box
    lo = np.asarray(box.min, dtype=np.float64)
    hi = np.asarray(box.max, dtype=np.float64)
    if job.scene.profile_heights == "above_ground":  # c = profile(z - ground): heights 0 .. z extent
        lo_eval, hi_eval = lo.copy(), hi.copy()
        lo_eval[2], hi_eval[2] = 0.0, hi[2] - lo[2]
    else:
        lo_eval, hi_eval = lo, hi
    points = _lattice(lo_eval, hi_eval)
    center = getattr(spec, "center", None)
    if center is not None:
        points = np.vstack([points, np.asarray(center, dtype=np.float64)[None, :]])
    problems: list[str] = []
    with np.errstate(all="ignore"):
        c = np.asarray(profile.sound_speed(points), dtype=np.float64).reshape(-1)
        grid_c = np.asarray(getattr(profile, "c", np.empty(0)), dtype=np.float64).reshape(-1)
    if isinstance(spec, GridSpec) and grid_c.size:
        bad = ~np.isfinite(grid_c) | (grid_c < C_MIN_M_S) | (grid_c > C_MAX_M_S)
        if np.any(bad):
            field = "path" if spec.path is not None else "c"
            first = float(grid_c[np.argmax(bad)])
            problems.append(
                f"{prefix}.{field}: {int(bad.sum()):,} of {grid_c.size:,} grid nodes have a sound speed outside "
                f"{C_MIN_M_S:g} .. {C_MAX_M_S:g} m/s (first: {first:.6g} m/s); bentray traces air"
            )
            return problems
        if grid_c.max() > MAX_CONTRAST * grid_c.min():
            field = "path" if spec.path is not None else "c"
            problems.append(
                f"{prefix}.{field}: the grid's sound speed ranges from {grid_c.min():.6g} to {grid_c.max():.6g} m/s, "
                f"more than {MAX_CONTRAST:g}x; air in any weather stays within that"
            )
            return problems
    bad = ~np.isfinite(c) | (c < C_MIN_M_S) | (c > C_MAX_M_S)
    if np.any(bad):
        k = int(np.argmax(bad))
        ref = float(c[0]) if c.size else float("nan")
        if isinstance(spec, TableSpec):
            field = _table_field(spec)
        elif np.isfinite(ref) and C_MIN_M_S <= ref <= C_MAX_M_S and kind in _SLOPE_FIELD:
            field = _SLOPE_FIELD[kind]
        else:
            field = _LEVEL_FIELD.get(kind, "kind")
        heights = "height above the ground" if job.scene.profile_heights == "above_ground" else "world point"
        problems.append(
            f"{prefix}.{field}: the {kind} profile's sound speed is {float(c[k]):.6g} m/s at {heights} "
            f"{_where(points[k])}; it must stay within {C_MIN_M_S:g} .. {C_MAX_M_S:g} m/s everywhere in the "
            "domain (bentray traces air)"
        )
        return problems
    if c.max() > MAX_CONTRAST * c.min():
        field = (
            _table_field(spec)
            if isinstance(spec, TableSpec)
            else _SLOPE_FIELD.get(kind, _LEVEL_FIELD.get(kind, "kind"))
        )
        problems.append(
            f"{prefix}.{field}: the {kind} profile's sound speed ranges from {c.min():.6g} to {c.max():.6g} m/s in "
            f"the domain, more than {MAX_CONTRAST:g}x; air in any weather stays within that"
        )
        return problems
    if job.wind is not None:
        from bentray.engine.wind import max_wind_speed
        from bentray.scenes.wind_models import wind_from_spec

        code, params = wind_from_spec(job.wind)
        world = _lattice(lo, hi)
        with np.errstate(all="ignore"):
            u = np.asarray(max_wind_speed(code, params, world), dtype=np.float64)
        c_min = float(np.min(c))
        bad_u = ~np.isfinite(u) | (u > MAX_MACH * c_min)
        if np.any(bad_u):
            k = int(np.argmax(bad_u))
            problems.append(
                f"wind.u_star: the wind speed reaches {float(u[k]):.4g} m/s at {_where(world[k])}, more than "
                f"{MAX_MACH:g} x the lowest sound speed ({c_min:.4g} m/s); lower u_star (or the domain top)"
            )
    return problems
