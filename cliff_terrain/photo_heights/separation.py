"""How plainly two classes of pixels differ: in colour (chroma) and in height (a surface model).

Ashman's D, D = sqrt(2) |m1 - m2| / sqrt(s1^2 + s2^2), with medians and robust spreads (1.4826 times
the median absolute deviation): 2 or more is Ashman, Bird and Zepf's (1994) bound for two cleanly
separated classes. :func:`cliff_terrain.photo_heights.vegetation.index_threshold` reads the chroma's
(colour photos) or the red reflectance's (multispectral NDVI) to take the photo's own split without a
valley; ``build_relief`` the surface's to decide a class that colour cannot (senescent canopy or straw?).
"""

from __future__ import annotations

import cv2
import numpy as np

from .._validate import check_rgb
from .histogram import otsu_threshold


def chroma_map(image):
    """CIELAB chroma C* = sqrt(a*^2 + b*^2) of an RGB image (OpenCV's 8-bit Lab), lightly blurred
    as :func:`blurred_index` is. Grey and brown soil score low, green leaves high.

    Examples
    --------
    >>> img = np.zeros((1, 2, 3), np.uint8); img[0, 0] = (40, 160, 40); img[0, 1] = (90, 85, 80)
    >>> c = chroma_map(np.repeat(np.repeat(img, 9, 0), 9, 1))
    >>> bool(c[4, 2] > 40 > 5 > c[4, 15])
    True
    """
    image = np.ascontiguousarray(check_rgb("image", image))
    if image.dtype.kind == "f":  # floating point is [0, 1] (check_rgb)
        image = np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)
    elif image.dtype != np.uint8:
        image = np.clip(image, 0, 255).astype(np.uint8)
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB)
    a = lab[..., 1].astype(np.float32) - np.float32(128.0)
    b = lab[..., 2].astype(np.float32) - np.float32(128.0)
    return cv2.GaussianBlur(np.hypot(a, b), (0, 0), 1.0)


def colour_separation(chroma, upper):
    """Ashman's D of `chroma` between the pixels where `upper` is True and the others.

    D = sqrt(2) |m1 - m2| / sqrt(s1^2 + s2^2) with medians m and robust spreads s (1.4826 times the
    median absolute deviation, at least 0.5: chroma is read on a whole-number scale), signed:
    positive when the upper side is the more chromatic. NaN when a side is empty.

    Examples
    --------
    >>> c = np.r_[np.full(50, 5.0), np.full(50, 40.0)]
    >>> round(colour_separation(c, np.arange(100) >= 50), 1)
    70.0
    """
    return _ashman_d(chroma, upper, min_spread=0.5)


def red_separation(red, upper):
    """Ashman's D of the red reflectance between the pixels where `upper` is False and the others.

    As :func:`colour_separation`, signed: positive when the `upper` side (the higher NDVI) is the
    darker in red, as chlorophyll makes leaves (red reflectance of a few percent over soil's 10-30 %).
    NDVI can split any class in two (its halves differ in NIR: sunlit and shaded leaves, dense and
    thin canopy); plants and soil differ in red too. Spreads of at least 1/512, half an 8-bit step of
    reflectance, the coarsest an orthomosaic stores. NaN when a side is empty.

    Examples
    --------
    >>> red = np.r_[np.full(50, 0.15), np.full(50, 0.04)]   # soil, then leaves
    >>> bool(red_separation(red, np.arange(100) >= 50) > 2)
    True
    """
    return _ashman_d(red, ~np.asarray(upper, dtype=bool), min_spread=1.0 / 512.0)


def _ashman_d(values, upper, *, min_spread):
    values = np.asarray(values, dtype=np.float64).ravel()
    upper = np.asarray(upper, dtype=bool).ravel()
    hi, lo = values[upper], values[~upper]
    if hi.size == 0 or lo.size == 0:
        return float("nan")
    m_hi, m_lo = float(np.median(hi)), float(np.median(lo))
    s_hi = max(1.4826 * float(np.median(np.abs(hi - m_hi))), min_spread)
    s_lo = max(1.4826 * float(np.median(np.abs(lo - m_lo))), min_spread)
    return float(np.sqrt(2.0) * (m_hi - m_lo) / np.hypot(s_hi, s_lo))


def surface_separation(surface, upper, *, valid=None):
    """How far the pixels where `upper` is True stand above the others on a surface model.

    Ashman's D (as :func:`colour_separation`, signed: positive when `upper` stands higher) of the
    surface's heights after a plane fitted to the other pixels (the ground, by least squares) is
    taken off, so that a field's slope or a flight's tilt does not pass for canopy. NaN when either
    side has fewer than 10 pixels with a height.

    Examples
    --------
    >>> rr, cc = np.mgrid[:60, :80]
    >>> ground = 100 + 0.05 * rr + 0.02 * cc            # a sloping field
    >>> canopy = (cc > 30) & (cc < 60)
    >>> bool(surface_separation(ground + 0.6 * canopy, canopy) > 2)
    True
    >>> bool(abs(surface_separation(ground, canopy)) < 2)  # straw lies on the ground
    True
    """
    surface = np.asarray(surface, dtype=np.float64)
    upper = np.asarray(upper, dtype=bool)
    ok = np.isfinite(surface) if valid is None else np.isfinite(surface) & np.asarray(valid, bool)
    lower = ok & ~upper
    upper = ok & upper
    if np.count_nonzero(upper) < 10 or np.count_nonzero(lower) < 10:
        return float("nan")
    rr, cc = np.nonzero(lower)
    step = max(1, rr.size // 100_000)
    rr, cc = rr[::step], cc[::step]
    design = np.column_stack([np.ones(rr.size), rr, cc]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(design, surface[rr, cc], rcond=None)
    gr, gc = np.nonzero(ok)
    residual = surface[gr, gc] - (coef[0] + coef[1] * gr + coef[2] * gc)
    # Heights are continuous: spreads of at least 1 cm, the photogrammetric DSM's own noise.
    hi, lo = residual[upper[gr, gc]], residual[lower[gr, gc]]
    m_hi, m_lo = float(np.median(hi)), float(np.median(lo))
    s_hi = max(1.4826 * float(np.median(np.abs(hi - m_hi))), 0.01)
    s_lo = max(1.4826 * float(np.median(np.abs(lo - m_lo))), 0.01)
    return float(np.sqrt(2.0) * (m_hi - m_lo) / np.hypot(s_hi, s_lo))


def surface_split(vi, surface, *, valid=None, upper=None):
    """The photo's own split of index `vi` (Otsu's) and how far its upper side stands on `surface`.

    Returns ``(split, d)``: Otsu's threshold of `vi` (on the `valid` pixels) and Ashman's D of the
    pixels above it against the others on `surface`
    (:func:`~cliff_terrain.photo_heights.separation.surface_separation`). With `upper` (the
    threshold of plants already above an upper valley), those plants are left out of both sides:
    the question is whether the class between the two splits (residue or senescent canopy) stands,
    and the plants' height must not speak for it. The split decides when ``d >=
    COLOUR_SEPARATION`` (2) (:func:`~cliff_terrain.photo_heights.segmentation.decide_by_surface`, and the
    windowed path's threshold).

    Examples
    --------
    >>> rr, cc = np.mgrid[:60, :80]
    >>> vi = np.where(cc > 40, 0.3, 0.1) + 0.01 * np.sin(rr)     # two classes by the index
    >>> dsm = 100 + 0.01 * rr + 0.7 * (cc > 40)                   # the upper one stands 0.7 m
    >>> split, d = surface_split(vi.astype(np.float32), dsm)
    >>> bool(0.1 < split < 0.3), bool(d >= 2)
    (True, True)
    """
    split = otsu_threshold(vi if valid is None else vi[valid])
    between = valid
    if upper is not None:
        between = ~(vi > upper) if valid is None else valid & ~(vi > upper)
    return split, surface_separation(surface, vi > split, valid=between)
