"""Shrinking a photo to the processing grid: its shape (:func:`resized_shape`) and its pixels."""

from __future__ import annotations

import cv2

from .._validate import check_int, check_rgb


def resize_longest(image, max_size):
    """Shrink `image` so its longest side is at most `max_size` (area averaging); never enlarge.

    Parameters
    ----------
    image : (rows, cols, 3) uint8 array
    max_size : int

    Returns
    -------
    (rows', cols', 3) uint8 array
        The same array when no shrinking is needed.
    """
    image = check_rgb("image", image)
    max_size = check_int("max_size", max_size, minimum=1)
    rows, cols = resized_shape(image.shape[:2], max_size)
    if (rows, cols) == image.shape[:2]:
        return image
    return cv2.resize(image, (cols, rows), interpolation=cv2.INTER_AREA)


def resized_shape(shape, max_size):
    """(rows, cols) of `shape` shrunk so its longest side is at most `max_size` (as :func:`resize_longest`).

    Examples
    --------
    >>> resized_shape((2300, 3500), 2000)
    (1314, 2000)
    """
    rows, cols = (int(n) for n in shape)
    longest = max(rows, cols)
    if longest <= max_size:
        return rows, cols
    scale = max_size / longest
    return max(1, round(rows * scale)), max(1, round(cols * scale))
