"""Checks of the GFPE oracle by itself: homogeneous air against the image source (rigid and grass),
refraction (downward log profile louder, upward a shadow), step convergence, read-out consistency.

Measured numbers are printed (run with ``-s``); the asserted tolerances are those numbers with margin.
"""

from __future__ import annotations

import time
from functools import cache

import numpy as np
import pytest

from tests.reference import image_source as im
from tests.reference import normal_modes as nm
from tests.reference.gfpe import gfpe_pressure, gfpe_tl, homogeneous, log_profile

SIGMA = 2.0e5  # Pa s/m^2 (grass)
C0 = 340.0
RANGES = np.arange(50.0, 1000.1, 2.0)
ZR = np.array([1.0, 2.0, 3.0, 4.0])

# asserted tolerances (measured values in the docstrings of the tests below)
TOL_DB = {None: 0.05, SIGMA: 0.15}  # |dTL| away from interference dips
TOL_REL = {None: 0.005, SIGMA: 0.02}  # |p_gfpe - p_image| / sqrt(incoherent |p|^2), everywhere
TOL_DIP_M = 1.0  # interference-dip positions along range, m


@cache
def _gfpe(f_hz: float, zs: float, sigma: float | None, b: float = 0.0, **kw: float) -> np.ndarray:
    prof = homogeneous(C0) if b == 0.0 else log_profile(C0, b, 1.0)
    return gfpe_pressure(prof, f_hz, zs, RANGES, ZR, sigma, **kw)


def _image(f_hz: float, zs: float, sigma: float | None) -> tuple[np.ndarray, np.ndarray]:
    p = im.exact_pressure(f_hz, zs, RANGES, ZR, sigma) if sigma else im.pressure(f_hz, zs, RANGES, ZR)
    inc = 10.0 ** (-im.incoherent_tl(f_hz, zs, RANGES, ZR, sigma) / 20.0)
    return p, inc


def _dips(tl: np.ndarray, tl_inc: np.ndarray) -> np.ndarray:
    """Positions (m) of the interference dips of the level along RANGES (see _dips_along)."""
    return _dips_along(RANGES, tl, tl_inc)


def _compare(f_hz: float, zs: float, sigma: float | None) -> tuple[float, float, float, int]:
    pg = _gfpe(f_hz, zs, sigma)
    pi, inc = _image(f_hz, zs, sigma)
    d_db = 20 * np.log10(np.abs(pg) / np.abs(pi))
    away = np.abs(pi) >= 0.5 * inc  # not within an interference dip
    rel = np.abs(pg - pi) / inc
    n_dips, dip_err = 0, 0.0
    for j in range(ZR.size):
        ti = -20 * np.log10(inc[:, j])
        di = _dips(-20 * np.log10(np.abs(pi[:, j])), ti)
        dg = _dips(-20 * np.log10(np.abs(pg[:, j])), ti)
        assert di.size == dg.size, f"zr={ZR[j]}: dips image {di} gfpe {dg}"
        if di.size:
            dip_err = max(dip_err, float(np.max(np.abs(di - dg))))
            n_dips += di.size
    return float(np.max(np.abs(d_db[away]))), float(np.max(rel)), dip_err, n_dips


@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
@pytest.mark.parametrize("zs", [2.0, 5.0])
@pytest.mark.parametrize("f_hz", [100.0, 500.0])
def test_homogeneous_against_image_source(f_hz: float, zs: float, sigma: float | None) -> None:
    """Homogeneous air, ranges 50-1000 m (2 m apart), receivers 1-4 m, source 2 or 5 m.

    Measured (``pytest -s tests/reference/test_gfpe.py -k image_source``): rigid max |dTL| <= 0.0083 dB
    away from dips, complex error <= 0.30 % of the incoherent amplitude; grass (exact complex-image
    integral as reference) <= 0.071 dB and <= 1.2 %; the 3 range dips (500 Hz, zs = 5 m) within 1 mm
    (dips are where the coherent level is > 3 dB below the incoherent one).
    """
    db, rel, dip_err, n_dips = _compare(f_hz, zs, sigma)
    print(
        f"\n f={f_hz} zs={zs} ground={sigma}: max|dTL|={db:.4f} dB rel={rel:.5f} dips={n_dips} dip_err={dip_err:.3f} m"
    )
    assert db < TOL_DB[sigma]
    assert rel < TOL_REL[sigma]
    assert dip_err < TOL_DIP_M


def test_dips_exist_where_expected() -> None:
    """The dip check above is not vacuous: rigid, 500 Hz, zs = 5 m, zr = 4 m has its first dip where
    R2 - R1 = lambda/2 (r ~ 4 zs zr / lambda = 118 m), found by both within a metre of the exact root."""
    lam = C0 / 500.0
    pg = _gfpe(500.0, 5.0, None)
    dg = _dips(-20 * np.log10(np.abs(pg[:, 3])), im.incoherent_tl(500.0, 5.0, RANGES, ZR)[:, 3])
    # exact root of hypot(r, 9) - hypot(r, 1) = lambda / 2
    from scipy.optimize import brentq

    r0 = brentq(lambda r: np.hypot(r, 9.0) - np.hypot(r, 1.0) - lam / 2, 50.0, 500.0)
    assert dg.size >= 1 and np.min(np.abs(dg - r0)) < 1.0


@pytest.mark.slow
@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
def test_homogeneous_against_image_source_1khz(sigma: float | None) -> None:
    db, rel, dip_err, n_dips = _compare(1000.0, 2.0, sigma)
    print(f"\n f=1000 ground={sigma}: max|dTL|={db:.4f} dB rel={rel:.5f} dips={n_dips} dip_err={dip_err:.3f} m")
    assert db < TOL_DB[sigma] and rel < TOL_REL[sigma] and dip_err < TOL_DIP_M


@pytest.mark.parametrize("starter", ["gaussian", "second_order"])
def test_narrow_starters(starter: str) -> None:
    """Salomons' Gaussian and second-order starters at these low angles (<= 8 degrees at 50 m), 100 Hz,
    grass, zs = 2 m: measured max |dTL| against the image source 0.080 and 0.103 dB away from dips
    (the default wide starter: 0.071 dB)."""
    ps = gfpe_pressure(homogeneous(C0), 100.0, 2.0, RANGES, ZR, SIGMA, starter=starter)
    pi, inc = _image(100.0, 2.0, SIGMA)
    away = np.abs(pi) >= 0.5 * inc
    d = np.abs(20 * np.log10(np.abs(ps) / np.abs(pi)))[away]
    print(f"\n {starter}: max |dTL| vs image source {d.max():.3f} dB")
    assert d.max() < 0.15


ZV = np.arange(0.25, 30.0, 0.05)


@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
@pytest.mark.parametrize("zs", [2.0, 5.0])
def test_vertical_dip_positions(zs: float, sigma: float | None) -> None:
    """Interference dips along height (0.25-30 m, 5 cm apart) at 100 and 300 m, 500 Hz: the GFPE finds
    the same dips as the image source (rigid: at z ~ (2m+1) lambda r / (4 zs)), positions within 2 cm.

    Measured: 3-6 dips per case, position errors 0.04 mm (rigid), 11 mm (grass, zs = 2 m: shallow
    dips); |dTL| away from dips <= 0.0003 dB (rigid), 0.106 dB (grass, up to 17 degrees elevation).
    """
    f = 500.0
    r = np.array([100.0, 300.0])
    pg = gfpe_pressure(homogeneous(C0), f, zs, r, ZV, sigma)
    pi = im.exact_pressure(f, zs, r, ZV, sigma) if sigma else im.pressure(f, zs, r, ZV)
    inc = 10.0 ** (-im.incoherent_tl(f, zs, r, ZV, sigma) / 20.0)
    n, err = 0, 0.0
    for i in range(r.size):
        ti = -20 * np.log10(inc[i])
        di = _dips_along(ZV, -20 * np.log10(np.abs(pi[i])), ti)
        dg = _dips_along(ZV, -20 * np.log10(np.abs(pg[i])), ti)
        assert di.size == dg.size, f"r={r[i]}: image {di} gfpe {dg}"
        if di.size:
            err = max(err, float(np.max(np.abs(di - dg))))
        n += di.size
    away = np.abs(pi) >= 0.5 * inc
    db = float(np.max(np.abs(20 * np.log10(np.abs(pg) / np.abs(pi)))[away]))
    print(f"\n zs={zs} ground={sigma}: {n} dips, max position error {err * 1e3:.2f} mm, max|dTL| {db:.3f} dB")
    assert n >= 2
    assert err < 0.02
    assert db < TOL_DB[sigma]


def _dips_along(x: np.ndarray, tl: np.ndarray, tl_inc: np.ndarray, excess_db: float = 3.0) -> np.ndarray:
    """Parabolically refined positions of the interference dips: local maxima of tl that lie more than
    excess_db above the incoherent-sum TL (destructive interference)."""
    i = np.nonzero((tl[1:-1] >= tl[:-2]) & (tl[1:-1] > tl[2:]) & (tl[1:-1] - tl_inc[1:-1] > excess_db))[0] + 1
    a, b, c = tl[i - 1], tl[i], tl[i + 1]
    return x[i] + 0.5 * (a - c) / (a - 2 * b + c) * (x[1] - x[0])


def _mean_level(p: np.ndarray, rmin: float = 800.0) -> float:
    """Energy-mean level re free field at 1 km (dB) over ranges >= rmin and all receiver heights."""
    sel = RANGES >= rmin
    return 10 * np.log10(np.mean(np.abs(p[sel]) ** 2)) + 60.0


@pytest.mark.parametrize("f_hz", [100.0, 500.0])
@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
def test_refraction_log_profile(f_hz: float, sigma: float | None) -> None:
    """c = 340 + b ln(z + 1), zs = 2 m, 800-1000 m, 1-4 m (energy mean, dB re free field at 1 km).

    Measured: rigid 100 Hz homogeneous +7.0, downward (b = +1) +18.1, upward (b = -1) -27.0;
    rigid 500 Hz +7.0 / +14.6 / -101 (500 Hz upward: at the absorbing-layer floor, see gfpe.py);
    grass 100 Hz +1.9 / -3.3 / -20.8; grass 500 Hz -22.6 / -1.0 / -105.
    Downward refraction is louder than homogeneous air except over grass at 100 Hz (-5 dB with this
    strong near-ground gradient, 1 1/s at z = 0; robust to steps, c_ref, starter and domain height within
    0.3 dB; not checked by an independent solution: the normal-mode cases over grass, with a weaker
    linear gradient, are 3.9 dB louder), upward refraction casts a shadow (>= 20 dB below homogeneous).
    """
    hom = _mean_level(_gfpe(f_hz, 2.0, sigma))
    down = _mean_level(_gfpe(f_hz, 2.0, sigma, 1.0))
    up = _mean_level(_gfpe(f_hz, 2.0, sigma, -1.0))
    print(f"\n f={f_hz} ground={sigma}: homogeneous {hom:.1f} downward {down:.1f} upward {up:.1f} dB re ff")
    if not (sigma is not None and f_hz == 100.0):
        assert down > hom + 5.0
    assert up < hom - 20.0
    assert up < -20.0


@pytest.mark.parametrize("b", [1.0, -1.0], ids=["downward", "upward"])
@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
def test_step_convergence(b: float, sigma: float | None) -> None:
    """Halving dr and dz together (5 lambda, lambda/10 -> 2.5 lambda, lambda/20), 500 Hz, zs = 2 m,
    ranges 50-1000 m (upward: 50-450 m, above the layer floor), receivers 1-4 m.

    Measured: max |dTL| away from dips (level within 10 dB of the maximum over heights) 0.20 / 0.07 dB
    (downward rigid / grass), 0.07 / 0.11 dB (upward); complex change <= 1.6 % of that maximum.
    """
    lam = C0 / 500.0
    p1 = _gfpe(500.0, 2.0, sigma, b)
    p2 = _gfpe(500.0, 2.0, sigma, b, dr=2.5 * lam, dz=lam / 20)
    sel = RANGES <= (1000.0 if b > 0 else 450.0)
    p1, p2 = p1[sel], p2[sel]
    scale = np.abs(p2).max(axis=1, keepdims=True)
    away = np.abs(p2) >= 0.3 * scale
    d = np.abs(20 * np.log10(np.abs(p1) / np.abs(p2)))[away]
    rel = np.abs(p1 - p2) / scale
    print(f"\n b={b} ground={sigma}: max|dTL| away from dips {d.max():.3f} dB, rel {rel.max():.4f}")
    assert d.max() < 0.5
    assert rel.max() < 0.03


def test_speed_and_read_out() -> None:
    """1 km at 500 Hz (downward, grass) well under 20 s (measured 0.5-2 s here); outputs do not depend
    on which and in which order ranges are requested (side steps), receivers read exactly in z."""
    prof = log_profile(C0, 1.0, 1.0)
    t = time.perf_counter()
    tl = gfpe_tl(prof, 500.0, 2.0, [1000.0, 333.3, 777.7], [1.5, 2.25], SIGMA, z_top=300.0)
    elapsed = time.perf_counter() - t
    print(f"\n 1 km at 500 Hz: {elapsed:.2f} s")
    assert elapsed < 15.0
    one = gfpe_tl(prof, 500.0, 2.0, [777.7], [2.25, 1.5], SIGMA, z_top=300.0)
    assert one[0, ::-1] == pytest.approx(tl[2], abs=1e-9)
    assert tl.shape == (3, 2) and np.all(np.isfinite(tl))
    # many receivers: the blocked read-out gives the same numbers
    zz = np.linspace(0.5, 20.0, 700)
    big = gfpe_tl(prof, 500.0, 2.0, [333.3], zz, SIGMA, z_top=300.0)
    small = gfpe_tl(prof, 500.0, 2.0, [333.3], zz[::100], SIGMA, z_top=300.0)
    assert big[0, ::100] == pytest.approx(small[0], abs=1e-9)


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="zs and ranges"):
        gfpe_tl(homogeneous(), 100.0, 0.0, [10.0], [1.0])
    with pytest.raises(ValueError, match="z_top"):
        gfpe_tl(homogeneous(), 100.0, 2.0, [10.0], [500.0], z_top=100.0)
    with pytest.raises(ValueError, match="Im Z"):
        gfpe_tl(homogeneous(), 100.0, 2.0, [10.0], [1.0], impedance=10.0 + 0j)
    with pytest.raises(ValueError, match="profile_c"):
        gfpe_tl(lambda z: -np.ones_like(z), 100.0, 2.0, [10.0], [1.0])
    with pytest.raises(ValueError, match="starter"):
        gfpe_tl(homogeneous(), 100.0, 2.0, [10.0], [1.0], starter="parabolic")


@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
@pytest.mark.parametrize("f_hz", [100.0, 500.0])
def test_wide_angles_homogeneous(f_hz: float, sigma: float | None) -> None:
    """Elevations up to 50 degrees (r = 50 and 100 m, receivers 1-60 m, zs = 2 m), homogeneous air: the
    default (wide) starter stays within 0.4 dB of the image source away from dips (measured 0.294 dB at
    40-50 degrees, rigid, 100 Hz; 0.017 dB rigid 500 Hz; <= 0.224 dB over grass); the Gaussian starter
    is up to 3.9 dB low at 20-45 degrees, as its amplitude exp(-sin^2(th)/2) predicts."""
    r = np.array([50.0, 100.0])
    z = np.arange(1.0, 60.0, 0.5)
    pi = im.exact_pressure(f_hz, 2.0, r, z, sigma) if sigma else im.pressure(f_hz, 2.0, r, z)
    away = np.abs(pi) >= 0.5 * 10.0 ** (-im.incoherent_tl(f_hz, 2.0, r, z, sigma) / 20.0)
    ang = np.degrees(np.arctan((z[None, :] - 2.0) / r[:, None]))
    pw = gfpe_pressure(homogeneous(C0), f_hz, 2.0, r, z, sigma)
    pgs = gfpe_pressure(homogeneous(C0), f_hz, 2.0, r, z, sigma, starter="gaussian")
    dw = np.abs(20 * np.log10(np.abs(pw) / np.abs(pi)))[away]
    band = away & (ang > 20.0) & (ang <= 45.0)
    dg = (20 * np.log10(np.abs(pgs) / np.abs(pi)))[band]
    print(f"\n f={f_hz} ground={sigma}: wide max|dTL| {dw.max():.3f} dB; gaussian at 20-45 deg {dg.min():.2f} dB")
    assert dw.max() < 0.4
    assert dg.min() < -1.0  # the comparison can tell a narrow-angle starter


@pytest.mark.parametrize("b", [1.0, -1.0], ids=["downward", "upward"])
@pytest.mark.parametrize("sigma", [None, SIGMA], ids=["rigid", "grass"])
@pytest.mark.parametrize("f_hz", [100.0, 500.0])
def test_reciprocity_refracting(f_hz: float, sigma: float | None, b: float) -> None:
    """Source 2 m / receiver 10 m against source 10 m / receiver 2 m in the log profiles, 100-1000 m:
    the two runs (different starters, reference wavenumbers c(zs) and phase screens) agree within
    0.5 dB where TL < 120 dB (measured <= 0.33 dB; deeper values sit on the absorbing-layer floor)."""
    r = np.array([100.0, 300.0, 600.0, 1000.0])
    prof = log_profile(C0, b, 1.0)
    a = gfpe_pressure(prof, f_hz, 2.0, r, [10.0], sigma, z_top=300.0)[:, 0]
    c = gfpe_pressure(prof, f_hz, 10.0, r, [2.0], sigma, z_top=300.0)[:, 0]
    tl = -20 * np.log10(np.abs(a))
    d = np.abs(20 * np.log10(np.abs(a) / np.abs(c)))[tl < 120.0]
    print(f"\n f={f_hz} ground={sigma} b={b}: reciprocity max |dTL| {d.max():.3f} dB over {d.size} ranges")
    assert d.size >= 2
    assert d.max() < 0.5


@pytest.mark.parametrize("a", [1e-4, 3e-4])
@pytest.mark.parametrize("f_hz", [100.0, 500.0])
def test_against_normal_modes(f_hz: float, a: float) -> None:
    """Linear-k^2 downward refraction c = c0 / sqrt(1 - a z) over rigid ground (dc/dz = 0.017 and
    0.05 1/s), zs = 2 m, receivers 1-4 m, 100-1000 m, against the exact Airy-mode sum (normal_modes.py):
    measured max |dTL| away from dips <= 0.02 dB, complex error <= 0.7 % of the rms over heights."""
    r = np.arange(100.0, 1000.1, 10.0)
    pm = nm.pressure(f_hz, a, 2.0, r, ZR)
    pg = gfpe_pressure(nm.profile_c(C0, a), f_hz, 2.0, r, ZR, None, c_ref=C0)
    sc = np.sqrt(np.mean(np.abs(pm) ** 2, axis=1, keepdims=True))
    away = np.abs(pm) >= 0.5 * sc
    d = np.abs(20 * np.log10(np.abs(pg) / np.abs(pm)))[away]
    rel = np.abs(pg - pm) / sc
    print(f"\n modes f={f_hz} a={a}: max|dTL| {d.max():.3f} dB, rel {rel.max():.4f}")
    assert d.max() < 0.1
    assert rel.max() < 0.02


def test_against_normal_modes_strong_gradient() -> None:
    """a = 1e-3 (c +5 % at 100 m, rays up to ~15 degrees reach 1 km), 500 Hz: the narrow-angle phase
    screen drifts in phase, measured max |dTL| 0.04 dB to 300 m, 0.68 dB to 600 m, 3.2 dB to 1 km at
    single points (median 0.07 dB), the energy mean over 100-1000 m and 1-4 m within 0.01 dB."""
    r = np.arange(100.0, 1000.1, 10.0)
    a = 1e-3
    pm = nm.pressure(500.0, a, 2.0, r, ZR)
    pg = gfpe_pressure(nm.profile_c(C0, a), 500.0, 2.0, r, ZR, None, c_ref=C0)
    sc = np.sqrt(np.mean(np.abs(pm) ** 2, axis=1, keepdims=True))
    away = np.abs(pm) >= 0.5 * sc
    d = np.abs(20 * np.log10(np.abs(pg) / np.abs(pm)))
    near = away & (r[:, None] <= 300.0)
    energy = 10 * np.log10(np.mean(np.abs(pg) ** 2) / np.mean(np.abs(pm) ** 2))
    print(f"\n modes a=1e-3: <=300 m {d[near].max():.3f} dB, all {d[away].max():.2f} dB, energy {energy:.4f} dB")
    assert d[near].max() < 0.1
    assert np.median(d[away]) < 0.15
    assert abs(energy) < 0.05


@pytest.mark.parametrize("f_hz", [100.0, 250.0])
def test_against_normal_modes_grass(f_hz: float) -> None:
    """Refraction and impedance together: c = c0 / sqrt(1 - a z), a = 3e-4, over grass, against the
    impedance Airy modes (surface wave included), 100-1000 m, 1-4 m: measured max |dTL| away from dips
    0.086 dB (100 Hz) and 0.079 dB (250 Hz), complex error <= 2.4 % of the rms over heights; the levels
    are 3.9 and 17.9 dB above homogeneous air at 820-1000 m."""
    r = np.arange(100.0, 1000.1, 10.0)
    a = 3e-4
    pm = nm.pressure(f_hz, a, 2.0, r, ZR, flow_resistivity=SIGMA)
    pg = gfpe_pressure(nm.profile_c(C0, a), f_hz, 2.0, r, ZR, SIGMA, c_ref=C0)
    sc = np.sqrt(np.mean(np.abs(pm) ** 2, axis=1, keepdims=True))
    away = np.abs(pm) >= 0.5 * sc
    d = np.abs(20 * np.log10(np.abs(pg) / np.abs(pm)))[away]
    rel = np.abs(pg - pm) / sc
    print(f"\n grass modes f={f_hz}: max|dTL| {d.max():.3f} dB, rel {rel.max():.4f}")
    assert d.max() < 0.15
    assert rel.max() < 0.04
