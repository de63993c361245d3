"""The exit search of a tetrahedron in one pass over its four faces as 4-wide vectors (lean and generic kernels).

The lean traversal (kernels/lean.py) finds a cell's exit face face by face: per face the plane coefficients
(A, B, C) of the parabolic curve (parabolic.plane_coefficients), a skip when A <= 0 and B <= 0 (no upward
crossing for u > 0), and roots.face_exit_parameter, then the smallest parameter wins (the first face on a
tie). For a tetrahedron that is four times ~25 scalar operations, a square root, a division and five
data-dependent branches: the branches' outcomes change from ray to ray, so with several rays in flight per
thread (the lean kernel's lanes) they are mispredicted often.

``exit_of_tet`` does the same for the four faces at once with LLVM vector operations (one <4 x double> per
quantity: the packed record's four face rows are loaded and transposed, so mx, my, mz and h are vectors),
every branch of the scalar code written as a lane-wise select, and returns (parameter, face) as the scalar
loop does. The arithmetic per face is the scalar code's, operation for operation and in the same order
(no fused multiply-add: the IR carries no fast-math flags), and IEEE square root and division are correctly
rounded in vector form too, so each lane's value is bit-identical to the scalar one; the reduction takes the
four results in face order with the scalar loop's strict ``<``. Equivalence of the branch-free form
(docs/physics.md section 9, "The exit search as vectors"):

- face_exit_parameter's linear shortcut of upcrossing_root (A == 0) returns what the general formula gives:
  -C / B is C / q with q = -(B + sqrt(B B)) / 2 = -B exactly (sqrt(fl(B^2)) = |B| while B^2 is a normal
  float), and with B < 0 the general formula's q / A is +-inf or nan, not a root in (0, inf);
- a non-positive or nan discriminant gives +inf in both (the scalar code's nan root fails 0 < r < inf);
- the skip (A <= 0 and B <= 0), unused faces (neighbour FACE_UNUSED) and the entry face (C = 0, no
  on-face exit) are masks.

Also here: ``exit_of_cell8``, the same for cells of 5 to 8 faces in two passes of four (the faces past K masked;
the second pass wins only where strictly smaller, the loop's first minimum); ``exit_of_tet_planes``, the
tetrahedron's search on the generic kernel's per-cell (4, 4) planes and (4,) neighbours (traverse.trace_slots,
parabolic curve), which has no skip: a face with A <= 0 and B <= 0 gives +inf there too; and
``exit_of_cell_planes``, the generic kernel's search for cells of 5 to 8 faces (slab boxes, prisms) in two passes
of four, whose rows past K are read at K - 1 (the per-cell view ends at the cell) and masked.

tests/engine/test_face_roots4.py checks all four against the scalar loops (lean._exit_search, curves.find_exit)
on random and adversarial inputs (zeros of either sign, nan, inf, subnormal and huge coefficients, points on
faces, ties, unused faces, strided planes).
"""

from __future__ import annotations

from typing import Any

from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import types
from numba.core.extending import intrinsic

from bentray.engine.constants import FACE_UNUSED
from bentray.engine.kernels.llvm_vec import I32, I64, V4, D, const4, item_ptr, shuffle, splat, splat_i64, vsqrt

__all__ = ["exit_of_cell8", "exit_of_cell_planes", "exit_of_tet", "exit_of_tet_planes"]


def _tet_exit(
    builder: Any, faces: list[Any], unused: Any, scalars: list[Any], entry: Any, tol: Any, base: int = 0
) -> tuple[Any, Any]:
    """IR of the search: faces, four <4 x double> rows (mx, my, mz, h); unused, <4 x i1> (faces to leave out);
    scalars, the nine doubles g0 g1 g2 p0 p1 p2 x0 x1 x2; entry (i64) and tol (double); base, the index of the
    first of the four faces. Returns the IR values (parameter double, face i64; -1 and +inf: no exit)."""
    # transpose the four (mx, my, mz, h) rows into per-quantity vectors over the faces
    t0 = shuffle(builder, faces[0], faces[1], [0, 4, 2, 6])  # mx0 mx1 mz0 mz1
    t1 = shuffle(builder, faces[0], faces[1], [1, 5, 3, 7])  # my0 my1 h0 h1
    t2 = shuffle(builder, faces[2], faces[3], [0, 4, 2, 6])
    t3 = shuffle(builder, faces[2], faces[3], [1, 5, 3, 7])
    mx = shuffle(builder, t0, t2, [0, 1, 4, 5])
    mz = shuffle(builder, t0, t2, [2, 3, 6, 7])
    my = shuffle(builder, t1, t3, [0, 1, 4, 5])
    hh = shuffle(builder, t1, t3, [2, 3, 6, 7])
    g0v, g1v, g2v, p0v, p1v, p2v, x0v, x1v, x2v = (splat(builder, a) for a in scalars)
    fmul, fadd, fsub = builder.fmul, builder.fadd, builder.fsub
    # parabolic.plane_coefficients: a = 0.25 (mx g0 + my g1 + mz g2), b = mx p0 + my p1 + mz p2,
    # c = mx x0 + my x1 + mz x2 - h, each summed left to right as there
    a = fmul(const4(0.25), fadd(fadd(fmul(mx, g0v), fmul(my, g1v)), fmul(mz, g2v)))
    b = fadd(fadd(fmul(mx, p0v), fmul(my, p1v)), fmul(mz, p2v))
    c = fsub(fadd(fadd(fmul(mx, x0v), fmul(my, x1v)), fmul(mz, x2v)), hh)
    zeros = const4(0.0)
    lane = ir.Constant(ir.VectorType(I64, 4), [ir.Constant(I64, base + f) for f in range(4)])
    is_entry = builder.icmp_signed("==", lane, splat_i64(builder, entry))
    c_eff = builder.select(is_entry, zeros, c)  # the entry face: C is 0 there
    # roots.upcrossing_root in its general form (module docstring: the linear shortcut gives the same)
    disc = fsub(fmul(b, b), fmul(fmul(const4(4.0), a), c_eff))
    ok = builder.fcmp_ordered(">", disc, zeros)  # false for nan, as 'disc <= 0' is then false but the root nan
    sq = vsqrt(builder, builder.select(ok, disc, zeros))
    pos = builder.fcmp_ordered(">=", b, zeros)
    half = const4(-0.5)
    q_pos = fmul(half, fadd(b, sq))
    q_neg = fmul(half, fsub(b, sq))
    r = builder.fdiv(builder.select(pos, c_eff, q_neg), builder.select(pos, q_pos, a))
    inf = const4(float("inf"))
    valid = builder.and_(ok, builder.and_(builder.fcmp_ordered(">", r, zeros), builder.fcmp_ordered("<", r, inf)))
    # roots.face_exit_parameter's on-face exit: not the entry face, c > -tol, moving out (b > 0, or b == 0, a > 0)
    neg_tol = splat(builder, builder.fsub(ir.Constant(D, -0.0), tol))  # -tol exactly
    out_going = builder.or_(
        builder.fcmp_ordered(">", b, zeros),
        builder.and_(builder.fcmp_ordered("==", b, zeros), builder.fcmp_ordered(">", a, zeros)),
    )
    on_face = builder.and_(builder.not_(is_entry), builder.and_(builder.fcmp_ordered(">", c, neg_tol), out_going))
    res = builder.select(valid, r, builder.select(on_face, zeros, inf))
    # the lean loop's skip (A <= 0 and B <= 0: +inf in any case, see roots) and unused faces
    skip = builder.and_(builder.fcmp_ordered("<=", a, zeros), builder.fcmp_ordered("<=", b, zeros))
    res = builder.select(builder.or_(skip, unused), inf, res)
    # the loop's reduction: faces in order, strict '<' (the first face wins a tie)
    param = ir.Constant(D, float("inf"))
    face = ir.Constant(I64, -1)
    for f in range(4):
        v = builder.extract_element(res, ir.Constant(I32, f))
        better = builder.fcmp_ordered("<", v, param)
        param = builder.select(better, v, param)
        face = builder.select(better, ir.Constant(I64, base + f), face)
    return param, face


def _record_row(context: Any, builder: Any, aryty: Any, arr: Any, cell: Any) -> Any:
    """Pointer to the first double of row ``cell`` of the packed records ``arr`` (C-contiguous, 2-D)."""
    ary = context.make_array(aryty)(context, builder, arr)
    return item_ptr(context, builder, aryty, ary, [cell, context.get_constant(types.intp, 0)])


def _rows(builder: Any, row: Any) -> list[Any]:
    """The four <4 x double> face rows from a pointer to the first double of (mx, my, mz, h) x 4."""
    vptr = builder.bitcast(row, V4.as_pointer())
    return [builder.load(builder.gep(vptr, [ir.Constant(I64, f)]), align=8) for f in range(4)]


def _exit_of_tet_intrinsic(typingctx, rec, cell, g0, g1, g2, p0, p1, p2, x0, x1, x2, entry, tol, o_nb):  # noqa: ARG001
    """(parameter, face) of the lean loop over the 4 faces of row ``cell`` of the packed records ``rec``
    (mesh/packed.py: planes at 0..15, neighbours at o_nb..o_nb+3 as float64)."""
    if not (isinstance(rec, types.Array) and rec.ndim == 2 and rec.dtype == types.float64 and rec.layout == "C"):
        return None
    sig = types.Tuple((types.float64, types.int64))(rec, cell, g0, g1, g2, p0, p1, p2, x0, x1, x2, entry, tol, o_nb)

    def codegen(context, builder, signature, args):
        row = _record_row(context, builder, signature.args[0], args[0], args[1])
        nbv = builder.load(builder.bitcast(builder.gep(row, [args[13]]), V4.as_pointer()), align=8)
        unused = builder.fcmp_ordered("==", nbv, const4(float(FACE_UNUSED)))
        param, face = _tet_exit(builder, _rows(builder, row), unused, list(args[2:11]), args[11], args[12])
        return context.make_tuple(builder, signature.return_type, [param, face])

    return sig, codegen


def _plane_row(context: Any, builder: Any, pty: Any, pl: Any, row: Any) -> Any:
    """Row ``row`` (an intp IR value) of a cell's planes (K, 4) float64 as one <4 x double>: one vector load
    when the array is C-contiguous, else (a strided view, as from a mesh built from slices) its four values
    gathered one by one."""
    zero = context.get_constant(types.intp, 0)
    if pty.layout == "C":  # the row's four doubles are consecutive
        ptr = item_ptr(context, builder, pty, pl, [row, zero])
        return builder.load(builder.bitcast(ptr, V4.as_pointer()), align=8)
    vec = ir.Constant(V4, ir.Undefined)
    for c in range(4):
        ptr = item_ptr(context, builder, pty, pl, [row, context.get_constant(types.intp, c)])
        vec = builder.insert_element(vec, builder.load(ptr), ir.Constant(I32, c))
    return vec


def _planes_group(
    context: Any, builder: Any, pty: Any, pl: Any, nty: Any, nbs: Any, base: int, k_faces: Any
) -> tuple[list[Any], Any]:
    """Faces base..base+3 of a cell's planes and neighbours: their four rows and the <4 x i1> mask of faces to
    leave out (neighbour FACE_UNUSED, or index >= k_faces). Rows past the cell's K faces are read at index K - 1
    instead (inside the view; masked), so nothing beyond the cell is touched."""
    rows = []
    unused = ir.Constant(ir.VectorType(ir.IntType(1), 4), None)
    last = builder.sub(k_faces, ir.Constant(k_faces.type, 1))
    for f in range(4):
        j = ir.Constant(k_faces.type, base + f)
        past = builder.icmp_signed(">=", j, k_faces)
        idx = builder.select(past, last, j) if base else j
        rows.append(_plane_row(context, builder, pty, pl, idx))
        nb_f = builder.load(item_ptr(context, builder, nty, nbs, [idx]))
        is_unused = builder.icmp_signed("==", nb_f, ir.Constant(I64, FACE_UNUSED))
        if base:
            is_unused = builder.or_(is_unused, past)
        unused = builder.insert_element(unused, is_unused, ir.Constant(I32, f))
    return rows, unused


def _planes_args_ok(planes: Any, neighbours: Any) -> bool:
    """A cell's planes (K, 4) float64 and neighbours (K,) int64, any layout."""
    ok_planes = isinstance(planes, types.Array) and planes.ndim == 2 and planes.dtype == types.float64
    ok_nb = isinstance(neighbours, types.Array) and neighbours.ndim == 1 and neighbours.dtype == types.int64
    return ok_planes and ok_nb


def _first_of_groups(builder: Any, results: list[tuple[Any, Any]]) -> tuple[Any, Any]:
    """(parameter, face) over groups of four faces taken in order: a later group wins only where strictly
    smaller (the scalar loop's first minimum)."""
    param, face = results[0]
    for p_next, f_next in results[1:]:
        better = builder.fcmp_ordered("<", p_next, param)
        param = builder.select(better, p_next, param)
        face = builder.select(better, f_next, face)
    return param, face


def _planes_exit_typing(groups: int, name: str) -> Any:
    """The typing function of a search on one cell's planes (K, 4) float64 and neighbours (K,) int64 (the generic
    kernel's per-cell views, any layout) in ``groups`` groups of four faces: 1 for a tetrahedron (K = 4), 2 for
    4 < K <= 8 (K from the view's shape; rows past K read at K - 1 and masked). Neither has the lean loop's
    skip, which changes nothing (A <= 0, B <= 0 give +inf)."""

    def typing(typingctx, planes, neighbours, g0, g1, g2, p0, p1, p2, x0, x1, x2, entry, tol):  # noqa: ARG001
        if not _planes_args_ok(planes, neighbours):
            return None
        sig = types.Tuple((types.float64, types.int64))(
            planes, neighbours, g0, g1, g2, p0, p1, p2, x0, x1, x2, entry, tol
        )

        def codegen(context, builder, signature, args):
            pty, nty = signature.args[0], signature.args[1]
            pl = context.make_array(pty)(context, builder, args[0])
            nbs = context.make_array(nty)(context, builder, args[1])
            if groups == 1:
                k_faces = context.get_constant(types.intp, 4)
            else:
                k_faces = builder.extract_value(pl.shape, 0)
            results = []
            for base in range(0, 4 * groups, 4):
                faces, unused = _planes_group(context, builder, pty, pl, nty, nbs, base, k_faces)
                results.append(_tet_exit(builder, faces, unused, list(args[2:11]), args[11], args[12], base))
            param, face = _first_of_groups(builder, results)
            return context.make_tuple(builder, signature.return_type, [param, face])

        return sig, codegen

    typing.__name__ = typing.__qualname__ = name
    return typing


def _exit_of_cell8_intrinsic(typingctx, rec, cell, g0, g1, g2, p0, p1, p2, x0, x1, x2, entry, tol, o_nb, k_faces):  # noqa: ARG001
    """(parameter, face) of the lean loop over the K faces (4 < K <= 8) of row ``cell`` of the packed records:
    two groups of four, faces K..7 masked (their rows and neighbour slots lie inside the record: a record holds
    6 K + 8 >= 8 (4 + 1) doubles), the second group taken only where strictly smaller (the loop's first
    minimum)."""
    if not (isinstance(rec, types.Array) and rec.ndim == 2 and rec.dtype == types.float64 and rec.layout == "C"):
        return None
    sig = types.Tuple((types.float64, types.int64))(
        rec, cell, g0, g1, g2, p0, p1, p2, x0, x1, x2, entry, tol, o_nb, k_faces
    )

    def codegen(context, builder, signature, args):
        row = _record_row(context, builder, signature.args[0], args[0], args[1])
        nb_row = builder.gep(row, [args[13]])
        k_vec = splat_i64(builder, args[14])
        results = []
        for base in (0, 4):
            nbv = builder.load(builder.bitcast(builder.gep(nb_row, [ir.Constant(I64, base)]), V4.as_pointer()), align=8)
            idx = ir.Constant(ir.VectorType(I64, 4), [ir.Constant(I64, base + f) for f in range(4)])
            unused = builder.or_(
                builder.fcmp_ordered("==", nbv, const4(float(FACE_UNUSED))),
                builder.icmp_signed(">=", idx, k_vec),
            )
            faces = _rows(builder, builder.gep(row, [ir.Constant(I64, 4 * base)]))
            results.append(_tet_exit(builder, faces, unused, list(args[2:11]), args[11], args[12], base))
        param, face = _first_of_groups(builder, results)
        return context.make_tuple(builder, signature.return_type, [param, face])

    return sig, codegen


exit_of_tet: Any = intrinsic(_exit_of_tet_intrinsic)
exit_of_cell8: Any = intrinsic(_exit_of_cell8_intrinsic)
# (parameter, face) of a tetrahedron's search on its planes (4, 4) and neighbours (4,), and of a cell of 4 < K <= 8
# faces on its (K, 4) and (K,) (the caller checks K <= 8: faces past 8 would be left out)
exit_of_tet_planes: Any = intrinsic(_planes_exit_typing(1, "exit_of_tet_planes"))
exit_of_cell_planes: Any = intrinsic(_planes_exit_typing(2, "exit_of_cell_planes"))
