"""``bentray bench``: run the bench sections and write report.md, CSVs and PNGs into a folder.

Sections (``only`` picks a subset, in this order): convergence (Fig. 3), error_vs_time (Fig. 4/5),
same_quality (Table 2), breakdown (Table 3), scaling (Fig. 8), throughput, extreme (stiff cases).
``quick`` runs every section on fewer rays, settings and repeats (a smoke run of a couple of minutes);
the full run reproduces the tables at the sizes the module docstrings give. A section that raises is
recorded as "failed: <error>" in the report (the others still run) and listed in the return value's
``failed``; built-in scene rows whose terrain mesh cannot be built say "skipped: <reason>".
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bentray.engine.bench.common import Section, machine_info

__all__ = ["SECTIONS", "run_bench", "run_bench_sections", "BenchOutcome"]


def _convergence(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import convergence

    return convergence.run(quick)


def _error_vs_time(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import error_vs_time

    return error_vs_time.run(quick)


def _same_quality(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import same_quality

    return same_quality.run(quick)


def _breakdown(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import breakdown

    return breakdown.run(quick, scene_cache=cache)


def _scaling(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import scaling

    return scaling.run(quick)


def _throughput(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import throughput

    return throughput.run(quick, scene_cache=cache)


def _table1(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import table1

    return table1.run(quick)


def _extreme(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import extreme

    return extreme.run(quick)


def _field_error(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import field_error

    return field_error.run(quick)


def _linked_surfaces(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import linked_surfaces

    return linked_surfaces.run(quick)


def _gpu(quick: bool, cache: dict[str, Any]) -> Section:
    from bentray.engine.bench import gpu  # skipped (status 0) without a CUDA device

    return gpu.run(quick, scene_cache=cache)


# name -> (title, runner(quick, shared scene-mesh cache) -> Section)
SECTIONS: dict[str, tuple[str, Callable[[bool, dict[str, Any]], Section]]] = {
    "convergence": ("Convergence of the three curves (Fig. 3)", _convergence),
    "error_vs_time": ("Error against run time (Fig. 4/5)", _error_vs_time),
    "same_quality": ("Same-quality comparison (Table 2)", _same_quality),
    "breakdown": ("Time breakdown (Table 3)", _breakdown),
    "scaling": ("Scaling (Fig. 8)", _scaling),
    "throughput": ("Throughput", _throughput),
    "extreme": ("Stiff and extreme cases", _extreme),
    "table1": ("Built-in scenes end to end (Table 1)", _table1),
    "field_error": ("Field error against run time", _field_error),
    "linked_surfaces": ("Appendix C: embedded vs linked surfaces", _linked_surfaces),
    "gpu": ("CUDA traversal against the CPU kernels", _gpu),
}


@dataclass
class BenchOutcome:
    """The report path, the sections run and the names of those that failed."""

    report: Path
    sections: list[Section] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)


def run_bench_sections(
    out_dir: Path | str, quick: bool, only: Sequence[str] | None = None, progress: Callable[[str], None] | None = None
) -> BenchOutcome:
    """Run the bench (see module docstring) into ``out_dir``; ``progress`` receives one line per section."""
    names = list(SECTIONS) if not only else list(dict.fromkeys(only))
    unknown = [n for n in names if n not in SECTIONS]
    if unknown:
        raise ValueError(f"unknown bench section(s) {unknown}; expected some of {list(SECTIONS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    machine = machine_info()
    cache: dict[str, Any] = {}
    sections: list[Section] = []
    failed: list[str] = []
    t_start = time.perf_counter()
    for name in [n for n in SECTIONS if n in names]:
        title, fn = SECTIONS[name]
        t0 = time.perf_counter()
        try:
            sec = fn(quick, cache)
        except Exception as exc:  # noqa: BLE001 - one broken section must not lose the others' results
            sec = Section(name, title, status=f"failed: {type(exc).__name__}: {exc}")
            sec.text.append("```\n" + traceback.format_exc(limit=8) + "```")
            failed.append(name)
        sec.wall_s = time.perf_counter() - t0
        sections.append(sec)
        if progress is not None:
            progress(f"{name}: {sec.status} ({sec.wall_s:.1f} s)")
    from bentray.engine.bench.report import write_report

    command = (
        "bentray bench --out "
        + str(out)
        + (" --quick" if quick else "")
        + (" --only " + " ".join(names) if only else "")
    )
    report = write_report(out, sections, machine, quick=quick, command=command, wall_s=time.perf_counter() - t_start)
    return BenchOutcome(report=report, sections=sections, failed=failed)


def run_bench(out_dir: Path | str, quick: bool, only: list[str] | None = None) -> Path:
    """Run the bench into ``out_dir`` (created) and return the path of its ``report.md``."""
    return run_bench_sections(out_dir, quick, only).report
