"""Whether the surface model's pixel smooths the plots' heights by more than their stated error.

A photogrammetric surface is a mean over its pixel: a DSM (or a measuring grid, ``--resolution``)
coarser than the plants lowers every plot's p90 toward the ground. The held-out ground check cannot
see it (a smoother surface predicts its soil *better*) and ``height_p90_err_m``, the ground's
error, does not hold it: on the shared pair averaged to 1.35 m pixels the plots read 14 cm low
with a stated error of 3 cm, and no word said.

The check asks the data itself how much the heights still depend on the smoothing: the canopy
height is smoothed once more, by a box twice the scale it was measured at (the coarser of the
DSM's pixel and the grid's), and each plot's p90 taken again. If one more doubling lowers the
median plot by more than the median stated error (never less than the error's floor,
:data:`~cliff_terrain.measure.ground_check.SIGMA_FLOOR_M`), the heights are still falling with the
scale: the surface is too coarse for these plants, and the heights are low by at least about as
much. The figures are reported in ``summary.json`` whatever the outcome; a failed check is said on
the summary line. On the validation fields (DSMs of 2-7 cm) one more doubling moves the median
plot by 0-0.3 cm; on the shared pair by 1.2 cm (its 0.27 m DSM), 5.5 cm at 1.35 m.
"""

from __future__ import annotations

import math

import numpy as np


def pixel_metres(transform):
    """Side of a pixel of the affine `transform` (the square root of its area)."""
    t = np.asarray(transform, dtype=np.float64)
    return math.sqrt(abs(t[0, 0] * t[1, 1] - t[0, 1] * t[1, 0]))


def doubled_box(grid_m, surface_m):
    """Side in grid pixels of the box that doubles the scale the heights were measured at.

    Examples
    --------
    >>> doubled_box(0.2, 0.27), doubled_box(0.2, 1.35), doubled_box(0.07, 0.068)
    (3, 14, 2)
    """
    return max(2, round(2 * max(grid_m, surface_m) / grid_m))


def box_mean(heights, box):
    """The mean of `heights` over a `box` x `box` square around each pixel, its NaNs left out, and
    NaN where `heights` is NaN (float64: the sums do not drift with the window's size).

    Examples
    --------
    >>> box_mean(np.array([[1.0, 2.0, 3.0, np.nan, 5.0]]), 3)[0, 1:].tolist()  # (1 + 2 + 3) / 3, (2 + 3) / 2
    [2.0, 2.5, nan, 5.0]
    """
    import cv2

    heights = np.asarray(heights, dtype=np.float64)
    ok = np.isfinite(heights)
    total = cv2.blur(np.where(ok, heights, 0.0), (box, box))
    count = cv2.blur(ok.astype(np.float64), (box, box))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok & (count > 0), total / count, np.nan)


def plot_p90s(layers, heights, n):
    """Each plot's p90 of `heights` (NaN where it has none), plots 1..n of the label images `layers`
    (:func:`~cliff_terrain.measure.field_plots.plot_layers`), each taken in the image that holds
    most of its pixels, as :func:`~cliff_terrain.measure.field_plots.plot_table` takes it: the
    check's second table, without the rest of its columns (a third of a window's table's time).

    Examples
    --------
    >>> labels = np.array([[1, 1, 0], [2, 2, 2]])
    >>> plot_p90s([labels], np.array([[0.0, 1.0, 5.0], [2.0, np.nan, 4.0]]), 2).tolist()
    [0.9, 3.8]
    """
    from scipy import ndimage

    p90, most = np.full(n, np.nan), np.zeros(n, np.int64)
    for layer in layers:
        for index, box in enumerate(ndimage.find_objects(np.asarray(layer), max_label=n) if n else []):
            if box is None:
                continue
            inside = layer[box] == index + 1
            pixels = int(np.count_nonzero(inside))
            if pixels <= most[index]:
                continue
            most[index] = pixels
            values = np.asarray(heights[box][inside], dtype=np.float64)
            values = values[np.isfinite(values)]
            p90[index] = np.percentile(values, 90.0) if values.size else np.nan
    return p90


def resolution_check(p90, p90_doubled, errors, *, grid_pixel_m, surface_pixel_m):
    """The check's record: the plots' median p90 drop when the scale doubles against their median
    stated error.

    Parameters
    ----------
    p90, p90_doubled, errors : sequence of float
        Per plot: ``height_p90_m``, the same on the canopy height smoothed by :func:`doubled_box`
        (:func:`box_mean`), and ``height_p90_err_m`` (NaN where a plot has none).
    grid_pixel_m, surface_pixel_m : float
        The measuring grid's and the surface model's pixel.

    Returns
    -------
    dict
        ``surface_pixel_m``, ``grid_pixel_m``, ``doubled_to_m``, ``p90_drop_m`` (median over the
        plots), ``stated_error_m`` (the median error, at least the floor), ``passed`` (None without
        a plot with a height) and ``note`` (why it failed, else "").

    Examples
    --------
    >>> r = resolution_check([0.5, 0.6], [0.38, 0.49], [0.03, 0.03], grid_pixel_m=0.2, surface_pixel_m=1.35)
    >>> r["passed"], round(r["p90_drop_m"], 3)
    (False, 0.115)
    """
    from .ground_check import SIGMA_FLOOR_M

    p90, doubled, errors = (np.asarray(v, dtype=np.float64) for v in (p90, p90_doubled, errors))
    both = np.isfinite(p90) & np.isfinite(doubled)
    scale = max(grid_pixel_m, surface_pixel_m)
    record = {
        "surface_pixel_m": float(surface_pixel_m),
        "grid_pixel_m": float(grid_pixel_m),
        "doubled_to_m": doubled_box(grid_pixel_m, surface_pixel_m) * float(grid_pixel_m),
        "p90_drop_m": None,
        "stated_error_m": None,
        "passed": None,
        "note": "",
    }
    if not both.any():
        return record
    drop = float(np.median(p90[both] - doubled[both]))
    finite = errors[np.isfinite(errors)]
    stated = max(float(np.median(finite)) if finite.size else 0.0, SIGMA_FLOOR_M)
    record.update(p90_drop_m=drop, stated_error_m=stated, passed=drop <= stated)
    if drop > stated:
        which = "surface model's" if surface_pixel_m >= grid_pixel_m else "measuring grid's"
        record["note"] = (
            f"the {which} {scale:.2f} m pixel smooths the plants: twice as coarse lowers the median "
            f"plot p90 by {drop * 100:.1f} cm, more than its stated error ({stated * 100:.1f} cm), "
            "so the heights read low by about as much or more (a finer surface model or grid)"
        )
    return record


def plots_resolution_check(plots, rows, heights, transform, *, surface_transform):
    """:func:`resolution_check` of a plot table's `rows` measured on `heights` (the canopy height on
    the grid `transform`), the surface model's pixel from `surface_transform`."""
    from .field_plots import plot_layers

    grid_m, surface_m = pixel_metres(transform), pixel_metres(surface_transform)
    smooth = box_mean(heights, doubled_box(grid_m, surface_m))
    layers = plot_layers(plots, transform=transform, shape=smooth.shape)
    return resolution_check(
        [row["height_p90_m"] for row in rows],
        plot_p90s(layers, smooth, len(plots.polygons)),
        [row.get("height_p90_err_m", math.nan) for row in rows],
        grid_pixel_m=grid_m,
        surface_pixel_m=surface_m,
    )


def resolution_line(record):
    """The summary line's words for a failed check (``"; NOTE ..."``), else ""."""
    return f"; note: {record['note']}" if record and record.get("note") else ""
