"""The largest value within a disk around every pixel: OpenCV's elliptical grey dilation, faster.

``cv2.dilate`` with an elliptical kernel of radius r compares every pixel with each of the
kernel's ~3r^2 points: at r = 20 (plants 40 px across, usual in a mosaic's 1 cm tiles) that is
1.6 s on a 21 MP tile, a quarter of the tile's relief. The disk is a union of centred rectangles
(one per distinct row width, a staircase), and rectangles are separable, so the same maximum is a
short chain of thin horizontal and vertical dilations: H_w for each width w in turn, each from the
previous one, and V between them (Horner's scheme for max over rectangles). Done in bands of rows
that stay in the cache, on threads. The numbers are OpenCV's, exactly.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from .._threads import map_row_bands
from .._validate import check_int
from ..errors import CliffTerrainError

# Below this radius the kernel is small and OpenCV's own dilation is as fast.
_DIRECT_BELOW = 5
# Output rows per band (at least twice the radius, so the margins read stay below half the work).
_BAND_ROWS = 96


def disk_maximum(image, radius):
    """The maximum of `image` over a disk of `radius` pixels around every pixel.

    The same numbers as ``cv2.dilate(image, cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
    (2 * radius + 1, 2 * radius + 1)))`` (pixels outside the image are ignored), in time that
    grows with the radius rather than its square.

    Parameters
    ----------
    image : (rows, cols) float32 array
    radius : int
        The disk's radius in pixels, >= 0.

    Returns
    -------
    (rows, cols) float32 array

    Examples
    --------
    >>> import numpy as np
    >>> image = np.zeros((5, 7), np.float32)
    >>> image[2, 3] = 1.0
    >>> disk_maximum(image, 2).astype(int)
    array([[0, 0, 0, 1, 0, 0, 0],
           [0, 1, 1, 1, 1, 1, 0],
           [0, 1, 1, 1, 1, 1, 0],
           [0, 1, 1, 1, 1, 1, 0],
           [0, 0, 0, 1, 0, 0, 0]])
    """
    radius = check_int("radius", radius, minimum=0)
    image = np.ascontiguousarray(image, dtype=np.float32)
    if image.ndim != 2:
        raise CliffTerrainError(f"`image` must be 2-D (rows, cols), got shape {image.shape}")
    steps = _staircase(radius)
    if radius < _DIRECT_BELOW or steps is None or image.size == 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        return cv2.dilate(image, kernel)
    rows = image.shape[0]
    band = max(_BAND_ROWS, 2 * radius)
    out = np.empty_like(image)

    def one_band(r0, r1):
        # Each band reads `radius` rows beyond its own on both sides: every vertical step below
        # reaches at most that far in all, so the band's own rows come out exact.
        a0, a1 = max(0, r0 - radius), min(rows, r1 + radius)
        out[r0:r1] = _staircase_max(image[a0:a1], steps)[r0 - a0 : r1 - a0]

    map_row_bands(one_band, rows, band)
    return out


@lru_cache(maxsize=64)
def _staircase(radius):
    """OpenCV's elliptical kernel as ((half_width, half_height), ...) by increasing width: the
    disk is the union of the centred rectangles of those half sizes. None if the kernel is not a
    symmetric stack of centred runs (then the caller uses OpenCV's dilation itself)."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)).astype(bool)
    if not (np.array_equal(kernel, kernel[::-1]) and np.array_equal(kernel, kernel[:, ::-1])):
        return None
    half = []
    for row in kernel[radius:]:  # the centre row, then outwards
        cols = np.flatnonzero(row)
        if len(cols) == 0 or len(cols) != cols[-1] - cols[0] + 1:
            return None
        half.append(int(cols[-1]) - radius)
    if any(b > a for a, b in zip(half, half[1:], strict=False)):
        return None
    return tuple((w, max(dy for dy, h in enumerate(half) if h >= w)) for w in sorted(set(half)))


def _staircase_max(image, steps):
    """max over the staircase's rectangles R(w, h) of the dilation by R, as
    V[h_n](H[w_n] v V[h_{n-1} - h_n](H[w_{n-1}] v ...)) with H[w] built up from H[w_previous]."""
    grown = image
    width = 0
    acc = None
    height = 0
    for w, h in steps:
        if w > width:
            grown = cv2.dilate(grown, np.ones((1, 2 * (w - width) + 1), np.uint8))
            width = w
        if acc is None:
            acc = np.array(grown)
        else:
            if height > h:
                acc = cv2.dilate(acc, np.ones((2 * (height - h) + 1, 1), np.uint8))
            np.maximum(acc, grown, out=acc)
        height = h
    if height:
        acc = cv2.dilate(acc, np.ones((2 * height + 1, 1), np.uint8))
    return acc
