"""GeoTIFF surface models (DSM/DTM) and orthophotos, with their georeference, and resampling between grids.

Photogrammetry tools (OpenDroneMap, Metashape, Pix4D) write float32 surface models and float or
8/16-bit orthophotos as GeoTIFFs: pixel-interleaved or planar, uncompressed, LZW or Deflate, tiled or
striped, with a GDAL_NODATA value (OpenDroneMap's -3.4e38 is not exactly a float32; tifffile warns).
tifffile reads the pixels (with imagecodecs for LZW/Deflate); the georeference comes from the
GeoTIFF tags: ModelPixelScale + ModelTiepoint or ModelTransformation, and the EPSG code of the
GeoKeys, parsed by :mod:`._geokeys` (the package's one GeoKey and GDAL_NODATA parser); the pixels
are read by :mod:`._tiff_window` (whole here, in windows for mosaics). Only projected CRSs in metres
are accepted: heights, areas and volumes are in metres.

Transforms map pixel (col, row) to map (x, y) with (0, 0) the top-left corner of the top-left
pixel, as 3x3 arrays (see :mod:`cliff_terrain.io.raster.transform`).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass

import numpy as np

from ..._threads import usable_cores
from ...errors import GeoreferenceError, RasterReadError
from ._geokeys import (
    GDAL_METADATA,
    GDAL_NODATA,
    GEO_ASCII_PARAMS,
    GEO_DOUBLE_PARAMS,
    GEO_KEY_DIRECTORY,
    METRE,
    MODEL_PIXEL_SCALE,
    MODEL_TIEPOINT,
    MODEL_TRANSFORMATION,
    check_metric_code,
    georeference,
    nodata_value,
    scale_offset,
)
from ._tiff_window import TiffRaster
from .bilinear import is_axis_aligned, on_grid, pixel_map
from .blocks import block_mean
from .crs import UserCrs, crs_text, user_geokeys
from .surface_values import check_scaled, surface_heights, zero_fill
from .transform import as_affine, grid_bounds, pixel_size


@dataclass
class GeoRaster:
    """A georeferenced raster.

    Attributes
    ----------
    data : (rows, cols) float32 or (rows, cols, 3) uint8 array
        Surface models: heights in metres, NaN where there is no data. Photos: RGB.
    transform : (3, 3) float64 array
        Pixel (col, row) -> map (x, y), (0, 0) being the top-left pixel's top-left corner.
    crs : int or UserCrs
        EPSG code of a projected CRS in metres, or a user-defined one (:mod:`.crs`).
    nodata : float or None
        The file's no-data value.
    path : str
        The file read.
    valid : (rows, cols) bool array or None
        Photos only: pixels with data (alpha or no-data value), None when all are.
    """

    data: np.ndarray
    transform: np.ndarray
    crs: int | UserCrs
    nodata: float | None
    path: str
    valid: np.ndarray | None = None

    @property
    def shape(self):
        return self.data.shape[:2]

    @property
    def pixel_size(self):
        """(x, y) size of a pixel in metres."""
        return pixel_size(self.transform)

    @property
    def pixel_area_m2(self):
        return float(abs(np.linalg.det(self.transform[:2, :2])))

    @property
    def bounds(self):
        """(xmin, ymin, xmax, ymax) of the raster's corners on the map."""
        return grid_bounds(self.transform, self.shape)


def read_surface(path):
    """Read a digital surface (or terrain) model GeoTIFF: one band of heights in metres.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    GeoRaster
        `data` is (rows, cols) float32 with NaN where the file has no data.

    Raises
    ------
    RasterReadError
        Missing or unreadable file, not one band, no georeference, an unknown CRS, or no data at all.
    GeoreferenceError
        A CRS in degrees or heights/coordinates in feet.

    Examples
    --------
    >>> import tempfile, os, tifffile
    >>> path = os.path.join(tempfile.mkdtemp(), "dsm.tif")
    >>> write_geotiff(path, np.full((4, 5), 100.0, np.float32), transform=[[0.5, 0, 1000], [0, -0.5, 2000]], crs=32616)
    >>> dsm = read_surface(path)
    >>> dsm.shape, dsm.crs, dsm.pixel_size, dsm.bounds
    ((4, 5), 32616, (0.5, 0.5), (1000.0, 1998.0, 1002.5, 2000.0))
    """
    name, array, tags = read_tiff(path)
    transform, crs = georeference(tags, name)
    if array.ndim == 3 and 1 in (array.shape[0], array.shape[2]):
        array = array.reshape(array.shape[1:] if array.shape[0] == 1 else array.shape[:2])
    elif array.ndim == 3:
        bands = array.shape[0] if tags.get("planar") else array.shape[2]
        raise RasterReadError(f"surface model {name!r} has {bands} bands, expected 1")
    if array.ndim != 2:
        raise RasterReadError(f"surface model {name!r} is not a single-band raster (shape {array.shape})")
    check_scaled(array.dtype, factors := scale_offset(tags.get(GDAL_METADATA)), name)
    nodata = nodata_value(tags.get(GDAL_NODATA), name)
    fill = zero_fill(array[[0, 0, -1, -1], [0, -1, 0, -1]], nodata=nodata)
    data = surface_heights(array, nodata=nodata, scale_offset=factors, zero_fill=fill)
    if np.isnan(data).all():
        raise RasterReadError(f"surface model {name!r} holds no data (every pixel is no-data)")
    return GeoRaster(data=data, transform=transform, crs=crs, nodata=nodata, path=name)


def read_orthophoto(path):
    """Read an orthophoto GeoTIFF as RGB uint8 with its georeference.

    Float photos in [0, 1] or [0, 255] (OpenDroneMap's, planar and tagged greyscale), 8- and
    16-bit ones, interleaved or planar; a fourth band is alpha. A multispectral orthomosaic
    (:mod:`.bands`) is rendered in true colour. Pixels that are no-data (or have
    zero alpha) are marked in `valid`.

    Returns
    -------
    GeoRaster
        `data` is (rows, cols, 3) uint8.
    """
    from .bands import is_multispectral, read_bands, rgb_rendering
    from .photo_samples import photo_bands

    # The header first: a multispectral file's pixels are decoded once, by read_bands.
    name, _, tags = read_tiff(path, pixels=False)
    transform, crs = georeference(tags, name)
    nodata = nodata_value(tags.get(GDAL_NODATA), name)
    if min(tags["samples"], *tags["size"]) >= 3 and is_multispectral(name):
        rgb, valid = rgb_rendering(read_bands(name))  # multispectral: a true-colour rendering
        return GeoRaster(data=rgb, transform=transform, crs=crs, nodata=nodata, path=name, valid=valid)
    _, array, _ = read_tiff(name)
    rgb, valid = photo_bands(array, name, nodata=nodata, planar=tags["planar"])
    return GeoRaster(data=rgb, transform=transform, crs=crs, nodata=nodata, path=name, valid=valid)


def read_georeference(path):
    """(3x3 transform, EPSG code) of a GeoTIFF from its tags alone (no pixel decoded)."""
    name, _, tags = read_tiff(path, pixels=False)
    return georeference(tags, name)


def read_tiff(path, *, pixels=True):
    """(name, samples or None, tags) of a TIFF's first image: its georeference and GDAL_NODATA tags,
    with ``"planar"``, ``"size"`` (rows, cols) and ``"samples"``; see :class:`cliff_terrain.io.raster._tiff_window.TiffRaster`."""
    with TiffRaster(path) as tiff:
        tags = dict(tiff.tags, planar=tiff.planar, size=tiff.shape, samples=tiff.samples)
        return tiff.path, (tiff.read() if pixels else None), tags


def raster_size(path):
    """(rows, cols) of a GeoTIFF from its header alone (no pixel decoded)."""
    _, _, tags = read_tiff(path, pixels=False)
    return tags["size"]


def check_same_crs(a, b):
    """Refuse two rasters in different CRSs, naming both."""
    if a.crs != b.crs:
        raise GeoreferenceError(
            f"{a.path!r} is in {crs_text(a.crs)} but {b.path!r} is in {crs_text(b.crs)}; reproject one"
        )


def overlap_fraction(transform_a, shape_a, transform_b, shape_b):
    """Fraction of grid a's bounding box that grid b's bounding box covers."""
    ax0, ay0, ax1, ay1 = grid_bounds(transform_a, shape_a)
    bx0, by0, bx1, by1 = grid_bounds(transform_b, shape_b)
    w = max(0.0, min(ax1, bx1) - max(ax0, bx0))
    h = max(0.0, min(ay1, by1) - max(ay0, by0))
    return w * h / max((ax1 - ax0) * (ay1 - ay0), 1e-300)


def resample(raster, *, transform, shape, crs=None, target="the target grid"):
    """A surface model resampled onto another grid (bilinear; NaN outside it and near no-data).

    Parameters
    ----------
    raster : GeoRaster
        A surface model (float32 data with NaN for no-data).
    transform : (2, 3) or (3, 3) array
        Pixel (col, row) -> map (x, y) of the target grid.
    shape : (int, int)
        (rows, cols) of the target grid.
    crs : int or UserCrs, optional
        CRS of the target grid; must be the raster's (a user-defined one: agree with it).
    target : str, optional
        Name of the target grid (a file) for error messages.

    Returns
    -------
    (rows, cols) float32 array

    Raises
    ------
    GeoreferenceError
        The CRSs differ or the grids do not overlap.

    Examples
    --------
    >>> dsm = GeoRaster(np.arange(4, dtype=np.float32).reshape(2, 2), as_affine([[2, 0, 0], [0, -2, 4]]), 32616, None, "a.tif")
    >>> resample(dsm, transform=[[1, 0, 0], [0, -1, 4]], shape=(4, 4))[1:3, 1:3]
    array([[0.75, 1.25],
           [1.75, 2.25]], dtype=float32)
    """
    import cv2

    t = as_affine(transform)
    rows, cols = (int(n) for n in shape)
    if crs is not None and crs != raster.crs:
        raise GeoreferenceError(
            f"{raster.path!r} is in {crs_text(raster.crs)} but {target} is in {crs_text(crs)}; reproject one"
        )
    if overlap_fraction(t, (rows, cols), raster.transform, raster.shape) <= 0.0:
        raise GeoreferenceError(f"{raster.path!r} does not overlap {target}")
    if np.allclose(t, raster.transform) and (rows, cols) == raster.shape:
        return raster.data.copy()
    m = pixel_map(raster.transform, t)  # target pixel -> source pixel, centres at integers
    source = raster.data
    scale = min(abs(np.linalg.det(m[:2, :2])) ** -0.5, 1e9)
    if scale < 0.5:
        # The target is much coarser: average the source first so bilinear sampling does not alias.
        factor = max(1, int(1.0 / scale))
        source = block_mean(source, factor)
        m = (
            np.array(
                [[1.0 / factor, 0, 0.5 / factor - 0.5], [0, 1.0 / factor, 0.5 / factor - 0.5], [0, 0, 1]]
            )
            @ m
        )
    if is_axis_aligned(m):
        # North-up grids: exact weights, the numbers the windowed measure reads window by window.
        return on_grid(lambda r0, r1, c0, c1: source[r0:r1, c0:c1], source.shape, m, 0, rows, 0, cols)
    out = cv2.warpAffine(  # a rotated grid (OpenCV rounds its coordinates to 1/32 pixel)
        source,
        m[:2].astype(np.float64),
        (cols, rows),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=float("nan"),
    )
    return out


def geotiff_tags(transform, crs, *, nodata=None):
    """tifffile ``extratags`` of a GeoTIFF's georeference (and GDAL_NODATA): what :func:`write_geotiff`
    writes, and what :mod:`cliff_terrain.measure.windowed` writes window by window."""
    t = as_affine(transform)
    if t[0, 1] == 0.0 and t[1, 0] == 0.0 and t[0, 0] > 0 and t[1, 1] < 0:
        geo = [
            (MODEL_PIXEL_SCALE, 12, 3, (t[0, 0], -t[1, 1], 0.0), True),
            (MODEL_TIEPOINT, 12, 6, (0.0, 0.0, 0.0, t[0, 2], t[1, 2], 0.0), True),
        ]
    else:
        matrix = (t[0, 0], t[0, 1], 0.0, t[0, 2], t[1, 0], t[1, 1], 0.0, t[1, 2], 0, 0, 0, 0, 0, 0, 0, 1)
        geo = [(MODEL_TRANSFORMATION, 12, 16, tuple(float(v) for v in matrix), True)]
    if isinstance(crs, UserCrs):
        keys, doubles, text = user_geokeys(crs)
        geo += [(GEO_DOUBLE_PARAMS, 12, len(doubles), doubles, True), (GEO_ASCII_PARAMS, 2, 0, text, True)]
    else:
        # A geographic code is no projected CRS; one in feet keeps the metre key it was read with.
        check_metric_code(int(crs), f"`crs` {crs!r}", linear=False)
        keys = (1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, int(crs), 3076, 0, 1, METRE)
    extratags = [*geo, (GEO_KEY_DIRECTORY, 3, len(keys), keys, True)]
    if nodata is not None:
        extratags.append((GDAL_NODATA, 2, 0, ("nan" if math.isnan(nodata) else repr(float(nodata))), True))
    return extratags


def write_geotiff(path, data, *, transform, crs, nodata=None, overviews=False):
    """Write a float32 (or other) single-band GeoTIFF with a georeference, atomically.

    The file is written beside `path` under a temporary name and renamed, so a failure never
    leaves a half-written raster. NaN stays NaN; `nodata` (e.g. ``float('nan')``) is recorded as
    GDAL_NODATA. The transform must be north-up (no rotation) for the scale/tie-point tags; a
    rotated one is written as a ModelTransformation.

    With `overviews`, the layout a GIS opens quickly (GDAL's COG driver's, as far as tifffile
    writes it): 512 x 512 tiles, Deflate with the floating-point (or horizontal) predictor, and
    reduced-resolution images (NewSubfileType 1, which GDAL and QGIS use as overviews) halving the
    size until one tile holds it, each the mean of the valid pixels below it. Unlike a strict COG,
    each image's directory sits before its own tiles, not all at the file's head: fast from a disk,
    ``gdal_translate -of COG`` rewrites it for reading over HTTP.
    """
    import tifffile

    data = np.asarray(data)
    extratags = geotiff_tags(transform, crs, nodata=nodata)
    path = os.fspath(path)
    tmp = f"{path}.part-{os.getpid()}"
    try:
        if overviews:
            _write_tiled_with_overviews(tmp, data, extratags)
        else:
            tifffile.imwrite(tmp, data, extratags=extratags, compression="zlib" if data.size > 4096 else None)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


# GDAL's COG driver's default block size.
COG_TILE = 512
# Deflate's fastest level (GDAL's ZLEVEL=1): on a CHM with the floating-point predictor it writes
# files 6 % larger than level 6 in half the time, and writing was a third of a windowed run.
DEFLATE_LEVEL = 1
#: How the CHM-like rasters are written: tiled, Deflate with the floating-point predictor.
COG_OPTIONS = dict(
    tile=(COG_TILE, COG_TILE),
    compression="zlib",
    compressionargs={"level": DEFLATE_LEVEL},
    predictor=True,
    photometric="minisblack",
)
# What tifffile holds of tiles waiting for the compressing threads (its default, 256 MiB, would be
# the biggest thing a windowed run holds while writing).
WRITE_BUFFER = 64 * 2**20


@functools.cache
def _writer_takes_buffersize():
    # TiffWriter.write takes `buffersize` since tifffile 2024; the oldest supported (2023.7.10, the
    # bpy 4.2 pins) has the same buffer but no parameter for it.
    import inspect

    import tifffile

    return "buffersize" in inspect.signature(tifffile.TiffWriter.write).parameters


def write_buffer_bytes():
    """The bytes tifffile holds of tiles waiting to be compressed, with :func:`cog_options`."""
    if _writer_takes_buffersize():
        return WRITE_BUFFER
    import tifffile

    return int(tifffile.TIFF.BUFFERSIZE)


def cog_options():
    """:data:`COG_OPTIONS`, the tiles compressed on every usable core.

    tifffile compresses on half the cores by default: on one of two, where writing the rasters
    was a third of a windowed run. Each tile is compressed by itself, so the bytes are the same.
    The tiles waiting for the threads are capped at :data:`WRITE_BUFFER` where tifffile lets us
    (see :func:`write_buffer_bytes`).
    """
    options = dict(COG_OPTIONS, maxworkers=usable_cores())
    if _writer_takes_buffersize():
        options["buffersize"] = WRITE_BUFFER
    return options


def _write_tiled_with_overviews(path, data, extratags):
    import tifffile

    with tifffile.TiffWriter(path, bigtiff=data.nbytes > 2**31) as tif:
        tif.write(data, extratags=extratags, **cog_options())
        level = data
        while max(level.shape[:2]) > COG_TILE:
            level = (
                block_mean(level.astype(np.float32), 2).astype(data.dtype)
                if data.dtype.kind == "f"
                else level[::2, ::2]
            )
            tif.write(level, subfiletype=1, **cog_options())
