"""Small LLVM IR helpers for the 4-wide vector intrinsics (kernels/face_roots4.py, kernels/lane_advance4.py).

Codegen-time Python only (they build IR inside a Numba ``@intrinsic``'s codegen): constants and splats of
<4 x double> / <4 x i64>, lane shuffles, the vector square root (``llvm.sqrt.v4f64``, correctly rounded like
the scalar one) and an array element's address without wraparound or bounds checks. No fast-math flags are
set anywhere, so the IR built with them does the scalar code's arithmetic lane by lane.
"""

from __future__ import annotations

from typing import Any

from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import cgutils

__all__ = ["D", "I32", "I64", "V4", "VI64", "const4", "item_ptr", "shuffle", "splat", "splat_i64", "vsqrt"]

D = ir.DoubleType()
I32 = ir.IntType(32)
I64 = ir.IntType(64)
V4 = ir.VectorType(D, 4)
VI64 = ir.VectorType(I64, 4)
_ZEROS4 = ir.Constant(ir.VectorType(I32, 4), [0, 0, 0, 0])


def const4(value: float) -> Any:
    """A constant <4 x double> with every lane ``value``."""
    return ir.Constant(V4, [ir.Constant(D, float(value))] * 4)


def splat(builder: Any, value: Any) -> Any:
    """A <4 x double> with every lane the IR double ``value``."""
    vec = builder.insert_element(ir.Constant(V4, ir.Undefined), value, ir.Constant(I32, 0))
    return builder.shuffle_vector(vec, vec, _ZEROS4)


def splat_i64(builder: Any, value: Any) -> Any:
    """A <4 x i64> with every lane the IR i64 ``value``."""
    vec = builder.insert_element(ir.Constant(VI64, ir.Undefined), value, ir.Constant(I32, 0))
    return builder.shuffle_vector(vec, vec, _ZEROS4)


def shuffle(builder: Any, a: Any, b: Any, mask: list[int]) -> Any:
    """LLVM's shufflevector of two <4 x ...> with a constant 4-lane mask (indices 0-7 over a then b)."""
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(I32, 4), mask))


def vsqrt(builder: Any, value: Any) -> Any:
    """Lane-wise square root of a <4 x double> (llvm.sqrt.v4f64)."""
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4]), "llvm.sqrt.v4f64")
    return builder.call(fn, [value])


def item_ptr(context: Any, builder: Any, aty: Any, arr: Any, idx: list[Any]) -> Any:
    """Address of arr[idx] (arr a Numba array struct of type aty; idx IR integers), no wraparound or bounds
    check: the callers index rows and columns they know are inside."""
    return cgutils.get_item_pointer(context, builder, aty, arr, idx, wraparound=False, boundscheck=False)
