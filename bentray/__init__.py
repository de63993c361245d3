"""bentray: outdoor-acoustics curved-ray engine.

The import-time environment defaults below must run before numpy/numba load:
- ``NUMBA_CACHE_DIR``: kernels use ``cache=True``; a read-only checkout would otherwise fail at import.
  The folder (default under ~/.cache/bentray, or a subfolder of the user's NUMBA_CACHE_DIR) is keyed by
  a hash of the engine's source: numba invalidates a cached kernel when
  its own file changes but not when a function it calls from another module does, so an upgrade or an
  edit could otherwise run stale machine code (this happened here with the ground-reflection table).
- ``OPENBLAS_NUM_THREADS=1``: scipy's first ``Delaunay.find_simplex`` took over 100 s on the 2-core
  machines with OpenBLAS threading on. Users can still override both from the environment.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

__version__ = "0.1.0"


def _engine_source_key() -> str:
    """Short hash of the engine source files that hold compiled code (those that mention njit or intrinsic; about
    1 ms): the numba cache folder's name. Plain-Python modules (orchestration, bench, I/O, even those that
    call numba.get_num_threads) do not count, so editing them does not recompile the kernels."""
    engine = Path(__file__).resolve().parent.parent / "engine"
    if not engine.is_dir():  # installed layout: bentray/engine
        engine = Path(__file__).resolve().parent / "engine"
    digest = hashlib.sha1(__version__.encode())
    for path in sorted(engine.rglob("*.py")):
        text = path.read_bytes()
        if b"njit" in text.lower() or b"intrinsic" in text:  # jitted code, or code generated into it
            digest.update(str(path.relative_to(engine)).encode())
            digest.update(text)
    return digest.hexdigest()[:12]


def _default_numba_cache_dir() -> str:
    home_cache = os.path.join(os.path.expanduser("~"), ".cache", "bentray", "numba", _engine_source_key())
    try:
        os.makedirs(home_cache, exist_ok=True)
        if os.access(home_cache, os.W_OK):
            return home_cache
    except OSError:
        pass
    return os.path.join(tempfile.gettempdir(), "bentray-numba-cache", _engine_source_key())


def _keyed_numba_cache_dir() -> str:
    """The cache folder numba will use: a user-set NUMBA_CACHE_DIR gets the engine-source key appended
    (once), so a changed kernel dependency can never load stale machine code from it either."""
    given = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if not given:
        return _default_numba_cache_dir()
    key = _engine_source_key()
    if os.path.basename(os.path.normpath(given)) == key:
        return given
    return os.path.join(given, key)


if "numba" not in __import__("sys").modules:  # numba reads NUMBA_CACHE_DIR when it is first imported
    os.environ["NUMBA_CACHE_DIR"] = _keyed_numba_cache_dir()
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
