"""`bentray run` end to end on the README example (the job issue 2 requires to run as written)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.clients.cli import main

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "scenes" / "examples" / "a-ld-fan.json"
COLUMNS = "ray,source,elevation_deg,azimuth_deg,x,y,z,dx,dy,dz,time_s,length_m,reflections,status".split(",")


def test_example_job_runs_as_written(tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(EXAMPLE), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["mesh.vtu", "rays.csv", "rays.vtp", "report.json"]
    with open(out / "rays.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0].keys()) == COLUMNS
    assert len(rows) == 91
    assert {r["status"] for r in rows} == {"time_limit"}
    assert all(float(r["time_s"]) == 10.0 for r in rows)
    report = json.loads((out / "report.json").read_text())
    assert report["representation"] == "slabs"
    assert report["rays"]["by_status"]["time_limit"] == 91
    assert report["rays"]["by_status"]["lost"] == 0
    assert report["mesh"]["sizing_rule"] == "gradient"  # the example gives epsilon
    assert report["stages"]["field"].startswith("skipped")
    for key in ("profile", "mesh", "locate", "trace"):
        assert report["timings_s"][key] >= 0.0

    import pyvista as pv

    rays = pv.read(out / "rays.vtp")
    assert rays.n_cells == 91
    # samples lie on the curves: time and arc length increase along every ray
    t = np.asarray(rays.point_data["time_s"])
    s = np.asarray(rays.point_data["length_m"])
    offsets = rays.lines
    i = 0
    while i < len(offsets):
        n = offsets[i]
        ids = offsets[i + 1 : i + 1 + n]
        assert np.all(np.diff(t[ids]) > 0) and np.all(np.diff(s[ids]) > 0)
        i += n + 1
    mesh = pv.read(out / "mesh.vtu")
    assert mesh.n_cells == report["mesh"]["cells"]


def test_console_script_reports_schema_errors_with_field(tmp_path):
    bad = json.loads(EXAMPLE.read_text())
    bad["rays"]["elevation_deg"]["count"] = 0
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    proc = subprocess.run(
        [sys.executable, "-m", "bentray.clients.cli", "run", str(path), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert "rays.elevation_deg.count" in proc.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("profile", "representation"),
    [
        ({"kind": "homogeneous"}, "uniform"),
        ({"kind": "linear_c"}, "slabs"),
        ({"kind": "table", "z": [0, 10, 100, 1000], "temperature_c": [20, 18, 15, 10]}, "slabs"),
    ],
)
def test_only_what_the_scene_needs(tmp_path, profile, representation):
    job = json.loads(EXAMPLE.read_text())
    job["profile"] = profile
    job["solver"] = {}
    job["outputs"] = ["report"]
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    assert main(["run", str(path), "--out", str(tmp_path / "o")]) == 0
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["representation"] == representation
    assert report["stages"]["paths"].startswith("skipped")
    assert report["stages"]["mesh_output"].startswith("skipped")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["report.json"]
    if representation == "uniform":
        assert report["mesh"]["cells"] == 1


def test_profile_linear_in_the_traced_quantity_needs_one_slab(tmp_path):
    job = json.loads(EXAMPLE.read_text())
    job["profile"] = {"kind": "linear_c"}
    job["solver"] = {"curve": "circular"}
    job["outputs"] = ["report"]
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    assert main(["run", str(path), "--out", str(tmp_path / "o")]) == 0
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["representation"] == "slabs" and report["mesh"]["cells"] == 1


def test_a_run_without_receivers_imports_neither_the_eigenray_search_nor_the_bench(tmp_path):
    """Lazy imports (startup time of ``bentray run``): the eigenray search loads only for a job with
    receivers, the bench only for ``bentray bench``. Checked in a fresh interpreter after a real run."""
    job = json.loads(EXAMPLE.read_text())
    job["outputs"] = ["report"]
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    watched = [
        "bentray.engine.eigenrays",
        "bentray.engine.bench.runner",
        "bentray.engine.stages",
        "bentray.engine.tracer",
    ]
    code = (
        "import sys\n"
        "from bentray.clients.cli import main\n"
        f"rc = main(['run', {str(path)!r}, '--out', {str(tmp_path / 'o')!r}])\n"
        f"print('LOADED', rc, *[m for m in {watched!r} if m in sys.modules])\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    loaded = [line for line in proc.stdout.splitlines() if line.startswith("LOADED ")]
    # only the run's own modules: stages and tracer show that the check sees what the run loaded
    assert loaded == ["LOADED 0 bentray.engine.stages bentray.engine.tracer"], proc.stdout
    assert json.loads((tmp_path / "o" / "report.json").read_text())["stages"]["eigenrays"].startswith("skipped")
