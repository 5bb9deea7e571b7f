"""Percentiles of many small groups at once, as numpy's ``nanpercentile`` gives them.

``np.nanpercentile(blocks, q, axis=-1)`` falls back to one Python call per group as soon as one
NaN is present: on a ground grid of 30 000 blocks that is seconds. Sorting every group at once
(NaN sorts last) and interpolating between the two order statistics gives the same numbers
(numpy's default ``"linear"`` method, its own interpolation formula) in one vectorized pass.
"""

from __future__ import annotations

import numpy as np

__all__ = ["nan_percentile"]


def nan_percentile(values, q):
    """The `q`-th percentile of `values` along its last axis, ignoring NaN (NaN for an all-NaN group).

    Parameters
    ----------
    values : (..., n) float array
    q : float
        Percentile in [0, 100].

    Returns
    -------
    (...) float64 array
        What ``np.nanpercentile(values, q, axis=-1)`` returns, without its per-group loop.

    Examples
    --------
    >>> groups = np.array([[1.0, np.nan, 3.0, 2.0], [np.nan] * 4, [4.0, 0.0, 8.0, 2.0]])
    >>> nan_percentile(groups, 25.0).tolist()
    [1.5, nan, 1.5]
    """
    from ..errors import CliffTerrainError

    values = np.asarray(values)
    q = float(q)
    if not 0.0 <= q <= 100.0:
        raise CliffTerrainError(f"`q` must be in [0, 100], got {q}")
    ordered = np.sort(values, axis=-1)  # NaN last
    count = np.count_nonzero(~np.isnan(ordered), axis=-1)
    virtual = (count - 1).astype(np.float64) * (q / 100.0)
    below = np.floor(virtual)
    gamma = virtual - below
    last = np.maximum(count - 1, 0)
    lo = np.clip(below, 0, None).astype(np.intp)
    lo = np.minimum(lo, last)
    hi = np.minimum(lo + 1, last)
    a = np.take_along_axis(ordered, lo[..., None], axis=-1)[..., 0]
    b = np.take_along_axis(ordered, hi[..., None], axis=-1)[..., 0]
    # numpy's _lerp: a + (b - a) t, or b - (b - a)(1 - t) from the upper half (exact at t = 1).
    diff = np.subtract(b, a)
    out = np.asarray(np.add(a, diff * gamma), np.float64)
    upper = gamma >= 0.5
    out[upper] = (b - diff * (1 - gamma))[upper]
    out[count == 0] = np.nan
    return out
