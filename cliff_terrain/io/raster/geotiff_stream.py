"""A float32 GeoTIFF larger than memory, written window by window: tiled, Deflate, with overviews.

:class:`RasterSpool` collects a raster's windows in any order in a raw file on disk (float32, in
the output's 512 x 512 tiles), then :meth:`RasterSpool.write_geotiff` streams it into the layout
:func:`cliff_terrain.io.raster.geotiff.write_geotiff` gives with ``overviews=True`` (512 x 512
tiles, Deflate with the floating-point predictor, reduced-resolution images halving the size until
one tile holds it, each the NaN-aware mean of 2 x 2 pixels of the level above). tifffile takes the
tiles from an iterator, a band of 512 rows at a time, and each level is spooled to disk while the
level above is written, so memory follows one band of 512 rows, not the raster. The pixels and the
overviews are those of ``write_geotiff(..., overviews=True)`` on the whole array (tested).
"""

from __future__ import annotations

import os

import numpy as np

from .blocks import block_mean
from .geotiff import COG_TILE, cog_options, geotiff_tags

_DTYPE = np.dtype(np.float32)


class RasterSpool:
    """A (rows, cols) float32 raster filled window by window in a raw file under `folder`.

    The file holds the raster in `tile` x `tile` tiles (row-major tile order, zero beyond the
    raster's edge), the output's own layout: a window whose core is made of whole tiles is a few
    large positioned writes (row by row, a 265 MP field's three rasters were 800 000 small writes
    and a fifth of the run), and a band of tiles is one contiguous read. A block that covers a tile
    only partly is merged into it (read, modify, write). Not for concurrent writers.

    Examples
    --------
    >>> import tempfile
    >>> folder = tempfile.mkdtemp()
    >>> spool = RasterSpool(folder, "chm", (3, 4), tile=2)
    >>> spool.put(0, 0, np.ones((3, 2), np.float32)); spool.put(0, 2, np.zeros((3, 2), np.float32))
    >>> spool.read_rows(1, 2).tolist()
    [[1.0, 1.0, 0.0, 0.0]]
    >>> spool.close()
    """

    def __init__(self, folder, name, shape, *, tile=COG_TILE):
        self.shape = (int(shape[0]), int(shape[1]))
        self.tile = int(tile)
        self.tiles = (-(-self.shape[0] // self.tile), -(-self.shape[1] // self.tile))
        self.path = os.path.join(os.fspath(folder), f"{name}.raw")
        self._file = open(self.path, "w+b")  # noqa: SIM115 (closed by close())
        self._file.truncate(self.tiles[0] * self.tiles[1] * self.tile**2 * _DTYPE.itemsize)  # sparse

    def _offset(self, ti, tj):
        return (ti * self.tiles[1] + tj) * self.tile**2 * _DTYPE.itemsize

    def _write(self, data, offset):
        if hasattr(os, "pwrite"):  # positioned writes: no seek, no copy into Python's buffer
            os.pwrite(self._file.fileno(), data, offset)
        else:  # Windows has no pwrite
            self._file.seek(offset)
            self._file.write(data.tobytes())

    def _read(self, offset, count):
        self._file.seek(offset)
        return np.fromfile(self._file, dtype=_DTYPE, count=count)

    def put(self, r0, c0, block):
        """Write `block` (float32) with its top-left pixel at (r0, c0)."""
        block = np.asarray(block, dtype=_DTYPE)
        t = self.tile
        rows, cols = self.shape
        r1, c1 = r0 + block.shape[0], c0 + block.shape[1]
        self._file.flush()
        for ti in range(r0 // t, -(-r1 // t)):
            tr0, tr1 = ti * t, min(ti * t + t, rows)
            ir0, ir1 = max(tr0, r0), min(tr1, r1)
            for tj in range(c0 // t, -(-c1 // t)):
                tc0, tc1 = tj * t, min(tj * t + t, cols)
                ic0, ic1 = max(tc0, c0), min(tc1, c1)
                offset = self._offset(ti, tj)
                if (ir0, ir1, ic0, ic1) == (tr0, tr1, tc0, tc1):  # the block covers the tile
                    data = np.zeros((t, t), _DTYPE)
                else:
                    data = self._read(offset, t * t).reshape(t, t)
                data[ir0 - tr0 : ir1 - tr0, ic0 - tc0 : ic1 - tc0] = block[
                    ir0 - r0 : ir1 - r0, ic0 - c0 : ic1 - c0
                ]
                self._write(data, offset)

    def tile_row(self, ti):
        """Tile row `ti` as a (tiles across, tile, tile) array, zero beyond the raster."""
        t = self.tile
        self._file.flush()
        return self._read(self._offset(ti, 0), self.tiles[1] * t * t).reshape(self.tiles[1], t, t)

    def read_rows(self, r0, r1):
        """Rows [r0:r1] of the raster."""
        t = self.tile
        parts = []
        for ti in range(r0 // t, -(-r1 // t)):
            band = _band(self.tile_row(ti))
            parts.append(band[max(r0 - ti * t, 0) : min(r1 - ti * t, t), : self.shape[1]])
        return np.concatenate(parts) if parts else np.zeros((0, self.shape[1]), _DTYPE)

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
    """`level`'s 512 x 512 tiles in row-major order (zero beyond its edge, as tifffile pads them);
    spools its 2 x 2 means into `below` on the way."""
    rows, cols = level.shape
    for ti in range(level.tiles[0]):
        tiles = level.tile_row(ti)
        if below is not None:  # bands of 512 (even) rows: the means of the whole level's, exactly
            r0 = ti * COG_TILE
            band = _band(tiles)[: min(rows - r0, COG_TILE), :cols]
            below.put(r0 // 2, 0, block_mean(band, 2))
        yield from tiles


def _band(tiles):
    """A tile row, (tiles across, tile, tile), as one band of pixels (tile, tiles across x tile)."""
    return tiles.transpose(1, 0, 2).reshape(tiles.shape[1], -1)
