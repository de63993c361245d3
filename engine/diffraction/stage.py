"""The diffraction stage: levels in the shadows of barriers and buildings, merged into the beam field.

Per source and per point (field grid points and receivers):

1. Line of sight: the straight segment source -> point against every wall (building walls, barriers;
   :func:`bentray.engine.diffraction.kernels.walls_blocking`); blocked by obstacle o means "in o's shadow".
2. Zone weight w (per band): 1 in the shadow; on the lit side it falls smoothly (smoothstep) from 1 on
   the shadow boundary to 0 at a Fresnel number ``DIFFRACTION_LIT_ZONE_FRESNEL`` of the lit-side path
   difference over the nearest of o's edges (those whose stationary point lies on the edge and that see
   both ends). Elsewhere w = 0 and the beam field stays as it is.
3. The obstacle's model where w > 0: its geometric waves (the direct wave and the ground-reflected one
   where the walls let them through) plus, per ground-image combination (S or S', R or R'), single UTD
   diffraction over every edge that sees both ends (barrier tops and ends; roof edges; building corners),
   and double diffraction over the two roof edges facing each other across the roof and around the two
   corners of each wall (lateral paths). Combinations add coherently in coherent / semicoherent maps,
   as energies in incoherent ones. Legs follow the job's profile (curved, :mod:`.legs`) unless the air is
   homogeneous; ISO 9613-1 absorption over the straight source-point distance when the field has it.
4. Main obstacle per point: the largest w, among equals (several shadows) the one that attenuates
   most (Deygout's main obstacle; the others' extra loss is not added).
5. Merge (:func:`bentray.engine.field_sources.combine`, mode "replace"): field = (1 - w) beams + w model.
   In the shadow the model replaces the beams entirely: beams that pass a barrier (barriers are not in the
   media mesh) or leak past a roof edge are not counted twice; across the transition zone the two
   representations of the same lit field are blended, so the level is continuous (UTD geometric +
   diffracted is continuous across the shadow boundary, the blend weight is). With several sources the
   weight and model are combined with each source's share of the unobstructed level (exact for one).

Terrain crests are extracted (:func:`.edges.terrain_crests`) and counted but not yet used as diffracting
edges in this stage; hills shadow nothing here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from bentray.engine.acoustics.absorption import absorption_db_per_m
from bentray.engine.acoustics.ground import ground_impedance, spherical_wave_coefficient
from bentray.engine.acoustics.weighting import a_weighting_db
from bentray.engine.constants import DIFFRACTION_LIT_ZONE_FRESNEL
from bentray.engine.diffraction.edges import EDGE_BARRIER_TOP, EDGE_ROOF, Obstacle, SceneEdges, scene_edges
from bentray.engine.diffraction.kernels import walls_blocking
from bentray.engine.diffraction.legs import ProfileLegs, straight_legs
from bentray.engine.diffraction.paths import GroundSide, LegModel, double_edge_paths, edge_paths
from bentray.engine.diffraction.wedge import edge_legs
from bentray.engine.field_sources import DIFFRACTED, FIELD_SOURCE_TEXT, Contribution, combine, combine_receiver_rows
from bentray.engine.field_sources import counts as source_counts
from bentray.engine.surfaces import SceneSurfaces

__all__ = ["inside_solid", "source_model", "stage_diffraction"]


# The geometric wave's share of each path family goes as |P_k|^(2 m): near a family's own shadow boundary
# its UTD wave (half the geometric one) dominates the others and must meet the whole geometric wave; m = 4
# makes the share decisive there (measured: the step across a building's lateral shadow boundary at 125 Hz
# fell from 1.4 dB with m = 1 to the printed value of tests/diffraction/test_stage_building.py)
SHARE_POWER = 4
ON_BOUNDARY_REL = 1e-11  # relative nudge that tells "exactly on a shadow boundary" (see _lit_weight)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def inside_solid(
    pts: np.ndarray, surfaces: SceneSurfaces | None, ground_z: Callable[[np.ndarray], np.ndarray], bases: np.ndarray
) -> np.ndarray:
    """(N,) bool: points (N, 3) below the ground or inside a building prism (holes excluded)."""
    solid = pts[:, 2] < np.asarray(ground_z(pts[:, :2]), float) - 1e-9
    if surfaces is not None and surfaces.footprints:
        from bentray.scenes.gis_geometry import footprint_polygon, points_in_polygon

        for fp, base in zip(surfaces.footprints, bases, strict=True):
            zin = (pts[:, 2] >= base) & (pts[:, 2] <= base + fp.height_m)
            if np.any(zin):
                idx = np.nonzero(zin)[0]
                solid[idx] |= points_in_polygon(footprint_polygon(fp), pts[idx, :2], margin=1e-9)
    return solid


def _zone_weight(ob: Obstacle, src: np.ndarray, pts: np.ndarray, f_hz: np.ndarray, c: float) -> np.ndarray:
    """(F, N) lit-side transition weight of one obstacle (module docstring, step 2), shadow not included."""
    delta = np.full(pts.shape[0], np.inf)
    for edge in ob.edges:
        leg = edge_legs(edge, src, pts, 1.0)
        inside = (leg.y_e >= edge.y_min) & (leg.y_e <= edge.y_max)
        lim = edge.n * np.pi
        beyond = (leg.phi_out <= lim) & (leg.phi_in <= lim) & (np.abs(leg.phi_out - leg.phi_in) > 0.5 * np.pi)
        d = leg.s_in + leg.s_out - np.linalg.norm(pts - src, axis=1)
        delta = np.where(inside & beyond, np.minimum(delta, d), delta)
    fresnel = 2.0 * delta[None, :] * f_hz[:, None] / c
    return _smoothstep(1.0 - fresnel / DIFFRACTION_LIT_ZONE_FRESNEL)


def _lit_weight(
    blocked: Callable[[np.ndarray, np.ndarray], np.ndarray], src: np.ndarray, pts: np.ndarray
) -> np.ndarray:
    """(N,) 1 where the segment src -> point is clear, 0 where blocked, 1/2 exactly on a shadow boundary
    (the point moved by ON_BOUNDARY_REL x its distance along some axis changes the answer): there the UTD
    wave carries the other half (kernels.EPS_ON_BOUNDARY), so map points that fall exactly on a boundary
    (integer coordinates are common) get the right level too."""
    hit = blocked(src, pts)
    weight = np.where(hit, 0.0, 1.0)
    step = ON_BOUNDARY_REL * np.linalg.norm(pts - src, axis=1)
    for axis in range(3):
        shift = np.zeros(3)
        shift[axis] = 1.0
        a = blocked(src, pts + step[:, None] * shift)
        b = blocked(src, pts - step[:, None] * shift)
        weight = np.where(a != b, 0.5, weight)
    return weight


def _wall_test(walls: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """(a (3,), b (N, 3)) -> (N,) bool: does the segment a -> b cross one of these walls (W, 6)?"""
    owner = np.zeros(len(walls), np.int64)
    walls = np.ascontiguousarray(walls, float)

    def test(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        hit = np.zeros((b.shape[0], 1), np.uint8)
        walls_blocking(np.ascontiguousarray(a, float), np.ascontiguousarray(b, float), walls, owner, hit)
        return hit[:, 0] > 0

    return test


def _geometric(
    src: np.ndarray,
    pts: np.ndarray,
    blocked: Callable[[np.ndarray, np.ndarray], np.ndarray],
    plan_crosses: Callable[[np.ndarray, np.ndarray], np.ndarray],
    f_hz: np.ndarray,
    c_ref: float,
    src_ground: GroundSide,
    legs: LegModel,
) -> np.ndarray:
    """(4, F, N) geometric waves per image combination: the direct wave in (S, R); the ground-reflected
    wave (image of the source in its local ground) in (S', R) when its ground point lies on the source
    side of the obstacle (the plan-view segment source -> ground point crosses none of its walls), else
    in (S, R'): the combination whose diffracted wave has the same shadow boundary, so the two add up
    continuously also when combinations add as energies. Zero where the walls block the wave."""
    k = 2.0 * np.pi * f_hz / c_ref
    out = np.zeros((4, len(f_hz), pts.shape[0]), complex)
    s = np.broadcast_to(src, pts.shape).copy()
    weight = _lit_weight(blocked, src, pts)
    ok = weight > 0
    if np.any(ok):
        d = legs(s[ok], pts[ok])
        out[0][:, ok] = weight[ok] * np.exp(1j * k[:, None] * c_ref * d.time[None, :]) / d.length[None, :]
        _shadow(out[0], ok, legs, s, pts, src_ground, f_hz)
    if src_ground.reflect:
        g = float(np.asarray(src_ground.z, float).reshape(-1)[0])
        img = src.copy()
        img[2] = 2.0 * g - src[2]
        mirrored = pts.copy()
        mirrored[:, 2] = 2.0 * g - pts[:, 2]
        wr = _lit_weight(blocked, img, pts) * _lit_weight(blocked, src, mirrored)
        ok = wr > 0
        if np.any(ok):
            d = legs(np.broadcast_to(img, pts[ok].shape).copy(), pts[ok])
            cos_t = np.clip((src[2] - g + pts[ok, 2] - g) / d.length, 0.0, 1.0)
            z = ground_impedance(f_hz, src_ground.flow_resistivity)[:, None]
            q = spherical_wave_coefficient(z, cos_t[None, :], k[:, None], d.length[None, :])
            wave = wr[ok] * q * np.exp(1j * k[:, None] * c_ref * d.time[None, :]) / d.length[None, :]
            t = (g - img[2]) / np.maximum(pts[ok, 2] - img[2], 1e-12)
            gp = img[None, :] + t[:, None] * (pts[ok] - img[None, :])
            after = plan_crosses(src, gp)
            idx = np.nonzero(ok)[0]
            full = np.zeros((len(f_hz), pts.shape[0]), complex)
            full[:, ok] = wave
            _shadow(full, ok, legs, s, pts, src_ground, f_hz)
            out[1][:, idx[~after]] = full[:, idx[~after]]
            out[2][:, idx[after]] = full[:, idx[after]]
    return out


def _shadow(
    wave: np.ndarray, ok: np.ndarray, legs: LegModel, s: np.ndarray, pts: np.ndarray, side: GroundSide, f_hz: np.ndarray
) -> None:
    """wave[:, ok] (F, N) times the refractive-shadow amplitude of the direct legs s -> pts over the
    source's ground plane (paths module docstring), when the leg model has one."""
    shadow = getattr(legs, "shadow", None)
    if shadow is None or not side.reflect or not np.any(ok):
        return
    amp = shadow(s[ok], pts[ok], side.z, f_hz, side.flow_resistivity)
    if amp is not None:
        wave[:, ok] *= amp


def _side(edge_xy: np.ndarray, src: np.ndarray, centre: np.ndarray) -> int:
    """1 where a vertical edge at edge_xy lies left of the plan line source -> obstacle centre, else 0
    (fixed per source and obstacle: the family of a lateral path must not change with the point)."""
    d = np.asarray(centre, float)[:2] - src[:2]
    v = np.asarray(edge_xy, float)[:2] - src[:2]
    return int(d[0] * v[1] - d[1] * v[0] > 0)


def obstacle_model(
    ob: Obstacle,
    src: np.ndarray,
    pts: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    src_ground: GroundSide,
    rec_ground: GroundSide,
    legs: LegModel,
    blocked: Callable[[np.ndarray, np.ndarray], np.ndarray],
    plan_crosses: Callable[[np.ndarray, np.ndarray], np.ndarray],
    paths: tuple[str, ...] = ("single", "roof", "lateral"),
) -> np.ndarray:
    """(4, 4, F, N) complex: [over the top, lateral on the left, lateral on the right, geometric] x the four
    image combinations. Over the top: single diffraction at top / roof edges and the double roof paths;
    lateral: single diffraction at vertical edges (corners, barrier ends) and the double paths around a
    wall, on the side of the source -> obstacle-centre line where the (first) vertical edge stands; geometric: the
    direct and ground-reflected waves. paths: which diffraction paths to include ("single", "roof",
    "lateral")."""
    n = pts.shape[0]
    out = np.zeros((4, 4, len(f_hz), n), complex)
    centre = np.mean([e.point for e in ob.edges], axis=0)
    if "single" in paths:
        for edge, kind in zip(ob.edges, ob.kinds, strict=True):
            top = kind in (EDGE_ROOF, EDGE_BARRIER_TOP)
            p = edge_paths(
                edge, src, pts, f_hz, c_ref, src_ground, rec_ground, legs, visible_only=True, lateral=not top
            )
            if top:
                out[0] += p
            else:
                out[1 + _side(edge.point, src, centre)] += p
    families = ((0, ob.roof_pairs if "roof" in paths else []), (1, ob.corner_pairs if "lateral" in paths else []))
    for g, pairs in families:
        for i, j in pairs:
            for a, b in ((i, j), (j, i)):
                p = double_edge_paths(
                    ob.edges[a], ob.edges[b], src, pts, f_hz, c_ref, src_ground, rec_ground, legs, lateral=g > 0
                )
                if g == 0:
                    out[0] += p
                else:
                    out[1 + _side(ob.edges[a].point, src, centre)] += p
    out[3] = _geometric(src, pts, blocked, plan_crosses, f_hz, c_ref, src_ground, legs)
    return out


def _energy(parts: np.ndarray, coherent: bool) -> tuple[np.ndarray, np.ndarray]:
    """(rel (F, N), p (F, N)) from obstacle_model's parts (4, 4, F, N).

    Coherent: |sum of everything|^2. Incoherent (band levels): the image combinations add as energies, and
    within each the path families (over the top, left, right) too, each coherently with its share of the
    geometric wave: sum_k |sqrt(a_k) G + P_k|^2, a_k = |P_k|^2m / sum_j |P_j|^2m (m = SHARE_POWER). Each
    family meets the
    geometric wave coherently at its own shadow boundaries (where it dominates, a_k -> 1), so the level
    stays continuous, and the interference fringes between the families (a tone's) do not appear in a
    band level; in the lit zone far from every boundary the sum is |G|^2."""
    fam, geo = parts[:3], parts[3]
    p = parts.sum(axis=(0, 1))
    if coherent:
        return np.abs(p) ** 2, p
    e = np.abs(fam) ** (2 * SHARE_POWER)
    tot = e.sum(axis=0)
    a = np.where(tot > 0, e / np.maximum(tot, 1e-300), 1.0 / 3.0)
    rel = (np.abs(np.sqrt(a) * geo[None] + fam) ** 2).sum(axis=0)
    return rel.sum(axis=0), p


def source_model(
    edges: SceneEdges,
    src: np.ndarray,
    pts: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    src_ground: GroundSide,
    rec_ground: GroundSide,
    legs: LegModel,
    coherent: bool,
    skip: np.ndarray | None = None,
    paths: tuple[str, ...] = ("single", "roof", "lateral"),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, int]]:
    """(w (F, N), rel (F, N), p (F, N) complex, stats) of one source at points pts (N, 3); module docstring.
    skip (N,) bool: points left alone (inside solids)."""
    n_f, n = len(f_hz), pts.shape[0]
    n_ob = len(edges.obstacles)
    shadow = np.zeros((n, max(n_ob, 1)), np.uint8)
    walls_blocking(np.ascontiguousarray(src, float), np.ascontiguousarray(pts, float), edges.walls, edges.owner, shadow)
    best_w = np.zeros((n_f, n))
    best_rel = np.zeros((n_f, n))
    best_p = np.zeros((n_f, n), complex)
    stats = {"shadowed": int(np.count_nonzero(shadow.any(axis=1) & (True if skip is None else ~skip)))}
    for o, ob in enumerate(edges.obstacles):
        w = np.where(shadow[:, o][None, :] > 0, 1.0, _zone_weight(ob, src, pts, f_hz, c_ref))
        if skip is not None:
            w[:, skip] = 0.0
        cand = np.nonzero(w.max(axis=0) > 0)[0]
        if cand.size == 0:
            continue
        walls = edges.walls[edges.owner == o]
        blocked = _wall_test(walls)
        plan_crosses = _wall_test(
            np.column_stack([walls[:, :4], np.full(len(walls), -1e300), np.full(len(walls), 1e300)])
        )

        rg = GroundSide(np.asarray(rec_ground.z, float)[cand] if np.ndim(rec_ground.z) else rec_ground.z,
                        rec_ground.flow_resistivity, rec_ground.reflect)  # fmt: skip
        model = partial(_chunk_model, ob, src, pts[cand], f_hz, c_ref, src_ground, rg, legs, blocked, plan_crosses,
                        paths, coherent)  # fmt: skip
        rel, p = _in_chunks(model, cand.size, n_f)
        wc = w[:, cand]
        take = (wc > best_w[:, cand]) | ((wc == best_w[:, cand]) & (wc >= 1.0) & (rel < best_rel[:, cand]))
        for arr, val in ((best_w, wc), (best_rel, rel), (best_p, p)):
            sub = arr[:, cand]
            sub[take] = val[take]
            arr[:, cand] = sub
    return best_w, best_rel, best_p, stats


MODEL_CHUNK_MIN = 1024  # points per thread of the obstacle model (smaller: not split)


def _chunk_model(
    ob: Obstacle,
    src: np.ndarray,
    pts: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    src_ground: GroundSide,
    rec_ground: GroundSide,
    legs: LegModel,
    blocked: Callable[[np.ndarray, np.ndarray], np.ndarray],
    plan_crosses: Callable[[np.ndarray, np.ndarray], np.ndarray],
    paths: tuple[str, ...],
    coherent: bool,
    sl: slice,
) -> tuple[np.ndarray, np.ndarray]:
    """_energy(obstacle_model(...)) for the points pts[sl] (rec_ground's per-point heights sliced too)."""
    g = rec_ground
    if np.ndim(g.z):
        g = GroundSide(np.asarray(g.z, float)[sl], g.flow_resistivity, g.reflect)
    parts = obstacle_model(ob, src, pts[sl], f_hz, c_ref, src_ground, g, legs, blocked, plan_crosses, paths)
    return _energy(parts, coherent)


def _in_chunks(
    model: Callable[[slice], tuple[np.ndarray, np.ndarray]], n: int, n_f: int
) -> tuple[np.ndarray, np.ndarray]:
    """model(slice of the n points) -> (rel (F, m), p (F, m)), run on point chunks in threads (numpy and the
    nogil UTD kernels release the GIL; numba.get_num_threads() workers, the job's --threads) and put
    together. Every point's result depends on that point alone, so the chunks change no bit."""
    import numba

    workers = max(1, min(numba.get_num_threads(), n // MODEL_CHUNK_MIN))
    if workers == 1:
        return model(slice(0, n))
    from concurrent.futures import ThreadPoolExecutor

    bounds = np.linspace(0, n, workers + 1).astype(int)
    slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        results = list(pool.map(model, slices))
    rel = np.empty((n_f, n))
    p = np.empty((n_f, n), complex)
    for sl, (r, q) in zip(slices, results, strict=True):
        rel[:, sl] = r
        p[:, sl] = q
    return rel, p


def _leg_model(profile: Any, wind: Any, c_ref: float) -> tuple[LegModel, str]:
    """Straight legs in homogeneous air without wind, else circular legs of the linear-c fit."""
    if profile.kind == "homogeneous" and wind is None:
        c = float(profile.sound_speed(np.zeros((1, 3)))[0])
        return (lambda a, b: straight_legs(a, b, c)), "straight (homogeneous air)"
    from bentray.engine.wind import check_wind, wind_along

    code, params = check_wind(wind) if wind is not None else (None, None)

    def c_eff(p: np.ndarray, e: np.ndarray) -> np.ndarray:
        c = np.asarray(profile.sound_speed(p), float)
        if code is not None and params is not None:
            c = c + wind_along(code, params, p, np.column_stack([e, np.zeros(len(e))]))
        return c

    from bentray.engine.wind import WIND_LOG

    stratified = bool(getattr(profile, "stratified", False)) and (code is None or code == WIND_LOG)
    return ProfileLegs(
        c_eff, stratified, code is not None
    ), "curved (circular rays of a linear-c fit per leg; legs in a refractive shadow decay)"


def _ground(job: Any, surfaces: SceneSurfaces | None) -> tuple[Callable[[np.ndarray], np.ndarray], float | None]:
    """Ground height function (M, 2) -> (M,) m and the ground's flow resistivity (None: rigid)."""
    lo = np.asarray(job.scene.box.min, float)
    if surfaces is not None and surfaces.terrain is not None:
        from bentray.engine.mesh.terrain import terrain_height_function

        fn = terrain_height_function(surfaces.terrain, lo, np.asarray(job.scene.box.max, float))
        mat = surfaces.materials[surfaces.terrain.default_material]
        return (lambda xy: np.asarray(fn(xy), float)), mat.flow_resistivity
    return (lambda xy: np.full(len(xy), float(lo[2]))), job.scene.ground.flow_resistivity


def _field_points(job: Any, field_arrays: Any, ground_z: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """(V, 3) world positions of the field grid's points (C order (i, j, k)); above-ground maps lifted."""
    grid = field_arrays.grid
    pts = grid.points()
    if job.field.heights == "above_ground":
        nz = grid.shape[2]
        cols = pts[::nz, :2]
        pts[:, 2] += np.repeat(ground_z(cols) - 0.0, nz)
    return pts


def stage_diffraction(
    job: Any,
    profile: Any,
    wind: Any,
    surfaces: SceneSurfaces | None,
    setup: Any,
    field_arrays: Any,
    receivers: Any,
    log: Any,
) -> dict[str, Any] | None:
    """Run the diffraction stage on the field arrays and receiver rows in place (module docstring);
    returns the report's ``diffraction`` section (None when skipped; the reason is in log.stages)."""
    has_edges = surfaces is not None and (surfaces.barriers or surfaces.footprints)
    if field_arrays is None and receivers is None:
        log.stages["diffraction"] = "skipped: no field and no receivers"
        return None
    if not has_edges:
        log.stages["diffraction"] = "skipped: no buildings or barriers in the scene (no diffracting edges)"
        if field_arrays is not None:
            _mark_geometric(job, surfaces, field_arrays)
        if receivers is not None:
            for r in receivers.rows:
                r["field_source"] = 1 if r.get("beam_hits", 0) else 0
            receivers.columns.append("field_source")
        return None
    assert surfaces is not None
    t0 = time.perf_counter()
    from bentray.scenes.scene_models import footprint_bases

    lo = np.asarray(job.scene.box.min, float)
    bases = np.asarray(footprint_bases(surfaces.terrain, surfaces.footprints, float(lo[2])), float)
    edges = scene_edges(surfaces, list(bases))
    ground_z, sigma = _ground(job, surfaces)
    c_ref = float(profile.c_ref)
    legs, legs_how = _leg_model(profile, wind, c_ref)
    spec = job.field
    out: dict[str, Any] = {
        "method": "UTD rigid wedges (Kouyoumjian-Pathak), four ground-image paths, double roof and lateral paths",
        "legs": legs_how,
        "obstacles": len(edges.obstacles),
        "edges": sum(len(o.edges) for o in edges.obstacles),
        "terrain_crests_found": len(edges.crests),
        "terrain_crests_used": 0,
    }
    if field_arrays is not None and spec is not None:
        labels = list(spec.labels)
        f_hz = np.asarray(spec.frequencies_hz, float)
        pts = _field_points(job, field_arrays, ground_z)
        solid = inside_solid(pts, surfaces, ground_z, bases)
        coherent = spec.mode != "incoherent"
        contrib, st = _contribution(job, setup, edges, pts, f_hz, c_ref, ground_z, sigma, legs, coherent, solid, spec)
        code = combine(field_arrays.arrays, labels, np.asarray(a_weighting_db(f_hz), float), [contrib], coherent, solid)
        shape = field_arrays.grid.shape
        field_arrays.arrays["field_source"] = code.reshape(shape)
        field_arrays.arrays["inside_solid"] = solid.astype(np.uint8).reshape(shape)
        field_arrays.field_data["field_source"] = FIELD_SOURCE_TEXT
        field_arrays.field_data["grid"] = str(field_arrays.field_data.get("grid", "")).replace(
            "NaN: no beam reached the point", "NaN: inside the ground or a building (see inside_solid)"
        )
        counts = source_counts(code, solid)
        field_arrays.stats["field_source"] = counts
        out["field"] = {**st, "field_source": counts}
    if receivers is not None and setup.receivers_xyz is not None:
        f_hz = np.asarray(receivers.stats["frequencies_hz"], float)
        labels = [c[len("tl_inc_") : -2] for c in receivers.columns if c.startswith("tl_inc_")]
        pts = np.asarray(setup.receivers_xyz, float)
        conts = []
        for coherent in (True, False):
            c, _ = _contribution(job, setup, edges, pts, f_hz, c_ref, ground_z, sigma, legs, coherent, None, None)
            conts.append(c)
        code = combine_receiver_rows(receivers.rows, labels, np.asarray(a_weighting_db(f_hz), float), [conts[0]],
                                     [conts[1]])  # fmt: skip
        receivers.columns.append("field_source")
        receivers.stats["field_source"] = source_counts(code)
        out["receivers"] = {"field_source": source_counts(code)}
    out["seconds"] = time.perf_counter() - t0
    log.timings["diffraction"] = out["seconds"]
    log.stages["diffraction"] = (
        f"ran: {out['obstacles']} obstacles, {out['edges']} edges, legs {legs_how}; "
        f"{len(edges.crests)} terrain crests found, not used"
    )
    return out


def _mark_geometric(job: Any, surfaces: SceneSurfaces | None, field_arrays: Any) -> None:
    """field_source / inside_solid arrays without a diffraction model (codes 1 and 0 only)."""
    ground_z, _ = _ground(job, surfaces)
    pts = _field_points(job, field_arrays, ground_z)
    solid = inside_solid(pts, surfaces, ground_z, np.zeros(0))
    labels = list(job.field.labels)
    f_hz = np.asarray(job.field.frequencies_hz, float)
    code = combine(field_arrays.arrays, labels, np.asarray(a_weighting_db(f_hz), float), [], False, solid)
    shape = field_arrays.grid.shape
    field_arrays.arrays["field_source"] = code.reshape(shape)
    field_arrays.arrays["inside_solid"] = solid.astype(np.uint8).reshape(shape)
    field_arrays.field_data["field_source"] = FIELD_SOURCE_TEXT
    field_arrays.stats["field_source"] = source_counts(code, solid)


def _contribution(
    job: Any,
    setup: Any,
    edges: SceneEdges,
    pts: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    ground_z: Callable[[np.ndarray], np.ndarray],
    sigma: float | None,
    legs: LegModel,
    coherent: bool,
    solid: np.ndarray | None,
    spec: Any,
) -> tuple[Contribution, dict[str, int]]:
    """The diffraction model of all sources as one replacing Contribution (multi-source weights: each
    source's share of the unobstructed level, module docstring step 5)."""
    n_f, n = len(f_hz), pts.shape[0]
    rec_ground = GroundSide(ground_z(pts[:, :2]), sigma)
    absorb = np.ones((n_f, 1))
    alpha = None
    if spec is not None and spec.absorption:
        alpha = np.array([absorption_db_per_m(f, spec.temperature_c, spec.humidity_percent, spec.pressure_kpa)
                          for f in f_hz])  # fmt: skip
    num_w = np.zeros((n_f, n))
    num_m = np.zeros((n_f, n))
    num_wp = np.zeros((n_f, n))
    num_mp = np.zeros((n_f, n))
    den = np.zeros((n_f, n))
    den_p = np.zeros((n_f, n))
    p_sum = np.zeros((n_f, n), complex)
    powers = setup.powers
    shadowed = 0
    for s, source in enumerate(job.sources):
        src = np.asarray(source.position, float)
        src_ground = GroundSide(float(ground_z(src[None, :2])[0]), sigma)
        w, rel, p, st = source_model(edges, src, pts, f_hz, c_ref, src_ground, rec_ground, legs, coherent, solid)
        shadowed += st["shadowed"]
        d2 = np.maximum(np.sum((pts - src) ** 2, axis=1), 1e-6)
        if alpha is not None:
            absorb = 10.0 ** (-alpha[:, None] * np.sqrt(d2)[None, :] / 10.0)
        rel = rel * absorb
        p = p * np.sqrt(absorb)
        g = 1.0 / d2[None, :]
        num_w += w * g
        num_m += w * rel
        den += g
        p_sum += w * p
        if powers is not None:
            pw = np.asarray(powers[s], float)[:, None] / (4.0 * np.pi)
            num_wp += w * g * pw
            num_mp += w * rel * pw
            den_p += g * pw
    w_eff = num_w / den
    model = np.where(w_eff > 0, num_m / np.maximum(w_eff, 1e-300), 0.0)
    powered = None
    w_pow = None
    if powers is not None:
        w_pow = num_wp / np.maximum(den_p, 1e-300)
        powered = np.where(w_pow > 0, num_mp / np.maximum(w_pow, 1e-300), 0.0)
    p_eff = np.where(w_eff > 0, p_sum / np.maximum(w_eff, 1e-300), 0.0) if coherent else None
    stats = {
        "points": n,
        "shadowed_point_source_pairs": shadowed,
        "modelled_points": int(np.count_nonzero(w_eff.max(axis=0) > 0)),
        "fully_replaced_points": int(np.count_nonzero(w_eff.min(axis=0) >= 1.0)),
    }
    return Contribution(DIFFRACTED, model, w_eff, powered, p_eff, "replace", w_pow), stats
