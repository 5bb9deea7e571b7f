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
import struct
import threading
from contextlib import contextmanager

import numpy as np

from ...errors import (
    DependencyError,
    ImageReadError,
    RasterReadError,
    TruncatedImageError,
    TruncatedRasterError,
)
from ._geokeys import GEO_TAGS


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


# The truncated kind of each reading error (a subclass of both, so callers catch either).
_TRUNCATED = {RasterReadError: TruncatedRasterError, ImageReadError: TruncatedImageError}


class TiffRaster:
    """The first image of a TIFF file, open for reading.

    Parameters
    ----------
    path : str or os.PathLike
    what : str, optional
        What the file is, for error messages ("raster", "mosaic", "image").
    error : type, optional
        The error raised for a missing or unreadable file (:class:`RasterReadError` by default); a
        file cut short raises its truncated kind (:class:`TruncatedRasterError`,
        :class:`TruncatedImageError`).

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
        (:data:`cliff_terrain.io.raster._geokeys.GEO_TAGS`).
    """

    def __init__(self, path, *, what="raster", error=RasterReadError):
        import tifffile

        self.path = name = os.fspath(path)
        truncated = _TRUNCATED.get(error, error)
        if not os.path.isfile(name):
            raise error(f"{what} {name!r} does not exist")
        try:
            with quiet_tifffile(), _header_problems() as problems:
                self._tif = tifffile.TiffFile(name)
                page = self._tif.pages[0]
                self.tags = {tag.code: tag.value for tag in page.tags.values() if tag.code in GEO_TAGS}
                end = _data_end(page)
        except Exception as exc:  # tifffile raises TiffFileError, OSError, and others on corrupt headers
            if hasattr(self, "_tif"):
                self._tif.close()
            size = os.path.getsize(name)
            kind = _other_format(name)
            if size == 0:
                raise error(f"{what} {name!r} is empty (0 bytes); copy or export it again") from None
            if kind is not None:
                raise error(
                    f"{what} {name!r} is {kind}, not a TIFF; give the GeoTIFF the survey exported"
                ) from None
            if isinstance(exc, tifffile.TiffFileError | EOFError | OSError | struct.error) and _looks_cut(
                name, size
            ):
                raise truncated(
                    f"{what} {name!r} is truncated: its TIFF header ends early ({size} bytes); copy or export it again"
                ) from None
            raise error(
                f"{what} {name!r} is corrupt: tifffile cannot read it as a TIFF ({first_line(exc)})"
            ) from None
        size = os.path.getsize(name)
        # A file cut short (a copy or download interrupted) is told as such, before any pixel is
        # decoded: its header points past its end (tifffile logs and skips such tags), or its strips
        # or tiles end beyond it. Otherwise tifffile would report a missing georeference or a strip
        # that "cannot be reshaped".
        if end > size or any("invalid value offset" in p or "missing data offset" in p for p in problems):
            self._tif.close()
            needs = f", its image data needs {end}" if end > size else ""
            raise truncated(
                f"{what} {name!r} is truncated: the file has {size} bytes{needs} (its header points past "
                "its end); copy or export it again"
            )
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
            raise RasterReadError(
                f"cannot read {name!r} as a TIFF: the file is corrupt ({first_line(exc)})"
            ) from None
        except ValueError as exc:
            if "imagecodecs" in str(exc):
                raise DependencyError(
                    f"cannot decode {name!r}: its compression needs the imagecodecs package ({first_line(exc)})"
                ) from None
            raise RasterReadError(
                f"cannot decode {name!r}: the file is corrupt ({first_line(exc)})"
            ) from None
        except Exception as exc:  # decoders raise their own errors on corrupt data
            raise RasterReadError(
                f"cannot decode {name!r}: the file is corrupt ({type(exc).__name__}: {first_line(exc)})"
            ) from None


class _Problems(logging.Handler):
    """Collects what tifffile logs about this thread's file while its header is parsed."""

    def __init__(self):
        super().__init__(level=logging.DEBUG)
        self.thread = threading.get_ident()
        self.messages = []

    def emit(self, record):
        if record.thread == self.thread:
            self.messages.append(record.getMessage())


@contextmanager
def _header_problems():
    logger = logging.getLogger("tifffile")
    handler = _Problems()
    logger.addHandler(handler)  # also keeps them off stderr (logging's last-resort handler)
    try:
        yield handler.messages
    finally:
        logger.removeHandler(handler)


def _data_end(page):
    """The byte just past the page's last strip or tile (0 when it has none)."""
    try:
        return max(
            (int(o) + int(n) for o, n in zip(page.dataoffsets, page.databytecounts, strict=False)), default=0
        )
    except (TypeError, ValueError):
        return 0


def _looks_cut(name, size):
    """A TIFF whose header tifffile cannot parse, and that starts like a TIFF: cut, not another format."""
    with open(name, "rb") as stream:
        head = stream.read(4)
    return size > 0 and head in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


_SIGNATURES = {
    b"\xff\xd8\xff": "a JPEG image",
    b"\x89PNG": "a PNG image",
    b"RIFF": "a RIFF file (WebP?)",
    b"BM": "a BMP image",
    b"%PDF": "a PDF document",
    b"PK\x03\x04": "a ZIP archive",
}


def _other_format(name):
    """What a file that is not a TIFF is, from its first bytes (None: not one of these)."""
    with open(name, "rb") as stream:
        head = stream.read(8)
    return next((kind for magic, kind in _SIGNATURES.items() if head.startswith(magic)), None)


def first_line(exc):
    """The first line of an exception's message, or its type's name."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
