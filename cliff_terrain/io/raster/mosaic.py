"""Windows of a GeoTIFF orthomosaic larger than memory, decoding only the TIFF tiles a window overlaps.

A whole farm's orthomosaic has hundreds of megapixels. :class:`MosaicReader` reads any window of a
*tiled* GeoTIFF by decoding only the TIFF tiles it overlaps (one at a time), so memory follows the
window, not the image, and an overview of the whole mosaic with every TIFF tile decoded once. A
striped (untiled) GeoTIFF cannot be read that way; above `max_striped_pixels` it is refused with
the command that tiles it. The relief is built tile by tile from it in
:mod:`cliff_terrain.mosaic.tiles`.
"""

from __future__ import annotations

import math

import numpy as np

from ..._validate import check_int
from ...errors import CliffTerrainError, ImageReadError, ImageTooLargeError
from ._geokeys import GDAL_NODATA, georeference, nodata_value
from ._tiff_window import TiffRaster
from .geotiff import black_corner, photo_bands

# A striped GeoTIFF is decoded whole: above this many pixels (a 12-bit 150 MP RGB image is 0.9 GB
# decoded) it is refused with the command that tiles it.
MAX_STRIPED_PIXELS = 150_000_000
# The overview that fixes the threshold: at most this many pixels.
OVERVIEW_PIXELS = 4_000_000


class MosaicReader:
    """Windows of a GeoTIFF orthomosaic, decoding only the TIFF tiles a window overlaps.

    Parameters
    ----------
    path : str or os.PathLike
        A GeoTIFF (or plain TIFF) with RGB(A) samples, uint8, uint16 or float.
    max_striped_pixels : int, optional
        A striped (untiled) TIFF up to this many pixels is decoded whole and served from memory;
        above it is refused (:class:`ImageTooLargeError`) with how to tile it.
    black_collar : bool, optional
        Take exact black for no data when a corner of the file is exact black and it has neither
        alpha nor a declared no-data value (a mosaic's collar, as :func:`.geotiff.photo_bands` does
        for a file read whole). The windowed heights read so; Import Mosaic's tiles do not yet.

    Examples
    --------
    >>> with MosaicReader(path) as mosaic:  # doctest: +SKIP
    ...     rgb, valid = mosaic.read(0, 512, 0, 512)
    """

    def __init__(self, path, *, max_striped_pixels=MAX_STRIPED_PIXELS, black_collar=False):
        max_striped_pixels = check_int("max_striped_pixels", max_striped_pixels, minimum=1)
        self.raster = TiffRaster(path, what="mosaic", error=ImageReadError)
        self.path = self.raster.path
        self.shape = self.raster.shape
        self.planar = self.raster.planar
        try:
            self._nodata = nodata_value(self.raster.tags.get(GDAL_NODATA), self.path)
        except CliffTerrainError:
            self.close()
            raise
        if self.raster.tiled:
            if self.planar:
                self.close()
                raise ImageReadError(
                    f"mosaic {self.path!r} stores its bands in separate planes; windows need "
                    "pixel-interleaved tiles: gdal_translate -co TILED=YES -co INTERLEAVE=PIXEL IN.tif OUT.tif"
                )
        else:
            pixels = self.shape[0] * self.shape[1]
            if pixels > max_striped_pixels:
                self.close()
                raise ImageTooLargeError(
                    f"mosaic {self.path!r} is a striped (untiled) TIFF of {self.shape[1]} x {self.shape[0]} "
                    f"pixels ({pixels / 1e6:.0f} MP), too big to decode whole (limit "
                    f"{max_striped_pixels / 1e6:.0f} MP) and not readable in windows; tile it first, for "
                    "example: gdal_translate -co TILED=YES -co COMPRESS=DEFLATE IN.tif OUT.tif"
                )
        self.tile_shape = self.raster.tile_shape
        # With `black_collar`, whether exact black is the collar is decided once from the file's
        # corners, as the whole file's reading decides it (photo_bands), so that every window agrees.
        # Not for Import Mosaic's tiles yet: their reduced windows (tiles._reach) then no longer give
        # the whole window's heights on every photo (broccoli clipped from a mosaic).
        self._collar = False
        if black_collar:
            rows, cols = self.shape
            corners = [
                self.raster.read_window(r, r + 1, c, c + 1)[0, 0]
                for r in (0, rows - 1)
                for c in (0, cols - 1)
            ]
            self._collar = black_corner(np.asarray(corners)[:, :3].reshape(2, 2, -1))
        try:
            self.transform, self.crs = georeference(self.raster.tags, self.path)
        except CliffTerrainError:
            self.transform, self.crs = None, None  # a plain TIFF: no georeference

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self):
        self.raster.close()

    @property
    def gsd(self):
        """Metres per pixel from the georeference, or None."""
        if self.transform is None:
            return None
        return float(np.hypot(*self.transform[:2, 0]))

    def read(self, r0, r1, c0, c1):
        """Pixels [r0:r1, c0:c1] as RGB uint8 and a valid mask (None when every pixel holds data).

        Only the TIFF tiles the window overlaps are read and decoded, one at a time.
        """
        rows, cols = self.shape
        if not (0 <= r0 < r1 <= rows and 0 <= c0 < c1 <= cols):
            raise CliffTerrainError(
                f"window [{r0}:{r1}, {c0}:{c1}] is not inside the mosaic's {rows} x {cols}"
            )
        raw = self.raster.read_window(r0, r1, c0, c1)
        return photo_bands(raw, self.path, nodata=self._nodata, collar=self._collar)

    def overview(self, *, max_pixels=OVERVIEW_PIXELS):
        """The whole mosaic reduced by an integer step (every `step`-th pixel) to at most `max_pixels`.

        Returns
        -------
        rgb : (rows', cols', 3) uint8
        valid : (rows', cols') bool or None
        step : int
        """
        step, bands = self.overview_bands(max_pixels=max_pixels)
        parts = (self.overview_band(r0, r1, step) for r0, r1 in bands)
        return (*overview_from_bands(self.shape, step, parts), step)

    def overview_bands(self, *, max_pixels=OVERVIEW_PIXELS):
        """(step, [(r0, r1), ...]): :meth:`overview`'s step and its bands of rows, whole rows of
        TIFF tiles (each tile decoded once) starting on a multiple of the step; a band can be read
        anywhere (:meth:`overview_band`), a cluster's worker or a thread."""
        rows, cols = self.shape
        step = max(1, math.ceil(math.sqrt(rows * cols / max_pixels)))
        band = max(self.tile_shape[0], step)
        band -= band % step or 0
        band = max(band, step)
        return step, [(r0, min(rows, r0 + band)) for r0 in range(0, rows, band)]

    def overview_band(self, r0, r1, step):
        """(row in the overview, every `step`-th pixel of rows [r0:r1] as RGB, valid mask or None)."""
        part, ok = self.read(r0, r1, 0, self.shape[1])
        # Copies: a view would hold the whole band while the result waits to be placed.
        return r0 // step, part[::step, ::step].copy(), (None if ok is None else ok[::step, ::step].copy())


def overview_from_bands(shape, step, parts):
    """(rgb, valid or None): the overview of a (rows, cols) mosaic at `step` from its bands'
    :meth:`MosaicReader.overview_band` results `parts` (in any order)."""
    rows, cols = shape
    rgb = np.zeros((math.ceil(rows / step), math.ceil(cols / step), 3), np.uint8)
    valid = np.ones(rgb.shape[:2], bool)
    for at, part, ok in parts:
        rgb[at : at + len(part)] = part
        if ok is not None:
            valid[at : at + len(part)] = ok
    return rgb, (None if valid.all() else valid)
