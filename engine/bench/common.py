"""Shared pieces of ``bentray bench``: section and table containers, warm best-of-N timing, machine facts.

A bench section (one module each: convergence, error_vs_time, same_quality, breakdown, scaling,
throughput, extreme) returns a :class:`Section`: markdown text, :class:`Table` objects (written as CSV
and shown in report.md) and :class:`Plot` specs (drawn by report.py with matplotlib's Agg canvas).
Timings are wall-clock seconds of warm runs (Numba compiled first), the best of ``repeats``.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import functools
import math
import os
import platform
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "Table",
    "Plot",
    "Series",
    "Section",
    "best_time",
    "machine_info",
    "fan",
    "sphere_directions",
    "status_text",
    "fmt",
    "numba_threads",
    "on_timing_threads",
    "TIMING_THREADS",
]

# Comparative timings (every section but throughput) run on this many numba threads. On a machine whose other
# cores are busy, a second thread waits for a scheduler tick at every parallel launch: measured here,
# a 0.4 ms trace took 8 ms on 2 threads while other processes ran, and 0.4 ms on 1. One thread gives
# per-core costs that compare methods fairly; throughput.py measures the multi-thread rate separately.
TIMING_THREADS = 1


@dataclass
class Table:
    """A table: ``name`` (CSV file stem), ``columns`` (ordered keys) and ``rows`` (dicts of those keys)."""

    name: str
    title: str
    columns: list[str]
    rows: list[dict[str, Any]] = field(default_factory=list)

    def add(self, **row: Any) -> None:
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"table {self.name}: unknown columns {sorted(unknown)}")
        self.rows.append({c: row.get(c, "") for c in self.columns})


@dataclass
class Series:
    """One line of a plot: x and y values (same length), a label and an optional matplotlib marker."""

    label: str
    x: Sequence[float]
    y: Sequence[float]
    marker: str = "o"
    linestyle: str = "-"


@dataclass
class Plot:
    """A plot (PNG file ``name``.png): one or more panels, each a list of series on log or linear axes."""

    name: str
    title: str
    panels: list[dict[str, Any]]  # {"title", "xlabel", "ylabel", "xlog", "ylog", "series": [Series], "hline"}


@dataclass
class Section:
    """What one bench section produced: markdown ``text`` (paragraphs), tables, plots, and its wall time."""

    key: str
    title: str
    text: list[str] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    plots: list[Plot] = field(default_factory=list)
    wall_s: float = 0.0
    status: str = "ran"


@contextlib.contextmanager
def numba_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` numba threads (at most the available ones); the count is restored after."""
    import numba

    before = numba.get_num_threads()
    limit = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import
    numba.set_num_threads(max(1, min(int(n), limit)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def on_timing_threads(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Decorator: run ``fn`` with TIMING_THREADS numba threads (see the constant)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with numba_threads(TIMING_THREADS):
            return fn(*args, **kwargs)

    return wrapper


def best_time(
    fn: Callable[[], Any], repeats: int, min_total_s: float = 0.0, max_repeats: int = 50
) -> tuple[float, Any]:
    """(best wall time in s, the last call's result) over at least ``repeats`` calls, continuing (up to
    ``max_repeats``) until the calls add up to ``min_total_s``: short runs get more tries, so a scheduler
    hiccup on a shared machine does not become the measurement. Call ``fn`` once before to warm it."""
    best = math.inf
    out = None
    total = 0.0
    done = 0
    while done < max(1, repeats) or (total < min_total_s and done < max_repeats):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        best = min(best, dt)
        total += dt
        done += 1
    return best, out


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict[str, Any]:
    """CPU model (/proc/cpuinfo), cores, numba threads, numpy / numba / scipy versions, Python, date (UTC)."""
    import numba
    import scipy

    import bentray

    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "numba_threads": int(numba.get_num_threads()),
        "bentray": bentray.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "scipy": scipy.__version__,
        "date_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M"),
    }


def fan(source: Sequence[float], elevations_deg: np.ndarray, azimuth_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Origins (n, 3) m and unit directions (n, 3) of a vertical fan from one source (world frame)."""
    el = np.radians(np.asarray(elevations_deg, float))
    az = math.radians(azimuth_deg)
    d = np.column_stack([np.cos(el) * math.cos(az), np.cos(el) * math.sin(az), np.sin(el)])
    return np.tile(np.asarray(source, float), (len(el), 1)), d


def sphere_directions(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere (Fibonacci lattice; deterministic)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def status_text(counts: dict[str, int]) -> str:
    """Non-zero status counts as ``time_limit 91, exited 2`` (``none`` when empty)."""
    parts = [f"{k} {v}" for k, v in counts.items() if v]
    return ", ".join(parts) or "none"


def fmt(value: Any) -> str:
    """Compact text for a table cell: floats in 3 significant digits, everything else as str."""
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, int | np.integer):
        return f"{int(value):,}"
    if isinstance(value, float | np.floating):
        v = float(value)
        if math.isnan(v):
            return "-"
        if v == 0.0:
            return "0"
        if abs(v) >= 1e4 or abs(v) < 1e-2:
            return f"{v:.2e}"
        return f"{v:.3g}"
    return str(value)
