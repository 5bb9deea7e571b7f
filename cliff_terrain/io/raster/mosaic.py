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

from ..._validate import check_float, check_int
from ...errors import CliffTerrainError, ImageReadError, ImageTooLargeError
from ._geokeys import GDAL_NODATA, georeference, nodata_value
from ._tiff_window import TiffRaster
from .photo_samples import OVERVIEW_PIXELS, black_corner, overview_step, photo_bands, sample_scale

_CMYK = 5  # TIFF PhotometricInterpretation "separated"
# A striped GeoTIFF is decoded whole: above this many pixels (a 12-bit 150 MP RGB image is 0.9 GB
# decoded) it is refused with the command that tiles it.
MAX_STRIPED_PIXELS = 150_000_000


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
        alpha nor a declared no-data value (a mosaic's collar, as :func:`.photo_samples.photo_bands`
        does for a file read whole). The windowed heights read so; Import Mosaic's tiles do not yet.
    scale : float, optional
        The value full-scale 16-bit or float samples reach (:func:`.photo_samples.sample_scale`),
        when the caller has it from the overview; by default taken by :meth:`overview`, or on the
        first window of a 16-bit or float file (an overview of its raw samples), so that every
        window of the file is scaled alike.

    Examples
    --------
    >>> with MosaicReader(path) as mosaic:  # doctest: +SKIP
    ...     rgb, valid = mosaic.read(0, 512, 0, 512)
    """

    def __init__(self, path, *, max_striped_pixels=MAX_STRIPED_PIXELS, black_collar=False, scale=None):
        max_striped_pixels = check_int("max_striped_pixels", max_striped_pixels, minimum=1)
        self.scale = None if scale is None else check_float("scale", scale, minimum=0.0, strict_minimum=True)
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
        from .bands import named_bands

        bands = named_bands(self.raster)
        if bands:
            # A window is read as RGB(A) (photo_bands); a multispectral file's true colour needs
            # its bands' gain over the whole file (bands.rgb_rendering), and a 4th band named NIR
            # would be taken for alpha.
            self.close()
            raise ImageReadError(_multispectral_message(self.path, bands))
        if int(self.raster.page.photometric) == _CMYK:  # its K would be read as alpha
            self.close()
            raise ImageReadError(
                f"mosaic {self.path!r} is CMYK; windows read RGB or RGBA orthophotos: convert it, for "
                "example: gdal_translate -co TILED=YES IN.tif OUT.tif (GDAL reads CMYK as RGBA)"
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
        return self.photo(self.raster.read_window(r0, r1, c0, c1))

    def photo(self, raw):
        """RGB uint8 and a valid mask (or None) of `raw` samples of this file (a window, or the
        overview :func:`overview_from_bands` assembles), by the whole file's rule."""
        if raw.dtype != np.uint8 and self.scale is None:
            self.scale = self.sample_scale()
        return photo_bands(raw, self.path, nodata=self._nodata, collar=self._collar, scale=self.scale)

    def sample_scale(self, raw=None):
        """The file's :func:`~.photo_samples.sample_scale` (None for 8 bits): from its overview's
        samples (`raw`, :func:`overview_from_bands`'s, or read here: every tile decoded once)."""
        if raw is None:
            step, bands = self.overview_bands()
            raw = overview_from_bands(
                self.shape, step, (self.overview_band(r0, r1, step) for r0, r1 in bands)
            )
        return sample_scale(raw, nodata=self._nodata)

    def overview(self, *, max_pixels=OVERVIEW_PIXELS):
        """The whole mosaic reduced by an integer step (every `step`-th pixel) to at most `max_pixels`.

        Returns
        -------
        rgb : (rows', cols', 3) uint8
        valid : (rows', cols') bool or None
        step : int
        """
        step, bands = self.overview_bands(max_pixels=max_pixels)
        raw = overview_from_bands(self.shape, step, (self.overview_band(r0, r1, step) for r0, r1 in bands))
        return (*(self.from_overview(raw) if max_pixels == OVERVIEW_PIXELS else self.photo(raw)), step)

    def from_overview(self, raw):
        """:meth:`photo` of the overview's raw samples (:func:`overview_from_bands` at
        :meth:`overview_bands`' step), the file's :attr:`scale` taken from them first."""
        if raw.dtype != np.uint8 and self.scale is None:
            self.scale = self.sample_scale(raw)
        return self.photo(raw)

    def overview_bands(self, *, max_pixels=OVERVIEW_PIXELS):
        """(step, [(r0, r1), ...]): :meth:`overview`'s step and its bands of rows, whole rows of
        TIFF tiles (each tile decoded once) starting on a multiple of the step; a band can be read
        anywhere (:meth:`overview_band`), a cluster's worker or a thread."""
        rows = self.shape[0]
        step = overview_step(self.shape, max_pixels=max_pixels)
        band = max(self.tile_shape[0], step)
        band -= band % step or 0
        band = max(band, step)
        return step, [(r0, min(rows, r0 + band)) for r0 in range(0, rows, band)]

    def overview_band(self, r0, r1, step):
        """(row in the overview, every `step`-th pixel of rows [r0:r1]: the raw samples, (rows',
        cols', samples)); :meth:`photo` makes the assembled overview RGB."""
        # A copy: a view would hold the whole band while the result waits to be placed.
        return r0 // step, self.raster.read_window(r0, r1, 0, self.shape[1])[::step, ::step].copy()


def overview_from_bands(shape, step, parts):
    """The raw samples of a (rows, cols) mosaic's overview at `step`, from its bands'
    :meth:`MosaicReader.overview_band` results `parts` (in any order)."""
    rows, cols = shape
    raw = None
    for at, part in parts:
        if raw is None:
            raw = np.zeros((math.ceil(rows / step), math.ceil(cols / step), part.shape[2]), part.dtype)
        raw[at : at + len(part)] = part
    return raw


def _multispectral_message(path, bands):
    """The line refusing a multispectral orthomosaic in windows, with the gdal_translate that keeps
    its red, green and blue bands when it names them."""
    from .bands import band_label

    described = ", ".join(band_label(n) if n else "unnamed" for n in bands)
    where = [bands.index(n) + 1 if n in bands else None for n in ("red", "green", "blue")]
    keep = " ".join(f"-b {k}" for k in where) if None not in where else "-b <red> -b <green> -b <blue>"
    return (
        f"mosaic {path!r} is a multispectral orthomosaic ({len(bands)} bands: {described}); windows "
        f"read RGB or RGBA orthophotos: keep its colour bands (gdal_translate {keep} -co TILED=YES "
        "IN.tif OUT.tif), or read it whole (heights without --windowed, with --max-size or "
        "--resolution and --bands; Build Relief in Blender)"
    )
