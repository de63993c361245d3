"""engine/kernels/llvm_inline.py: njit_inline functions are inlined by LLVM, not by Numba, with the same results.

Oracles: the library's module for linking (what callers link in) carries ``alwaysinline`` on an njit_inline
function and not on a plain njit twin compiled from the same source; a caller's optimised LLVM has no call
left to it; results equal the plain function's bit for bit. The engine-level check (the README job's
final ray states and beam field identical to Numba-IR inlining) is in docs/physics.md §9.
"""

from __future__ import annotations

import re
from typing import Any

import numba as nb
import numpy as np

from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels import llvm_inline, parabolic
from bentray.engine.kernels.llvm_inline import mangled_prefix, njit_inline


def _inlined_body(x, a):
    s = 0.0
    for i in range(x.shape[0]):
        v = x[i] * a + 1.0
        s += v * v / (1.0 + v) + np.sqrt(abs(v)) - np.log1p(abs(v)) + np.exp(-v * v) * np.cos(v)
    return s


def _plain_body(x, a):  # the same body under another name (so another symbol)
    s = 0.0
    for i in range(x.shape[0]):
        v = x[i] * a + 1.0
        s += v * v / (1.0 + v) + np.sqrt(abs(v)) - np.log1p(abs(v)) + np.exp(-v * v) * np.cos(v)
    return s


_inlined = njit_inline(_inlined_body)
_plain = nb.njit(**{**NJIT_FLAGS, "cache": False})(_plain_body)  # njit_inline's flags


@nb.njit(cache=False)
def _calls_inlined(x):
    return _inlined(x, 2.0) + _inlined(x, 3.0) + _inlined(x, 5.0)


@nb.njit(cache=False)
def _calls_plain(x):
    return _plain(x, 2.0) + _plain(x, 3.0) + _plain(x, 5.0)


def _attributes(dispatcher: Any, prefix: str) -> list[bytes]:
    library = dispatcher.overloads[dispatcher.signatures[0]].library
    module = library._get_module_for_linking()
    return [b" ".join(fn.attributes) for fn in module.functions if fn.name.startswith(prefix)]


def test_the_hook_is_active_on_this_numba() -> None:
    assert llvm_inline.ACTIVE


def test_inlined_definition_is_marked_alwaysinline_and_the_plain_twin_is_not() -> None:
    x = np.linspace(0.0, 1.0, 7)
    assert _calls_inlined(x) == _calls_plain(x)  # same arithmetic, bit for bit
    inl = _attributes(_inlined, mangled_prefix(_inlined.py_func))
    plain = _attributes(_plain, mangled_prefix(_plain.py_func))
    assert len(inl) == 1 and len(plain) == 1
    assert b"alwaysinline" in inl[0]
    assert b"alwaysinline" not in plain[0]


def test_a_caller_keeps_no_call_to_an_inlined_function() -> None:
    x = np.linspace(0.0, 1.0, 7)
    _calls_inlined(x)
    llvm = _calls_inlined.inspect_llvm(_calls_inlined.signatures[0])
    assert not re.search(r"call [^\n]*@\"?" + re.escape(mangled_prefix(_inlined.py_func)), llvm)
    assert "log1p" in llvm  # the body is there instead


def test_prefixes_do_not_overlap_between_kernels() -> None:
    """Each later name part is length-prefixed: _speed's prefix is no prefix of _speed_up's (wind.py)."""
    a = mangled_prefix(parabolic.arc_length.py_func)
    b = mangled_prefix(parabolic.arc_length_closed.py_func)
    assert not b.startswith(a) and not a.startswith(b)
    assert a.endswith("10arc_length")


def test_the_traversal_keeps_no_call_to_an_inlined_kernel() -> None:
    """The README job's kernel (a 5 x 5 fan of it: beams, wind, terrain) as callers link it: every njit_inline
    function it uses is inlined, none is left as a call or a definition (the module's IR as the cache keeps it)."""
    import json
    from pathlib import Path

    from bentray.engine.kernels import traverse
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    job_file = Path(__file__).resolve().parents[2] / "scenes" / "examples" / "ridge-wind-map.json"
    spec = json.loads(job_file.read_text())
    spec["rays"]["elevation_deg"]["count"] = 5
    spec["rays"]["azimuth_deg"]["count"] = 5
    spec["outputs"] = ["field", "report"]
    run_job(Job.model_validate(spec), job_file.parent)
    prefixes = tuple(llvm_inline._PREFIXES)
    assert len(prefixes) > 50  # the engine's small kernels are registered
    assert traverse.trace_slots.overloads
    for overload in traverse.trace_slots.overloads.values():
        module = overload.library._get_module_for_linking()
        text = str(module)
        called = {m.group(1) for m in re.finditer(r"call [^\n]*?@\"?(_ZN[\w.$]+)", text)}
        assert called  # the kernel does call plain njit functions (the test sees calls)
        assert not [name for name in called if name.startswith(prefixes)]
        assert not [f.name for f in module.functions if not f.is_declaration and f.name.startswith(prefixes)]
