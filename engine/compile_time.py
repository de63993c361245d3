"""Numba compilation time, measured (not guessed) with numba's own compile events.

Every real compilation of a dispatcher (a cache miss: machine code built, not loaded from the on-disk
cache) runs inside a ``numba:compile`` event (numba.core.event). :func:`compile_timer` listens to those
events for the duration of a ``with`` block and adds up the wall time of the outermost ones (a kernel's
callees compile inside their caller's event; they are counted as functions, not twice as time). Loading
already-compiled code from the cache raises no such event: a warm run reports 0.

Compilation in other processes (Dask workers, validation helpers) is not seen here. Events are global to
the process, so a compile on another thread during the block is counted too.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from numba.core import event

__all__ = ["CompileTime", "compile_timer"]


@dataclass
class CompileTime:
    """seconds : wall time inside outermost compile events (s); functions : dispatcher compilations
    (every signature compiled, callees included)."""

    seconds: float = 0.0
    functions: int = 0


class _CompileListener(event.Listener):
    """Adds the outermost ``numba:compile`` spans and counts every one into a CompileTime."""

    def __init__(self, into: CompileTime) -> None:
        self._into = into
        self._depth = 0
        self._t0 = 0.0
        self._lock = threading.Lock()

    def on_start(self, ev: event.Event) -> None:
        with self._lock:
            if self._depth == 0:
                self._t0 = time.perf_counter()
            self._depth += 1
            self._into.functions += 1

    def on_end(self, ev: event.Event) -> None:
        with self._lock:
            self._depth -= 1
            if self._depth == 0:
                self._into.seconds += time.perf_counter() - self._t0


@contextmanager
def compile_timer() -> Iterator[CompileTime]:
    """Measure the Numba compilation inside the ``with`` block: yields a CompileTime filled as it runs."""
    into = CompileTime()
    with event.install_listener("numba:compile", _CompileListener(into)):
        yield into
