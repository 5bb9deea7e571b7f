"""The one exception family of Cliff Terrain, so callers (the Blender UI, the CLI) can catch precisely."""


class CliffTerrainError(ValueError):
    """Raised for any bad input or setting that Cliff Terrain refuses.

    It subclasses :class:`ValueError` so generic callers still see a value problem; the message
    always names the parameter (or file) and the value received.
    """


class ImageReadError(CliffTerrainError):
    """An image file is missing, unreadable, truncated, or not an image."""


class ImageTooLargeError(CliffTerrainError):
    """An image would decode past the documented memory limit and cannot be reduced."""


class DependencyError(CliffTerrainError, ImportError):
    """A library Cliff Terrain needs is missing, too old, or lacks an API: the environment, not the data.

    The message names the package and its version. It is also an :class:`ImportError`, so code that
    guards an import (the Blender add-on does) catches it as one.
    """


class RasterReadError(CliffTerrainError):
    """A surface model or orthophoto GeoTIFF is missing, unreadable, or lacks a usable georeference."""


class TruncatedFileError(CliffTerrainError):
    """A file cut short (a copy or download interrupted): copying or exporting it again mends it.

    Raised as :class:`TruncatedImageError` or :class:`TruncatedRasterError`, so a caller that catches
    the reading error of its kind catches this one too.
    """


class TruncatedImageError(TruncatedFileError, ImageReadError):
    """An image (photo or mosaic) file cut short."""


class TruncatedRasterError(TruncatedFileError, RasterReadError):
    """A surface model or orthophoto GeoTIFF cut short."""


class GeoreferenceError(CliffTerrainError):
    """Rasters or plots that cannot be put on one map: other CRSs, no overlap, feet or degrees."""


class PlotFileError(CliffTerrainError):
    """A plot polygon file (GeoJSON or ESRI Shapefile) is missing, broken, empty or not polygons."""


class GroundError(CliffTerrainError):
    """Too little exposed soil to estimate the ground under the crop from one flight: give a DTM."""


class MissingBandError(CliffTerrainError):
    """A vegetation index needs a band the multispectral file lacks (the message names both)."""


class RulerError(CliffTerrainError):
    """A ruler file (measured plot heights) that cannot be read or matched to the plots."""
