"""The scripted study of the README (clients/examples/day_night_ridge.py) runs end to end: a local
service, two jobs (day A-LU and night A-LD on the ridge), downloads, the dB(A) maps, the plot and the CSV;
on its coarse --quick configuration."""

from __future__ import annotations

import csv
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

SCRIPT = Path(__file__).resolve().parents[2] / "clients" / "examples" / "day_night_ridge.py"


def _load_study():
    spec = importlib.util.spec_from_file_location("day_night_ridge", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["day_night_ridge"] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def test_study_jobs_are_valid_jobs_with_the_advertised_profiles():
    from bentray.scenes.schema import Job

    study = _load_study()
    for config in (study.FULL, study.QUICK):
        jobs = {period: Job.model_validate(study.study_job(period, config)) for period in study.PROFILES}
        assert jobs["day"].profile.b == -1.0 and jobs["night"].profile.b == 1.0  # A-LU by day, A-LD at night
        assert tuple(jobs["day"].field.shape) == config.grid_shape
    assert study.FULL.elevations * study.FULL.azimuths == 121 * 720  # the README's study, unchanged


@pytest.mark.slow  # a local service, two job processes, two ridge meshes: 21 s warm
def test_quick_day_night_study_writes_maps_plot_and_csv(tmp_path, capsys):
    study = _load_study()
    assert study.main(["--start-server", "--quick", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "day_night_ridge.png").stat().st_size > 10_000
    for period in ("day", "night"):
        assert (tmp_path / period / "field.vti").is_file() and (tmp_path / period / "report.json").is_file()
    with open(tmp_path / "day_night_ridge.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == study.QUICK.grid_shape[0]
    night = np.array([float(r["night_dBA"]) for r in rows])
    day = np.array([float(r["day_dBA"]) for r in rows])
    assert np.isfinite(night).sum() >= len(rows) // 2  # downward refraction reaches most of the line
    both = np.isfinite(night) & np.isfinite(day)
    # where both periods have rays, the CSV's difference column is night - day
    diff = np.array([float(r["night_minus_day_dB"]) for r in rows])
    np.testing.assert_allclose(diff[both], (night - day)[both], atol=0.011)
    assert "map points reached" in capsys.readouterr().out
