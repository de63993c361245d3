"""engine.mesh is below the scene schema: it imports nothing from bentray.scenes; its box search and
closed-surface checks are the engine's own (engine/mesh/boxes.py, engine/mesh/surface_checks.py)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from bentray.engine.mesh.boxes import CandidateLimitError, box_pairs
from bentray.engine.mesh.surface_checks import basic_mesh_problem, closed_mesh_problem

MESH_DIR = Path(__file__).resolve().parents[2] / "engine" / "mesh"


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return names


def test_engine_mesh_imports_nothing_from_the_scene_layer():
    files = sorted(MESH_DIR.glob("*.py"))
    assert len(files) > 5  # the check looks at the real package
    offenders = {p.name: sorted(m for m in _imports(p) if m.startswith("bentray.scenes")) for p in files}
    assert {k: v for k, v in offenders.items() if v} == {}


@pytest.mark.parametrize("dim", [2, 3])
def test_engine_box_pairs_matches_brute_force(dim):
    rng = np.random.default_rng(10 + dim)
    lo = rng.uniform(0, 100, (300, dim))
    hi = lo + rng.uniform(0, 8, (300, dim)) ** 2 / 8
    hi[:5] = lo[:5] + 60.0  # a few large boxes
    hi[5] = lo[5]  # a point
    ia, ib = box_pairs(lo, hi)
    overlap = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    assert set(zip(ia.tolist(), ib.tolist(), strict=True)) == set(zip(*np.nonzero(np.triu(overlap, 1)), strict=True))
    pa, pb = box_pairs(lo[:50], hi[:50], lo[50:], hi[50:])
    assert set(zip(pa.tolist(), pb.tolist(), strict=True)) == set(zip(*np.nonzero(overlap[:50, 50:]), strict=True))
    assert issubclass(CandidateLimitError, ValueError)


def _cube() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]  # outward
    f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return v, f


def test_closed_surface_checks_accept_a_cube_and_name_what_is_wrong():
    v, f = _cube()
    assert basic_mesh_problem(v, f) is None
    assert closed_mesh_problem(v, f) is None
    assert "not watertight" in closed_mesh_problem(v, f[:-1])
    assert "signed volume" in closed_mesh_problem(v, f[:, ::-1].copy())  # inward normals
    assert "same vertex twice" in basic_mesh_problem(v, np.vstack([f, [[0, 0, 1]]]))
