"""engine/bench/compile_profile.py: per-function compile times from Numba's compile events, LLVM's steps timed.

Oracle: two functions made here (a caller and its callee, no on-disk cache), compiled inside the profile:
both appear, the callee nested in the caller (depth 1 vs 0), each self time at most its inclusive time and the
caller's inclusive time covering the callee's; a second signature is listed as a repeat; LLVM's steps take
some but not all of the wall time; Numba's private methods are put back afterwards.
"""

from __future__ import annotations

from pathlib import Path

import numba
import pytest

from bentray.engine.bench.compile_profile import LLVM_STEPS, format_profile, main, profile_compilation


def _pair() -> tuple[object, object]:
    @numba.njit(cache=False)
    def callee(x):
        return x * 2.0 + 1.0

    @numba.njit(cache=False)
    def caller(x):
        return callee(x) - callee(x + 1.0)

    return caller, callee


def test_profile_nests_callees_and_times_llvm() -> None:
    from numba.core import codegen

    before = codegen.CPUCodeLibrary._optimize_final_module
    caller, callee = _pair()
    prof = profile_compilation(lambda: (caller(1.0), caller(2)))  # float64 and int64: two signatures each
    names = [f.name.rsplit(".", 1)[-1] for f in prof.functions]
    assert names.count("caller") == 2 and names.count("callee") == 2
    by = {(f.name.rsplit(".", 1)[-1], i): f for i, f in enumerate(prof.functions)}
    for f in prof.functions:
        assert 0.0 <= f.self_s <= f.inclusive_s + 1e-12
    callers = [f for (n, _), f in by.items() if n == "caller"]
    callees = [f for (n, _), f in by.items() if n == "callee"]
    assert all(f.depth == 0 for f in callers) and all(f.depth == 1 for f in callees)
    assert sum(f.inclusive_s for f in callers) >= sum(f.inclusive_s for f in callees)
    assert set(prof.llvm_s) == set(LLVM_STEPS)
    assert 0.0 < sum(prof.llvm_s.values()) < prof.wall_s
    assert codegen.CPUCodeLibrary._optimize_final_module is before  # Numba's method put back
    text = format_profile(prof, top=5)
    assert "4 compilations" in text and "more than one signature" in text and "caller" in text


def test_missing_job_is_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "none.json")]) == 2
    assert "no such file" in capsys.readouterr().err
