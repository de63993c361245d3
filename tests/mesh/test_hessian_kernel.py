"""engine/mesh/hessian_kernel.py against the batched-numpy formulas it replaced (tests/reference/hessian_numpy.py).

Meshes: slabs of a quadratic profile (boxes: 8 of 20 vertex slots), a tetrahedral mesh of a quadratic field with
boundary cells, and the same tetrahedra with one cell's planes made unbounding (the error). The two differ in
rounding only (Cramer's rule against LAPACK's factorised solve, sums in another order): measured, the Hessians
agree to 3.2e-12 of each cell's largest entry on the tet mesh (the stated tolerance is 1e-9), the centroids to
1e-11 m; the consultant example's 1.76 million tetrahedra (too large for this suite) to 2.8e-10 at worst
(engine/mesh/hessian_kernel.py).
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.hessian import cell_hessians
from bentray.engine.mesh.slabs import build_slab_mesh
from bentray.engine.mesh.tets import build_tet_mesh
from tests.reference.hessian_numpy import cell_hessians_numpy, cell_vertices, face_areas


def _tets() -> CellMesh:
    rng = np.random.default_rng(5)
    lo, hi = np.zeros(3), np.array([40.0, 30.0, 20.0])

    def field(p: np.ndarray) -> np.ndarray:
        return 1.0 + 0.01 * p[:, 2] + 0.003 * p[:, 2] ** 2 + 0.001 * p[:, 0] * p[:, 1] - 2e-4 * p[:, 1] ** 2

    return build_tet_mesh(lo, hi, rng.uniform(lo + 0.5, hi - 0.5, (2500, 3)), field).cells


def _close(got: np.ndarray, want: np.ndarray, rel: float) -> float:
    """Largest |got - want| per cell over the cell's largest |want| entry (Hessian columns 0..5)."""
    scale = np.maximum(np.abs(want[:, :6]).max(axis=1), 1e-300)
    worst = float((np.abs(got[:, :6] - want[:, :6]).max(axis=1) / scale).max())
    assert worst <= rel, worst
    return worst


def test_tet_mesh_matches_the_numpy_formulas() -> None:
    mesh = _tets()
    got, want = cell_hessians(mesh), cell_hessians_numpy(mesh)
    _close(got, want, 1e-9)
    np.testing.assert_allclose(got[:, 6:9], want[:, 6:9], rtol=0.0, atol=1e-9)
    # the areas too (the kernel's are the volumes' source)
    from bentray.engine.mesh.hessian_kernel import cell_geometry

    _, areas, _, _, _, _, _ = cell_geometry(mesh.planes, mesh.neighbours, mesh.gradient)
    pts, valid = cell_vertices(mesh)
    np.testing.assert_allclose(areas, face_areas(mesh, pts, valid), rtol=1e-9, atol=1e-12)


def test_slab_mesh_matches_the_numpy_formulas() -> None:
    rng = np.random.default_rng(2)
    z = np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 3.0, 40))])
    mesh = build_slab_mesh(
        np.array([-50.0, -50.0, 0.0]), np.array([50.0, 50.0, z[-1]]), z, lambda zz: 1.0 - 3e-3 * zz + 2.5e-5 * zz**2
    )
    got, want = cell_hessians(mesh), cell_hessians_numpy(mesh)
    _close(got, want, 1e-9)
    np.testing.assert_allclose(got[:, 6:9], want[:, 6:9], rtol=0.0, atol=1e-9)


def test_a_cell_without_a_vertex_is_an_error() -> None:
    mesh = _tets()
    planes = mesh.planes.copy()
    planes[7, :, 3] = -1e6 * (1.0 + np.arange(planes.shape[1]))  # offsets no point satisfies together
    with pytest.raises(ValueError, match="no vertex"):
        cell_hessians(mesh._replace(planes=planes))
