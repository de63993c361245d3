"""The product's default field in refracting, range-independent scenes against the GFPE oracle (issue 12).

The eight cases of tests/fields/test_beam_refraction_gfpe.py (log c = 340 +- ln(z + 1), linear c = 340 +- 0.1 z,
grass 200 kPa s/m^2, source 2 m, receivers 1.5 m every 2 m over 20 m - 1 km, coherent, 100 and 500 Hz), run
through ``run_job`` with the default ``field.wave_model`` ("auto"): the wave-field stage (engine/wave_stage.py)
gives these bands from the wavenumber integral of the profile (engine/acoustics/wave_field.py), the beams stay
where it does not apply. Compared with tests/reference/gfpe.py (independent of the engine): the beam test's
points (beam_weight >= 0.5, not in an interference dip of the oracle: 6 dB below its 50 m running median)
plus the refractive-shadow points (beam_weight < 0.5) where the GFPE is above its floor (at most 80 dB below
the free field). Asserted: mean |difference| <= 1 dB over each set (the issue's bound), and every compared
point from the wave field (field_source 5).

Measured (2026-12-02, /tmp script calling this module's ``_compare`` for the eight cases, the same numbers as
``timeout 2400 .venv/bin/python -m pytest -q -p no:cacheprovider -m "slow or not slow"
tests/fields/test_wave_field_gfpe.py``): mean |wave - GFPE| over the lit points (count) / the shadow points
(count), dB:

    case          100 Hz                          500 Hz
    log up        0.061 (29) / 0.057 (393)        0.047 (29) / 0.015 (68)
    log down      0.109 (491) / - (no shadow)     0.072 (491) / -
    linear up     0.063 (100) / 0.067 (391)       0.045 (100) / 0.035 (27)
    linear down   0.082 (491) / -                 0.042 (491) / -

against the beams alone (``wave_model`` "off", tests/fields/test_beam_refraction_gfpe.py, lit points only):
log up 0.66 / 4.32, log down 5.15 / 2.15, linear up 0.52 / 8.71, linear down 3.28 / 4.34 dB. The stage took
0.3-0.4 s at 100 Hz and 2.2-7.0 s at 500 Hz (tops 63-199 m) of runs of 80-116 s, nearly all of it the beams'
trace (load average 13 on 2 cores), so the eight are slow; the default suite's run_job check against the GFPE
is the 3D grid below (14 s).

The 3D aspect: the integral is axisymmetric about the source's vertical; a 3D grid (four azimuths, three
heights) must give at each point the GFPE's (r, z) answer (measured: mean 0.09 dB, max 0.20 dB over
72 points, 150-424 m, 16 azimuths; the same (r, z) at different azimuths identical); two sources (mode
semicoherent: coherent mode takes one source) add their energies. Cost: docs/physics.md §18.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy.ndimage import median_filter

from bentray.engine.acoustics.wave_field import wave_pressure
from bentray.engine.field_sources import WAVE
from bentray.engine.profiles import Log
from bentray.engine.run import run_job
from bentray.scenes.schema import Job
from tests.fields.test_beam_refraction_gfpe import GRASS, PROFILES, XS, ZR, ZS, _spec
from tests.reference.gfpe import gfpe_tl


def _auto_spec(name: str, f: float) -> dict:
    spec = _spec(name, f)
    spec["name"] = f"wave-{name}"
    spec["field"].pop("wave_model")  # the default: "auto"
    return spec


@cache
def _run(name: str, f: float):
    return run_job(Job.model_validate(_auto_spec(name, f)))


@cache
def _gfpe(name: str, f: float) -> np.ndarray:
    return gfpe_tl(PROFILES[name][1], f, ZS, XS, np.array([ZR]), flow_resistivity=GRASS)[:, 0]


def _compare(name: str, f: float) -> dict:
    out = _run(name, f)
    tl = out.field.arrays[f"tl_{f:g}hz"].ravel()
    w = out.field.arrays["beam_weight"].ravel()
    code = out.field.arrays["field_source"].ravel()
    ref = _gfpe(name, f)
    dips = ref - median_filter(ref, size=25, mode="nearest") >= 6.0
    lit = (w >= 0.5) & ~dips
    shadow = (w < 0.5) & ~dips & (ref <= 80.0)
    d = np.abs(tl - ref)
    return {
        "lit": int(lit.sum()),
        "lit_mean_db": float(d[lit].mean()),
        "shadow": int(shadow.sum()),
        "shadow_mean_db": float(d[shadow].mean()) if shadow.any() else 0.0,
        "all_mean_db": float(d[lit | shadow].mean()),
        "wave_coded": bool(np.all(code[lit | shadow] == WAVE)),
        "report": out.report.get("wave_field"),
        "stage": out.report["stages"].get("wave_field", ""),
    }


CASES = [pytest.param(name, f, marks=(pytest.mark.slow,)) for name in PROFILES for f in (100.0, 500.0)]


@pytest.mark.parametrize(("name", "f"), CASES)
def test_default_field_matches_gfpe(name, f):
    res = _compare(name, f)
    assert res["stage"].startswith("ran:"), res["stage"]
    assert res["report"]["bands_hz"] == [f], res["report"]
    assert res["wave_coded"], res
    assert res["lit"] >= 20, res
    assert res["lit_mean_db"] <= 1.0, res
    assert res["shadow_mean_db"] <= 1.0, res


# --- the 3D grid: axisymmetric about each source, the (r, z) answer at every azimuth and height ----------
GRID_Z = (1.5, 6.0, 10.5)
RECEIVERS = ((200.0, 0.0, 1.5), (0.0, -250.0, 6.0), (-300.0, 300.0, 10.5), (150.0, 150.0, 1.5))


def _grid_spec(sources: list[list[float]], mode: str = "coherent", **field) -> dict:
    spec = {
        "name": "wave-3d",
        "scene": {"domain": {"min": [-420, -420, 0], "max": [420, 420, 100]},
                  "ground": {"kind": "flat", "flow_resistivity": GRASS}},  # fmt: skip
        "profile": PROFILES["log_down"][0],
        "sources": [{"position": s} for s in sources],
        "rays": {"elevation_deg": {"min": -20.0, "max": 20.0, "count": 41},
                 "azimuth_deg": {"min": 0.0, "max": 350.0, "count": 36}, "max_time_s": 1.6, "max_reflections": 3},
        "field": {"origin": [-300.0, -300.0, GRID_Z[0]], "spacing": [150.0, 150.0, 4.5], "shape": [5, 5, 3],
                  "frequencies_hz": [100.0], "absorption": False, "mode": mode, **field},
        "receivers": [{"id": f"r{i}", "position": list(xyz)} for i, xyz in enumerate(RECEIVERS)],
        "outputs": ["field", "report"],
    }  # fmt: skip
    return spec


@cache
def _grid_run(sources: tuple[tuple[float, float, float], ...], mode: str = "coherent"):
    return run_job(Job.model_validate(_grid_spec([list(s) for s in sources], mode)))


def grid_points(out):
    """The 3D grid run's points (n, 3), tl_100hz and field_source (n,), each point's horizontal range r and
    height z (rounded to 1e-6 m), the points off the source's vertical (r > 0) and their distinct ranges."""
    pts = out.field.grid.points()
    tl = out.field.arrays["tl_100hz"].ravel()
    code = out.field.arrays["field_source"].ravel()
    r = np.round(np.hypot(pts[:, 0], pts[:, 1]), 6)
    z = np.round(pts[:, 2], 6)
    off = r > 0
    return pts, tl, code, r, z, off, np.unique(r[off])


def test_3d_grid_is_the_gfpe_r_z_answer_at_every_azimuth_and_height():
    """Source at the origin, 5 x 5 x 3 grid (ranges 150-424 m, 16 azimuths, heights 1.5 / 6 / 10.5 m): each
    point's TL equals the GFPE's at its (r, z); the same (r, z) at different azimuths agrees to 0.01 dB. The
    point on the source's vertical (r = 0, k r < 20) keeps the beams."""
    out = _grid_run(((0.0, 0.0, ZS),))
    pts, tl, code, r, z, off, ranges = grid_points(out)
    assert np.all(code[off] == WAVE) and np.all(code[~off] != WAVE)
    ref = gfpe_tl(PROFILES["log_down"][1], 100.0, ZS, ranges, np.array(GRID_Z), flow_resistivity=GRASS)
    want = ref[np.searchsorted(ranges, r[off]), np.searchsorted(np.array(GRID_Z), z[off])]
    d = np.abs(tl[off] - want)
    assert d.mean() <= 0.5 and d.max() <= 1.5, (d.mean(), d.max())
    for rr in ranges:
        for zz in GRID_Z:
            same = off & (r == rr) & (z == zz)
            assert np.ptp(tl[same]) <= 0.01, (rr, zz, tl[same])
    # receivers.csv: the coherent columns from the same integral (the grid point (150, 150, 1.5) included)
    rows = out.receivers.rows
    rr = np.array([np.hypot(x, y) for x, y, _ in RECEIVERS])
    got = np.array([row["tl_coh_100hz"] for row in rows])
    for row, (_, _, zz), r_i in zip(rows, RECEIVERS, rr, strict=True):
        one = gfpe_tl(PROFILES["log_down"][1], 100.0, ZS, np.array([r_i]), np.array([zz]), flow_resistivity=GRASS)
        assert abs(row["tl_coh_100hz"] - float(one[0, 0])) <= 0.5, (row, float(one[0, 0]))
    at = int(np.flatnonzero((pts[:, 0] == 150.0) & (pts[:, 1] == 150.0) & (pts[:, 2] == 1.5))[0])
    assert abs(got[3] - tl[at]) <= 1e-6
    assert out.report["wave_field"]["receivers"]["rows"] == len(RECEIVERS)


@pytest.mark.slow
def test_two_sources_add_their_energies():
    """Several sources (mode semicoherent; coherent takes one source): TL of the two-source map = the energy
    sum of the one-source maps (each source's own field coherent, ground reflection included), SPL the sum of
    the powered energies; one source alone: semicoherent and coherent give the same wave field."""
    a, b = (0.0, 0.0, ZS), (60.0, 40.0, 3.0)
    both, one, two = (_grid_run(s, "semicoherent") for s in ((a, b), (a,), (b,)))
    ok = np.ones(both.field.arrays["tl_100hz"].size, bool)
    for o in (both, one, two):
        ok &= o.field.arrays["field_source"].ravel() == WAVE
    assert ok.sum() >= 70
    e = [10 ** (-o.field.arrays["tl_100hz"].ravel()[ok] / 10) for o in (both, one, two)]
    np.testing.assert_allclose(e[0], e[1] + e[2], rtol=1e-9)
    coh = _grid_run((a,), "coherent")
    np.testing.assert_allclose(one.field.arrays["tl_100hz"].ravel()[ok], coh.field.arrays["tl_100hz"].ravel()[ok])
    p = (coh.field.arrays["p_re_100hz"] + 1j * coh.field.arrays["p_im_100hz"]).ravel()[ok]
    np.testing.assert_allclose(-10 * np.log10(np.abs(p) ** 2), coh.field.arrays["tl_100hz"].ravel()[ok], atol=1e-9)


def test_top_height_is_converged():
    """The integral's top is a numerical parameter: doubling it moves the 100 Hz line (log b = +1) by little."""
    pts = np.column_stack([XS[::10], np.zeros(XS[::10].size), np.full(XS[::10].size, ZR)])
    prof = Log(c0=340.0, b=1.0, z_g=1.0)
    auto = wave_pressure(prof, [[0.0, 0.0, ZS]], pts, 0.0, GRASS, [100.0])
    tall = wave_pressure(prof, [[0.0, 0.0, ZS]], pts, 0.0, GRASS, [100.0], z_top_m=2.0 * auto.z_top_m)
    d = np.abs(10 * np.log10(np.abs(auto.p[0, 0]) ** 2 / np.abs(tall.p[0, 0]) ** 2))
    assert 100.0 <= auto.z_top_m <= 200.0, auto.z_top_m
    assert d.mean() <= 0.1 and d.max() <= 0.5, (d.mean(), d.max())


@pytest.mark.slow
def test_turbulent_scattering_is_still_added_in_the_shadow():
    """Upward log profile, 100 Hz, with ``turbulence``: the wave stage gives the band (its integral holds the
    creeping waves, so the shadow stage adds none), the shadow stage adds the scattered energy in the shadow
    only: more energy there (measured: up to 0.020 dB with these weak constants at 100 Hz), the lit points
    untouched."""
    spec = _auto_spec("log_up", 100.0)
    spec["turbulence"] = {"c_t2": 1e-5, "c_v2": 1e-4}
    turb = run_job(Job.model_validate(spec))
    plain = _run("log_up", 100.0)
    assert turb.report["wave_field"]["bands_hz"] == [100.0]
    assert "turbulent scattering" in turb.report["stages"]["refractive_shadow"]
    a, b = plain.field.arrays["tl_100hz"].ravel(), turb.field.arrays["tl_100hz"].ravel()
    assert np.all(b <= a + 1e-9)
    assert np.array_equal(a[:10], b[:10])  # 20-38 m: lit
    assert np.max(a - b) > 0.01  # added in the shadow (0.02 dB at most here: weak turbulence at 100 Hz)


def test_wind_enters_through_the_effective_sound_speed_per_azimuth():
    """Homogeneous air with a log-law wind toward +x (u* = 0.3 m/s, z_g = 0.1 m), 100 Hz, grass: points
    downwind (azimuth 0) and upwind (180 degrees) at 1.5 m, 60-600 m, each match the GFPE of its own
    c_eff(z) = 340 +- (u*/0.41) ln(z / z_g) (above the floor, outside the oracle's dips). Measured: downwind
    0.105 / 0.189 dB mean / max, upwind (into its shadow, TL to 67 dB) 0.111 / 0.308 dB, 91 points each."""
    from bentray.engine.profiles import build_profile
    from bentray.scenes.wind_models import wind_from_spec

    u_star, z_g = 0.3, 0.1
    wind = wind_from_spec({"kind": "log", "u_star": u_star, "z_g": z_g, "direction_deg": 0.0})
    xs = 60.0 + 6.0 * np.arange(91)
    pts = np.concatenate([np.column_stack([s * xs, np.zeros(xs.size), np.full(xs.size, ZR)]) for s in (1.0, -1.0)])
    wf = wave_pressure(build_profile("homogeneous", c0=340.0), [[0.0, 0.0, ZS]], pts, 0.0, GRASS, [100.0], wind)
    tl = -10 * np.log10(np.abs(wf.p[0, 0]) ** 2)
    for k, sign in enumerate((1.0, -1.0)):
        ref = gfpe_tl(lambda z, s=sign: 340.0 + s * (u_star / 0.41) * np.log(np.maximum(z, z_g) / z_g), 100.0, ZS,
                      xs, np.array([ZR]), flow_resistivity=GRASS)[:, 0]  # fmt: skip
        dips = ref - median_filter(ref, size=9, mode="nearest") >= 6.0
        ok = ~dips & (ref <= 80.0)
        d = np.abs(tl[k * xs.size : (k + 1) * xs.size] - ref)[ok]
        assert ok.sum() >= 60 and d.mean() <= 0.5, (sign, ok.sum(), d.mean(), d.max())
