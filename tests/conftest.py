"""Session-wide test setup.

bentray is imported before any test module imports numba: its import picks the numba cache folder
(keyed by the engine's source, see bentray/__init__.py) and numba reads it once, at its own import. A
module importing numba first (tests/acoustics/test_ground.py does) would leave this process on another
folder than the worker processes it spawns (tests/scale/test_dask.py), which then compile every kernel.
"""

import bentray  # noqa: F401


def _engine_indexes_naming_tests() -> list[str]:
    """Numba cache indexes of engine kernels whose signatures name a type defined under tests/.

    A cached engine kernel called by a test with a test-defined type (a stand-in namedtuple for a BeamGrid, say)
    keeps that signature in its cache index, and every later process that loads the kernel (the CLI, the
    service's workers, subprocess tests) must unpickle it and fails with "No module named 'tests'". Tests pass
    the engine's own structs instead."""
    import os
    from pathlib import Path

    import bentray.engine

    cache = Path(os.environ.get("NUMBA_CACHE_DIR", ""))
    if not cache.is_dir():
        return []
    engine = {p.stem for p in Path(bentray.engine.__file__).parent.rglob("*.py")} - {"__init__"}
    return sorted(
        str(index)
        for index in cache.rglob("*.nbi")
        if index.name.split(".", 1)[0] in engine and b"tests." in index.read_bytes()
    )


def pytest_sessionfinish(session, exitstatus):  # type: ignore[no-untyped-def]
    bad = _engine_indexes_naming_tests()
    if bad:
        print("\nengine kernels cached with test-defined types (delete these files; pass engine structs):")
        for path in bad:
            print(f"  {path}")
        session.exitstatus = 1
