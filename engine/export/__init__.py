"""Noise-map exports from a finished field (``field.vti`` point arrays ``spl_*``, ``spl_a``).

Modules, one job each: :mod:`.field_grid` (read ``field.vti`` + georeference), :mod:`.slices` (2D maps:
a z index or a height above the ground), :mod:`.rasters` (GeoTIFF, ESRI ASCII + ``.prj``),
:mod:`.isophones` (GeoJSON level bands), :mod:`.facades` (facade receivers, point levels as GeoJSON /
CSV), :mod:`.exposure` (area and buildings per level class), :mod:`.lden` (Lden, meteorological
combination). The GIS libraries come from the ``gis`` extra (``pip install 'bentray[gis]'``).
"""
