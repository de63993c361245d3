"""sweep.csv: the field summary is an energy mean over the finite points and says which points."""

from __future__ import annotations

import csv
import math
from types import SimpleNamespace

import numpy as np
import pytest

from bentray.clients.sweep_cli import SweepRow, _job_name, energy_mean_db, field_summary, write_sweep_csv


def test_energy_mean_by_hand():
    # 60 and 70 dB: 10 lg((10^6 + 10^7) / 2) = 67.4036..., not the arithmetic 65
    mean, n = energy_mean_db(np.array([60.0, 70.0, np.nan, np.inf]))
    assert n == 2 and mean == pytest.approx(10 * math.log10((1e6 + 1e7) / 2), abs=1e-12)
    # a loss averages the intensities it stands for: -10 lg((10^-2 + 10^-4) / 2)
    loss, _ = energy_mean_db(np.array([20.0, 40.0]), loss=True)
    assert loss == pytest.approx(-10 * math.log10((1e-2 + 1e-4) / 2), abs=1e-12)
    assert energy_mean_db(np.array([400.0, 400.0]))[0] == pytest.approx(400.0)  # no overflow
    assert math.isnan(energy_mean_db(np.array([np.nan]))[0])


class _Field:
    def __init__(self, arrays):
        self.arrays = arrays

    def preview_array(self):
        return ("spl_a", "SPL (dB(A))") if "spl_a" in self.arrays else ("tl_1000hz", "TL (dB)")


def test_field_summary_and_csv(tmp_path):
    spl = np.array([[[50.0], [53.0]], [[np.nan], [56.0]]])
    name, mean, over = field_summary(SimpleNamespace(field=_Field({"spl_a": spl})))
    hand = 10 * math.log10((10**5 + 10**5.3 + 10**5.6) / 3)
    assert name == "spl_a" and mean == pytest.approx(hand, abs=1e-12)
    assert over == "energy mean over the 3 of 4 grid points with a finite spl_a"
    row = SweepRow("1", 1, tmp_path / "profile.b=1", {"ok": 5}, 0.1, 0.2, name, mean, over)
    write_sweep_csv("profile.b", [row], tmp_path / "sweep.csv")
    with (tmp_path / "sweep.csv").open() as fh:
        got = list(csv.DictReader(fh))[0]
    assert float(got["field_mean_db"]) == pytest.approx(hand, abs=1e-6) and got["field_mean_over"] == over
    assert _job_name({"name": "town"}, "profile.b", "+0.5") == "town_profile.b__0.5"
