"""Optional GIS dependencies (the ``gis`` extra: shapely, pyproj, rasterio, contourpy).

Every module that needs one of them imports it through :func:`require`, so a missing package is one clear
error naming the extra to install instead of a bare ``ModuleNotFoundError`` deep in a reader.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from bentray.engine.errors import BentrayError

__all__ = ["GIS_EXTRA", "GisDependencyError", "require"]

GIS_EXTRA = "gis"
_PIP_NAME = {"shapely": "shapely", "pyproj": "pyproj", "rasterio": "rasterio", "contourpy": "contourpy"}


class GisDependencyError(BentrayError, ImportError):
    """A package of the ``gis`` extra is not installed."""


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` (e.g. ``"shapely"``, ``"rasterio.transform"``) or raise GisDependencyError saying
    which package of the ``gis`` extra is missing and what it is needed for (``purpose``)."""
    top = module.split(".")[0]
    try:
        return importlib.import_module(module)
    except ImportError:
        package = _PIP_NAME.get(top, top)
        raise GisDependencyError(
            f"{purpose} needs the {package!r} package of the {GIS_EXTRA!r} extra: "
            f"pip install 'bentray[{GIS_EXTRA}]' (or pip install {package})"
        ) from None
