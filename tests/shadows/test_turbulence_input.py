"""The ``turbulence`` key: typical values accepted, physically impossible ones refused with the field path
and the valid range (schema, ``bentray run`` exit 2 with the same text), and the scattered level of
engine/acoustics/scattering.py against hand values."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.clients.cli import main
from bentray.engine.acoustics.scattering import gamma_t, scattered_energy, scattered_level_db
from bentray.scenes.schema import format_validation_error, parse_job_text
from bentray.scenes.turbulence_models import TURBULENCE_PRESETS, TurbulenceSpec
from tests.hardening.conftest import base_job


def _lines(turbulence) -> list[str]:
    job = base_job()
    job["turbulence"] = turbulence
    with pytest.raises(ValidationError) as info:
        parse_job_text(json.dumps(job))
    return format_validation_error(info.value).splitlines()


def test_default_is_off_and_presets_are_accepted():
    assert parse_job_text(json.dumps(base_job())).turbulence is None
    for c_t2, c_v2 in TURBULENCE_PRESETS.values():
        job = base_job()
        job["turbulence"] = {"c_t2": c_t2, "c_v2": c_v2}
        assert parse_job_text(json.dumps(job)).turbulence == TurbulenceSpec(c_t2=c_t2, c_v2=c_v2)


@pytest.mark.parametrize(
    ("turbulence", "start"),
    [
        ({"c_t2": -0.01, "c_v2": 0.1}, "turbulence.c_t2: c_t2 (C_T^2) must be in [0, 10] K^2 m^-2/3"),
        ({"c_t2": 0.01, "c_v2": 50.0}, "turbulence.c_v2: c_v2 (C_v^2) must be in [0, 10] m^4/3 s^-2"),
        ({"c_t2": 0.01, "c_v2": -1e-9}, "turbulence.c_v2: c_v2 (C_v^2) must be in [0, 10]"),
        ({"c_t2": 0.0, "c_v2": 0.0}, "turbulence: c_t2 and c_v2 are both 0"),
        ({"c_t2": 0.01}, "turbulence.c_v2: Field required"),
        ({"c_t2": 0.01, "c_v2": 0.1, "cn2": 1e-14}, "turbulence.cn2: Extra inputs are not permitted"),
    ],
)
def test_bad_turbulence_is_refused_with_the_field_and_range(turbulence, start):
    lines = _lines(turbulence)
    assert len(lines) == 1 and lines[0].startswith(start), lines


def test_nan_is_refused_with_the_range_in_python():
    with pytest.raises(ValidationError) as info:
        TurbulenceSpec(c_t2=math.nan, c_v2=0.1)
    assert "c_t2 (C_T^2) must be in [0, 10] K^2 m^-2/3" in str(info.value)


def test_cli_gives_the_schema_text(tmp_path, capsys):
    job = base_job()
    job["turbulence"] = {"c_t2": 20.0, "c_v2": 0.1}
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    rc = main(["run", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2
    assert _lines(job["turbulence"])[0] in err.splitlines()


def test_scattered_level_hand_values():
    c0 = 340.0
    t0 = c0 * c0 / (1.4 * 287.05)
    g = gamma_t(0.008, 0.12, c0)
    assert g == pytest.approx(0.008 / t0**2 + 22.0 / 3.0 * 0.12 / c0**2, rel=1e-12)
    # moderate turbulence, 100 Hz, 500 m: 25 + 10 lg(7.70e-6) - 3 + 6.99 = -22.1 dB re the free field
    assert float(scattered_level_db(100.0, 500.0, 0.008, 0.12, c0)) == pytest.approx(-22.14, abs=0.01)
    e = scattered_energy(np.array([1000.0]), np.array([100.0, 1000.0]), 0.008, 0.12, c0)
    assert e[1] / e[0] == pytest.approx(0.1)  # 10 lg(R/100) on top of 1/R^2: the energy falls as 1/R
    assert scattered_energy(1000.0, 100.0, 0.0, 0.0, c0) == 0.0
