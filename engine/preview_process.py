"""preview.png drawn in a child process, so matplotlib's import and drawing overlap the job.

Drawing the README job's preview costs ~0.85 s on one core, ~0.5 s of it importing matplotlib, all at the
end of the job where nothing else runs beside it. :class:`PreviewWorker` starts a child Python process as
soon as a job is known to want a field; the child imports matplotlib and the drawing code while the parent
builds the mesh (a serial stage, so the second core is idle), then blocks on its stdin (no CPU) through
the trace. When the field is ready the parent hands it over (a pickle in the output's staging directory,
a path on the pipe), writes field.vti and report.json meanwhile, and waits for the child's answer.

The child is an accelerator, never a dependency: any failure of its own (it could not start, died, timed
out, answered nonsense) makes :func:`bentray.engine.writers.write_outcome` draw the preview in the parent
with the same function and arguments, so the file and any error about the data are the same either way
(``PreviewWorker.fallback_reason`` says why it was needed). The child writes only the file it was given,
atomically (``write_preview_png`` renames a finished temporary file into place).

Protocol (one request per child): stdin line ``<request.pkl path>\\n``; the pickle holds
``(png_path, args, kwargs)`` for :func:`bentray.engine.field_output.write_preview_png`; stdout line
``ok`` or ``error <ExceptionType>: <message>``; then the child exits.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["PREVIEW_TIMEOUT_S", "PreviewWorker", "PreviewRequest", "main"]

_CHILD_MODULE = "bentray.engine.preview_process"
PREVIEW_TIMEOUT_S = 120.0  # the child's whole life after a request; the parent then draws it itself

PreviewRequest = tuple[Path, tuple[Any, ...], dict[str, Any]]  # (png path, args, kwargs) of write_preview_png


class PreviewWorker:
    """A child process waiting to draw one preview.png; see the module docstring.

    ``start()`` never raises: a child that cannot be started leaves ``process`` None and every later call
    reports a fallback. ``submit`` sends the request; ``wait`` returns True when the child drew the file,
    False (with ``fallback_reason``) when the caller must draw it itself. ``close`` kills a child still
    running (a job that failed before its outputs): call it in a ``finally``.
    """

    def __init__(self, timeout_s: float = PREVIEW_TIMEOUT_S) -> None:
        self.process: subprocess.Popen[bytes] | None = None
        self.fallback_reason: str | None = None
        self.timeout_s = float(timeout_s)
        self._submitted_at: float | None = None

    @classmethod
    def start(cls, command: Sequence[str] | None = None, timeout_s: float = PREVIEW_TIMEOUT_S) -> PreviewWorker:
        """Start the child (``command``, default ``python -P -m bentray.engine.preview_process``: the
        parent's interpreter and environment, and ``-P`` so that a module in the working directory cannot
        shadow numpy or matplotlib); ``timeout_s``: how long ``wait`` waits after the request."""
        worker = cls(timeout_s)
        try:
            worker.process = subprocess.Popen(
                list(command) if command is not None else [sys.executable, "-P", "-m", _CHILD_MODULE],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                close_fds=True,
            )
        except OSError as exc:  # no fork, no executable: the parent draws
            worker.fallback_reason = f"the preview process did not start ({exc})"
        return worker

    def submit(self, request_path: Path, request: PreviewRequest) -> bool:
        """Pickle ``request`` to ``request_path`` and send its path; False when the child is not usable."""
        if self.process is None or self.process.stdin is None:
            self.fallback_reason = self.fallback_reason or "no preview process"
            return False
        if self.process.poll() is not None:
            self.fallback_reason = f"the preview process exited early (status {self.process.returncode})"
            return False
        try:
            with open(request_path, "wb") as fh:
                pickle.dump(request, fh, protocol=pickle.HIGHEST_PROTOCOL)
            self.process.stdin.write(os.fsencode(str(request_path)) + b"\n")
            self.process.stdin.close()  # one request: end of input
        except (OSError, pickle.PicklingError, ValueError) as exc:
            self.fallback_reason = f"the preview request could not be sent ({exc})"
            return False
        self._submitted_at = time.monotonic()
        return True

    def wait(self) -> bool:
        """The child's answer: True when it wrote the file; else False and ``fallback_reason``."""
        timeout_s = self.timeout_s
        proc = self.process
        if proc is None or self._submitted_at is None:
            self.fallback_reason = self.fallback_reason or "no preview request was sent"
            return False
        try:  # the answer is one short line: it fits the pipe's buffer, so waiting first cannot deadlock
            proc.wait(timeout=max(0.0, timeout_s - (time.monotonic() - self._submitted_at)))
        except subprocess.TimeoutExpired:
            self.close()
            self.fallback_reason = f"the preview process did not answer within {timeout_s:g} s"
            return False
        out = proc.stdout.read(4096) if proc.stdout is not None else b""
        answer = out.decode("utf-8", "replace").strip()
        if proc.returncode == 0 and answer == "ok":
            return True
        self.fallback_reason = f"the preview process failed (status {proc.returncode}): {answer[:300] or 'no answer'}"
        return False

    def close(self) -> None:
        """Kill the child if it still runs and reap it (idempotent)."""
        proc = self.process
        if proc is None:
            return
        if proc.poll() is None:
            proc.kill()
        for pipe in (proc.stdin, proc.stdout):
            if pipe is not None and not pipe.closed:
                try:
                    pipe.close()
                except OSError:  # a broken pipe to a killed child
                    pass
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:  # a kill that did not take within 5 s: leave it to the OS
            pass


def main() -> int:
    """The child: import the drawing code, then draw the one requested preview."""
    from matplotlib import figure  # noqa: F401
    from matplotlib.backends import backend_agg  # noqa: F401  (imported now, while the parent traces)

    from bentray.engine import preview_layout  # noqa: F401
    from bentray.engine.field_output import write_preview_png

    line = sys.stdin.buffer.readline()
    if not line.strip():
        return 0  # the parent closed the pipe without a request (the job failed or drew nothing)
    try:
        with open(os.fsdecode(line.strip()), "rb") as fh:
            png_path, args, kwargs = pickle.load(fh)
        write_preview_png(png_path, *args, **kwargs)
    except Exception as exc:  # reported to the parent, which draws again in-process and raises there
        message = " ".join(str(exc).split())[:1000]  # one short line: it must fit the pipe (see wait)
        sys.stdout.write(f"error {type(exc).__name__}: {message}\n")
        return 1
    sys.stdout.write("ok\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
