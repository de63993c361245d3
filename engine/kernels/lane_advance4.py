"""The lean kernel's advance stage for four lanes at once as 4-wide vectors (kernels/lean.py).

After the exit search, each lane of the lean traversal takes the same closed forms (physics.md section 2):
the travel time (parabolic.travel_time), the new position and unit tangent (parabolic.state_at) and the
arc length by Gauss-Legendre quadrature (parabolic.arc_length), 2 points where the segment turns by a
half-turning ratio e up to ARC_E2, 3 points up to ARC_E3. That is six square roots and five divisions per
lane, one after another in the scalar code, and square roots and divisions are what the core does slowest
(2.5 and 1.3 ns each at full throughput on the AMD EPYC of the bench, against 0.1 ns for a multiply or add).
``advance4`` takes four lanes' values as <4 x double> vectors and does the same operations, in the same
order, for all four: one vector square root or division does four lanes' work. Both quadratures are taken
for every lane and the rule is chosen per lane by a select (so no lane waits on a branch that changes from
ray to ray); a lane whose e exceeds ARC_E3 (GL4 or the closed form, one segment in a thousand on the desert)
is flagged in the returned mask and its length left for the caller to take with parabolic.arc_length.

Bits: the IR carries no fast-math flags (no fused multiply-add, no reassociation) and vector square roots and
divisions are correctly rounded like scalar ones, so every output is the scalar helpers' value bit for bit
(tests/engine/test_lane_advance4.py: against the helpers on random and special-value lanes; the lean kernel
against the generic one in tests/engine/test_lean_traversal.py).

Layout (the lean kernel's stage arrays, rows = lanes, C-contiguous float64): lf columns 0 m0 (n^2 at the
start), 1-3 g (grad n^2), 4-6 p0 (n T at the start), 7 g.p0, 8 |g|^2, 10 the exit parameter sigma; 11 gets
dt. lx (lanes, 3) the start position; lxn, ldn (lanes, 3) get the new position and unit tangent; lds (lanes,)
the arc length.
"""

from __future__ import annotations

from typing import Any

from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import types
from numba.core.extending import intrinsic

from bentray.engine.kernels import parabolic
from bentray.engine.kernels.llvm_vec import I32, I64, V4, const4, item_ptr, splat, vsqrt

__all__ = ["advance4"]


def _advance4_intrinsic(typingctx, lf, lx, lxn, ldn, lds, k0, c_ref):  # noqa: ARG001
    """Advance stage of lanes k0..k0+3 (module docstring); returns the mask (bit j: lane k0 + j) of lanes
    whose arc length is left to the caller."""
    for a in (lf, lx, lxn, ldn):
        if not (isinstance(a, types.Array) and a.ndim == 2 and a.dtype == types.float64 and a.layout == "C"):
            return None
    if not (isinstance(lds, types.Array) and lds.ndim == 1 and lds.dtype == types.float64):
        return None
    sig = types.int64(lf, lx, lxn, ldn, lds, k0, c_ref)

    def codegen(context, builder, signature, args):
        tys = signature.args
        arrs = [context.make_array(tys[i])(context, builder, args[i]) for i in range(5)]
        a_lf, a_lx, a_lxn, a_ldn, a_lds = arrs
        k0v = args[5]
        rows = [builder.add(k0v, ir.Constant(I64, j)) for j in range(4)]

        def const_idx(v: int) -> Any:
            return context.get_constant(types.intp, v)

        def gather(aty: Any, arr: Any, col: int) -> Any:
            vec = ir.Constant(V4, ir.Undefined)
            for j in range(4):
                val = builder.load(item_ptr(context, builder, aty, arr, [rows[j], const_idx(col)]))
                vec = builder.insert_element(vec, val, ir.Constant(I32, j))
            return vec

        def scatter(aty: Any, arr: Any, col: int | None, vec: Any) -> None:
            for j in range(4):
                idx = [rows[j]] if col is None else [rows[j], const_idx(col)]
                lane_value = builder.extract_element(vec, ir.Constant(I32, j))
                builder.store(lane_value, item_ptr(context, builder, aty, arr, idx))

        fmul, fadd, fsub, fdiv = builder.fmul, builder.fadd, builder.fsub, builder.fdiv

        def sqrt(v: Any) -> Any:
            return vsqrt(builder, v)

        m0 = gather(tys[0], a_lf, 0)
        g = [gather(tys[0], a_lf, 1 + i) for i in range(3)]
        p0 = [gather(tys[0], a_lf, 4 + i) for i in range(3)]
        gp0 = gather(tys[0], a_lf, 7)
        gg = gather(tys[0], a_lf, 8)
        sigma = gather(tys[0], a_lf, 10)
        x0 = [gather(tys[1], a_lx, i) for i in range(3)]
        # parabolic.travel_time: sigma * (n0sq + sigma * (0.5 * gp0 + sigma * gg / 12.0)) / c_ref
        inner = fadd(fmul(const4(0.5), gp0), fdiv(fmul(sigma, gg), const4(12.0)))
        dt = fdiv(fmul(sigma, fadd(m0, fmul(sigma, inner))), splat(builder, args[6]))
        scatter(tys[0], a_lf, 11, dt)
        # parabolic.state_at: p = p0 + 0.5 g sigma, x = x0 + sigma (p0 + 0.25 g sigma), T = p / |p|
        p = [fadd(p0[i], fmul(fmul(const4(0.5), g[i]), sigma)) for i in range(3)]
        for i in range(3):
            xn = fadd(x0[i], fmul(sigma, fadd(p0[i], fmul(fmul(const4(0.25), g[i]), sigma))))
            scatter(tys[2], a_lxn, i, xn)
        norm = sqrt(fadd(fadd(fmul(p[0], p[0]), fmul(p[1], p[1])), fmul(p[2], p[2])))
        for i in range(3):
            scatter(tys[3], a_ldn, i, fdiv(p[i], norm))

        # parabolic.arc_length, its 2- and 3-point rules
        def speed(u: Any) -> Any:
            q = [fadd(p0[i], fmul(fmul(const4(0.5), g[i]), u)) for i in range(3)]
            return sqrt(fadd(fadd(fmul(q[0], q[0]), fmul(q[1], q[1])), fmul(q[2], q[2])))

        mm = fadd(fadd(fmul(p0[0], p0[0]), fmul(p0[1], p0[1])), fmul(p0[2], p0[2]))
        ggs = fadd(fadd(fmul(g[0], g[0]), fmul(g[1], g[1])), fmul(g[2], g[2]))
        q = fmul(fmul(fmul(const4(0.0625), ggs), sigma), sigma)
        h = fmul(const4(0.5), sigma)
        r2 = fmul(const4(parabolic.GL2_T), h)
        a2 = fmul(h, fadd(speed(fsub(h, r2)), speed(fadd(h, r2))))
        r3 = fmul(const4(parabolic.GL3_T), h)
        outer3 = fmul(const4(parabolic.GL3_W1), fadd(speed(fsub(h, r3)), speed(fadd(h, r3))))
        a3 = fmul(h, fadd(outer3, fmul(const4(parabolic.GL3_W0), speed(h))))
        two = builder.fcmp_ordered("<=", q, fmul(const4(parabolic.ARC_Q2), mm))
        three = builder.fcmp_ordered("<=", q, fmul(const4(parabolic.ARC_Q3), mm))
        scatter(tys[4], a_lds, None, builder.select(two, a2, a3))
        rare = builder.not_(builder.or_(two, three))
        mask = ir.Constant(I64, 0)
        for j in range(4):
            bit = builder.zext(builder.extract_element(rare, ir.Constant(I32, j)), I64)
            mask = builder.or_(mask, builder.shl(bit, ir.Constant(I64, j)))
        return mask

    return sig, codegen


advance4: Any = intrinsic(_advance4_intrinsic)
