"""A plane (or any linear model) fitted by least squares with its outliers dropped, as the ground's
field plane and the occlusion check's open-soil plane are."""

from __future__ import annotations

import numpy as np


def robust_plane(design, z, *, rounds=5, cut=3.0):
    """Coefficients of `z` ~ `design` by least squares, refitted without the points lying more than
    `cut` robust deviations (1.4826 times the median absolute deviation, at least 1 mm) off the fit,
    up to `rounds` times or until the points kept stop changing (or fewer than three would be).

    Parameters
    ----------
    design : (n, k) float array
    z : (n,) float array
    rounds : int, optional
    cut : float, optional

    Returns
    -------
    (k,) float64 array

    Examples
    --------
    >>> x = np.arange(10.0)
    >>> z = 2.0 + 0.5 * x
    >>> z[3] += 5.0                                    # one outlier
    >>> np.round(robust_plane(np.column_stack([np.ones(10), x]), z), 6).tolist()
    [2.0, 0.5]
    """
    keep = np.ones(z.size, bool)
    coef = np.zeros(design.shape[1])
    for _ in range(rounds):
        coef, *_ = np.linalg.lstsq(design[keep], z[keep], rcond=None)
        residual = z - design @ coef
        spread = max(1.4826 * float(np.median(np.abs(residual[keep] - np.median(residual[keep])))), 1e-3)
        new_keep = np.abs(residual) <= cut * spread
        if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return coef
