"""What every photo reader offers (:class:`PhotoReader`), and the error handling they share.

:func:`cliff_terrain.io.photo.open_image` returns a reader chosen by the file's format: Pillow's
(:class:`cliff_terrain.io.photo.OpenImage`) for JPEG, PNG, WebP, BMP and most TIFFs, tifffile's
(:class:`cliff_terrain.io.photo.TiffPhoto`) for the TIFF orthophotos Pillow cannot read.
"""

from __future__ import annotations

import contextlib
import warnings
from typing import Protocol, runtime_checkable

from PIL import Image

from ..._deps import environment_error
from ...errors import CliffTerrainError, ImageReadError, ImageTooLargeError

#: Fewest rows and columns an image may have (a 1-pixel-wide image has no surface to relieve).
MIN_SIDE = 2


@runtime_checkable
class PhotoReader(Protocol):
    """A photo whose header has been read and checked, its pixels not yet decoded.

    Attributes
    ----------
    shape : tuple of int
        (rows, cols) of the array :meth:`decode` returns.
    metadata : ImageMetadata
        What the header tells (no pixel decoded: ``valid_fraction`` and ``valid_mask`` are None).
    """

    shape: tuple

    @property
    def metadata(self): ...

    def decode(self):
        """Decode the pixels (once) and close the file: ``(rgb, metadata)``."""

    def close(self):
        """Close the file; decoding is then no longer possible. Closing twice is harmless."""


@contextlib.contextmanager
def reading(name):
    """Turn whatever Pillow raises or warns while reading `name` into Cliff Terrain errors."""
    try:
        with warnings.catch_warnings():
            # Corrupt-EXIF and decompression-bomb warnings: our own checks decide instead.
            warnings.simplefilter("ignore")
            yield
    except CliffTerrainError:
        raise
    except Image.DecompressionBombError as error:
        raise ImageTooLargeError(f"image {name!r} is too large to decode: {error}") from error
    except MemoryError as error:
        raise ImageTooLargeError(f"image {name!r}: ran out of memory while decoding it") from error
    except Exception as error:
        environment = environment_error(error, doing=f"cannot read image {name!r}")
        if environment is not None:
            raise environment from error
        text = str(error)
        if "truncated" in text:
            why = f"the file is truncated (its data ends before the image does: {text})"
        else:
            why = f"its data is corrupt or unsupported ({type(error).__name__}: {text})"
        raise ImageReadError(f"cannot read image {name!r}: {why}") from error
