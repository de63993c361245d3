"""`bentray run` progress: a stage line and a ray bar on a terminal, nothing when stdout is not one."""

from __future__ import annotations

import io
from pathlib import Path

from bentray.clients.cli import main
from bentray.clients.progress import RunProgress

EXAMPLE = Path(__file__).resolve().parents[2] / "scenes" / "examples" / "a-ld-fan.json"


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_terminal_gets_stages_and_a_ray_bar():
    out = _Tty()
    p = RunProgress(1000, stream=out)
    assert p.enabled
    seen = []
    for stage, f in [("profile", 0.0), ("mesh", 0.05), ("trace", 0.1), ("trace", 0.5), ("trace", 0.9), ("done", 1.0)]:
        p(stage, f)
        seen.append(p.rays_done(stage, f))
    p.close()
    text = out.getvalue()
    assert seen == [0, 0, 0, 500, 1000, 1000]
    assert "bentray: mesh" in text and "bentray: trace" in text
    assert "500/1000" in text and "1000/1000" in text and "rays" in text


def test_terminal_says_when_numba_compiles():
    import numba

    from bentray.clients.progress import COMPILING_NOTE

    out = _Tty()
    p = RunProgress(10, stream=out)
    p("trace", 0.1)
    numba.njit(cache=False)(lambda x: x + 1)(1)  # a fresh compilation while the line is up
    p.close()
    assert COMPILING_NOTE in out.getvalue()
    after = out.getvalue()
    numba.njit(cache=False)(lambda x: x + 2)(1)  # closed: the listener is gone, nothing is drawn
    assert out.getvalue() == after


def test_pipe_gets_no_progress(tmp_path, capsys):
    quiet = io.StringIO()  # not a terminal
    p = RunProgress(1000, stream=quiet)
    p("trace", 0.5)
    p.close()
    assert quiet.getvalue() == ""
    assert main(["run", str(EXAMPLE), "--out", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    for text in (captured.out, captured.err):
        assert "\r" not in text and "bentray: trace" not in text and "\x1b[" not in text
    assert "wrote" in captured.out  # the summary is still there
