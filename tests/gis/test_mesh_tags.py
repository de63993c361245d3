"""mesh.vtu says which material each reflecting face carries (issue 14: material/zone tags on mesh faces)
and rays.vtp carries its status legend: a DEM with buildings, the mesh written and read back with pyvista."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bentray.engine.run import run_job
from bentray.engine.writers import write_outcome
from bentray.scenes.schema import Job
from tests.diffraction.test_consultant_mini import _inputs


def test_mesh_vtu_tags_reflecting_materials(tmp_path: Path) -> None:
    import pyvista as pv

    _inputs(tmp_path)
    job = {
        "name": "mesh-tags",
        "scene": {
            "domain": {"min": [10, 10, 0], "max": [600, 600, 200]},
            "terrain": {"file": "dem.asc", "material": "grass"},
            "materials": [{"name": "grass", "flow_resistivity": 200000.0}],
            "buildings": {"file": "buildings.geojson"},  # rigid walls and roofs
        },
        "profile": {"kind": "homogeneous"},
        "sources": [{"position": [80, 300], "height_above_ground_m": 3.0}],
        "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 0.5, "max_reflections": 2},
        "outputs": ["mesh", "rays", "paths", "report"],
    }
    out = run_job(Job.model_validate(job), base_dir=tmp_path)
    write_outcome(out, job["outputs"], tmp_path / "out")
    grid = pv.read(tmp_path / "out" / "mesh.vtu")
    tags = np.asarray(grid.cell_data["reflecting_material"])
    legend = str(grid.field_data["reflecting_material_legend"][0])
    names = [m["name"] for m in job["scene"]["materials"]]
    assert "-1 no reflecting face" in legend and all(n in legend for n in names)
    used = set(np.unique(tags).tolist())
    assert -1 in used and len(used - {-1}) >= 2  # interior cells, grass ground and rigid buildings
    assert np.count_nonzero(tags >= 0) < tags.size // 2
    rays = pv.read(tmp_path / "out" / "rays.vtp")
    assert "exited" in str(rays.field_data["status_legend"][0])
