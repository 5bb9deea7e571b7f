"""Otsu's threshold of an index histogram, and how empty the valley at a threshold is: the two
measures every plant/soil rule of :mod:`~cliff_terrain.photo_heights.vegetation` is made of."""

from __future__ import annotations

import numpy as np

# The valley is read from a histogram of this many bins between the 0.5th and 99.5th percentiles.
VALLEY_BINS = 128


def otsu_threshold(values):
    """Otsu's threshold of `values` (a sample of large arrays); the value itself when all are equal."""
    flat = values.ravel()
    if flat.size == 0:
        return 0.0
    if flat.size > 400_000:  # a sample gives the same threshold at a fraction of the cost
        flat = flat[:: flat.size // 400_000]
    if float(flat.min()) == float(flat.max()):
        return float(flat[0])
    # float64: numpy 2 refuses 256 histogram bins over a float32 range of a few ulps.
    return _otsu(flat.astype(np.float64))


def _otsu(values):
    """``skimage.filters.threshold_otsu(values)`` for float values not all equal, step for step
    (tested equal): importing scikit-image's `filters` brings SciPy's `ndimage` with it, 0.16 s of
    a fresh Blender's first Build, for these few lines.
    """
    counts, edges = np.histogram(values, bins=256, range=(values.min(), values.max()))
    centres = (edges[:-1] + edges[1:]) / 2.0
    counts = counts.astype(np.float32)
    weight1 = np.cumsum(counts)
    weight2 = np.cumsum(counts[::-1])[::-1]
    mean1 = np.cumsum(counts * centres) / weight1
    mean2 = (np.cumsum((counts * centres)[::-1]) / weight2[::-1])[::-1]
    between = weight1[:-1] * weight2[1:] * (mean1[:-1] - mean2[1:]) ** 2
    return float(centres[np.argmax(between)])


def valley_ratio(values, split, thresholds):
    """Histogram density at each of `thresholds` over its mean between the class means of `split`.

    0 is an empty valley, about 1 no valley at all; NaN when the values have no spread.

    Examples
    --------
    Two classes apart (an empty valley at their split), then one class (none):

    >>> rng = np.random.default_rng(0)
    >>> two = np.concatenate([rng.normal(0.0, 0.05, 5000), rng.normal(0.6, 0.05, 5000)])
    >>> bool(valley_ratio(two, 0.3, (0.3,))[0] < 0.05)
    True
    >>> one = rng.normal(0.3, 0.1, 10000)
    >>> bool(valley_ratio(one, otsu_threshold(one), (0.3,))[0] > 0.9)
    True
    """
    nan = (float("nan"),) * len(thresholds)
    below, above = values[values <= split], values[values > split]
    if below.size == 0 or above.size == 0:
        return nan
    lo, hi = np.percentile(values, (0.5, 99.5))
    if not hi > lo:
        return nan
    hist, edges = np.histogram(values, VALLEY_BINS, range=(float(lo), float(hi)))
    # A Gaussian of 2 bins smooths the counts' noise without filling a valley.
    smooth = np.convolve(hist.astype(np.float64), np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2), "same")
    centres = 0.5 * (edges[:-1] + edges[1:])
    between = (centres >= below.mean()) & (centres <= above.mean())
    if not between.any() or smooth[between].mean() <= 0:
        return nan
    mean = smooth[between].mean()
    return tuple(float(smooth[int(np.argmin(np.abs(centres - t)))] / mean) for t in thresholds)
