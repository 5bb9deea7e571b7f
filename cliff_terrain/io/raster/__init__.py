"""Georeferenced rasters: GeoTIFF surface models and orthophotos (``geotiff``), multispectral bands
(``bands``), CRSs without an EPSG code (``crs``), affine pixel <-> map maths (``transform``) and windows of
orthomosaics larger than memory (``mosaic``); the GeoKeys and the TIFF windows are private helpers.
The names below are loaded when first used.
"""

from ..._lazy import attach

# Public name -> the module of this package that defines it (imported when the name is first used).
_EXPORTS = {
    "Bands": "bands",
    "GeoRaster": "geotiff",
    "MosaicReader": "mosaic",
    "UserCrs": "crs",
    "affine_inverse": "transform",
    "apply_affine": "transform",
    "as_affine": "transform",
    "is_multispectral": "bands",
    "pixel_size": "transform",
    "read_bands": "bands",
    "read_georeference": "geotiff",
    "read_orthophoto": "geotiff",
    "read_surface": "geotiff",
    "resample": "geotiff",
    "write_geotiff": "geotiff",
}

__getattr__, __dir__, __all__ = attach(__name__, _EXPORTS)
