"""The field's ground-reflection table against the mesh's face materials (issue 18).

The field kernel reads q2tab[material, band, ...] without a bounds check; a FieldBuffers built with fewer
materials than the mesh's reflecting faces use used to read foreign memory inside ``trace()``: with the
check bypassed, material index 100,000,000 ends the process with SIGSEGV (exit -11, measured). The wrapper
now refuses such a call with a MaterialTableError naming both counts. The trace runs in a subprocess, so a
crash fails the test instead of killing pytest.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from bentray.engine.errors import MaterialTableError
from bentray.engine.field_buffers import FieldBuffers, FieldGrid
from bentray.engine.mesh.slabs import build_slab_mesh
from bentray.engine.tracer import check_material_table

_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    from bentray.engine.errors import MaterialTableError
    from bentray.engine.field import tag_ground_material
    from bentray.engine.field_buffers import FieldBuffers, FieldGrid
    from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
    from bentray.engine.tracer import trace

    material, n_mat = int(sys.argv[1]), int(sys.argv[2])
    z = np.array([0.0, 100.0])
    mesh = build_slab_mesh(np.array([-50.0, -50.0, 0.0]), np.array([500.0, 50.0, 100.0]), z, lambda z: 1.0 + 0 * z)
    mesh = tag_ground_material(mesh, 0.0, material)
    grid = FieldGrid(origin=np.array([0.0, 0.0, 1.0]), spacing=np.array([10.0, 10.0, 5.0]), shape=(40, 2, 4))
    o = np.array([[0.0, 0.0, 10.0]])
    d = np.array([[1.0, 0.0, -0.3]])
    buf = FieldBuffers("incoherent", grid, np.ones((1, 1)), np.zeros(1), np.zeros(1, np.int64),
                       np.ones((n_mat, 1, 4, 4)), np.array([np.log(1e-3), 1.0, 0.0, 1.2, 1e-3]), 5.0, 1)
    try:
        trace(mesh, "parabolic", 340.0, o, d, locate_in_slabs(z, o), max_time_s=1.0, max_reflections=3, field=buf)
    except MaterialTableError as exc:
        print("REFUSED", exc)
        sys.exit(0)
    print("TRACED")
    """
)


@pytest.mark.parametrize(("material", "n_mat"), [(2, 2), (100_000_000, 1)])
def test_fewer_materials_than_the_mesh_is_refused_not_a_crash(material: int, n_mat: int) -> None:
    proc = subprocess.run(
        [sys.executable, "-c", _SCRIPT, str(material), str(n_mat)], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, f"the trace crashed (exit {proc.returncode}): {proc.stderr[-2000:]}"
    assert proc.stdout.startswith("REFUSED"), proc.stdout
    assert f"use {material + 1} materials" in proc.stdout
    assert f"ground table has {n_mat}" in proc.stdout


def _mesh_and_buffers(material: int, n_mat: int, band_of: np.ndarray | None = None):
    from bentray.engine.field import tag_ground_material

    z = np.array([0.0, 100.0])
    mesh = build_slab_mesh(np.array([-50.0, -50.0, 0.0]), np.array([500.0, 50.0, 100.0]), z, lambda z: 1.0 + 0 * z)
    mesh = tag_ground_material(mesh, 0.0, material)
    grid = FieldGrid(origin=np.zeros(3), spacing=np.ones(3), shape=(2, 2, 2))
    bands = np.zeros(1, np.int64) if band_of is None else band_of
    q2ax = np.array([np.log(1e-3), 1.0, 0.0, 1.2, 1e-3])
    buf = FieldBuffers(
        "incoherent", grid, np.ones((1, len(bands))), np.zeros(len(bands)), bands, np.ones((n_mat, 2, 4, 4)), q2ax, 1, 1
    )
    return mesh, buf


def test_a_table_with_every_material_passes_and_one_short_names_both_counts() -> None:
    mesh, buf = _mesh_and_buffers(material=3, n_mat=4)
    check_material_table(mesh, buf)  # indices 0..3, four rows: fine
    mesh, buf = _mesh_and_buffers(material=3, n_mat=3)
    with pytest.raises(
        MaterialTableError, match=r"use 4 materials \(indices 0\.\.3\) but the field's ground table has 3"
    ):
        check_material_table(mesh, buf)


def test_a_band_past_the_table_is_refused() -> None:
    mesh, buf = _mesh_and_buffers(material=0, n_mat=1, band_of=np.array([0, 2], np.int64))
    with pytest.raises(MaterialTableError, match="band index 2 but the ground table has 2 bands"):
        check_material_table(mesh, buf)
