"""``field.wave_model`` (scenes/field_models.py) and the wave stage's cost (scenes/cost.py): "on" is refused,
naming the field, where the wavenumber integral cannot apply (terrain, buildings, ground zones, a reflecting
top, a range-dependent profile or wind, a directional source; an incoherent map is accepted: band averages);
"auto" takes the bands lowest first while their estimated seconds fit WAVE_AUTO_MAX_SECONDS and none in
homogeneous air without
wind; an expensive "on" gets a budget line naming field.wave_model."""

from __future__ import annotations

import copy

import pytest
from pydantic import ValidationError

from bentray.engine.acoustics.wave_field import band_nodes
from bentray.engine.acoustics.wavenumber import ffp_cells
from bentray.scenes.cost import (
    WAVE_AUTO_MAX_SECONDS,
    WAVE_SECONDS_PER_CELL,
    CostLimits,
    cost_problems,
    estimate_cost,
    wave_blockers,
    wave_cost,
    wave_frequencies,
)
from bentray.scenes.schema import Job

BASE = {
    "name": "wave-schema",
    "scene": {
        "domain": {"min": [-500, -500, 0], "max": [1100, 500, 300]},
        "ground": {"kind": "flat", "flow_resistivity": 200000.0},
    },  # fmt: skip
    "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
    "sources": [{"position": [0.0, 0.0, 2.0]}],
    "rays": {"elevation_deg": {"min": -30, "max": 30, "count": 31}, "max_time_s": 2.0, "max_reflections": 2},
    "field": {
        "origin": [20, 0, 1.5],
        "spacing": [2, 1, 1],
        "shape": [491, 1, 1],
        "frequencies_hz": [100, 500],
        "mode": "coherent",
    },  # fmt: skip
    "outputs": ["field", "report"],
}
FOOTPRINT = {"footprints": [{"polygon": [[300, -20], [320, -20], [320, 20], [300, 20]], "height_m": 10.0}]}


def _spec(**changes) -> dict:
    spec = copy.deepcopy(BASE)
    for path, value in changes.items():
        node = spec
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return spec


@pytest.mark.parametrize(
    ("changes", "why"),
    [
        ({"scene__buildings": FOOTPRINT}, "buildings"),
        ({"scene__top": {"kind": "reflect"}}, "reflect"),
        (
            {
                "wind": {
                    "kind": "ridge",
                    "u_star": 0.5,
                    "z_g": 0.1,
                    "direction_deg": 0.0,
                    "height_m": 30.0,
                    "half_width_m": 200.0,
                    "crest_x_m": 300.0,
                }
            },
            "ridge",
        ),  # fmt: skip
        ({"profile": {"kind": "hot_spot"}}, "stratified"),
    ],
)
def test_on_is_refused_naming_the_field_where_it_cannot_apply(changes, why):
    ok = _spec(field__wave_model="on")
    assert wave_blockers(Job.model_validate(ok)) == []
    try:
        spec = _spec(field__wave_model="on", **changes)
        Job.model_validate(_spec(**changes))  # 'auto' accepts the same job (and skips the stage)
    except ValidationError as exc:  # a variant this schema version rejects on its own grounds
        pytest.skip(f"variant not valid here: {exc}")
    with pytest.raises(ValidationError) as info:
        Job.model_validate(spec)
    text = str(info.value)
    assert "field.wave_model" in text and why in text, text


def test_auto_takes_the_bands_lowest_first_within_its_limit():
    job = Job.model_validate(_spec(field__frequencies_hz=[63, 125, 250, 500, 1000, 2000, 4000, 8000]))
    bands, seconds = wave_cost(job)
    assert bands == [63.0, 125.0, 250.0, 500.0, 1000.0]  # 2 kHz would take the sum over the limit
    assert sum(seconds) <= WAVE_AUTO_MAX_SECONDS
    r_max = 1000.0 + 10.0
    top = 0.3 * r_max + 20.0
    assert seconds[3] == pytest.approx(ffp_cells(500.0, 340.0, 2.0, r_max, top) * WAVE_SECONDS_PER_CELL)
    on = Job.model_validate(_spec(field__wave_model="on", field__frequencies_hz=[63, 1000, 8000]))
    assert wave_cost(on)[0] == [63.0, 1000.0, 8000.0]
    assert wave_cost(Job.model_validate(_spec(field__wave_model="off")))[0] == []
    assert wave_cost(Job.model_validate(_spec(profile={"kind": "homogeneous"})))[0] == []  # nothing to correct
    # an incoherent map: the band's Gauss nodes (7 by default), each its own integral: fewer bands fit
    inc = Job.model_validate(_spec(field__mode="incoherent", field__frequencies_hz=[63, 125, 250, 500, 1000]))
    b_inc, s_inc = wave_cost(inc)
    assert b_inc == [63.0, 125.0, 250.0], b_inc
    nodes = band_nodes(250.0, "octave", 7)[0]
    want = sum(ffp_cells(f, 340.0, 2.0, r_max, max(top, 40.0 * 340.0 / f)) for f in nodes) * WAVE_SECONDS_PER_CELL
    assert s_inc[2] == pytest.approx(want)
    assert wave_frequencies(inc, 250.0) == pytest.approx(list(nodes))
    even = Job.model_validate(_spec(field__wave_band_points=4, receivers=[{"id": "a", "position": [300, 0, 1.5]}]))
    assert len(wave_frequencies(even, 500.0)) == 5  # 4 nodes + the band's own frequency (coherent columns)
    assert wave_frequencies(Job.model_validate(_spec()), 500.0) == [500.0]  # coherent map, no receivers


@pytest.mark.parametrize(("field", "value"), [("wave_band_points", 0), ("wave_band_points", 32),
                                              ("wave_band", "decade")])  # fmt: skip
def test_band_options_are_bounded_naming_the_field(field, value):
    with pytest.raises(ValidationError) as info:
        Job.model_validate(_spec(**{f"field__{field}": value}))
    assert f"field.{field}" in str(info.value) or f"field -> {field}" in str(info.value) or field in str(info.value)


def test_an_expensive_on_is_refused_naming_the_field():
    job = Job.model_validate(_spec(field__wave_model="on", field__frequencies_hz=[2000, 4000, 8000]))
    assert estimate_cost(job, 2).wave_seconds > CostLimits().wave_seconds
    lines = cost_problems(job, CostLimits())
    assert any(line.startswith("field.wave_model: ") for line in lines), lines
    cheap = Job.model_validate(_spec(field__wave_model="on"))
    assert not any(line.startswith("field.wave_model") for line in cost_problems(cheap, CostLimits()))


def test_the_report_says_which_stage_gave_which_band_and_why():
    """A coherent log-profile line to 1 km with a band over the 'auto' limit: 100 Hz from the wave stage, 4 kHz
    from the beams, the report says both and why, and each point's field_source is 4 (combination); the same
    job as an incoherent map runs the stage with band averages (7 Gauss nodes over the octave), and says so."""
    from bentray.engine.field_sources import COMBINATION
    from bentray.engine.run import run_job

    small = {"rays": {"elevation_deg": {"min": -20, "max": 20, "count": 41}, "max_time_s": 3.2, "max_reflections": 3},
             "field": {"origin": [100, 0, 1.5], "spacing": [100, 1, 1], "shape": [10, 1, 1],
                       "frequencies_hz": [100, 4000], "mode": "coherent"}}  # fmt: skip
    out = run_job(Job.model_validate(_spec(**small)))
    wave = out.report["wave_field"]
    assert wave["bands_hz"] == [100.0] and wave["beam_bands_hz"] == [4000.0], wave
    stage = out.report["stages"]["wave_field"]
    assert stage.startswith("ran: bands 100 Hz") and "4000 Hz keep the beams" in stage, stage
    assert set(out.field.arrays["field_source"].ravel().tolist()) == {COMBINATION}
    small["field"]["mode"] = "incoherent"
    inc = run_job(Job.model_validate(_spec(**small)))
    wave = inc.report["wave_field"]
    assert wave["bands_hz"] == [100.0] and wave["map"] == "band average (incoherent)", wave
    assert wave["band_average"]["points"] == 7 and len(wave["band_average"]["frequencies_hz"]["100"]) == 7
    stage = inc.report["stages"]["wave_field"]
    assert "band levels from octave band averages over 7 frequencies" in stage and "4000 Hz keep the beams" in stage
