"""Means of square blocks of pixels: the ground grid's reduction and the overviews' 2 x 2 means.

Both are `factor`² strided float32 additions (numpy's reduction over a short axis of a reshaped
array is three to four times slower, and writing the overviews of a windowed run's three rasters
was most of its writing time). A block's order of summation is fixed by its position in the block,
so a window's blocks give the numbers the whole raster's give.
"""

from __future__ import annotations

import numpy as np


def reduce_blocks(values, factor, weights):
    """Means of `factor` x `factor` blocks of `values` (rows, cols[, bands]) over `weights` (bool),
    and each block's count of weighted pixels.

    The sums are float32: exact for photos (integers below 2^24). Blocks cut by the edge count
    only their pixels; a block without weight has the mean NaN.

    Examples
    --------
    >>> means, counts = reduce_blocks(np.arange(6.0).reshape(2, 3), 2, np.ones((2, 3), bool))
    >>> means.tolist(), counts.tolist()
    ([[2.0, 3.5]], [[4.0, 2.0]])
    """
    rows, cols = weights.shape
    nr, nc = -(-rows // factor), -(-cols // factor)
    bands = values.shape[2:]
    if (rows, cols) != (nr * factor, nc * factor):  # pad to whole blocks; padding has no weight
        padded_w = np.zeros((nr * factor, nc * factor), bool)
        padded_w[:rows, :cols] = weights
        padded_v = np.zeros((nr * factor, nc * factor, *bands), values.dtype)
        padded_v[:rows, :cols] = values
        weights, values = padded_w, padded_v
    spread = weights.reshape(*weights.shape, *([1] * len(bands)))
    if np.issubdtype(values.dtype, np.integer):
        v = values.astype(np.float32)
        v *= spread
    else:  # NaN where there is no weight must not reach the sums
        v = np.where(spread, values, np.float32(0)).astype(np.float32, copy=False)
    w = weights.astype(np.float32)
    sums = np.zeros((nr, nc, *bands), np.float32)
    counts = np.zeros((nr, nc), np.float32)
    for i in range(factor):
        for j in range(factor):
            sums += v[i::factor, j::factor]
            counts += w[i::factor, j::factor]
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts.reshape(nr, nc, *([1] * len(bands)))
    return means, counts


def block_mean(data, factor):
    """Mean of `factor` x `factor` blocks of a 2-D raster, ignoring NaN (NaN where a block holds
    no data), as float32.

    Examples
    --------
    >>> block_mean(np.array([[1.0, np.nan], [3.0, np.nan]]), 2).tolist()
    [[2.0]]
    """
    data = np.asarray(data)
    means, _ = reduce_blocks(data, int(factor), np.isfinite(data))
    return means.astype(np.float32, copy=False)
