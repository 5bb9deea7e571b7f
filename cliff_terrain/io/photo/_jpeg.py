"""JPEG specifics: decoding reduced by libjpeg, the size-versus-bytes check, and OpenCV's decode.

A colour or greyscale JPEG is decoded by OpenCV in one call that releases the GIL, with the same
libjpeg-turbo settings as Pillow (the same pixels, bit for bit).
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from ...errors import ImageReadError
from ._reader import MIN_SIDE

JPEG_FORMATS = ("JPEG", "MPO")


_JPEG_REDUCTIONS = (8, 4, 2)


# OpenCV's flags for a colour decode reduced by libjpeg while decoding (RGB order is added).
_CV2_REDUCED = {
    1: cv2.IMREAD_COLOR,
    2: cv2.IMREAD_REDUCED_COLOR_2,
    4: cv2.IMREAD_REDUCED_COLOR_4,
    8: cv2.IMREAD_REDUCED_COLOR_8,
}


# A flat grey JPEG with optimised Huffman tables stores about 250 pixels per byte; a header claiming
# 16 times more than that for the file's size describes data that is not there (a patched header or
# a cut file that libjpeg would silently fill with grey).
_JPEG_MAX_PIXELS_PER_BYTE = 4096


def check_jpeg_size(name, width, height):
    """Refuse a JPEG whose header claims far more pixels than its bytes could hold."""
    size = os.path.getsize(name)
    if width * height > _JPEG_MAX_PIXELS_PER_BYTE * size:
        raise ImageReadError(
            f"cannot read image {name!r}: its header claims {width}x{height} pixels but the file holds "
            f"only {size} bytes; it is truncated or corrupt"
        )


def jpeg_reduction(width, height, max_size):
    """Largest libjpeg reduction (8, 4, 2) keeping the longest side >= `max_size`, else 1."""
    longest = max(width, height)
    for scale in _JPEG_REDUCTIONS:
        if -(-longest // scale) >= max_size and min(width, height) // scale >= MIN_SIDE:
            return scale
    return 1


def jpeg_data(im, name):
    """The bytes of a colour or greyscale JPEG, for :func:`decode_jpeg_at_once`; else None."""
    if im.format not in JPEG_FORMATS or im.mode not in ("RGB", "L"):
        return None  # CMYK: Pillow's conversion to RGB
    with open(name, "rb") as file:
        return file.read()


def decode_jpeg_at_once(data, shape, reduction):
    """A JPEG's pixels as (rows, cols, 3) uint8 RGB in stored orientation, or None.

    OpenCV decodes the whole file in one call that releases the GIL, where Pillow returns to
    Python every 64 KiB of data and every band of rows: a thread decoding a photo keeps going
    while another holds the GIL (as Blender's bulk calls do). Both bundle libjpeg-turbo with the
    same settings, so the pixels are Pillow's, bit for bit, at every reduction (tested). None, and
    Pillow decodes instead (and words any error), when OpenCV cannot decode the data (a truncated
    file: its decoder stops rather than filling with grey) or its size disagrees with the
    (rows, cols) `shape` Pillow read from the header.
    """
    flags, swap = cv2_colour_flags(reduction)
    if swap and data.rfind(b"\xff\xd9") < data.rfind(b"\xff\xda"):
        # No end-of-image marker after the last scan: the file is cut. OpenCV 4.11 and newer (those
        # with IMREAD_COLOR_RGB) return nothing then; older releases fill the missing rows with
        # grey, so the bytes are checked for them only. Pillow words the error.
        return None
    try:
        rgb = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error:
        return None  # an OpenCV that refuses these flags: Pillow decodes the same pixels
    if rgb is None or rgb.shape != (*shape, 3):
        return None
    if swap:
        cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB, dst=rgb)  # in place, and it releases the GIL too
    return rgb


def cv2_colour_flags(reduction):
    """OpenCV's imread flags for a colour decode in RGB order, and whether BGR must still be swapped.

    OpenCV 4.11 added ``IMREAD_COLOR_RGB``; OpenCV 5 refuses it beside the BGR bit that the reduced
    colour modes carry (``IMREAD_REDUCED_COLOR_2 = IMREAD_COLOR_BGR | 16``), so that bit is cleared.
    Older releases decode BGR, swapped afterwards.
    """
    flags = _CV2_REDUCED[reduction] | cv2.IMREAD_IGNORE_ORIENTATION
    rgb_flag = getattr(cv2, "IMREAD_COLOR_RGB", None)
    if rgb_flag is None:
        return flags, True
    return (flags & ~getattr(cv2, "IMREAD_COLOR_BGR", cv2.IMREAD_COLOR)) | rgb_flag, False
