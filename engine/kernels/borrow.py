"""Borrowed views of a kernel's input structs: the same arrays, without reference counting.

Numba counts references to every array that carries a memory-info pointer (every array that came from Python
or was allocated in compiled code): binding one to a variable, passing it to a call that is not inlined or
taking it out of a struct costs an atomic increment and decrement. The traversal's hot paths take the beam's,
the mesh's and the rays' arrays out of their structs many times per chord sample. A prange caller hides that
cost: numba's parallel gufunc rebuilds its array arguments without a memory-info pointer, and NRT_incref /
NRT_decref return at once for those. A kernel called from Python threads (traverse.trace_rays) gets its
arrays with their memory-info pointers, and measured 10-15 % slower on the README job's beam trace until its
inputs were borrowed with :func:`borrow`.

``borrow(value)`` returns ``value`` with every array in it (recursively through tuples and named tuples)
rebuilt without its memory-info and parent pointers: the same data, shape and strides, no reference counted.
The views are valid while the caller holds the originals, which it does for the whole kernel call; nothing
may keep them beyond it (the trace kernels write into the arrays and keep no reference).
"""

from __future__ import annotations

from typing import Any

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["borrow", "held_until_here"]


def _borrowed(context: Any, builder: Any, ty: types.Type, value: Any) -> Any:
    """LLVM value of ``ty`` with the memory-info and parent pointers of every array in it set to null."""
    if isinstance(ty, types.Array):
        ary = context.make_array(ty)(context, builder, value)
        ary.meminfo = cgutils.get_null_value(ary.meminfo.type)
        ary.parent = cgutils.get_null_value(ary.parent.type)
        return ary._getvalue()
    if isinstance(ty, types.BaseTuple):
        out = value
        for k, member in enumerate(ty.types):  # type: ignore[attr-defined]  # (every concrete tuple type has .types)
            item = builder.extract_value(value, k)
            out = builder.insert_value(out, _borrowed(context, builder, member, item), k)
        return out
    return value


def _borrow_intrinsic(typingctx: Any, value: types.Type) -> Any:
    """Typing and code of :func:`borrow`: same type out as in."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return _borrowed(context, builder, signature.args[0], args[0])

    return value(value), codegen


borrow: Any = intrinsic(_borrow_intrinsic)


def _held_intrinsic(typingctx: Any, value: types.Type) -> Any:
    """Typing and code of :func:`held_until_here`: no code; the call is a use of ``value``."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return context.get_dummy_value()

    return types.none(value), codegen


# held_until_here(x): a use of x that generates no code. Numba releases a variable after its last use (on each
# path: where no later use is reachable); a borrowed view of x is valid only while x is held, so a kernel that
# borrows from an array it allocated calls this where the view's use ends, and every path that uses the view must
# reach the call (no continue, break or return between them: the traversal's per-ray body has none at its level).
held_until_here: Any = intrinsic(_held_intrinsic)
