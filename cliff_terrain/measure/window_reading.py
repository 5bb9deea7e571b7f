"""Reading an orthophoto, its DSM and DTM in windows, for :mod:`cliff_terrain.measure.windowed`.

Every value is computed from global pixel coordinates (bilinear weights from the coordinates alone),
so a pixel's value does not depend on the window it is read in.
"""

from __future__ import annotations

import numpy as np

from ..errors import CliffTerrainError, GeoreferenceError, RasterReadError
from ..io.raster.bilinear import bilinear, is_axis_aligned, on_grid, pixel_map
from ..io.raster.crs import crs_text


def require_axis_aligned(m, *, name):
    """`m` (:func:`~cliff_terrain.io.raster.bilinear.pixel_map`), or GeoreferenceError naming
    `name` when it rotates: the windows read rows of one raster as rows of the other."""
    if not is_axis_aligned(m):
        raise GeoreferenceError(
            f"{name!r} is rotated against the orthophoto's grid; the windowed measure needs north-up "
            "rasters: measure it without --windowed or warp it north-up"
        )
    return m


class SurfaceWindows:
    """A surface model GeoTIFF (DSM or DTM) read in windows: heights in metres, NaN for no data.

    The no-data rules are :func:`cliff_terrain.io.raster.geotiff.read_surface`'s. A tiled file decodes
    only the TIFF tiles a window overlaps; a striped one is decoded whole once.
    """

    def __init__(self, path, *, what="surface model"):
        from ..io.raster._geokeys import GDAL_METADATA, GDAL_NODATA, georeference, nodata_value, scale_offset
        from ..io.raster._tiff_window import TiffRaster
        from ..io.raster.surface_values import check_scaled, zero_fill

        self.raster = TiffRaster(path)
        self.path = self.raster.path
        try:
            if self.raster.samples != 1:
                raise RasterReadError(f"{what} {self.path!r} has {self.raster.samples} bands, expected 1")
            self.transform, self.crs = georeference(self.raster.tags, self.path)
            self.nodata = nodata_value(self.raster.tags.get(GDAL_NODATA), self.path)
            self.scale_offset = scale_offset(self.raster.tags.get(GDAL_METADATA))
            check_scaled(self.raster.page.dtype, self.scale_offset, self.path)
            rows, cols = self.raster.shape
            corners = [
                self.raster.read_window(r, r + 1, c, c + 1)[0, 0, 0]
                for r in (0, rows - 1)
                for c in (0, cols - 1)
            ]
            self.zero_fill = zero_fill(np.array(corners), nodata=self.nodata)  # as read_surface decides
        except CliffTerrainError:
            self.raster.close()
            raise
        self.shape = self.raster.shape

    def close(self):
        self.raster.close()

    def read(self, r0, r1, c0, c1):
        """Heights [r0:r1, c0:c1] (float32, NaN for no data)."""
        from ..io.raster.surface_values import surface_heights

        raw = self.raster.read_window(r0, r1, c0, c1)[..., 0]
        return surface_heights(
            raw, nodata=self.nodata, scale_offset=self.scale_offset, zero_fill=self.zero_fill
        )

    def on_grid(self, transform, r0, r1, c0, c1):
        """The surface bilinearly resampled onto pixels [r0:r1, c0:c1] of the grid `transform`
        (:func:`cliff_terrain.io.raster.bilinear.on_grid`: the numbers the whole raster's resampling
        gives)."""
        m = require_axis_aligned(pixel_map(self.transform, transform), name=self.path)
        return on_grid(self.read, self.shape, m, r0, r1, c0, c1)


def upsample(coarse, factor, r0, r1, c0, c1):
    """Pixels [r0:r1, c0:c1] of the full grid, bilinear from `coarse` (`factor` full pixels per
    coarse pixel, centres aligned, held flat beyond the outer centres).

    Examples
    --------
    >>> upsample(np.array([[0.0, 2.0]], np.float32), 2, 0, 1, 0, 4).tolist()
    [[0.0, 0.5, 1.5, 2.0]]
    """
    if factor == 1:
        return np.asarray(coarse[r0:r1, c0:c1], np.float32).copy()
    rows, cols = coarse.shape
    y = np.clip((np.arange(r0, r1) + 0.5) / factor - 0.5, 0, rows - 1)
    x = np.clip((np.arange(c0, c1) + 0.5) / factor - 0.5, 0, cols - 1)
    return bilinear(np.asarray(coarse, np.float32), y, x)


def windows(shape, size):
    """Core windows ``(r0, r1, c0, c1)`` of side `size` covering `shape`, row-major."""
    rows, cols = shape
    return [
        (r0, min(rows, r0 + size), c0, min(cols, c0 + size))
        for r0 in range(0, rows, size)
        for c0 in range(0, cols, size)
    ]


class WindowSources:
    """The orthophoto (in windows, :class:`cliff_terrain.io.raster.mosaic.MosaicReader`), DSM and DTM."""

    def __init__(self, ortho, dsm, dtm, *, scale=None):
        from ..io.raster.mosaic import MosaicReader

        # As a file read whole: its collar, and its sample `scale` (from the overview, given to
        # every window's reader).
        self.ortho = MosaicReader(ortho, black_collar=True, scale=scale)
        self.opened = [self.ortho]
        try:
            if self.ortho.transform is None:
                raise RasterReadError(f"orthophoto {self.ortho.path!r} has no georeference")
            self.dsm = SurfaceWindows(dsm)
            self.opened.append(self.dsm)
            self.dtm = None
            if dtm is not None:
                self.dtm = SurfaceWindows(dtm, what="terrain model")
                self.opened.append(self.dtm)
            for surface in filter(None, (self.dsm, self.dtm)):
                if surface.crs != self.ortho.crs:
                    raise GeoreferenceError(
                        f"{surface.path!r} is in {crs_text(surface.crs)} but {self.ortho.path!r} is in "
                        f"{crs_text(self.ortho.crs)}; reproject one"
                    )
                require_axis_aligned(pixel_map(surface.transform, self.ortho.transform), name=surface.path)
        except BaseException:
            self.close()
            raise

    def close(self):
        for reader in self.opened:
            reader.close()

    def photo(self, r0, r1, c0, c1):
        rgb, valid = self.ortho.read(r0, r1, c0, c1)
        return rgb, (np.ones(rgb.shape[:2], bool) if valid is None else valid)
