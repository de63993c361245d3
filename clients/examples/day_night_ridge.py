"""Scripted study: day versus night noise map around a source on the ``ridge`` built-in scene.

Day is the upward-refracting A-LU profile (c = c0 - ln(z/z_g + 1): sound bends up, shadow zones),
night the downward-refracting A-LD profile (b = +1: sound bends down over the ridge flanks). The
source (100 dB sound power in each band) sits 2 m above the ridge crest. Both jobs are submitted to a
bentray service, waited for and downloaded; the script then samples the A-weighted level 4 m above
the terrain and writes

    OUT/day_night_ridge.png   maps (day, night, night - day) and the level along y = 0
    OUT/day_night_ridge.csv   x, terrain height, day dB(A), night dB(A), night - day along y = 0
    OUT/day/, OUT/night/      the jobs' result files (field.vti, preview.png, report.json)

    python clients/examples/day_night_ridge.py --start-server --out results/day-night-ridge
    python clients/examples/day_night_ridge.py --url http://host:8000 --key KEY --out DIR
    python clients/examples/day_night_ridge.py --start-server --quick --out DIR    # coarse smoke run

``--start-server`` runs ``python -m bentray.service serve`` on a free local port for the study.
Geometric shadows get the refractive-shadow model's level (the field's ``field_source`` 3); cells no model
reaches are NaN, blank in the maps and in the CSV.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bentray.clients.client import BentrayClient
from bentray.scenes.library.ridge import ridge_height

SOURCE = (0.0, 0.0, 42.0)  # 2 m above the 40 m crest
RECEIVER_HEIGHT_M = 4.0  # above the local terrain
PROFILES = {"day": -1.0, "night": 1.0}  # log-profile b: A-LU (day), A-LD (night)


@dataclass(frozen=True)
class Study:
    """Sizes of the study: field grid (origin, spacing m; shape points) and launch fan (counts)."""

    grid_origin: tuple[float, float, float] = (-1400.0, -180.0, 1.0)
    grid_spacing: tuple[float, float, float] = (20.0, 20.0, 4.0)
    grid_shape: tuple[int, int, int] = (141, 19, 30)
    elevations: int = 121
    azimuths: int = 720
    bands_hz: tuple[int, ...] = (125, 250, 500, 1000, 2000)
    max_time_s: float = 4.5


FULL = Study()
# --quick: the same study on a coarse grid and a sparse fan (seconds; used by the test suite)
QUICK = Study(
    grid_origin=(-600.0, -100.0, 1.0),
    grid_spacing=(100.0, 100.0, 10.0),
    grid_shape=(13, 3, 8),
    elevations=61,
    azimuths=24,
    bands_hz=(500, 1000),
    max_time_s=2.0,
)


def study_job(period: str, study: Study = FULL) -> dict[str, Any]:
    """The job of one period (a job dict in the format of scenes/, see README)."""
    return {
        "name": f"ridge-{period}",
        "scene": {"builtin": "ridge", "resolution": "medium", "ground": {"kind": "flat"}},
        "profile": {"kind": "log", "c0": 340.0, "b": PROFILES[period], "z_g": 1.0},
        "sources": [{"position": list(SOURCE), "name": "crest", "power_db": {str(f): 100.0 for f in study.bands_hz}}],
        "rays": {
            "elevation_deg": {"min": -45, "max": 45, "count": study.elevations},
            "azimuth_deg": {"min": 0, "max": 360.0 * (1 - 1 / study.azimuths), "count": study.azimuths},
            "max_time_s": study.max_time_s,
            "max_reflections": 4,
        },
        "field": {
            "origin": list(study.grid_origin),
            "spacing": list(study.grid_spacing),
            "shape": list(study.grid_shape),
            "frequencies_hz": list(study.bands_hz),
            "mode": "incoherent",
            "heights": "above_ground",  # the map product: each column's points stand on the terrain under it
        },
        "outputs": ["field", "report"],
    }


@contextlib.contextmanager
def local_server() -> Iterator[str]:
    """A throw-away local service (2 job processes) on a free port; yields its URL."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with tempfile.TemporaryDirectory(prefix="bentray-study-") as data:
        env = {k: v for k, v in os.environ.items() if not k.startswith("BENTRAY_")}
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bentray.service",
                "serve",
                "--port",
                str(port),
                "--workers",
                "2",
                "--data-dir",
                data,
                "--log-level",
                "warning",
            ],
            env=env,
        )
        url = f"http://127.0.0.1:{port}"
        try:
            with BentrayClient(url) as client:
                for _ in range(600):
                    with contextlib.suppress(Exception):
                        client.health()
                        break
                    time.sleep(0.1)
            yield url
        finally:
            proc.terminate()
            proc.wait(30)


def level_above_ground(vti: Path, study: Study = FULL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x (nx,), y (ny,) and spl_a (nx, ny) in dB(A) at RECEIVER_HEIGHT_M above the terrain: the field's heights are
    above the ground (``field.heights = "above_ground"``), so the level is interpolated linearly between the two
    grid levels around that height in every column. (Until 2026-12-05 the grid stood at absolute heights and the
    interpolation took a point inside the ridge, whose level is NaN, wherever the terrain rose above a level.)"""
    import pyvista as pv

    grid = pv.read(vti)
    nx, ny, nz = study.grid_shape
    spl = np.asarray(grid.point_data["spl_a"], dtype=np.float64).reshape((nz, ny, nx)).transpose(2, 1, 0)
    origin, spacing = study.grid_origin, study.grid_spacing
    x = origin[0] + spacing[0] * np.arange(nx)
    y = origin[1] + spacing[1] * np.arange(ny)
    z = origin[2] + spacing[2] * np.arange(nz)  # heights above the ground
    k = int(np.clip(np.searchsorted(z, RECEIVER_HEIGHT_M) - 1, 0, nz - 2))
    w = (RECEIVER_HEIGHT_M - z[k]) / (z[k + 1] - z[k])
    return x, y, (1 - w) * spl[:, :, k] + w * spl[:, :, k + 1]


def plot(x: np.ndarray, y: np.ndarray, maps: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(10, 11), constrained_layout=True)
    extent = (x[0], x[-1], y[0], y[-1])
    finite = np.concatenate([m[np.isfinite(m)] for m in maps.values()])
    vmin, vmax = (np.percentile(finite, 2), np.percentile(finite, 99.5)) if finite.size else (0, 1)
    for ax, period in zip(axes[:2], ("day", "night"), strict=True):
        im = ax.imshow(
            maps[period].T, origin="lower", extent=extent, aspect="auto", vmin=vmin, vmax=vmax, cmap="viridis"
        )
        ax.set_title(f"{period} ({'A-LU' if period == 'day' else 'A-LD'}): L_A {RECEIVER_HEIGHT_M:g} m above ground")
        ax.set_ylabel("y (m)")
        fig.colorbar(im, ax=ax, label="dB(A)")
    diff = maps["night"] - maps["day"]
    im = axes[2].imshow(diff.T, origin="lower", extent=extent, aspect="auto", cmap="RdBu_r", vmin=-20, vmax=20)
    axes[2].set_title("night - day (blank: no level in one of the periods)")
    axes[2].set_ylabel("y (m)")
    fig.colorbar(im, ax=axes[2], label="dB")
    j = int(np.argmin(np.abs(y)))
    for period, style in (("day", "C0-"), ("night", "C3-")):
        axes[3].plot(x, maps[period][:, j], style, label=period)
    axes[3].set_xlabel("x (m)")
    axes[3].set_ylabel("L_A at y = 0 (dB(A))")
    axes[3].legend()
    axes[3].grid(True, alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--url", default=os.environ.get("BENTRAY_URL", "http://127.0.0.1:8000"))
    parser.add_argument("--key", default=os.environ.get("BENTRAY_API_KEY"))
    parser.add_argument("--out", default="results/day-night-ridge")
    parser.add_argument("--start-server", action="store_true", help="run a local service for the study")
    parser.add_argument("--quick", action="store_true", help="a coarse grid and a sparse fan (a smoke run)")
    args = parser.parse_args(argv)
    study = QUICK if args.quick else FULL
    out = Path(args.out)
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        url = stack.enter_context(local_server()) if args.start_server else args.url
        client = stack.enter_context(BentrayClient(url, api_key=args.key))
        ids = {period: client.submit(study_job(period, study)).id for period in PROFILES}  # both queued at once
        maps = {}
        for period, job_id in ids.items():
            info = client.wait(job_id, progress=True)
            if info.status != "succeeded":
                print(f"{period}: job {job_id} {info.status}: {info.error}", file=sys.stderr)
                return 1
            client.download(job_id, out / period)
            x, y, maps[period] = level_above_ground(out / period / "field.vti", study)
    plot(x, y, maps, out / "day_night_ridge.png")
    j = int(np.argmin(np.abs(y)))
    with open(out / "day_night_ridge.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["x_m", "terrain_z_m", "day_dBA", "night_dBA", "night_minus_day_dB"])
        for i, xi in enumerate(x):
            d, n = maps["day"][i, j], maps["night"][i, j]
            writer.writerow(
                [f"{xi:g}", f"{float(ridge_height(np.array(xi))):.2f}", f"{d:.2f}", f"{n:.2f}", f"{n - d:.2f}"]
            )
    covered = {p: float(np.mean(np.isfinite(m))) for p, m in maps.items()}
    print(
        f"wrote {out / 'day_night_ridge.png'} and {out / 'day_night_ridge.csv'} in {time.perf_counter() - t0:.1f} s; "
        f"map points reached: day {covered['day']:.0%}, night {covered['night']:.0%}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
