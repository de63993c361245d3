"""``njit_inline``: a small kernel compiled once and inlined by LLVM into its callers, not by Numba.

Numba's own inlining (``@njit(inline="always")``) copies the callee's Numba IR into every call site before
type inference. Each copy is then typed, SSA-rebuilt and lowered again, with the callees it inlines in turn,
so one big kernel (the traversal with beam deposits) grows to tens of thousands of IR statements whose
typing dominated the first run's compilation. ``njit_inline`` compiles the function as an ordinary Numba
function (typed and optimised once per signature) and marks its machine-level definition ``alwaysinline``
for LLVM: when a caller links it in (Numba links a callee's LLVM module into each caller and optimises the
whole), LLVM's inliner puts its body at every call site, where the caller's arrays, structs and constants
meet it, as Numba's inlining did, and Numba's reference-count pruning then runs on the inlined code.

Measured on the reduced README job (181 x 61 rays, one thread, empty cache; docs/physics.md §9): the first
run 88 s -> 59 s of wall time, the warm traces unchanged (with field 1.89 -> 1.86 CPU-s, without
0.67 -> 0.68), the final ray states and the beam field bit-identical (no fast-math: LLVM inlining does not
reassociate).

Mechanism: Numba has no public switch for LLVM function attributes. A library's module for linking into
callers is made by ``CPUCodeLibrary._get_module_for_linking`` (numba/core/codegen.py); the wrapper below
adds ``alwaysinline`` to the definitions of registered functions in that module (also what the on-disk
cache stores as the library's bitcode for linking). Functions are recognised by the prefix of their mangled
names (``_ZN`` + Numba's itanium encoding of ``module.qualname``; every later part is length-prefixed, so
one prefix cannot match another function). Should a Numba version lack the hook, :data:`ACTIVE` is False
and the functions are plain calls: the same results, slower (tests/engine/test_llvm_inline.py fails then).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba as nb
from numba.core import codegen, itanium_mangler

from bentray.engine.constants import NJIT_FLAGS

__all__ = ["ACTIVE", "mangled_prefix", "njit_inline"]

_PREFIXES: set[str] = set()
_original_module_for_linking = getattr(codegen.CPUCodeLibrary, "_get_module_for_linking", None)
ACTIVE = _original_module_for_linking is not None


def mangled_prefix(fn: Callable[..., Any]) -> str:
    """The start of every Numba symbol compiled from ``fn`` (its mangled ``module.qualname``)."""
    encoded = itanium_mangler.mangle_identifier(f"{fn.__module__}.{fn.__qualname__}")
    return "_ZN" + encoded[1:-1]  # mangle_identifier gives N<parts>E; symbols continue with abi tags


def njit_inline(fn: Callable[..., Any]) -> Any:
    """``nb.njit(**NJIT_FLAGS)(fn)``, inlined by LLVM wherever another Numba function calls it."""
    _PREFIXES.add(mangled_prefix(fn))
    return nb.njit(**NJIT_FLAGS)(fn)


def _module_for_linking(self: Any) -> Any:
    """CPUCodeLibrary._get_module_for_linking, with registered definitions marked ``alwaysinline``."""
    fresh = self._shared_module is None
    mod = _original_module_for_linking(self)  # type: ignore[misc]
    if not fresh or not _PREFIXES:
        return mod
    prefixes = tuple(_PREFIXES)
    marked = [fn for fn in mod.functions if not fn.is_declaration and fn.name.startswith(prefixes)]
    if not marked:
        return mod
    if mod is self._final_module:  # never edit the module the library's own machine code came from
        mod = mod.clone()
        self._shared_module = mod
        marked = [mod.get_function(fn.name) for fn in marked]
    for fn in marked:
        if not any(b"noinline" in attrs for attrs in fn.attributes):  # bytes, space-separated
            fn.add_function_attribute("alwaysinline")
    return mod


if ACTIVE:
    codegen.CPUCodeLibrary._get_module_for_linking = _module_for_linking  # type: ignore[method-assign]
