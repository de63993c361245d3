"""An atomic counter for compiled kernels that share work across threads (kernels/lean.py's ray queue).

``fetch_add(counter, value)`` adds ``value`` to ``counter[0]`` (an int64 array of at least one element) as one
atomic read-modify-write (LLVM ``atomicrmw add``; x86's ``lock xadd``) and returns the value before the
addition. Threads that call it on the same array each get a distinct range [old, old + value): no ray is taken
twice and none is skipped, whatever the interleaving (tests/engine/test_lean_traversal.py). The ordering is
``monotonic`` (relaxed): the counter's own updates are atomic and totally ordered, which is all a work queue
needs; the counter publishes no other data (each ray's outputs are read only after the threads are joined),
so no fence is asked for around it.
"""

from __future__ import annotations

from typing import Any

from numba import types
from numba.extending import intrinsic

from bentray.engine.kernels.llvm_vec import item_ptr

__all__ = ["fetch_add"]


def _fetch_add_intrinsic(typingctx: Any, counter: types.Type, value: types.Type) -> Any:
    """Typing and code of :func:`fetch_add`: counter an int64 array (element 0 is the counter), value an
    integer; returns int64."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and isinstance(value, types.Integer)):
        return None
    sig = types.int64(counter, value)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        aty = signature.args[0]
        arr = context.make_array(aty)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        ptr = item_ptr(context, builder, aty, arr, [zero] * aty.ndim)
        add = context.cast(builder, args[1], signature.args[1], types.int64)
        return builder.atomic_rmw("add", ptr, add, "monotonic")

    return sig, codegen


fetch_add: Any = intrinsic(_fetch_add_intrinsic)
