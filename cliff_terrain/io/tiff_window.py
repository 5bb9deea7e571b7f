"""The first image of a TIFF, read whole or in windows: the one TIFF reader of surface models,
orthophotos, TIFF photos and mosaics.

tifffile decodes the pixels (with imagecodecs for LZW/Deflate/...). A window of a *tiled* TIFF
decodes only the TIFF tiles it overlaps, one at a time, so memory follows the window, not the
image; a striped TIFF is decoded whole once and windows are cut from it. Whatever tifffile or a
codec raises becomes one :class:`RasterReadError` (or :class:`DependencyError` for a missing codec)
naming the file.
"""

from __future__ import annotations

import logging
import math
import os
import threading
from contextlib import contextmanager

import numpy as np

from ..errors import DependencyError, RasterReadError
from .geokeys import GEO_TAGS


@contextmanager
def quiet_tifffile():
    """tifffile logs a warning for OpenDroneMap's GDAL_NODATA (-3.4e38 is not a float32); we parse it.

    Safe from several threads at once (a mosaic's next tile is read while this one is meshed): the
    logger's own level comes back when the last of them leaves.
    """
    global _quiet_depth, _quiet_level
    logger = logging.getLogger("tifffile")
    with _quiet_lock:
        if _quiet_depth == 0:
            _quiet_level = logger.level
            logger.setLevel(logging.ERROR)
        _quiet_depth += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet_depth -= 1
            if _quiet_depth == 0:
                logger.setLevel(_quiet_level)


_quiet_lock = threading.Lock()
_quiet_depth = 0
_quiet_level = logging.NOTSET


class TiffRaster:
    """The first image of a TIFF file, open for reading.

    Parameters
    ----------
    path : str or os.PathLike
    what : str, optional
        What the file is, for error messages ("raster", "mosaic", "image").
    error : type, optional
        The error raised for a missing or unreadable file (:class:`RasterReadError` by default).

    Attributes
    ----------
    path : str
    shape : (int, int)
        (rows, cols).
    samples : int
        Samples per pixel.
    planar : bool
        Samples stored in separate planes (only with more than one).
    tiled : bool
    tile_shape : (int, int)
        (rows, cols) of a TIFF tile; the whole image when striped.
    tags : dict
        Tag code -> value of the georeference and GDAL_NODATA tags present
        (:data:`cliff_terrain.io.geokeys.GEO_TAGS`).
    """

    def __init__(self, path, *, what="raster", error=RasterReadError):
        import tifffile

        self.path = name = os.fspath(path)
        if not os.path.isfile(name):
            raise error(f"{what} {name!r} does not exist")
        try:
            with quiet_tifffile():
                self._tif = tifffile.TiffFile(name)
                page = self._tif.pages[0]
                self.tags = {tag.code: tag.value for tag in page.tags.values() if tag.code in GEO_TAGS}
        except Exception as exc:  # tifffile raises TiffFileError, OSError, and others on corrupt headers
            if hasattr(self, "_tif"):
                self._tif.close()
            raise error(f"cannot read {name!r} as a TIFF: {first_line(exc)}") from None
        self.page = page
        self.shape = (int(page.imagelength), int(page.imagewidth))
        self.samples = int(page.samplesperpixel)
        self.planar = page.planarconfig == 2 and self.samples > 1
        self.tiled = bool(page.is_tiled)
        self.tile_shape = (int(page.tilelength), int(page.tilewidth)) if self.tiled else self.shape
        self._whole = None
        # The file handle's position is shared: one window's reads at a time (decoding is not).
        self._file_lock = threading.Lock()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self):
        self._tif.close()

    def read(self):
        """Every sample, as tifffile lays them out: (rows, cols[, samples]), planar (samples, rows, cols)."""
        with self._decoding():
            return self.page.asarray()

    def read_window(self, r0, r1, c0, c1):
        """Samples [r0:r1, c0:c1] as (rows, cols, samples), decoding only the TIFF tiles they overlap."""
        if not self.tiled:
            with self._file_lock:
                if self._whole is None:
                    whole = self.read()
                    whole = np.moveaxis(whole, 0, -1) if self.planar else whole
                    self._whole = whole if whole.ndim == 3 else whole[..., None]
            return self._whole[r0:r1, c0:c1]
        page = self.page
        th, tw = self.tile_shape
        samples = self.samples
        tiles_across = math.ceil(self.shape[1] / tw)
        out = np.empty((r1 - r0, c1 - c0, samples), dtype=page.dtype)
        with self._decoding():
            for tr in range(r0 // th, (r1 - 1) // th + 1):
                for tc in range(c0 // tw, (c1 - 1) // tw + 1):
                    segment = self.decode_tile(tr * tiles_across + tc).reshape(th, tw, samples)
                    # The part of this tile inside the window.
                    ar0, ar1 = max(r0, tr * th), min(r1, (tr + 1) * th)
                    ac0, ac1 = max(c0, tc * tw), min(c1, (tc + 1) * tw)
                    out[ar0 - r0 : ar1 - r0, ac0 - c0 : ac1 - c0] = segment[
                        ar0 - tr * th : ar1 - tr * th, ac0 - tc * tw : ac1 - tc * tw
                    ]
        return out

    def decode_tile(self, index):
        """Read and decode TIFF tile `index` (row-major) alone."""
        page, fh = self.page, self._tif.filehandle
        with self._file_lock:
            fh.seek(page.dataoffsets[index])
            data = fh.read(page.databytecounts[index])
        segment, _, _ = page.decode(data, index, jpegtables=page.jpegtables)
        return segment

    @contextmanager
    def _decoding(self):
        import tifffile

        name = self.path
        try:
            with quiet_tifffile():
                yield
        except (tifffile.TiffFileError, OSError, EOFError) as exc:
            raise RasterReadError(f"cannot read {name!r} as a TIFF: {first_line(exc)}") from None
        except ValueError as exc:
            if "imagecodecs" in str(exc):
                raise DependencyError(
                    f"cannot decode {name!r}: its compression needs the imagecodecs package ({first_line(exc)})"
                ) from None
            raise RasterReadError(f"cannot decode {name!r}: {first_line(exc)}") from None
        except Exception as exc:  # decoders raise their own errors on corrupt data
            raise RasterReadError(
                f"cannot decode {name!r}: {type(exc).__name__}: {first_line(exc)}"
            ) from None


def first_line(exc):
    """The first line of an exception's message, or its type's name."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
