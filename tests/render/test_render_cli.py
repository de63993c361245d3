"""Issue 17: ``bentray render JOB.json --out IMAGE.png`` and the bounded ``camera`` of the job schema."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bentray.clients.cli import main
from bentray.scenes.camera_models import MAX_PIXELS


def _job(tmp_path, camera: dict | None, profile: str = "homogeneous") -> str:
    spec = {
        "name": "render-cli",
        "scene": {"domain": {"min": [0, -25, 0], "max": [400, 25, 50]}},
        "profile": {"kind": profile},
        "sources": [{"position": [2, 0, 2]}],
        "rays": {"elevation_deg": {"min": 0, "max": 0, "count": 1}, "max_time_s": 5.0, "max_reflections": 0},
    }
    if camera is not None:
        spec["camera"] = camera
    path = tmp_path / "job.json"
    path.write_text(json.dumps(spec))
    return str(path)


CAMERA = {"position": [2, 0, 2], "look_at": [400, 0, 2], "fov_deg": 30, "width": 32, "height": 24}


def test_render_writes_the_png_and_its_stats(tmp_path, capsys):
    import matplotlib.image

    out = tmp_path / "img.png"
    assert main(["render", _job(tmp_path, CAMERA), "--out", str(out), "--width", "40"]) == 0
    img = matplotlib.image.imread(out)
    assert img.shape[:2] == (24, 40)
    stats = json.loads(out.with_suffix(".json").read_text())
    assert stats["pixels"] == 960 and stats["surface"] + stats["sky"] == 960 and stats["device"] == "cpu"
    # sky on top (bluish: blue > red), ground at the bottom (warm grey: red > blue)
    assert img[0, 20, 2] > img[0, 20, 0] and img[-1, 20, 0] > img[-1, 20, 2]
    assert "render render-cli: 960 rays" in capsys.readouterr().out


def test_render_without_a_camera_names_the_field(tmp_path, capsys):
    assert main(["render", _job(tmp_path, None), "--out", str(tmp_path / "x.png")]) == 2
    assert "camera: the job has no camera" in capsys.readouterr().err


@pytest.mark.parametrize(
    "update, message",
    [
        (
            {"width": 4096, "height": 4096},
            f"camera: width x height = 16,777,216 pixels is over the limit of {MAX_PIXELS:,}",
        ),
        ({"width": 5000}, "camera.width: Input should be less than or equal to 4096"),
        ({"up": [1, 0, 0]}, "camera: up must not be parallel to the view direction"),
        ({"look_at": [2, 0, 2]}, "camera: look_at must differ from position"),
        ({"fov_deg": 179}, "camera.fov_deg: Input should be less than or equal to 170"),
        ({"position": [2, 0, 1e300]}, "camera.position.2: Input should be less than or equal to"),
    ],
)
def test_camera_is_bounded_with_errors_naming_the_field(tmp_path, capsys, update, message):
    assert main(["render", _job(tmp_path, {**CAMERA, **update}), "--out", str(tmp_path / "x.png")]) == 2
    assert message in capsys.readouterr().err


def test_camera_below_the_ground_or_outside_the_mesh_is_refused(tmp_path, capsys):
    below = {**CAMERA, "position": [2, 0, -1]}
    assert main(["render", _job(tmp_path, below), "--out", str(tmp_path / "x.png")]) == 2
    assert "camera.position: z=-1 m is not above the ground" in capsys.readouterr().err
    outside = {**CAMERA, "position": [2, 80, 2]}
    assert main(["render", _job(tmp_path, outside), "--out", str(tmp_path / "x.png")]) == 2
    assert (
        "camera.position: [2.0, 80.0, 2.0] is not strictly inside the domain [0, -25, 0] to [400, 25, 50]"
        in capsys.readouterr().err
    )


def test_pixel_directions_follow_the_pinhole_model():
    from bentray.engine.render.camera import pixel_directions
    from bentray.scenes.camera_models import Camera

    cam = Camera(position=(0, 0, 0), look_at=(10, 0, 0), fov_deg=90.0, width=2, height=2)
    d = pixel_directions(cam)
    # fov 90: tan(45) = 1; pixel centres at +-1/2 of the half-extent, right = -y for a +x view with z up
    expected = np.array([[1, 0.5, 0.5], [1, -0.5, 0.5], [1, 0.5, -0.5], [1, -0.5, -0.5]])
    np.testing.assert_allclose(d, expected / np.linalg.norm(expected, axis=1)[:, None], atol=1e-15)
