"""Specks dropped and holes filled in a plant mask: which holes lie inside a plant.

The paper fills every hole (``imfill``); the vegetation mode fills only the holes plausibly inside
a plant (:func:`plant_holes`): a leaf gap, a highlight, a shadow; soil enclosed by canopy, such as
the strip between two rows that join at their ends, stays flat.
"""

from __future__ import annotations

import cv2
import numpy as np


def clean_mask(mask, min_region, *, vi=None, threshold=None, soil=None):
    """Drop specks and fill holes (the paper's ``bwareaopen`` and ``imfill``).

    Without `vi` every hole is filled (``imfill``); with it only the holes that
    :func:`plant_holes` finds plausibly inside a plant.
    """
    mask = np.ascontiguousarray(mask, dtype=np.uint8)
    components = None
    if min_region > 0:
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        keep = stats[:, cv2.CC_STAT_AREA] >= min_region
        keep[0] = False
        mask = keep.astype(np.uint8)[labels]
        # Holes lie next to kept components only: the labels and areas serve plant_holes as they are.
        components = (labels, stats[:, cv2.CC_STAT_AREA])
    # Holes: background that cannot be reached from the frame (flood the padded background).
    padded = np.pad(mask, 1)
    flood = padded.copy()
    cv2.floodFill(flood, None, (0, 0), 1)
    holes = flood[1:-1, 1:-1] == 0
    if vi is None or not holes.any():
        return holes | (mask > 0)
    filled = plant_holes(mask, holes, vi, threshold, min_region=min_region, soil=soil, _components=components)
    return filled | (mask > 0)


# A hole this small against the plant region around it is a leaf gap or a highlight.
HOLE_FRACTION = 0.02


def plant_holes(mask, holes, vi, threshold, *, min_region=0, soil=None, _components=None):
    """The holes of `mask` that plausibly lie inside a plant, to be filled.

    A hole is kept (filled) when it is small compared with the region that encloses it (at most
    ``HOLE_FRACTION`` = 2 % of that region's area, or smaller than `min_region`): a gap between
    leaves, a specular highlight; or when it is not soil-coloured: its mean vegetation index lies
    above the midpoint between the soil's (:func:`soil_level`, the median over all non-plant
    pixels) and the threshold (shadows and pale spots inside a plant). Any other hole is soil
    enclosed by canopy, such as the strip between two crop rows that join at their ends, and
    stays flat.

    Parameters
    ----------
    mask : (rows, cols) bool or uint8 array
        Plant pixels.
    holes : (rows, cols) bool array
        Non-plant pixels that cannot be reached from the frame.
    vi : (rows, cols) float array
        The vegetation index the mask was thresholded from.
    threshold : float
        Its threshold.
    min_region : int, optional
        Holes smaller than this many pixels are always filled.
    soil : float, optional
        The soil's index; default ``soil_level(vi, mask)``.

    Returns
    -------
    (rows, cols) bool array
        The holes to fill.

    Examples
    --------
    >>> mask = np.zeros((60, 60), bool); mask[5:55, 5:55] = True
    >>> mask[10:12, 10:12] = False; mask[20:50, 30:34] = False   # a leaf gap and a soil strip
    >>> vi = np.where(mask, 0.4, -0.2).astype(np.float32)
    >>> holes = np.zeros_like(mask); holes[5:55, 5:55] = ~mask[5:55, 5:55]
    >>> filled = plant_holes(mask, holes, vi, 0.1)
    >>> bool(filled[10, 10]), bool(filled[30, 31])
    (True, False)
    """
    mask = np.ascontiguousarray(mask, dtype=np.uint8)
    holes = np.ascontiguousarray(holes, dtype=bool)
    vi = np.asarray(vi, dtype=np.float32)
    n_holes, hole_labels, hole_stats, _ = cv2.connectedComponentsWithStats(
        holes.view(np.uint8), connectivity=4, ltype=cv2.CV_32S
    )
    if n_holes <= 1:
        return np.zeros(mask.shape, dtype=bool)
    if _components is None:
        _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
        _components = (labels, stats[:, cv2.CC_STAT_AREA])
    components, component_area = _components
    area = hole_stats[:, cv2.CC_STAT_AREA].astype(np.float64)
    inside = np.flatnonzero(holes)
    which = hole_labels.ravel()[inside]
    # The pixel above a hole's first pixel (in raster order) belongs to the region around it.
    # Assigning in reverse order leaves each hole's first pixel (the last write wins).
    first = np.empty(n_holes, dtype=np.intp)
    first[which[::-1]] = inside[::-1]
    enclosing = components.ravel()[first[1:] - mask.shape[1]]
    small = (area[1:] < min_region) | (area[1:] <= HOLE_FRACTION * component_area[enclosing])
    if soil is None:
        soil = soil_level(vi, mask)
        soil = float(threshold) if soil is None else soil
    mean_vi = np.bincount(which, weights=vi.ravel()[inside], minlength=n_holes)[1:] / area[1:]
    not_soil = mean_vi > 0.5 * (soil + float(threshold))
    fill = np.zeros(n_holes, dtype=bool)
    fill[1:] = small | not_soil
    if fill[1:].all():  # the usual case: every hole is inside a plant
        return holes
    return fill[hole_labels]


def soil_level(vi, mask):
    """The soil's vegetation index: its median over the pixels outside `mask` (a sample).

    Holes count as soil. None when every pixel is in `mask`.
    """
    vi = np.asarray(vi, dtype=np.float32)
    step = max(1, vi.size // 200_000)
    ground = vi.ravel()[::step][np.asarray(mask).ravel()[::step] == 0]
    return float(np.median(ground)) if ground.size else None
