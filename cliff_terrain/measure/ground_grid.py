"""The grid the ground is fitted on: whole orthophoto pixels up to 5 cm, in memory as in windows.

The ground's finest detail is a Gaussian of 0.15 m (:data:`cliff_terrain.measure.ground.DEFAULT_DETAIL_M`)
and its checks work in blocks of metres: a 1 cm orthophoto holds 25 times the pixels the ground
can use. :func:`fit_on_ground_grid` reduces the surface and its bare-soil evidence to the ground
grid as the windowed path's first pass does (:func:`cliff_terrain.measure.window_tasks.coarse_window`),
fits the ground there (:func:`cliff_terrain.measure.ground.fit_ground`), and brings the ground, its
standard error and its support back bilinearly, pixel centres aligned
(:func:`cliff_terrain.measure.window_reading.upsample`). On a 12 MP orthophoto at 1 cm the ground,
CHM and plot table took 18 s on the full grid and 1.6-2.3 s on the 5 cm grid (``bench/bench_canopy.py``).
"""

from __future__ import annotations

import math

import numpy as np

from ..io.raster.blocks import reduce_blocks
from .ground import BASELINE_PERCENTILE, DEFAULT_BLOCK_M, fit_ground, naive_block_ground, surface_data
from .ground_blocks import block_count
from .window_reading import upsample

#: The ground grid's coarsest pixel (metres) for the detail's sake: the ground's finest detail is
#: a Gaussian of 0.15 m.
GROUND_PIXEL_M = 0.05
#: The ground grid keeps at least this many pixels across: its minimums of bare soil (100 pixels,
#: :func:`cliff_terrain.measure.ground.check_enough_soil`) count its pixels.
MIN_GROUND_SIDE = 100


def ground_factor(shape, pixel_size, *, ground_pixels=None):
    """Orthophoto pixels per ground-grid pixel: the most whole pixels up to 5 cm, within `ground_pixels`.

    The ground grid's pixel is the largest whole multiple of the orthophoto's that is at most
    `GROUND_PIXEL_M` (a 2.2 cm orthophoto: 4.4 cm; 3.1 cm: its own), on a grid at least
    `MIN_GROUND_SIDE` pixels across; then coarser if `ground_pixels` asks for it.

    Parameters
    ----------
    shape : (rows, cols)
    pixel_size : float
        Metres per orthophoto pixel.
    ground_pixels : int, optional
        Budget of the ground grid (pixels); default none.

    Examples
    --------
    >>> ground_factor((20000, 20000), 0.01, ground_pixels=8_000_000)   # 400 MP at 1 cm: 8 cm
    8
    >>> ground_factor((4000, 3000), 0.01)                               # 12 MP at 1 cm: 5 cm
    5
    >>> ground_factor((535, 550), 0.2)                                  # a small field: its own grid
    1
    >>> ground_factor((300, 400), 0.005)                                # 1.5 m at 5 mm: 100 across
    3
    """
    rows, cols = shape
    by_detail = max(1, math.floor(GROUND_PIXEL_M / pixel_size + 1e-9))
    by_detail = max(1, min(by_detail, min(rows, cols) // MIN_GROUND_SIDE))
    if ground_pixels is None:
        return by_detail
    by_budget = max(1, math.ceil(math.sqrt(rows * cols / ground_pixels)))
    factor = max(by_detail, by_budget)
    while math.ceil(rows / factor) * math.ceil(cols / factor) > ground_pixels:
        factor += 1
    return factor


def reduce_for_ground(surface, soil, has_data, factor):
    """`surface` and `soil` reduced by `factor` as the windowed path's ground grid is.

    Each ``factor`` x ``factor`` block gives the mean of its bare-soil pixels when it shows any
    (so that its plants do not lift the soil it shows; any, not most, since a share threshold
    aliases with the crop rows), else the mean of its pixels with data; it has data when most of
    its pixels inside the raster have.

    Returns
    -------
    surface : float32 array
        The ground grid's heights, NaN where it has no data or no surface
        (:func:`~cliff_terrain.measure.ground.surface_data`).
    soil, data : bool arrays
        Blocks that show bare soil (and have data), and blocks with data.

    Examples
    --------
    >>> surface = np.array([[0.0, 1.0, 5.0, 5.0], [0.0, 1.0, 5.0, 5.0]], np.float32)
    >>> soil = np.array([[True, False, False, False]] * 2)
    >>> coarse, bare, data = reduce_for_ground(surface, soil, np.ones((2, 4), bool), 2)
    >>> coarse.tolist(), bare.tolist(), data.tolist()
    ([[0.0, 5.0]], [[True, False]], [[True, True]])
    """
    finite = has_data & surface_data(surface)  # an undeclared -3.4e38 would swamp its block's mean
    heights, _ = reduce_blocks(surface, factor, finite)
    heights_bare, n_bare = reduce_blocks(surface, factor, soil & finite)
    shows_soil = n_bare > 0
    heights = np.where(shows_soil, heights_bare, heights)
    data = block_count(has_data, factor) * 2 > _block_pixels(has_data.shape, factor)
    return np.where(data, heights, np.nan).astype(np.float32), shows_soil & data, data


def _block_pixels(shape, factor):
    """Pixels of each block inside a raster of `shape` (fewer in the blocks the edge cuts)."""
    rows, cols = shape
    in_rows = np.minimum(factor, rows - np.arange(0, rows, factor))
    in_cols = np.minimum(factor, cols - np.arange(0, cols, factor))
    return np.outer(in_rows, in_cols)


def fit_on_ground_grid(surface, *, soil, has_data, pixel_size, factor, **options):
    """:func:`~cliff_terrain.measure.ground.fit_ground` on the ground grid, its rasters on `surface`'s.

    Parameters
    ----------
    surface : (rows, cols) float array
        The DSM on the orthophoto's grid (metres).
    soil, has_data : (rows, cols) bool arrays
        Bare soil (the ground's evidence) and the pixels with data.
    pixel_size : float
        Metres per pixel of `surface`.
    factor : int
        :func:`ground_factor`; 1 fits on `surface`'s own grid.
    **options
        Passed to :func:`~cliff_terrain.measure.ground.fit_ground` (``block_m``, ``method``, ``source``).

    Returns
    -------
    ground, sigma, support : (rows, cols) float32 arrays
        The support is the share of the ground grid's blocks around each pixel that carried the
        ground (a block carries it when it shows bare soil).
    check : dict
        The fit's held-out check, with ``ground_pixel_m``, the ground grid's pixel.

    Examples
    --------
    >>> rows, cols = np.mgrid[:600, :600]
    >>> ground = 100.0 + 0.002 * cols                    # a tilt, 1 cm pixels
    >>> plants = np.hypot(rows % 120 - 60, cols % 120 - 60) < 24
    >>> dsm = (ground + 0.5 * plants).astype(np.float32)
    >>> fit = fit_on_ground_grid(dsm, soil=~plants, has_data=np.ones(dsm.shape, bool),
    ...                          pixel_size=0.01, factor=5)
    >>> bool(np.abs(fit[0] - ground).max() < 0.01), fit[3]["ground_pixel_m"]
    (True, 0.05)
    """
    has_data = has_data & surface_data(surface)
    surface = np.where(has_data, surface, np.float32(np.nan))
    if factor == 1:
        fit = fit_ground(surface, soil=soil & has_data, pixel_size=pixel_size, **options)
        fit.check["ground_pixel_m"] = pixel_size
        return fit.ground, fit.sigma, fit.support, fit.check
    coarse, bare, _ = reduce_for_ground(surface, soil & has_data, has_data, factor)
    fit = fit_ground(coarse, soil=bare, pixel_size=pixel_size * factor, **options)
    fit.check["ground_pixel_m"] = pixel_size * factor
    rows, cols = surface.shape
    if options.get("method") == "baseline":
        # Asked for by name, the baseline is the naive peer, the DSM's own block percentile: on
        # the full grid (a percentile of the ground grid's soil means is not the peer's). Chosen by
        # the check, it is the candidate the check measured, on the ground grid.
        block_m = options.get("block_m", DEFAULT_BLOCK_M)
        ground = naive_block_ground(
            surface, pixel_size=pixel_size, block_m=block_m, percentile=BASELINE_PERCENTILE
        )
    else:
        ground = upsample(fit.ground, factor, 0, rows, 0, cols)
    sigma, support = (upsample(a, factor, 0, rows, 0, cols) for a in (fit.sigma, fit.support))
    return ground, sigma, support, fit.check
