"""`bentray bench`: a tiny subset runs into a folder, writes report.md, parseable CSVs and PNGs.

No timing assertions (timings are the bench's output, not something a unit test can pin). Also checked:
the speed-up / stall bookkeeping on hand-made rows, the breakdown's recording walk against the real
tracer's step counts, and that a failing section is reported without losing the others.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.clients.cli import main
from bentray.engine.bench import breakdown, convergence, error_vs_time, runner, same_quality
from bentray.engine.bench.common import Section, Table

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _read_csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


def test_cli_quick_subset_writes_report_csvs_and_pngs(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "--out", str(out), "--quick", "--only", "convergence", "same_quality"]) == 0
    assert "report.md" in capsys.readouterr().out
    report = (out / "report.md").read_text(encoding="utf-8")
    for text in (
        "# bentray bench (quick)",
        "| cpu |",
        "| numba_threads |",
        "Convergence of the three curves",
        "Same-quality comparison",
        "fig3_convergence.png",
    ):
        assert text in report
    assert "Error against run time" not in report  # not selected
    assert "Table 2: cost at the same quality" in (out / "summary.md").read_text(encoding="utf-8")
    for name, columns in (
        ("fig3_convergence", convergence.COLUMNS),
        ("table2_same_quality", same_quality.COLUMNS),
        ("table2_search", same_quality.SEARCH_COLUMNS),
    ):
        header, rows = _read_csv(out / f"{name}.csv")
        assert header == columns
        assert rows
    _, rows = _read_csv(out / "fig3_convergence.csv")
    assert len(rows) == 3 * 3 * 3  # profiles x curves x epsilons
    for r in rows:
        assert float(r["position_error_max"]) >= 0.0 and float(r["trace_time_s"]) > 0.0
        assert int(r["layers"]) > 0 and int(r["lost"]) == 0
    # the curve matching its profile is exact at every epsilon; the others are not
    exact = {"c-linear": "circular", "n-linear": "n_linear", "n2-linear": "parabolic"}
    for r in rows:
        if exact[r["profile"]] == r["curve"]:
            assert float(r["position_error_max"]) < 1e-12
        else:
            assert float(r["position_error_max"]) > 1e-9
    _, rows = _read_csv(out / "table2_same_quality.csv")
    assert {r["config"] for r in rows} == set(same_quality.QUICK_CONFIGS)
    for png in ("fig3_convergence.png", "table2_same_quality.png"):
        assert (out / png).read_bytes()[:8] == PNG_MAGIC


def test_cli_rejects_unknown_sections(tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--out", str(tmp_path), "--only", "nonsense"])
    assert exc.value.code == 2


def test_a_failing_section_is_reported_and_the_others_kept(tmp_path, monkeypatch):
    def boom(quick, cache):
        raise RuntimeError("deliberate")

    def tiny(quick, cache):
        sec = Section("tiny", "Tiny")
        t = Table("tiny_table", "Tiny table", ["a", "b"])
        t.add(a=1, b=float("nan"))
        sec.tables.append(t)
        return sec

    monkeypatch.setitem(runner.SECTIONS, "convergence", ("Convergence", boom))
    monkeypatch.setitem(runner.SECTIONS, "extreme", ("Tiny", tiny))
    outcome = runner.run_bench_sections(tmp_path, quick=True, only=["convergence", "extreme"])
    assert outcome.failed == ["convergence"]
    text = outcome.report.read_text(encoding="utf-8")
    assert "failed: RuntimeError: deliberate" in text and "Tiny table" in text
    header, rows = _read_csv(tmp_path / "tiny_table.csv")
    assert header == ["a", "b"] and rows == [{"a": "1", "b": "nan"}]


def _row(case, method, media, setting, err, t, rejected=0.0):
    return {
        "case": case,
        "method": method,
        "media": media,
        "setting": f"s={setting:g}",
        "tolerance": setting,
        "error_max": err,
        "trace_time_s": t,
        "status": {"lost": 0},
        "rejected_per_ray": rejected,
    }


def test_speedups_and_stalls_bookkeeping():
    rows = [
        _row("A-LD", "analytic", "mesh", 1e-5, 2e-4, 0.001),
        _row("A-LD", "analytic", "mesh", 1e-6, 5e-5, 0.002),
        _row("A-LD", "analytic", "mesh", 1e-8, 5e-8, 0.010),
        _row("A-LD", "dopri5", "exact", 1e-4, 8e-5, 0.004),
        _row("A-LD", "dopri5", "exact", 1e-8, 1e-8, 0.009),
        _row("A-LD", "dopri5", "mesh", 1e-6, 3e-5, 0.030),
        _row("A-LD", "dopri5", "mesh", 1e-8, 9e-5, 0.200, 700.0),
        _row("A-LD", "rk4", "mesh", 4.0, 1e-3, 0.05),
        _row("A-LD", "rk4", "mesh", 1.0, 5e-4, 0.2),  # 2x for 256x
        _row("A-LD", "rk4", "exact", 4.0, 1e-3, 0.05),
        _row("A-LD", "rk4", "exact", 1.0, 1e-5, 0.2),  # 100x: fine
        _row("A-LD", "euler", "exact", 4.0, 1e-9, 0.05),
        _row("A-LD", "euler", "exact", 1.0, 1e-9, 0.2),  # at ref
    ]
    sp = {e["target"]: e for e in error_vs_time.speedups(rows, targets=(1e-4, 1e-7))}
    assert sp[1e-4]["analytic_setting"] == "s=1e-06" and sp[1e-4]["best_exact"] == "dopri5 s=0.0001"
    assert sp[1e-4]["speedup_vs_exact"] == pytest.approx(2.0) and sp[1e-4]["speedup_vs_mesh"] == pytest.approx(15.0)
    assert sp[1e-7]["best_mesh"] == "not reached" and math.isnan(sp[1e-7]["speedup_vs_mesh"])
    assert sp[1e-7]["speedup_vs_exact"] == pytest.approx(0.9)
    st = {e["family"]: e for e in error_vs_time.stalls(rows)}
    assert st["dopri5 (mesh)"]["stalls"] and st["dopri5 (mesh)"]["best_error"] == 3e-5
    assert st["rk4 (mesh)"]["stalls"] and st["rk4 (mesh)"]["expected_gain"] == pytest.approx(256.0)
    assert not st["rk4 (exact)"]["stalls"] and not st["euler (exact)"]["stalls"]
    assert not st["dopri5 (exact)"]["stalls"] and not st["analytic (mesh)"]["stalls"]


def test_breakdown_recording_walk_matches_the_tracer():
    """The recording walk behind Table 3 takes exactly as many steps as the real tracer (one entry per
    segment on a slab mesh without nudges), and every recorded entry point lies in its cell."""
    from bentray.engine.bench.baselines_probe import CASES
    from bentray.engine.media import build_media
    from bentray.engine.tracer import trace
    from bentray.scenes.schema import Solver

    case = CASES["A-LD"]
    med = build_media(
        case.profile(), "parabolic", Solver(delta=1e-6), np.array(case.domain_min), np.array(case.domain_max)
    )
    o, d = case.fan(9)
    cells = med.locate(o)
    res = trace(med.mesh, "parabolic", 340.0, o, d, cells, max_time_s=10.0, max_reflections=50)
    ent = breakdown.record_entries(
        med.mesh, "parabolic", 340.0, o, d, cells, max_time_s=10.0, max_reflections=50, cap=int(res.steps.max()) + 2
    )
    assert len(ent[0]) == int(res.steps.sum())
    planes = med.mesh.planes[ent[0]]  # (E, K, 4)
    violation = np.einsum("ekj,ej->ek", planes[:, :, :3], ent[2]) - planes[:, :, 3]
    assert np.all(violation.max(axis=1) <= 1e-9 * med.mesh.size[ent[0]])
    assert np.allclose(np.linalg.norm(ent[3], axis=1), 1.0, atol=1e-12)
    p = breakdown.phase_times(
        med.mesh, "parabolic", 340.0, o, d, cells, max_time_s=10.0, max_reflections=50, repeats=1, min_total_s=0.0
    )
    assert p["recorded_entries"] == p["segments"] == int(res.steps.sum())
    assert all(math.isfinite(p[k]) for k in ("total_s", "setup_s", "face_intersections_s", "advance_s"))
