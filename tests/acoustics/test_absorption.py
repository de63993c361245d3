"""ISO 9613-1 atmospheric absorption against the published octave-band table (ISO 9613-2:1996 Table 2).

The table lists alpha in dB/km at the nominal octave midbands, computed from ISO 9613-1 at the *exact*
midband frequencies 1000 * 10^(0.3 k) Hz and rounded to 0.1 dB/km (three significant figures at the
largest values). Evaluated at the nominal frequencies instead, the 4 kHz and 8 kHz entries miss by up to
1.4 dB/km (tested below), so the exact frequencies are the right reading of the table.
"""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.acoustics.absorption import absorption_db_per_m, water_vapour_molar_percent
from bentray.engine.acoustics.weighting import OCTAVE_BANDS_EXACT_HZ, OCTAVE_BANDS_HZ

# (temperature C, relative humidity %) -> dB/km at 63, 125, 250, 500, 1k, 2k, 4k, 8k Hz
ISO_9613_2_TABLE_2 = {
    (10.0, 70.0): [0.1, 0.4, 1.0, 1.9, 3.7, 9.7, 32.8, 117.0],
    (20.0, 70.0): [0.1, 0.3, 1.1, 2.8, 5.0, 9.0, 22.9, 76.6],
    (30.0, 70.0): [0.1, 0.3, 1.0, 3.1, 7.4, 12.7, 23.1, 59.3],
    (15.0, 20.0): [0.3, 0.6, 1.2, 2.7, 8.2, 28.2, 88.8, 202.0],
    (15.0, 50.0): [0.1, 0.5, 1.2, 2.2, 4.2, 10.8, 36.2, 129.0],
    (15.0, 80.0): [0.1, 0.3, 1.1, 2.4, 4.1, 8.3, 23.7, 82.8],
}


def _tolerance(table_db_per_km: np.ndarray) -> np.ndarray:
    # The table's rounding: 0.05 dB/km absolute or 1.5 % relative, whichever is larger. The largest
    # measured excess over pure half-unit rounding is 15 C / 80 % at 1 kHz: 4.151 computed vs 4.1
    # printed (1.2 %); every other entry rounds to the printed value except 15 C / 50 % at 8 kHz
    # (128.57 vs 129, 0.3 %) and 15 C / 20 % at 8 kHz (201.76 vs 202).
    return np.maximum(0.05, 0.015 * table_db_per_km)


@pytest.mark.parametrize(("conditions", "table"), list(ISO_9613_2_TABLE_2.items()))
def test_octave_bands_match_iso_9613_2_table_2(conditions: tuple[float, float], table: list[float]) -> None:
    expected = np.asarray(table)
    alpha_db_per_km = 1000.0 * absorption_db_per_m(OCTAVE_BANDS_EXACT_HZ, *conditions)
    assert np.all(np.abs(alpha_db_per_km - expected) <= _tolerance(expected))


def test_nominal_frequencies_do_not_reproduce_the_table() -> None:
    expected = np.asarray(ISO_9613_2_TABLE_2[(20.0, 70.0)])
    nominal = 1000.0 * absorption_db_per_m(OCTAVE_BANDS_HZ, 20.0, 70.0)
    # 8 kHz: 77.63 dB/km at 8000 Hz against 76.6 in the table (76.62 at 7943 Hz)
    assert abs(nominal[-1] - expected[-1]) > 0.8


def test_shape_dtype_and_monotone_in_frequency() -> None:
    f = np.geomspace(50.0, 10_000.0, 12).reshape(3, 4)
    a = absorption_db_per_m(f, 20.0, 50.0)
    assert a.shape == (3, 4) and a.dtype == np.float64
    assert np.all(np.diff(a.ravel()) > 0.0)  # absorption grows with frequency at fixed conditions
    assert absorption_db_per_m(1000.0, 20.0, 50.0).shape == ()


def test_saturation_vapour_pressure_against_steam_tables() -> None:
    # h at 100 % relative humidity is psat / pa; psat from the IAPWS-95 steam tables (kPa, over liquid
    # water): 0 C 0.6112, 10 C 1.2282, 20 C 2.3393, 30 C 4.2470, 50 C 12.352. The standard's Annex B
    # formula is an approximation; measured within 0.13 %.
    for t_c, psat_kpa in ((0.0, 0.6112), (10.0, 1.2282), (20.0, 2.3393), (30.0, 4.2470), (50.0, 12.352)):
        for pa in (101.325, 80.0):
            h = water_vapour_molar_percent(t_c, 100.0, pa)
            assert h / 100.0 * pa == pytest.approx(psat_kpa, rel=3e-3)
    # proportional to relative humidity
    assert water_vapour_molar_percent(20.0, 35.0, 101.325) == pytest.approx(
        0.35 * water_vapour_molar_percent(20.0, 100.0, 101.325), rel=1e-14
    )


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"humidity_percent": 120.0}, "humidity_percent"),
        ({"humidity_percent": -1.0}, "humidity_percent"),
        ({"temperature_c": -60.0}, "temperature_c"),
        ({"temperature_c": 70.0}, "temperature_c"),
        ({"pressure_kpa": 0.0}, "pressure_kpa"),
        ({"pressure_kpa": float("nan")}, "pressure_kpa"),
        ({"frequency_hz": [100.0, 0.0]}, "frequency_hz"),
        ({"frequency_hz": -5.0}, "frequency_hz"),
    ],
)
def test_input_validation_names_the_argument(kwargs: dict, name: str) -> None:
    args = {"frequency_hz": 1000.0, "temperature_c": 20.0, "humidity_percent": 50.0, "pressure_kpa": 101.325}
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        absorption_db_per_m(**args)


def test_dry_air_is_allowed() -> None:
    # h = 0: only the classical term and the h-independent parts of the relaxation frequencies remain.
    a = absorption_db_per_m(OCTAVE_BANDS_EXACT_HZ, 20.0, 0.0)
    assert np.all(np.isfinite(a)) and np.all(a > 0.0)
