"""How well a relief's plant mask and volume agree with an independent reference mask.

The references are textbook ones, each one index with Otsu's threshold and nothing else (no blur,
no band, no hole filling, no second index): the excess-green index ExG = 2g - r - b on chromatic
coordinates (Woebbecke et al. 1995; Meyer & Neto 2008), or (NIR - B) / (NIR + B) for a false-colour
NIR camera (NIR in the red channel), or the green-red axis a* of CIELAB (plants below the
threshold), which PlantCV's workflows use and which, unlike ExG, keeps pale and bluish-green plants
such as broccoli. They are independent of :func:`cliff_terrain.photo_heights.segmentation.segment` (ExG + NGRDI,
a blue penalty, a threshold band, hole filling, speck removal) and imperfect themselves (Otsu
always splits, so a photo of bare soil still gets a "plant" class), so agreement with them is a
measure, not ground truth.
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage import filters

from .._validate import check_choice, check_rgb
from ..errors import CliffTerrainError

REFERENCES = ("exg", "nir", "lab_a")


def reference_mask(image, *, index="exg", valid=None):
    """Plant pixels by one vegetation index and Otsu's threshold (a reference mask).

    Parameters
    ----------
    image : (rows, cols, 3) uint8 array
        RGB image.
    index : {"exg", "nir", "lab_a"}, optional
        ``"exg"``: ExG = 2g - r - b above the threshold. ``"nir"``: (NIR - B) / (NIR + B) above
        it, for false-colour NIR frames. ``"lab_a"``: CIELAB a* below it (green side).
    valid : (rows, cols) bool array, optional
        Pixels that hold data; the others are never plant and do not count for the threshold.

    Returns
    -------
    (rows, cols) bool array

    Examples
    --------
    >>> img = np.full((20, 20, 3), (120, 90, 60), np.uint8); img[5:10, 5:10] = (40, 160, 40)
    >>> int(reference_mask(img).sum()), int(reference_mask(img, index="lab_a").sum())
    (25, 25)
    """
    image = check_rgb("image", image)
    check_choice("index", index, REFERENCES)
    rgb = image.astype(np.float64)
    if index == "lab_a":
        lab = cv2.cvtColor(np.ascontiguousarray(image, dtype=np.uint8), cv2.COLOR_RGB2LAB)
        score = 128.0 - lab[..., 1].astype(np.float64)  # greener is larger
    elif index == "nir":
        score = (rgb[..., 0] - rgb[..., 2]) / (rgb[..., 0] + rgb[..., 2] + 1e-9)
    else:
        score = (2.0 * rgb[..., 1] - rgb[..., 0] - rgb[..., 2]) / (rgb.sum(axis=2) + 1e-9)
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != score.shape:
            raise CliffTerrainError(f"`valid` must have shape {score.shape}, got {valid.shape}")
    values = score[valid] if valid is not None else score.ravel()
    if values.size == 0 or values.min() == values.max():
        return np.zeros(score.shape, dtype=bool)
    mask = score > filters.threshold_otsu(values)
    return mask & valid if valid is not None else mask


def mask_agreement(mask, reference):
    """Precision, recall, F1 and IoU of `mask` against `reference`.

    Parameters
    ----------
    mask, reference : (rows, cols) bool arrays

    Returns
    -------
    dict
        ``precision`` (share of `mask` in `reference`), ``recall`` (share of `reference` in
        `mask`), ``f1`` and ``iou`` (intersection over union); 1.0 where both masks are empty.

    Examples
    --------
    >>> a = np.zeros((4, 4), bool); a[:2] = True
    >>> b = np.zeros((4, 4), bool); b[1:3] = True
    >>> mask_agreement(a, b)["iou"]
    0.3333333333333333
    """
    mask = np.asarray(mask, dtype=bool)
    reference = np.asarray(reference, dtype=bool)
    if mask.shape != reference.shape:
        raise CliffTerrainError(
            f"`mask` must have the shape of `reference` {reference.shape}, got {mask.shape}"
        )
    both = float(np.count_nonzero(mask & reference))
    n_mask, n_ref = float(np.count_nonzero(mask)), float(np.count_nonzero(reference))
    union = n_mask + n_ref - both
    return {
        "precision": both / n_mask if n_mask else 1.0,
        "recall": both / n_ref if n_ref else 1.0,
        "f1": 2.0 * both / (n_mask + n_ref) if n_mask + n_ref else 1.0,
        "iou": both / union if union else 1.0,
    }


def volume_fraction(heights, mask):
    """Share of the relief's volume (sum of heights) that stands on `mask`; 1.0 for a flat relief.

    Examples
    --------
    >>> h = np.array([[0.0, 3.0], [1.0, 0.0]])
    >>> volume_fraction(h, h > 2)
    0.75
    """
    heights = np.asarray(heights, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != heights.shape:
        raise CliffTerrainError(f"`mask` must have the shape of `heights` {heights.shape}, got {mask.shape}")
    total = float(heights.sum())
    return float(heights[mask].sum()) / total if total > 0 else 1.0
