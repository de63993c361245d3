"""Every example job in scenes/examples validates, and the README's first command runs (scaled down).

The README's first command traces scenes/examples/ridge-wind-map.json (43,681 rays, about 40 s); here the
same job runs with a coarser fan and grid through the CLI so the example cannot rot: it must write
field.vti with finite A-weighted levels near the source and a report with zero lost rays, and only the
files its user looks at (the field, the preview, the report; "rays" and "mesh" outputs are opt-in).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bentray.clients.cli import main
from bentray.scenes.schema import load_job

EXAMPLES = Path(__file__).resolve().parents[2] / "scenes" / "examples"
README = Path(__file__).resolve().parents[2] / "README.md"


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.json")), ids=lambda p: p.name)
def test_example_job_validates(path):
    job = load_job(path)
    assert job.n_rays > 0


def test_readme_first_command_runs_scaled_down(tmp_path):
    first = README.read_text().splitlines()[2]
    assert "bentray run scenes/examples/ridge-wind-map.json" in first
    spec = json.loads((EXAMPLES / "ridge-wind-map.json").read_text())
    spec["rays"]["elevation_deg"]["count"] = 31
    spec["rays"]["azimuth_deg"]["count"] = 11
    spec["field"].update({"spacing": [100, 50, 20], "shape": [30, 5, 6], "origin": [-1490, -100, 1]})
    job_file = tmp_path / "job.json"
    job_file.write_text(json.dumps(spec))
    out = tmp_path / "out"
    assert main(["run", str(job_file), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["rays"]["by_status"]["lost"] == 0
    assert report["stages"]["wind"].startswith("ran: ridge")
    import pyvista as pv

    grid = pv.read(out / "field.vti")
    spl_a = np.asarray(grid.point_data["spl_a"])
    assert np.isfinite(spl_a).any() and np.nanmax(spl_a) > 40.0
    assert sorted(p.name for p in out.iterdir()) == ["field.vti", "preview.png", "report.json"]
    for name in ("field.vti", "preview.png", "report.json"):
        assert (out / name).stat().st_size > 0
