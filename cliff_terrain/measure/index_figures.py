"""Vegetation index columns of the plant, plot and season tables: mean and median per region.

For each index (``NDVI`` -> prefix ``ndvi``): ``ndvi_mean`` and ``ndvi_median`` over every pixel
of the region (the whole plot, or the plant's region) with a value, and ``ndvi_plant_mean`` and
``ndvi_plant_median`` over its plant pixels only (the segmentation's mask).
"""

from __future__ import annotations

import math

import numpy as np

INDEX_STATISTICS = ("mean", "median", "plant_mean", "plant_median")


def index_columns(names):
    """The columns of indices `names`, in order: ``ndvi_mean``, ``ndvi_median``, ``ndvi_plant_mean`` ..."""
    return tuple(f"{name.lower()}_{stat}" for name in names for stat in INDEX_STATISTICS)


def index_figures(labels, n, *, maps, mask):
    """Index columns of regions 1..n of `labels`: a list of n dicts (NaN where a region has no value).

    Parameters
    ----------
    labels : (rows, cols) int array
        0 outside every region.
    n : int
    maps : dict
        Index name -> (rows, cols) float map on the grid of `labels` (NaN = no value).
    mask : (rows, cols) bool array
        Plant pixels.

    Examples
    --------
    >>> labels = np.array([[1, 1, 1, 0]]); mask = np.array([[True, False, True, False]])
    >>> row = index_figures(labels, 1, maps={"NDVI": np.array([[0.8, 0.2, 0.6, 0.9]])}, mask=mask)[0]
    >>> [round(row[k], 3) for k in ("ndvi_mean", "ndvi_median", "ndvi_plant_mean", "ndvi_plant_median")]
    [0.533, 0.6, 0.7, 0.7]
    """
    labels = np.asarray(labels)
    mask = np.asarray(mask, dtype=bool)
    rows = [{} for _ in range(n)]
    for name, values in maps.items():
        prefix = name.lower()
        values = np.asarray(values, dtype=np.float64)
        inside = (labels > 0) & (labels <= n) & np.isfinite(values)
        for suffix, keep in (("", inside), ("plant_", inside & mask)):
            means, medians = _label_stats(labels[keep], values[keep], n)
            for k in range(n):
                rows[k][f"{prefix}_{suffix}mean"] = means[k]
                rows[k][f"{prefix}_{suffix}median"] = medians[k]
    return rows


def _label_stats(ids, values, n):
    """Mean and median of `values` per label 1..n (NaN for a label without values)."""
    means, medians = [math.nan] * n, [math.nan] * n
    if ids.size == 0:
        return means, medians
    order = np.argsort(ids, kind="stable")
    ids, values = ids[order], values[order]
    starts = np.searchsorted(ids, np.arange(1, n + 2))
    for k in range(n):
        part = values[starts[k] : starts[k + 1]]
        if part.size:
            means[k], medians[k] = float(part.mean()), float(np.median(part))
    return means, medians
