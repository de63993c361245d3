"""bentray: outdoor-acoustics curved-ray engine.

The import-time environment defaults below must run before numpy/numba load:
- ``NUMBA_CACHE_DIR``: kernels use ``cache=True``; a read-only checkout would otherwise fail at import.
- ``OPENBLAS_NUM_THREADS=1``: scipy's first ``Delaunay.find_simplex`` took over 100 s on the 2-core
  machines with OpenBLAS threading on. Users can still override both from the environment.
"""

from __future__ import annotations

import os
import tempfile

__version__ = "0.1.0"


def _default_numba_cache_dir() -> str:
    home_cache = os.path.join(os.path.expanduser("~"), ".cache", "bentray", "numba")
    try:
        os.makedirs(home_cache, exist_ok=True)
        if os.access(home_cache, os.W_OK):
            return home_cache
    except OSError:
        pass
    return os.path.join(tempfile.gettempdir(), "bentray-numba-cache")


os.environ.setdefault("NUMBA_CACHE_DIR", _default_numba_cache_dir())
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
