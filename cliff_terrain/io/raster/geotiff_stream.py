"""A float32 GeoTIFF larger than memory, written window by window: tiled, Deflate, with overviews.

:class:`RasterSpool` collects a raster's windows in any order in a raw file on disk (float32, in
the output's 512 x 512 tiles), then :meth:`RasterSpool.write_geotiff` streams it into the layout
:func:`cliff_terrain.io.raster.geotiff.write_geotiff` gives with ``overviews=True`` (512 x 512
tiles, Deflate with the floating-point predictor, reduced-resolution images halving the size until
one tile holds it, each the NaN-aware mean of 2 x 2 pixels of the level above). tifffile takes the
tiles from an iterator, a band of 512 rows at a time, and each level is spooled to disk while the
level above is written (:class:`TileSpool`'s first overview while the windows arrive), so memory
follows one band of 512 rows, not the raster. The pixels and the
overviews are those of ``write_geotiff(..., overviews=True)`` on the whole array (tested).

:class:`TileSpool` is the same raster arriving already encoded: a window whose core is made of whole
tiles is compressed where it was measured (:func:`encode_block`, on a Dask worker or a window's
thread) into the bytes tifffile would write, with its 2 x 2 means for the first overview. Writing
is then a copy of those bytes and the overviews' encoding (a third of the pixels): the Deflate of
the full-resolution image, most of a windowed run's writing, runs where the windows do. A window of
1024 pixels (2048) is whole tiles of the first overview too (and the second): those arrive encoded
as well (:func:`encoded_levels`), and the one process writing compresses a twelfth of the pixels
(a forty-eighth). The file is byte for byte :class:`RasterSpool`'s (tested).
"""

from __future__ import annotations

import os

import numpy as np

from .blocks import block_mean
from .geotiff import COG_TILE, DEFLATE_LEVEL, cog_options, geotiff_tags

_DTYPE = np.dtype(np.float32)


class _TiledFile:
    """A (rows, cols) float32 raster in `tile` x `tile` tiles, kept in a file under `folder`: what
    both spools share (their tile grid, their file, reading rows from their :meth:`tile_row`)."""

    def __init__(self, folder, name, shape, tile):
        self.shape = (int(shape[0]), int(shape[1]))
        self.tile = int(tile)
        self.tiles = (-(-self.shape[0] // self.tile), -(-self.shape[1] // self.tile))
        self.path = os.path.join(os.fspath(folder), name)
        self._file = open(self.path, "w+b")  # noqa: SIM115 (closed by close())

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


class RasterSpool(_TiledFile):
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
        super().__init__(folder, f"{name}.raw", shape, tile)
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

    def write_geotiff(self, path, *, transform, crs, nodata=None):
        """Write the raster as a tiled, Deflate GeoTIFF with overviews at `path` (not atomically:
        the caller writes to a temporary name, as :func:`cliff_terrain.measure.tables.write_files`)."""
        below = _overview_spool(self, path, 0)
        try:
            _write_pyramid(
                path, self, _tiles(self, below), below, transform=transform, crs=crs, nodata=nodata
            )
        finally:
            if below is not None:
                below.close()


class TileSpool(_TiledFile):
    """A (rows, cols) float32 raster arriving as encoded tiles (:func:`encode_block`), under `folder`.

    Level 0 is kept as its tiles' bytes (appended to a file, in any order); the first overview as a
    :class:`RasterSpool` of the blocks' 2 x 2 means. :meth:`write_geotiff` writes the file
    :class:`RasterSpool` writes for the same pixels, byte for byte, without compressing level 0
    again. Not for concurrent writers.

    Examples
    --------
    >>> import tempfile
    >>> folder = tempfile.mkdtemp()
    >>> spool = TileSpool(folder, "chm", (3, 4), tile=2)
    >>> spool.put(0, 0, encode_block(np.ones((3, 2), np.float32), tile=2))
    >>> spool.put(0, 2, encode_block(np.zeros((3, 2), np.float32), tile=2))
    >>> spool.read_rows(1, 2).tolist()
    [[1.0, 1.0, 0.0, 0.0]]
    >>> spool.close()
    """

    def __init__(self, folder, name, shape, *, tile=COG_TILE, levels=1):
        super().__init__(folder, f"{name}.tiles", shape, tile)
        self._end = 0
        self._offsets = np.full(self.tiles, -1, np.int64)
        self._sizes = np.zeros(self.tiles, np.int64)
        self.half = None
        if max(self.shape) > self.tile:
            half = ((self.shape[0] + 1) // 2, (self.shape[1] + 1) // 2)
            if levels > 1:  # the overview arrives encoded too (encode_block's `levels`)
                self.half = TileSpool(folder, f"{name}-half", half, tile=self.tile, levels=levels - 1)
            else:
                self.half = RasterSpool(folder, f"{name}-half", half, tile=self.tile)

    def put(self, r0, c0, encoded):
        """Store `encoded` (:func:`encode_block` of a block whose top-left pixel is (r0, c0), a tile
        corner)."""
        t = self.tile
        rows, cols = encoded["shape"]
        if r0 % t or c0 % t:
            raise ValueError(f"a block of encoded tiles must start on a tile corner, not at ({r0}, {c0})")
        if (rows % t and r0 + rows != self.shape[0]) or (cols % t and c0 + cols != self.shape[1]):
            raise ValueError(
                f"a block of encoded tiles must be whole tiles but at the raster's edge, not {rows} x {cols} "
                f"at ({r0}, {c0}) of {self.shape[0]} x {self.shape[1]}"
            )
        across = -(-cols // t)
        for k, data in enumerate(encoded["tiles"]):
            ti, tj = r0 // t + k // across, c0 // t + k % across
            self._offsets[ti, tj], self._sizes[ti, tj] = self._end, len(data)
            self._file.seek(self._end)
            self._file.write(data)
            self._end += len(data)
        if self.half is not None:
            half = encoded["half"]
            if isinstance(half, dict) != isinstance(self.half, TileSpool):
                raise ValueError(
                    f"a block encoded to {_levels(encoded)} level(s) given to a spool of {_levels(self)}"
                )
            self.half.put(r0 // 2, c0 // 2, half)

    def encoded_tiles(self):
        """The tiles' bytes in row-major order (every tile must have arrived)."""
        self._file.flush()
        if (self._offsets < 0).any():
            ti, tj = np.argwhere(self._offsets < 0)[0]
            raise ValueError(f"tile ({ti}, {tj}) of {self.path!r} was never written")
        for ti, tj in np.ndindex(*self.tiles):
            yield self._tile_bytes(ti, tj)

    def _tile_bytes(self, ti, tj):
        self._file.seek(self._offsets[ti, tj])
        return self._file.read(self._sizes[ti, tj])

    def tile_row(self, ti):
        """Tile row `ti` decoded, as :meth:`RasterSpool.tile_row` gives it."""
        self._file.flush()
        return np.stack([decode_tile(self._tile_bytes(ti, tj), self.tile) for tj in range(self.tiles[1])])

    def close(self):
        super().close()
        if self.half is not None:
            self.half.close()

    def write_geotiff(self, path, *, transform, crs, nodata=None):
        """As :meth:`RasterSpool.write_geotiff`: the same file, level 0 copied as encoded."""
        _write_pyramid(
            path, self, self.encoded_tiles(), self.half, transform=transform, crs=crs, nodata=nodata
        )


def encode_tile(tile):
    """A (tile, tile) float32 tile's bytes as the output stores it: the floating-point predictor
    along each row, then Deflate at :data:`~cliff_terrain.io.raster.geotiff.DEFLATE_LEVEL`, with
    the codecs tifffile itself uses for :data:`~cliff_terrain.io.raster.geotiff.COG_OPTIONS`."""
    import tifffile

    data = tifffile.TIFF.PREDICTORS[3](np.ascontiguousarray(tile, _DTYPE), axis=-1)
    return tifffile.TIFF.COMPRESSORS[8](data, level=DEFLATE_LEVEL)


def decode_tile(data, tile=COG_TILE):
    """The (tile, tile) float32 pixels of :func:`encode_tile`'s bytes."""
    import tifffile

    raw = np.frombuffer(tifffile.TIFF.DECOMPRESSORS[8](data), _DTYPE).reshape(tile, tile).copy()
    return tifffile.TIFF.UNPREDICTORS[3](raw, axis=-1, out=raw)


def encode_block(block, *, tile=COG_TILE, levels=1):
    """A window's raster as :class:`TileSpool` takes it: its tiles encoded (row-major, zero beyond
    the block, as tifffile pads a raster's edge tiles) and its 2 x 2 means for the first overview;
    with `levels` > 1 the overview is encoded too, as such a dict (its own means below it), down to
    `levels` encoded levels (:func:`encoded_levels`).

    The block must start on a tile corner and be whole tiles but at the raster's right and bottom
    edges, where the tiles it leaves short are the raster's last (at every encoded level).

    Examples
    --------
    >>> encoded = encode_block(np.ones((3, 5), np.float32), tile=2)
    >>> len(encoded["tiles"]), encoded["half"].shape
    (6, (2, 3))
    >>> len(encode_block(np.ones((4, 4), np.float32), tile=2, levels=2)["half"]["tiles"])
    1
    """
    block = np.asarray(block, dtype=_DTYPE)
    rows, cols = block.shape
    tiles = []
    for r in range(0, rows, tile):
        for c in range(0, cols, tile):
            part = block[r : r + tile, c : c + tile]
            if part.shape != (tile, tile):
                part = np.pad(part, ((0, tile - part.shape[0]), (0, tile - part.shape[1])))
            tiles.append(encode_tile(part))
    half = block_mean(block, 2)
    if levels > 1:
        half = encode_block(half, tile=tile, levels=levels - 1)
    return {"shape": (rows, cols), "tiles": tiles, "half": half}


def encoded_levels(window, tile=COG_TILE):
    """How many levels of a raster windows of side `window` (starting at multiples of it) give as
    whole tiles, encoded where they are measured: level k's while `window` / 2**k is a multiple of
    `tile` (0: none; 1024-pixel windows give the full resolution and the first overview, whose
    Deflate was a quarter of the writing left to the one process writing the file).

    Examples
    --------
    >>> encoded_levels(512), encoded_levels(1024), encoded_levels(2048), encoded_levels(1000)
    (1, 2, 3, 0)
    """
    levels = 0
    while window % (tile << levels) == 0:
        levels += 1
    return levels


def _levels(spool_or_encoded):
    """How many encoded levels a :class:`TileSpool` (or an :func:`encode_block` dict) holds."""
    if isinstance(spool_or_encoded, TileSpool):
        half = spool_or_encoded.half
        return 1 + (_levels(half) if isinstance(half, TileSpool) else 0)
    half = spool_or_encoded["half"]
    return 1 + (_levels(half) if isinstance(half, dict) else 0)


def _overview_spool(level, path, index):
    """The spool of `level`'s next overview (None when one tile holds `level`)."""
    if max(level.shape) <= COG_TILE:
        return None
    half = ((level.shape[0] + 1) // 2, (level.shape[1] + 1) // 2)
    return RasterSpool(os.path.dirname(level.path), f"{os.path.basename(path)}-{index}", half)


def _write_pyramid(path, level0, tiles0, below, *, transform, crs, nodata):
    """Write `level0` (its tiles `tiles0`: arrays, or bytes already encoded) and its overviews,
    the first being `below` (filled by the time `tiles0` is exhausted), each spooled while the level
    above is written."""
    import tifffile

    rows, cols = level0.shape
    options = cog_options()
    levels = []
    try:
        with tifffile.TiffWriter(os.fspath(path), bigtiff=rows * cols * _DTYPE.itemsize > 2**31) as tif:
            tif.write(
                tiles0,
                shape=level0.shape,
                dtype=_DTYPE,
                extratags=geotiff_tags(transform, crs, nodata=nodata),
                subfiletype=0,
                **options,
            )
            level = below
            while level is not None:
                if isinstance(level, TileSpool):  # an overview that arrived encoded: copied
                    tif.write(
                        level.encoded_tiles(), shape=level.shape, dtype=_DTYPE, subfiletype=1, **options
                    )
                    level = level.half
                    continue
                below = _overview_spool(level, path, len(levels) + 1)
                if below is not None:
                    levels.append(below)
                tif.write(_tiles(level, below), shape=level.shape, dtype=_DTYPE, subfiletype=1, **options)
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
