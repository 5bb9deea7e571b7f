"""Bare soil by colour: the pixels surely soil, stricter than "not a plant" (the ground's support).

The photo's plant threshold (:mod:`.vegetation`) says what is not a plant; shaded, yellowing or
senescent leaves fall below it too. :func:`soil_ceiling` bounds the soil class from its own peak.
"""

from __future__ import annotations

import numpy as np

from .._validate import check_rgb
from ..errors import CliffTerrainError
from .vegetation import blurred_index, photo_threshold

# Soil sure enough to carry the ground: index within this many robust standard deviations of the
# soil class's mode (the lower side of the soil peak, which no plant pixel widens).
SOIL_SPREAD = 5.0


def bare_soil(image, *, valid=None, index="auto", threshold=None):
    """Pixels that are surely soil, by colour: the ground's support, stricter than "not a plant".

    A pixel is bare soil when its (blurred) index lies below the photo's plant threshold
    (:func:`~.vegetation.index_threshold`) and below the soil class's ceiling (:func:`soil_ceiling`). Shaded,
    yellowing or senescent leaves that fall below the plant threshold lie above that ceiling, and
    would otherwise lift the ground under a canopy (on a real potato trial they stood 5.8 cm,
    median, above the early-season surface and lifted the ground by 4.5 cm; see docs/concepts/ground.md). Soil
    seen through gaps in a plant counts: the relief fills such holes so that a plant is one dome,
    but the ground under the plant is best seen there.

    Parameters
    ----------
    image : (rows, cols, 3) uint8 array
    valid : (rows, cols) bool array, optional
        Pixels with data.
    index : {"auto", "green", "nir"}, optional
    threshold : float, optional
        The plant threshold the segmentation used, when it was not the photo's own rule's (for
        instance a senescent canopy that the DSM showed standing above the ground).

    Returns
    -------
    (rows, cols) bool array

    Examples
    --------
    >>> img = np.full((40, 40, 3), (120, 90, 60), np.uint8)
    >>> img[:, 20:] = (70, 80, 50)                      # dull, yellowing leaves: not plant, not soil
    >>> img[10:15, 25:30] = (40, 160, 40)
    >>> soil = bare_soil(img)
    >>> bool(soil[:, :15].all()), bool(soil[:, 22:].any())
    (True, False)
    """
    image = check_rgb("image", image)
    vi, name = blurred_index(image, index=index)
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != vi.shape:
            raise CliffTerrainError(f"`valid` must have shape {vi.shape}, got {valid.shape}")
    if threshold is None:
        threshold = photo_threshold(vi, image, index=name, valid=valid).threshold
    candidates = vi <= threshold
    if valid is not None:
        candidates &= valid
    return candidates & (vi <= soil_ceiling(vi[candidates]))


def soil_ceiling(values):
    """The highest index value that is surely soil: ``SOIL_SPREAD`` (5) robust standard deviations
    above the soil class's mode, the spread measured on the lower side of the soil peak, which no
    plant pixel widens (:func:`bare_soil`'s limit).

    `values` are the blurred index of the pixels below the plant threshold (with data), in any
    order; with fewer than 10 there is no class to measure and the ceiling is +inf.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> soil = rng.normal(-0.05, 0.02, 20000)
    >>> yellow_leaves = rng.normal(0.04, 0.01, 5000)   # below the plant threshold, not soil
    >>> ceiling = soil_ceiling(np.concatenate([soil, yellow_leaves]))
    >>> bool(0.02 < ceiling < 0.07), float(np.mean(yellow_leaves > ceiling)) > 0.3
    (True, True)
    """
    values = np.asarray(values).ravel()
    if values.size < 10:
        return float("inf")
    values = values[:: max(1, values.size // 400_000)].astype(np.float64)
    hist, edges = np.histogram(values, 200)
    smooth = np.convolve(hist.astype(np.float64), np.ones(3) / 3, "same")
    mode = float(0.5 * (edges[:-1] + edges[1:])[int(np.argmax(smooth))])
    lower = values[values <= mode]
    spread = 1.4826 * float(np.median(mode - lower)) if lower.size else 0.0
    spread = max(spread, float(edges[1] - edges[0]))
    return mode + SOIL_SPREAD * spread
