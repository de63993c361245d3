"""Progress of ``bentray run`` on a terminal: the stage names and a bar of the rays traced.

The engine reports ``progress(stage, fraction)`` (engine/run.py: profile, scene, mesh, trace after each
ray batch, field, done). :class:`RunProgress` draws one line, rewritten in place with a carriage return:

    bentray: trace  [##############----------------]  46%  12,288 / 26,624 rays  3.1 s

It draws only when its stream is a terminal (``isatty``): piped or redirected output (CI logs, files,
the service) gets no progress line at all, only the summary. Standard library only (no rich or tqdm:
neither is a bentray dependency, and one rewritten line needs neither).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["RunProgress"]

# The engine's trace stage spans fractions 0.1 .. 0.9 of the job (engine/stages.py: stage_trace).
_TRACE_START, _TRACE_SPAN = 0.1, 0.8


class RunProgress:
    """Callable ``(stage, fraction)`` for :func:`bentray.engine.run.run_job`; ``n_rays`` of the job."""

    def __init__(self, n_rays: int, stream: TextIO | None = None, width: int = 30) -> None:
        self.stream = stream if stream is not None else sys.stdout
        isatty = getattr(self.stream, "isatty", None)
        self.enabled = bool(isatty()) if callable(isatty) else False
        self.n_rays, self.width = int(n_rays), int(width)
        self.t0 = time.perf_counter()
        self._last = ""

    def line(self, stage: str, fraction: float) -> str:
        """The progress line for a stage (a ray bar in the trace stage)."""
        seconds = time.perf_counter() - self.t0
        if stage != "trace":
            return f"bentray: {stage:<7} {100 * fraction:3.0f}%  {seconds:.1f} s"
        part = min(max((fraction - _TRACE_START) / _TRACE_SPAN, 0.0), 1.0)
        filled = round(part * self.width)
        bar = "#" * filled + "-" * (self.width - filled)
        rays = round(part * self.n_rays)
        return f"bentray: trace   [{bar}] {100 * part:3.0f}%  {rays:,} / {self.n_rays:,} rays  {seconds:.1f} s"

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        text = self.line(stage, fraction)
        pad = " " * max(len(self._last) - len(text), 0)
        self.stream.write("\r" + text + pad)
        self.stream.flush()
        self._last = text

    def close(self) -> None:
        """End the progress line (a newline), so the summary starts on its own line."""
        if self.enabled and self._last:
            self.stream.write("\n")
            self.stream.flush()
            self._last = ""
