"""Issue 17: the desert example renders over the terrain-following mesh (slow: the 1.2M-cell mesh of the
V-IM profile takes 15-45 s to build on 2 cores). Under V-IM the camera 40 m up, looking 35 degrees down,
sees the dunes in the lower image and the mirage's sky over the crests; no ray is lost."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bentray.engine.render.image import render_job
from bentray.scenes.schema import Job

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_desert_inferior_mirage_renders_ground_and_mirage_sky():
    spec = json.loads((REPO / "scenes" / "examples" / "desert-mirage-inferior.json").read_text())
    spec["camera"].update({"width": 32, "height": 24})
    out = render_job(Job.model_validate(spec), REPO)
    assert out.stats["mesh"] == "terrain" and out.stats["lost"] == 0
    assert out.hit[-1].all()  # the bottom row (55 degrees down) sees the dunes
    sky_rows = (~out.hit).any(axis=1)
    assert sky_rows[: out.hit.shape[0] // 2].any()  # and the upper half shows the mirage's sky
    assert (out.direction[~out.hit][:, 2] > 0).all()
