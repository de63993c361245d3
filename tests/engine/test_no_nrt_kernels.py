"""engine/constants.py ``NJIT_NO_NRT``: the beams' per-chord deposit kernels are compiled without Numba's reference
counting, which is safe only while they allocate nothing and keep no array past the call.

Oracles: the two deposit kernels carry the switch; under the same flags a kernel that allocates does not compile
(so the switch cannot hide a leak or a freed array), one that only reads arrays out of a tuple computes what the
counted version computes, and its LLVM has no reference-count call left while the counted twin's has. The
engine-level check (the README job's beam field identical with and without the switch) is in docs/physics.md §9.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from bentray.engine.constants import NJIT_FLAGS, NJIT_NO_NRT
from bentray.engine.kernels import beams

_FLAGS = {**NJIT_NO_NRT, "cache": False}  # test-local kernels: never cached (no test type in a cache index)


def test_deposit_kernels_run_without_reference_counting() -> None:
    for kernel in (beams.deposit_chord, beams.deposit_points):
        assert kernel.targetoptions.get("_nrt") is False, kernel


def test_an_allocation_does_not_compile_without_the_runtime() -> None:
    @nb.njit(**_FLAGS)
    def allocates(n):  # type: ignore[no-untyped-def]
        return np.zeros(n).sum()

    with pytest.raises(nb.core.errors.TypingError):
        allocates(3)


def _reads_tuple(t, x):  # type: ignore[no-untyped-def]
    a = t[0]
    b = t[1]
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * x + b[i % b.shape[0]]
    b[0] += s
    return s


def test_a_kernel_reading_arrays_from_a_tuple_gives_the_counted_result_without_counting() -> None:
    bare = nb.njit(**_FLAGS)(_reads_tuple)
    counted = nb.njit(**{**NJIT_FLAGS, "cache": False})(_reads_tuple)
    a = np.linspace(0.0, 1.0, 7)
    b1 = np.array([0.5, -2.0, 3.0])
    b2 = b1.copy()
    assert bare((a, b1), 1.25) == counted((a, b2), 1.25)
    assert np.array_equal(b1, b2)
    ir_bare = bare.inspect_llvm(bare.signatures[0])
    ir_counted = counted.inspect_llvm(counted.signatures[0])
    assert "call void @NRT_incref" not in ir_bare and "call void @NRT_decref" not in ir_bare
    assert "call void @NRT_incref" in ir_counted or "call void @NRT_decref" in ir_counted
