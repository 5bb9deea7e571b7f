"""A float32 GeoTIFF larger than memory, written window by window: tiled, Deflate, with overviews.

:class:`RasterSpool` collects a raster's windows in any order in a raw file on disk (row-major
float32, one seek per window row), then :meth:`RasterSpool.write_geotiff` streams it into the
layout :func:`cliff_terrain.io.raster.geotiff.write_geotiff` gives with ``overviews=True`` (512 x 512
tiles, Deflate with the floating-point predictor, reduced-resolution images halving the size until
one tile holds it, each the NaN-aware mean of 2 x 2 pixels of the level above). tifffile takes the
tiles from an iterator, 512 rows at a time, and each level is spooled to disk while the level above
is written, so memory follows one band of 512 rows, not the raster. The pixels and the overviews
are those of ``write_geotiff(..., overviews=True)`` on the whole array (tested).
"""

from __future__ import annotations

import os

import numpy as np

from .blocks import block_mean
from .geotiff import COG_TILE, cog_options, geotiff_tags

_DTYPE = np.dtype(np.float32)


class RasterSpool:
    """A (rows, cols) float32 raster filled window by window in a raw file under `folder`.

    Examples
    --------
    >>> import tempfile
    >>> folder = tempfile.mkdtemp()
    >>> spool = RasterSpool(folder, "chm", (3, 4))
    >>> spool.put(0, 0, np.ones((3, 2), np.float32)); spool.put(0, 2, np.zeros((3, 2), np.float32))
    >>> spool.read_rows(1, 2).tolist()
    [[1.0, 1.0, 0.0, 0.0]]
    >>> spool.close()
    """

    def __init__(self, folder, name, shape):
        self.shape = (int(shape[0]), int(shape[1]))
        self.path = os.path.join(os.fspath(folder), f"{name}.raw")
        self._file = open(self.path, "w+b")  # noqa: SIM115 (closed by close())
        self._file.truncate(self.shape[0] * self.shape[1] * _DTYPE.itemsize)  # sparse until written

    def put(self, r0, c0, block):
        """Write `block` (float32) with its top-left pixel at (r0, c0)."""
        block = np.ascontiguousarray(block, dtype=_DTYPE)
        cols = self.shape[1]
        at = [((r0 + i) * cols + c0) * _DTYPE.itemsize for i in range(block.shape[0])]
        if hasattr(os, "pwrite"):  # positioned writes: no seek, no copy into Python's buffer
            self._file.flush()
            fd = self._file.fileno()
            for offset, row in zip(at, block, strict=True):
                os.pwrite(fd, row, offset)
            return
        for offset, row in zip(at, block, strict=True):  # Windows has no pwrite
            self._file.seek(offset)
            self._file.write(row.tobytes())

    def read_rows(self, r0, r1):
        """Rows [r0:r1] of the raster."""
        cols = self.shape[1]
        self._file.flush()
        self._file.seek(r0 * cols * _DTYPE.itemsize)
        data = np.fromfile(self._file, dtype=_DTYPE, count=(r1 - r0) * cols)
        return data.reshape(r1 - r0, cols)

    def close(self):
        self._file.close()
        if os.path.exists(self.path):
            os.remove(self.path)

    def write_geotiff(self, path, *, transform, crs, nodata=None):
        """Write the raster as a tiled, Deflate GeoTIFF with overviews at `path` (not atomically:
        the caller writes to a temporary name, as :func:`cliff_terrain.measure.tables.write_files`)."""
        import tifffile

        rows, cols = self.shape
        levels = []
        options = cog_options()
        try:
            with tifffile.TiffWriter(os.fspath(path), bigtiff=rows * cols * _DTYPE.itemsize > 2**31) as tif:
                level = self
                extratags = geotiff_tags(transform, crs, nodata=nodata)
                while True:
                    below = None
                    if max(level.shape) > COG_TILE:  # the next overview, spooled while this level is written
                        half = ((level.shape[0] + 1) // 2, (level.shape[1] + 1) // 2)
                        below = RasterSpool(
                            os.path.dirname(self.path), f"{os.path.basename(path)}-{len(levels)}", half
                        )
                        levels.append(below)
                    tif.write(
                        _tiles(level, below),
                        shape=level.shape,
                        dtype=_DTYPE,
                        extratags=extratags,
                        subfiletype=0 if level is self else 1,
                        **options,
                    )
                    extratags = ()
                    if below is None:
                        break
                    level = below
        finally:
            for spool in levels:
                spool.close()


def _tiles(level, below):
    """`level`'s 512 x 512 tiles in row-major order; spools its 2 x 2 means into `below` on the way."""
    rows, cols = level.shape
    for r0 in range(0, rows, COG_TILE):
        band = level.read_rows(r0, min(rows, r0 + COG_TILE))
        if below is not None:  # bands of 512 (even) rows: the means of the whole level's, exactly
            below.put(r0 // 2, 0, block_mean(band, 2))
        for c0 in range(0, cols, COG_TILE):
            yield band[:, c0 : c0 + COG_TILE]
