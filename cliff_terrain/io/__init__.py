"""Reading and writing the field's files, by idea: ``photo`` (JPEG, PNG, TIFF photos, their metadata and
the camera's ground sampling distance), ``raster`` (GeoTIFF surface models and orthophotos, multispectral
bands, CRSs, affine maths, windows of mosaics) and ``vector`` (plot polygons, the plot grid's files,
GeoJSON, transects). Each subpackage names its public API in ``__all__``."""

__all__ = ["photo", "raster", "vector"]
