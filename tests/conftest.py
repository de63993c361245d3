"""Session-wide test setup.

bentray is imported before any test module imports numba: its import picks the numba cache folder
(keyed by the engine's source, see bentray/__init__.py) and numba reads it once, at its own import. A
module importing numba first (tests/acoustics/test_ground.py does) would leave this process on another
folder than the worker processes it spawns (tests/scale/test_dask.py), which then compile every kernel.
"""

import bentray  # noqa: F401
