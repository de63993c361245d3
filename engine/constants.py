"""Named tolerances, status codes, boundary tags and numba flags, in one place.

Every tolerance says why it has the value it has. Units: metres, seconds, m/s unless stated.
"""

from __future__ import annotations

from typing import Any

# ---------------------------------------------------------------------------------------------
# Ray end states (int8 in kernels). Every ray ends with exactly one of these; the report counts them.
# ---------------------------------------------------------------------------------------------
STATUS_RUNNING = 0
STATUS_TIME_LIMIT = 1  # reached exactly max_time_s of travel time (solved inside the last segment)
STATUS_REFLECTION_LIMIT = 2  # hit a reflecting face after max_reflections reflections
STATUS_EXITED = 3  # left the domain through an open face
STATUS_STEP_LIMIT = 4  # used max_steps segment steps (reported, never silent)
STATUS_LOST = 5  # no consistent exit after nudging, invalid media (n^2 <= 0, c <= 0) or NaN

STATUS_NAMES = {
    STATUS_RUNNING: "running",
    STATUS_TIME_LIMIT: "time_limit",
    STATUS_REFLECTION_LIMIT: "reflection_limit",
    STATUS_EXITED: "exited",
    STATUS_STEP_LIMIT: "step_limit",
    STATUS_LOST: "lost",
}

# ---------------------------------------------------------------------------------------------
# Output columns shared by every traversal kernel (kernels/traverse.py, baselines/trace_numerical.py,
# experimental/traverse_linked.py). out_state (n, STATE_SIZE) float64, world frame:
# ---------------------------------------------------------------------------------------------
STATE_X = 0  # position x, y, z (m): columns STATE_X .. STATE_X + 2
STATE_D = 3  # unit tangent dx, dy, dz: columns STATE_D .. STATE_D + 2
STATE_TIME = 6  # travel time (s)
STATE_LENGTH = 7  # arc length (m)
STATE_SIZE = 8
# out_counts (n, COUNT_SIZE) int64 of the analytic tracer (the numerical baselines share the first three
# columns and keep their own after them: baselines/trace_numerical.py)
COUNT_STATUS = 0  # STATUS_* end state
COUNT_REFLECTIONS = 1
COUNT_CROSSINGS = 2  # faces crossed into a neighbouring cell
COUNT_NUDGES = 3  # nudges and slides (robustness events, physics.md section 5)
COUNT_STEPS = 4  # segment steps (every curve set-up, zero-length ones included)
COUNT_SAMPLES = 5  # path samples recorded
COUNT_SIZE = 6

# ---------------------------------------------------------------------------------------------
# Boundary tags stored in CellMesh.neighbours where a face has no neighbouring cell.
# Non-negative values are cell ids.
# ---------------------------------------------------------------------------------------------
BOUNDARY_OPEN = -1  # the ray leaves the domain (box sides, open top)
BOUNDARY_REFLECT = -2  # ground, wall or reflecting top: specular reflection with the face normal
FACE_UNUSED = -9  # padding slot in cells with fewer than MAX_FACES faces (never an exit)

# ---------------------------------------------------------------------------------------------
# Curve kinds (the quantity m each one needs the cell to be linear in)
# ---------------------------------------------------------------------------------------------
CURVE_PARABOLIC = 0  # m = n^2, constant grad(n^2)      (physics.md section 2)
CURVE_CIRCULAR = 1  # m = c,   constant grad(c)         (physics.md section 3)
CURVE_NLINEAR = 2  # m = n,   constant grad(n), bisection (physics.md section 4)

CURVE_CODES = {"parabolic": CURVE_PARABOLIC, "circular": CURVE_CIRCULAR, "n_linear": CURVE_NLINEAR}
CURVE_QUANTITY = {"parabolic": "n2", "circular": "c", "n_linear": "n"}

# ---------------------------------------------------------------------------------------------
# Tolerances
# ---------------------------------------------------------------------------------------------
# A point whose signed distance to a face plane exceeds -ON_FACE_REL * cell size counts as "on or
# beyond" that face when the ray moves outward through it (immediate exit). 1e-12 of the cell size is
# ~1e3 ulps of a coordinate at km scale relative to a metre-sized cell: large enough to absorb plane
# rounding, small enough never to skip a real segment longer than a nanometre-per-metre.
ON_FACE_REL = 1e-12
# Beam fields bound the paraxial "onto the face" shift |d sigma_k| by cell size / n on faces that are not
# horizontal (|m_z| below this): on terrain-following tets, rays that cross slanted faces nearly
# tangentially get large exact kicks from the per-cell gradient jumps of the piecewise-linear medium,
# which flip tubes (spurious caustics; the ridge map's point noise fell from 1.7 to 0.16 dB). Horizontal
# faces (slabs, the stratified part of a mesh) keep the exact derivative: bounding it there too made the
# upward-refraction GFPE cases worse (0.66 -> 1.76 dB). Exact derivatives are always kept when the state
# is asked for (trace(paraxial=True): eigenrays, tests). Without wind (parabolic curve) beams carry the state
# through the smooth medium instead (mesh/hessian.py: no face kicks at all); there the bound applies only at
# boundary faces (terrain reflections).
BEAM_KICK_BOUND_NZ = 1.0 - 1e-9
# When a ray finds no exit (rounding at an edge or vertex), it is moved along its tangent by
# NUDGE_REL * cell size and re-located by walking; such events are counted in the report.
NUDGE_REL = 1e-9
# Zero-length steps in a row (edge/vertex walks) before the ray is nudged: a walk around one edge
# of a Delaunay mesh visits at most a few dozen cells.
MAX_ZERO_STEPS = 64
# A step shorter than TINY_STEP_REL * cell size makes no progress: a ray that starts on an edge shared by
# many cells and moves within one of their faces (a source on a terrain-grid column, launched along a
# grid line) can circle the edge with steps of 1e-10 m. MAX_ZERO_STEPS such steps in a row -> nudge.
TINY_STEP_REL = 1e-6
# Sliding: a stalled ray within SLIDE_DIST_REL * cell size of a face and moving along it (|d . m| <=
# SLIDE_COS) sits in a zero-width channel of the piecewise-linear medium: the per-cell gradients on the
# two sides of the face both push it back toward the face (a gradient jump the continuous medium does
# not have), so the exact per-cell curves zig-zag across it with steps of 1e-8 m forever. It then
# slides: x and d are projected onto the face plane and the next segment uses the two cells' mean
# gradient without its normal part, so it stays in the plane until another face (counted as a nudge).
SLIDE_DIST_REL = 1e-6
SLIDE_COS = 1e-3
# A ray that meets a reflecting face with |d . m| <= GRAZE_COS at a zero-length step (it sits on the
# face, tangent to it, curving into it) slides along the face instead of reflecting without effect.
GRAZE_COS = 1e-12
# A ray that crosses the same face back and forth PINGPONG_SLIDE times in a row while moving along it
# (|d . m| <= SLIDE_COS) is in such a channel too, with steps too long to count as stalls: it slides.
PINGPONG_SLIDE = 4
# Walking steps allowed for one re-location before the ray is declared lost.
MAX_WALK = 64
# Consecutive nudges allowed at one place before the ray is declared lost.
MAX_NUDGES_IN_A_ROW = 8
# Bisection iterations for the n-linear curve's plane intersections: 2^-60 of the bracket is below
# float64 resolution of any bracket shorter than 1e3 cell sizes.
NLINEAR_BISECTION_ITERS = 60
# An n-linear ray whose direction is within NLINEAR_STRAIGHT_COS of the gradient axis (cos of the angle to
# the plane normal to e_z) is traced as a straight line: the catenary's horizontal extent inside any cell
# is then below 1e-12 of its length, far under the other errors of the method.
NLINEAR_STRAIGHT_COS = 1e-12
# Doublings allowed when bracketing an n-linear root from above (the catenary grows like cosh, so a
# handful suffice; 200 doublings of a metre overflow float64 long before).
NLINEAR_MAX_DOUBLINGS = 200
# Newton iterations for inverting the cubic time equation t(sigma) = t_target inside one segment;
# the iteration is safeguarded by a bracket and converges quadratically in 3-5 steps.
TIME_SOLVE_ITERS = 50

# ---------------------------------------------------------------------------------------------
# Numba flags (cache=True needs a writable NUMBA_CACHE_DIR: set in bentray/__init__.py)
# ---------------------------------------------------------------------------------------------
# error_model="numpy": float division by zero gives inf/nan (checked explicitly) instead of raising,
# which also lets numba drop the per-division zero checks in the hot loops.
NJIT_FLAGS: dict[str, Any] = {"cache": True, "fastmath": False, "nogil": True, "error_model": "numpy"}
# For called kernels that allocate nothing and keep no reference to an array past the call (the beams' deposit
# kernels, beams.deposit_chord and deposit_points): Numba's reference counting off ("_nrt", Numba's own switch for
# code without its runtime), so the ~30 arrays of a call's arguments (grid, accumulators, the chord's samples and
# tables) cost no atomic increments and decrements per call. The caller holds every array for the call's
# duration; an allocation inside such a kernel fails to compile. docs/physics.md §9;
# tests/engine/test_no_nrt_kernels.py.
NJIT_NO_NRT: dict[str, Any] = {**NJIT_FLAGS, "_nrt": False}
PARALLEL_FLAGS: dict[str, Any] = {
    "cache": True,
    "fastmath": False,
    "nogil": True,
    "error_model": "numpy",
    "parallel": True,
}

# ---------------------------------------------------------------------------------------------
# Edge diffraction (engine/diffraction/)
# ---------------------------------------------------------------------------------------------
# A terrain mesh edge is a diffracting crest when the two triangles that share it turn away from each
# other (convex, a ridge) by more than this angle between their normals. 10 degrees: gentler bends
# diffract (and shadow) little at noise-map distances, and a 1 m DEM of real ground has bends of a few
# degrees on every edge (roughness, not crests); a road embankment's shoulder or a ridge crest passes it.
TERRAIN_CREST_MIN_DEG = 10.0
# Lit-side width of the transition zone where the diffraction model replaces the beam field, as a
# Fresnel number N = 2 delta / lambda of the lit-side path difference delta over the edge: at N = 1 the
# UTD edge wave is ~0.2 of the geometric one (a +-1.6 dB ripple), and it falls as 1/sqrt(N) beyond; the
# weight goes smoothly from 1 on the shadow boundary to 0 here, so the map stays continuous.
DIFFRACTION_LIT_ZONE_FRESNEL = 1.0
