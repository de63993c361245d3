"""Progress of ``bentray run`` on a terminal: the stage name and a bar of the rays traced (rich).

The engine reports ``progress(stage, fraction)`` (engine/run.py: profile, scene, mesh, trace after each
ray batch, field, eigenrays, done). :class:`RunProgress` maps that onto one ``rich.progress`` task:

    bentray: trace   ━━━━━━━━━━━━━━━━━━━━━━━━━━━╸━━━━━━━━━━━━   46%  12288/26624 rays  0:00:03

It draws only when its stream is a terminal (rich's ``Console.is_terminal``): piped or redirected output
(CI logs, files, the service) gets no progress at all, only the summary. While Numba compiles (a first run
after an install or an engine change: the trace's kernels take most of a minute), the line says so, so a bar
standing at 0 % is not mistaken for a hang.
"""

from __future__ import annotations

import sys
from typing import TextIO

from numba.core import event
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn

__all__ = ["RunProgress"]

# The engine's trace stage spans fractions 0.1 .. 0.9 of the job (engine/stages.py: stage_trace).
_TRACE_START, _TRACE_SPAN = 0.1, 0.8
COMPILING_NOTE = "compiling (once per install)"


class _CompileNotice(event.Listener):
    """Shows :data:`COMPILING_NOTE` on the progress line while an outermost ``numba:compile`` event is open
    (callees compile inside their caller's event; events come from whichever thread compiles)."""

    def __init__(self, owner: RunProgress) -> None:
        self._owner = owner
        self._depth = 0

    def on_start(self, ev: event.Event) -> None:
        self._depth += 1
        if self._depth == 1:
            self._owner._note(COMPILING_NOTE)

    def on_end(self, ev: event.Event) -> None:
        self._depth -= 1
        if self._depth == 0:
            self._owner._note("")


class RunProgress:
    """Callable ``(stage, fraction)`` for :func:`bentray.engine.run.run_job`; ``n_rays`` of the job."""

    def __init__(self, n_rays: int, stream: TextIO | None = None) -> None:
        console = Console(file=stream if stream is not None else sys.stdout, highlight=False)
        self.enabled = console.is_terminal
        self.n_rays = max(int(n_rays), 1)
        self._progress = Progress(
            TextColumn("bentray: {task.fields[stage]:<9}"),
            BarColumn(),
            TaskProgressColumn(),
            MofNCompleteColumn(),
            TextColumn("rays"),
            TimeElapsedColumn(),
            TextColumn("{task.fields[note]}"),
            console=console,
            disable=not self.enabled,
            auto_refresh=False,
        )
        self._task = self._progress.add_task("run", total=self.n_rays, stage="start", note="")
        self._started = False
        self._notice: _CompileNotice | None = None
        if self.enabled:
            self._notice = _CompileNotice(self)
            event.register("numba:compile", self._notice)  # type: ignore[no-untyped-call]

    def _note(self, text: str) -> None:
        """Set the line's trailing note (drawn at once: the line is not refreshed during a compilation)."""
        if not self._started:
            self._progress.start()
            self._started = True
        self._progress.update(self._task, note=text)
        self._progress.refresh()

    def rays_done(self, stage: str, fraction: float) -> int:
        """Rays traced so far by the job's fraction (the trace stage spans 0.1 .. 0.9; 0 before it)."""
        if stage == "done":
            return self.n_rays
        part = min(max((fraction - _TRACE_START) / _TRACE_SPAN, 0.0), 1.0)
        return round(part * self.n_rays)

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        if not self._started:
            self._progress.start()
            self._started = True
        self._progress.update(self._task, completed=self.rays_done(stage, fraction), stage=stage)
        self._progress.refresh()

    def close(self) -> None:
        """Stop the live display (a final line), so the summary starts on its own line."""
        if self._notice is not None:
            event.unregister("numba:compile", self._notice)  # type: ignore[no-untyped-call]
            self._notice = None
        if self._started:
            self._progress.stop()
            self._started = False
