"""Sangwine's quaternion colour-edge filter, computed as the linear RGB filter it is.

The two-sided quaternion convolution of Sangwine (1998) with its six non-zero taps reduces to two
3x3 colour matrices applied to sums of three neighbouring pixels, so it runs as a handful of
OpenCV passes over cache-sized strips instead of quaternion products per pixel.
"""

from __future__ import annotations

import cv2
import numpy as np

from .._threads import map_row_bands, usable_cores
from .._validate import check_choice, check_float, check_rgb

__all__ = ["DEFAULT_SCALE", "ORIENTATIONS", "colour_matrices", "quaternion_filter"]

ORIENTATIONS = ("horizontal", "vertical")
# Maps a uniform colour to its grey level: 6 taps of modulus squared 1/6 sum to the identity on grey.
DEFAULT_SCALE = 1 / np.sqrt(6)

# OpenCV's default border (gfedcb|abcdefgh|gfedcba, numpy's mode="reflect"): the edge pixel is not
# repeated, so the colour difference across the border is zero and the border stays grey.
_BORDER = cv2.BORDER_REFLECT_101

# sepFilter2D kernels: a sum of three pixels along one axis, nothing along the other. (It runs
# 2-3x faster than boxFilter from uint8 or float32 to float32.)
_THREE = np.ones(3, np.float32)
_ONE = np.ones(1, np.float32)

_N = 1.0 / np.sqrt(3.0)
_GREY_PROJECTION = np.full((3, 3), 1.0 / 3.0)  # J = n n^T, n the unit grey axis
_GREY_CROSS = np.array([[0.0, -_N, _N], [_N, 0.0, -_N], [-_N, _N, 0.0]])  # K p = n x p

# A float32 strip of about this many bytes stays in a core's L2 cache between the passes.
_STRIP_BYTES = 1 << 20
# Below this many pixels a thread pool costs more than it saves.
_MIN_PIXELS_PER_WORKER = 1 << 18
# The passes are memory-bound; two threads were measured (on 2 cores) to help, more were not.
_MAX_WORKERS = 2


def colour_matrices(scale=DEFAULT_SCALE, *, gain=1.0):
    """The two colour matrices of the filter's linear form.

    Parameters
    ----------
    scale : float, optional
        Modulus of the mask coefficient R = scale * exp(mu * pi / 4).
    gain : float, optional
        Factor folded into both matrices (1/255 for uint8 input).

    Returns
    -------
    below, above : (3, 3) float64 ndarray
        ``gain * scale**2 * (J + K)`` and ``gain * scale**2 * (J - K)``: the maps R p conj(R) and
        conj(R) p R of a pixel p, applied to the row (or column) sums that meet the mask's R and
        conj(R) taps.

    Examples
    --------
    >>> below, above = colour_matrices()
    >>> np.allclose(below @ [1.0, 1.0, 1.0], [1 / 6, 1 / 6, 1 / 6])
    True
    """
    factor = gain * scale * scale
    return factor * (_GREY_PROJECTION + _GREY_CROSS), factor * (_GREY_PROJECTION - _GREY_CROSS)


def quaternion_filter(image, *, scale=DEFAULT_SCALE, orientation="horizontal"):
    """Filter an RGB image with Sangwine's quaternion colour-edge mask.

    Each pixel is the pure quaternion q = R i + G j + B k. With mu = (i + j + k) / sqrt(3) and
    Rq = scale * exp(mu * pi / 4), the left mask is ``[Rq Rq Rq; 0 0 0; Rq* Rq* Rq*]`` and the right
    mask its element-wise conjugate; the result is the vector part of the two-sided convolution
    sum of L * q * R, a true convolution as QTFM's ``conv2({left, right}, q)`` computes it.

    Parameters
    ----------
    image : (rows, cols, 3) ndarray
        RGB image. uint8 is scaled to [0, 1]; floating point is taken as it is.
    scale : float, optional
        Modulus of the mask coefficient Rq, > 0. The default 1/sqrt(6) maps a uniform colour to
        its grey level (R + G + B) / 3.
    orientation : {"horizontal", "vertical"}, optional
        "horizontal" uses the mask as written (rows of Rq above and below the centre: it responds
        to colour changes from row to row); "vertical" uses the transposed masks (changes from
        column to column).

    Returns
    -------
    filtered : (rows, cols, 3) float32 ndarray
        The vector part (i, j, k as R, G, B) of the convolution, the same size as `image`.
        Borders are reflected without repeating the edge pixel (OpenCV ``BORDER_REFLECT_101``,
        numpy's ``mode="reflect"``).

    Raises
    ------
    CliffTerrainError
        If `image` is not an RGB uint8 or finite floating-point array, `scale` is not a finite
        number > 0, or `orientation` is not one of the choices.

    Notes
    -----
    Conjugating a pure quaternion p by Rq rotates it by +90 degrees about the grey axis
    n = (1, 1, 1)/sqrt(3) and scales it by s^2 = scale^2: ``Rq p Rq* = s^2 (J + K) p`` and
    ``Rq* p Rq = s^2 (J - K) p``, with J = n n^T (projection on the grey axis) and K p = n x p.
    Summing the six taps therefore gives, per pixel (horizontal orientation),

        y = s^2 J (sum_below + sum_above) + s^2 K (sum_below - sum_above),

    where ``sum_below`` and ``sum_above`` are the sums of the three pixels in the rows below and
    above (for "vertical", the three pixels in the columns to the right and to the left). A
    convolution flips the mask, so its Rq row meets the row *below* the pixel; a
    correlation would swap the two sums and flip the sign of the K term, i.e. the hue of every
    edge colour (a red-over-green edge turns blue here, yellow under correlation). With the
    default scale a uniform colour maps to its grey, an edge between two greys stays grey
    (K kills the grey axis) and only chroma changes produce colour.

    The computation is this linear form in float32: a horizontal (vertical) box sum of three
    pixels, which also converts uint8 to float, then the two 3x3 colour matrices (with the 1/255
    and s^2 folded in) applied to the rows below and above, and one addition. It runs over strips
    of rows small enough to stay in cache, on up to two threads; the only large allocation is the
    result. It agrees with a quaternion-by-quaternion evaluation to about 1e-7.

    References
    ----------
    .. [1] S. J. Sangwine, "Colour image edge detector based on quaternion convolution",
       Electronics Letters 34(10), 969-971, 1998.
    .. [2] S. J. Sangwine and N. Le Bihan, Quaternion Toolbox for Matlab (QTFM), ``conv2``.

    Examples
    --------
    >>> red_over_green = np.zeros((4, 3, 3), np.uint8)
    >>> red_over_green[:2, :, 0] = 255
    >>> red_over_green[2:, :, 1] = 255
    >>> out = quaternion_filter(red_over_green)
    >>> out.shape, out.dtype
    ((4, 3, 3), dtype('float32'))
    >>> np.round(out[0, 0], 3)  # inside the red: its grey level
    array([0.333, 0.333, 0.333], dtype=float32)
    >>> bool(out[1, 0, 2] > 0.9)  # at the edge: blue
    True
    """
    image = check_rgb("image", image)
    scale = check_float("scale", scale, minimum=0.0, strict_minimum=True)
    orientation = check_choice("orientation", orientation, ORIENTATIONS)

    gain = 1.0 / 255.0 if image.dtype == np.uint8 else 1.0
    below, above = (m.astype(np.float32) for m in colour_matrices(scale, gain=gain))
    image = np.ascontiguousarray(image)

    rows, cols = image.shape[:2]
    out = np.empty((rows, cols, 3), np.float32)
    strip = max(1, _STRIP_BYTES // (cols * 12))
    run = _horizontal_strips if orientation == "horizontal" else _vertical_strips
    workers = max(
        1, min(_MAX_WORKERS, usable_cores(), rows * cols // _MIN_PIXELS_PER_WORKER, -(-rows // strip))
    )
    # Contiguous blocks of strips, one per worker (OpenCV releases the GIL); each reuses its buffers.
    step = -(-rows // (workers * strip)) * strip
    map_row_bands(lambda r0, r1: run(image, out, below, above, r0, r1, strip), rows, step)
    return out


_FILTER_DTYPES = (np.dtype(np.uint8), np.dtype(np.float32))


def _as_filter_input(rows, staging):
    """`rows` as sepFilter2D takes them: uint8 or native float32 as they are, other floats copied."""
    if staging is None:
        return rows
    staged = staging[: len(rows)]
    np.copyto(staged, rows, casting="same_kind")  # float64, float16, longdouble, other byte order
    return staged


def _reflect(index, size):
    """OpenCV's BORDER_REFLECT_101 for an index at most one step outside [0, size)."""
    if size == 1:
        return 0
    if index < 0:
        return -index
    if index >= size:
        return 2 * size - 2 - index
    return index


def _horizontal_strips(image, out, below, above, start, stop, strip):
    """Fill out[start:stop]: y[r] = below @ box[r + 1] + above @ box[r - 1], box = 3-pixel row sums."""
    rows, cols = image.shape[:2]
    box = np.empty((strip + 2, cols, 3), np.float32)  # box[i] is the sum for image row r0 - 1 + i
    partial = np.empty((strip, cols, 3), np.float32)  # the conj(R) taps, added last
    staging = None if image.dtype in _FILTER_DTYPES else np.empty((strip + 2, cols, 3), np.float32)
    for r0 in range(start, stop, strip):
        r1 = min(r0 + strip, stop)
        m = r1 - r0
        lo, hi = max(r0 - 1, 0), min(r1 + 1, rows)
        source = _as_filter_input(image[lo:hi], staging)
        cv2.sepFilter2D(
            source, cv2.CV_32F, _THREE, _ONE, dst=box[lo - r0 + 1 : hi - r0 + 1], borderType=_BORDER
        )
        if r0 == 0:
            box[0] = box[_reflect(-1, rows) + 1]
        if r1 == rows:
            box[m + 1] = box[_reflect(rows, rows) - r0 + 1]
        target = out[r0:r1]
        cv2.transform(box[2 : m + 2], below, dst=target)
        cv2.transform(box[:m], above, dst=partial[:m])
        cv2.add(target, partial[:m], dst=target)


def _vertical_strips(image, out, below, above, start, stop, strip):
    """Fill out[start:stop]: y[:, c] = below @ box[:, c + 1] + above @ box[:, c - 1], box = 3-pixel column sums."""
    rows, cols = image.shape[:2]
    box = np.empty((strip + 2, cols, 3), np.float32)
    partial = np.empty((strip, cols, 3), np.float32)  # the conj(R) taps, added last
    staging = None if image.dtype in _FILTER_DTYPES else np.empty((strip + 2, cols, 3), np.float32)
    right, left = _reflect(cols, cols), _reflect(-1, cols)
    for r0 in range(start, stop, strip):
        r1 = min(r0 + strip, stop)
        m = r1 - r0
        lo, hi = max(r0 - 1, 0), min(r1 + 1, rows)
        # The halo rows make the column sums of rows r0..r1-1 exact; OpenCV reflects only at the
        # image's own top and bottom, where lo == 0 or hi == rows.
        source = _as_filter_input(image[lo:hi], staging)
        cv2.sepFilter2D(source, cv2.CV_32F, _ONE, _THREE, dst=box[: hi - lo], borderType=_BORDER)
        sums = box[r0 - lo : r0 - lo + m]
        target, other = out[r0:r1], partial[:m]
        if cols > 1:
            cv2.transform(sums[:, 1:], below, dst=target[:, :-1])
            cv2.transform(sums[:, :-1], above, dst=other[:, 1:])
        cv2.transform(sums[:, right : right + 1], below, dst=target[:, cols - 1 :])
        cv2.transform(sums[:, left : left + 1], above, dst=other[:, :1])
        cv2.add(target, other, dst=target)
