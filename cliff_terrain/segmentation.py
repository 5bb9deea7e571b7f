"""Segmentation (the paper's Algorithm 2): which pixels rise, split into regions.

Two modes:

``"paper"``
    Algorithm 2 taken literally: grey level of the quaternion-filtered image, Otsu threshold, the
    bright class becomes the regions, holes filled, regions labelled, touching regions split by a
    watershed of the distance map. The filter keeps the image's brightness (a uniform colour maps to
    its grey), so this thresholds *brightness*: on bright broccoli over dark soil it finds the plants,
    on pale soil with dark plants it raises the soil instead.
``"vegetation"`` (default)
    Plants rise, soil stays flat. A vegetation index decides what is plant: the excess-green index
    ExG = 2g - r - b on chromatic coordinates for colour photos, or (NIR - B) / (NIR + B) for
    false-colour NIR frames (detected when no pixel is green and green is the weakest channel of
    most pixels). Otsu's threshold on the index is kept within a prior band, so that an image of
    bare soil yields (almost) nothing and a closed canopy is not split into a bright and a dark
    class, unless the photo shows the band is wrong (see :func:`index_threshold`): its histogram
    is clearly two-class, Otsu's threshold lies in an almost empty valley above the band, and the
    band's threshold cuts into a class (dark, wet soil). Then the photo's own threshold is used.
    Touching plants are split by a
    watershed whose markers are the distance map's peaks and whose landscape adds the quaternion
    filter's colour-edge strength, so boundaries follow colour edges between plants. Holes are
    filled only where they are plausibly inside a plant (see :func:`plant_holes`): soil enclosed
    by canopy, such as the strips between rows that join at their ends, stays flat.
"""

from __future__ import annotations

import contextlib
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from skimage import filters, segmentation

try:  # scikit-image's flooding kernel, for _flood (pinned version; the public function otherwise)
    from skimage.morphology._util import _offsets_to_raveled_neighbors, _validate_connectivity
    from skimage.segmentation._watershed_cy import watershed_raveled as _watershed_raveled
except ImportError:  # pragma: no cover
    _watershed_raveled = None

from ._validate import check_choice, check_int, check_rgb
from .errors import CliffTerrainError
from .settings import SEGMENTATIONS, ids

METHODS = ids(SEGMENTATIONS)
INDICES = ("auto", "green", "nir")

# Threshold bands (Otsu's threshold is clipped into them unless the photo is clearly two-class):
# bare soil and grey objects sit at or below 0, pale or bluish plants and yellow senescent canopy
# above about 0.15. The lower end is a floor in every case.
_GREEN_BAND = (0.06, 0.14)
_NIR_BAND = (0.12, 0.3)
# A photo is clearly two-class when the histogram at Otsu's threshold is at most this fraction of
# its mean between the two class means (0: an empty valley; about 1: no valley at all). On real
# annotated photos (README, "Validation on real fields") dark-soil fields whose own threshold is
# right measured 0.09-0.38, closed canopies that Otsu splits in two 0.75-1.11.
TWO_CLASS_VALLEY = 0.5
# Soil sure enough to carry the ground: index within this many robust standard deviations of the
# soil class's mode (the lower side of the soil peak, which no plant pixel widens).
SOIL_SPREAD = 5.0


@dataclass
class Segmentation:
    """Result of :func:`segment`.

    Attributes
    ----------
    mask : (rows, cols) bool
        Pixels that rise.
    labels : (rows, cols) int32
        0 for flat ground, 1..n for the regions.
    boundaries : (rows, cols) bool
        Inner boundary pixels of the regions.
    threshold : float
        The threshold used (on the index or on the grey level).
    index : str
        ``"green"``, ``"nir"`` or ``"grey"`` (paper mode).
    threshold_source : str
        ``"photo"`` (the photo's own: a clearly two-class index histogram), ``"band"`` (Otsu's
        kept within the prior band) or ``"otsu"`` (paper mode: Otsu's on the grey level).
    valley : float
        The histogram at the threshold relative to its mean between the class means (see
        :func:`index_threshold`); NaN in paper mode.
    distance : (rows, cols) float32
        ``distance_map(mask)``: each plant pixel's distance to flat ground (the watershed's, kept
        for the plateau profile).
    """

    mask: np.ndarray
    labels: np.ndarray
    boundaries: np.ndarray
    threshold: float
    index: str
    distance: np.ndarray | None = None
    threshold_source: str = "band"
    valley: float = float("nan")

    @property
    def n_regions(self) -> int:
        return int(self.labels.max(initial=0))


def vegetation_index(image, *, index="auto"):
    """Per-pixel vegetation index of an RGB image.

    Parameters
    ----------
    image : (rows, cols, 3) uint8 or float array
        RGB image.
    index : {"auto", "green", "nir"}, optional
        ``"green"``: excess green on chromatic coordinates plus the normalised green-red
        difference, ExG + NGRDI = (2g - r - b) + (G - R) / (G + R). ExG alone separates yellow
        senescent canopy from tan soil; NGRDI alone separates pale, bluish-green plants
        (broccoli) from brown soil; their sum does both. Grey objects (roads) score 0, brown
        soil below 0, and pixels clearly bluer than green (tarps, panels, water) are pushed down
        by 4 (b - g - 0.02).
        ``"nir"``: (NIR - B) / (NIR + B) for false-colour NIR cameras whose red channel holds
        near-infrared. ``"auto"`` picks ``"nir"`` when no pixel is green and green is the
        weakest channel of most pixels (lilac soil, red plants), else ``"green"``.

    Returns
    -------
    vi : (rows, cols) float32 array
    name : str
        The index used, ``"green"`` or ``"nir"``.

    Examples
    --------
    >>> img = np.zeros((1, 2, 3), np.uint8); img[0, 0] = (40, 160, 40); img[0, 1] = (120, 90, 60)
    >>> vi, name = vegetation_index(img)
    >>> name, bool(vi[0, 0] > 0.5 > 0 > vi[0, 1])
    ('green', True)
    """
    image = check_rgb("image", image)
    check_choice("index", index, INDICES)
    # Contiguous float32 planes, and every step below one pass written in place: fresh arrays
    # for the temporaries would cost as much again (allocation and page faults).
    red, green, blue = (plane.astype(np.float32) for plane in cv2.split(np.ascontiguousarray(image)))
    inv_total = red + green
    inv_total += blue
    inv_total += np.float32(1e-6)
    np.divide(np.float32(1.0), inv_total, out=inv_total)
    # ExG = 2g - r - b = 3 G / (R + G + B) - 1 on chromatic coordinates.
    exg = green * np.float32(3.0)
    exg *= inv_total
    exg -= np.float32(1.0)
    if index == "auto":
        index = "nir" if _looks_false_colour_nir(image, exg) else "green"
    if index == "nir":
        return (red - blue) / (red + blue + np.float32(1e-6)), "nir"
    vi = exg
    ngrdi = green - red
    red += green
    red += np.float32(1e-6)
    ngrdi /= red
    vi += ngrdi
    # Plants are never clearly bluer than green; tarps, panels and water often are.
    blue_excess = blue
    blue_excess -= green
    blue_excess *= inv_total
    blue_excess -= np.float32(0.02)
    np.maximum(blue_excess, np.float32(0.0), out=blue_excess)
    blue_excess *= np.float32(4.0)
    vi -= blue_excess
    return vi, "green"


def _looks_false_colour_nir(rgb, exg):
    # A colour photo of a field has green among its pixels, and blue is its weakest channel
    # (brown soil, green and yellow plants). A NIR-modified camera (NIR in the red channel) shows
    # plants red and soil lilac: no green anywhere and green the weakest channel of most pixels.
    step = max(1, exg.size // 200_000)
    exg_s = exg.ravel()[::step]
    px = rgb.reshape(-1, 3)[::step]
    px = px[px.sum(axis=1) > 30]  # black no-data borders say nothing
    if px.shape[0] == 0:
        return False
    green_weakest = float(np.mean(px[:, 1] <= px.min(axis=1)))
    return float(np.percentile(exg_s, 99)) < 0.02 and green_weakest > 0.5


def segment(
    image,
    *,
    method="vegetation",
    filtered=None,
    index="auto",
    min_region=None,
    valid=None,
):
    """Find the regions that rise: binarize, label, fill holes, trace boundaries, split by watershed.

    Parameters
    ----------
    image : (rows, cols, 3) uint8 array
        RGB image at processing size.
    method : {"vegetation", "paper"}, optional
        How pixels are chosen; see the module documentation.
    filtered : (rows, cols, 3) float array, optional
        The quaternion filter's output for `image` (required by ``"paper"``; used by
        ``"vegetation"`` for colour edges when given).
    index : {"auto", "green", "nir"}, optional
        Vegetation index for ``"vegetation"`` (see :func:`vegetation_index`).
    min_region : int, optional
        Regions (and holes) smaller than this many pixels are dropped (filled); default scales with
        the image, 0.002 % of its pixels and at least 4.
    valid : (rows, cols) bool array, optional
        Pixels that hold data (an orthophoto's alpha); the others stay flat and do not count
        for the threshold.

    Returns
    -------
    Segmentation

    Examples
    --------
    >>> img = np.full((40, 40, 3), (120, 90, 60), np.uint8)
    >>> img[10:20, 10:20] = (40, 160, 40)
    >>> seg = segment(img)
    >>> seg.n_regions, int(seg.mask[10:20, 10:20].sum())
    (1, 100)

    The index is lightly blurred (sigma 1 pixel) so single noisy pixels neither rise nor punch
    holes; a sharp edge therefore keeps a one-pixel rim (the square's 40 side neighbours):

    >>> int(seg.mask.sum())
    140
    """
    image = check_rgb("image", image)
    check_choice("method", method, METHODS)
    rows, cols = image.shape[:2]
    if min_region is None:
        min_region = max(4, int(2e-5 * rows * cols))
    min_region = check_int("min_region", min_region, minimum=0)
    if filtered is not None:
        filtered = check_rgb("filtered", filtered)
        if filtered.shape != image.shape:
            raise CliffTerrainError(
                f"`filtered` must have the shape of `image` {image.shape}, got {filtered.shape}"
            )
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != image.shape[:2]:
            raise CliffTerrainError(f"`valid` must have shape {image.shape[:2]}, got {valid.shape}")
        if valid.all():
            valid = None
    vi = None
    if method == "paper":
        if filtered is None:
            raise CliffTerrainError("`filtered` is required when `method` is 'paper', got None")
        mask, threshold, index_name = _paper_mask(filtered, valid)
        source, valley = "otsu", float("nan")
    else:
        mask, rule, vi = _vegetation_mask(image, index, valid)
        threshold, index_name, source, valley = rule.threshold, rule.index, rule.source, rule.valley
    if valid is not None:
        mask &= valid

    # The paper fills every hole (imfill); vegetation mode only those plausibly inside a plant.
    mask = _clean(mask, min_region, vi=vi, threshold=threshold)
    distance = distance_map(mask)
    edges = colour_edges(filtered) if (filtered is not None and method == "vegetation") else None
    labels = split_regions(mask, distance, edges=edges)
    boundaries = inner_boundaries(labels)
    return Segmentation(
        mask=mask,
        labels=labels,
        boundaries=boundaries,
        threshold=threshold,
        index=index_name,
        distance=distance,
        threshold_source=source,
        valley=valley,
    )


def _paper_mask(filtered, valid):
    grey = filtered.astype(np.float32).mean(axis=2)
    threshold = _otsu(grey if valid is None else grey[valid])
    return grey > threshold, threshold, "grey"


def _vegetation_mask(image, index, valid):
    """``(mask, ThresholdRule, blurred index)`` of the vegetation mode."""
    vi, name = blurred_index(image, index=index)
    rule = index_threshold(vi if valid is None else vi[valid], index=name)
    return vi > rule.threshold, rule, vi


def blurred_index(image, *, index="auto"):
    """:func:`vegetation_index` lightly blurred (sigma 1 px): what the threshold applies to.

    Single noisy pixels should neither rise nor punch holes. Returns ``(vi, name)``.
    """
    vi, name = vegetation_index(image, index=index)
    return cv2.GaussianBlur(vi, (0, 0), 1.0), name


@dataclass(frozen=True)
class ThresholdRule:
    """How the plant/soil threshold of a photo was chosen (see :func:`index_threshold`)."""

    threshold: float
    index: str
    source: str
    valley: float


def index_threshold(values, *, index="green"):
    """The plant/soil threshold of a vegetation index: the photo's own when clearly two-class.

    Otsu's threshold is the photo's own. The prior is Otsu's threshold kept within the band of
    `index`. The photo's own wins when the histogram is clearly two-class and the prior is not in
    its valley: the density at Otsu's threshold is at most ``TWO_CLASS_VALLEY`` (0.5) times the
    mean density between the two class means, and the density at the prior's is above that, so
    the band would cut into a class. Dark, wet soil whose index reaches 0.3 beside green plants
    is such a case. Otherwise the prior stands: one class (bare soil, or a closed canopy that
    Otsu would split into sunlit and shaded leaves), or two classes whose valley holds the prior
    too (then either threshold gives the same mask but for the blurred rims, and the prior keeps
    every figure measured with it). The band's lower end is a floor in both cases: soil and grey
    objects score at or below 0.

    Parameters
    ----------
    values : array of float
        Index values of the pixels with data (any shape; a sample is taken from large arrays).
    index : {"green", "nir"}, optional
        Which index, for its prior band.

    Returns
    -------
    ThresholdRule
        ``threshold``, ``index``, ``source`` (``"photo"`` or ``"band"``) and ``valley`` (the
        density ratio; NaN when there is no spread).

    Examples
    --------
    Soil around 0.2 (dark and wet) and plants around 0.8, an empty valley between them:

    >>> rng = np.random.default_rng(0)
    >>> vi = np.concatenate([rng.normal(0.2, 0.05, 9000), rng.normal(0.8, 0.1, 1000)])
    >>> rule = index_threshold(vi)
    >>> rule.source, bool(0.35 < rule.threshold < 0.65)
    ('photo', True)

    One class only (a closed canopy): Otsu's threshold would split it, the band keeps it whole.

    >>> rule = index_threshold(rng.normal(0.5, 0.1, 10000))
    >>> rule.source, rule.threshold
    ('band', 0.14)
    """
    check_choice("index", index, ("green", "nir"))
    flat = np.asarray(values, dtype=np.float32).ravel()
    if flat.size > 400_000:  # a sample gives the same threshold at a fraction of the cost
        flat = flat[:: flat.size // 400_000]
    # float64: numpy 2 refuses 128 histogram bins over a float32 range of a few ulps.
    flat = flat.astype(np.float64)
    low, high = _GREEN_BAND if index == "green" else _NIR_BAND
    otsu = _otsu(flat)
    banded = float(np.clip(otsu, low, high))
    valley, at_band = _valley(flat, otsu, (otsu, banded))
    # Two classes whose valley the band misses (it cuts into one of them): the photo's own.
    if otsu > high and valley <= TWO_CLASS_VALLEY and not at_band <= TWO_CLASS_VALLEY:
        return ThresholdRule(otsu, index, "photo", valley)
    return ThresholdRule(banded, index, "band", valley)


def _valley(values, split, thresholds):
    """Histogram density at each of `thresholds` over its mean between the class means of `split`.

    0 is an empty valley, about 1 no valley at all; NaN when the values have no spread.
    """
    nan = (float("nan"),) * len(thresholds)
    below, above = values[values <= split], values[values > split]
    if below.size == 0 or above.size == 0:
        return nan
    lo, hi = np.percentile(values, (0.5, 99.5))
    if not hi > lo:
        return nan
    hist, edges = np.histogram(values, 128, range=(float(lo), float(hi)))
    # A Gaussian of 2 bins smooths the counts' noise without filling a valley.
    smooth = np.convolve(hist.astype(np.float64), np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2), "same")
    centres = 0.5 * (edges[:-1] + edges[1:])
    between = (centres >= below.mean()) & (centres <= above.mean())
    if not between.any() or smooth[between].mean() <= 0:
        return nan
    mean = smooth[between].mean()
    return tuple(float(smooth[int(np.argmin(np.abs(centres - t)))] / mean) for t in thresholds)


def bare_soil(image, *, valid=None, index="auto"):
    """Pixels that are surely soil, by colour: the ground's support, stricter than "not a plant".

    A pixel is bare soil when its (blurred) index lies below the photo's plant threshold
    (:func:`index_threshold`) and within ``SOIL_SPREAD`` (5) robust standard deviations of the
    soil class's mode, measured on the lower side of the soil peak, which no plant pixel widens.
    Shaded, yellowing or senescent leaves that fall below the plant threshold lie above that
    limit, and would otherwise lift the ground under a canopy (on a real potato trial they stood
    5.8 cm, median, above the early-season surface and lifted the ground by 4.5 cm; see the README). Soil seen through gaps in a plant counts: the relief fills such holes so that a
    plant is one dome, but the ground under the plant is best seen there.

    Parameters
    ----------
    image : (rows, cols, 3) uint8 array
    valid : (rows, cols) bool array, optional
        Pixels with data.
    index : {"auto", "green", "nir"}, optional

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
    threshold = index_threshold(vi if valid is None else vi[valid], index=name).threshold
    candidates = vi <= threshold
    if valid is not None:
        candidates &= valid
    values = vi[candidates]
    if values.size < 10:
        return candidates
    values = values[:: max(1, values.size // 400_000)].astype(np.float64)
    hist, edges = np.histogram(values, 200)
    smooth = np.convolve(hist.astype(np.float64), np.ones(3) / 3, "same")
    mode = float(0.5 * (edges[:-1] + edges[1:])[int(np.argmax(smooth))])
    lower = values[values <= mode]
    spread = 1.4826 * float(np.median(mode - lower)) if lower.size else 0.0
    spread = max(spread, float(edges[1] - edges[0]))
    return candidates & (vi <= mode + SOIL_SPREAD * spread)


def _otsu(values):
    flat = values.ravel()
    if flat.size == 0:
        return 0.0
    if flat.size > 400_000:  # a sample gives the same threshold at a fraction of the cost
        flat = flat[:: flat.size // 400_000]
    if float(flat.min()) == float(flat.max()):
        return float(flat[0])
    # float64: numpy 2 refuses 256 histogram bins over a float32 range of a few ulps.
    return float(filters.threshold_otsu(flat.astype(np.float64)))


def _clean(mask, min_region, *, vi=None, threshold=None):
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
    return plant_holes(mask, holes, vi, threshold, min_region=min_region, _components=components) | (mask > 0)


# A hole this small against the plant region around it is a leaf gap or a highlight.
HOLE_FRACTION = 0.02


def plant_holes(mask, holes, vi, threshold, *, min_region=0, _components=None):
    """The holes of `mask` that plausibly lie inside a plant, to be filled.

    A hole is kept (filled) when it is small compared with the region that encloses it (at most
    ``HOLE_FRACTION`` = 2 % of that region's area, or smaller than `min_region`): a gap between
    leaves, a specular highlight; or when it is not soil-coloured: its mean vegetation index lies
    above the midpoint between the soil's (the median over all non-plant pixels) and the
    threshold (shadows and pale spots inside a plant). Any other hole is soil enclosed by canopy,
    such as the strip between two crop rows that join at their ends, and stays flat.

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
    # Soil colour: the median index of the non-plant pixels (a sample), holes included.
    step = max(1, vi.size // 200_000)
    ground = vi.ravel()[::step][mask.ravel()[::step] == 0]
    soil = float(np.median(ground)) if ground.size else float(threshold)
    mean_vi = np.bincount(which, weights=vi.ravel()[inside], minlength=n_holes)[1:] / area[1:]
    not_soil = mean_vi > 0.5 * (soil + float(threshold))
    fill = np.zeros(n_holes, dtype=bool)
    fill[1:] = small | not_soil
    if fill[1:].all():  # the usual case: every hole is inside a plant
        return holes
    return fill[hole_labels]


def distance_map(labels):
    """Euclidean distance of each region pixel to the nearest pixel outside its region (0 outside).

    Where two labelled regions touch, the pixels on one side of the line between them count as
    outside, so each region gets its own distance map (touching plants become separate domes).
    The image border counts as region, not as flat ground, like MATLAB's ``bwdist`` of the
    complement: a plant cut by the frame keeps its height at the border.

    Parameters
    ----------
    labels : (rows, cols) bool or int array
        A mask, or labels with 0 on flat ground.

    Returns
    -------
    (rows, cols) float32 array

    Examples
    --------
    >>> distance_map(np.array([[0, 1, 1, 1, 0]], bool)).tolist()
    [[0.0, 1.0, 2.0, 1.0, 0.0]]
    """
    inner = region_interiors(labels)
    if not inner.any():
        return np.zeros(inner.shape, dtype=np.float32)
    if inner.all():
        # No flat pixel at all: distance to the frame instead, so a full canopy still has a shape.
        padded = np.pad(inner, 1, constant_values=False).astype(np.uint8)
        return cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    return cv2.distanceTransform(inner.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def inner_boundaries(labels):
    """Region pixels with a 4-neighbour of another label (ground or region); the frame is no edge.

    What ``skimage.segmentation.find_boundaries(labels, mode="inner")`` marks for 4-connectivity,
    in a few comparisons of shifted arrays.
    """
    labels = np.asarray(labels)
    edge = np.zeros(labels.shape, dtype=bool)
    dh = labels[:, 1:] != labels[:, :-1]
    dv = labels[1:, :] != labels[:-1, :]
    edge[:, 1:] |= dh
    edge[:, :-1] |= dh
    edge[1:, :] |= dv
    edge[:-1, :] |= dv
    return edge & (labels > 0)


def region_interiors(labels):
    """``labels > 0`` less one pixel line wherever two different regions touch (4-neighbours)."""
    labels = np.asarray(labels)
    mask = labels > 0
    if labels.dtype == bool:
        return mask
    split = np.zeros_like(mask)
    split[:, 1:] |= (labels[:, 1:] != labels[:, :-1]) & mask[:, 1:] & mask[:, :-1]
    split[1:, :] |= (labels[1:, :] != labels[:-1, :]) & mask[1:, :] & mask[:-1, :]
    return mask & ~split


def colour_edges(filtered):
    """Colour-edge strength of the quaternion filter's output: its distance from the grey axis.

    A uniform colour maps to grey and so does a pure brightness edge; only chroma changes leave
    the grey axis, which is what separates touching plants of slightly different colour.

    Parameters
    ----------
    filtered : (rows, cols, 3) float array

    Returns
    -------
    (rows, cols) float32 array
    """
    filtered = np.ascontiguousarray(filtered, dtype=np.float32)
    # The chroma vector (I - J) p with J the projection on the grey axis, then its length.
    chroma = cv2.transform(filtered, (np.eye(3) - 1.0 / 3.0).astype(np.float32))
    return np.sqrt(cv2.transform(chroma * chroma, np.ones((1, 3), np.float32)))


def split_regions(mask, distance, *, edges=None, radius=None, edge_scale=None):
    """Label `mask`, splitting touching blobs by a marker-controlled watershed of the distance map.

    Parameters
    ----------
    mask : (rows, cols) bool array
    distance : (rows, cols) float array
        Distance map of `mask`.
    edges : (rows, cols) float array, optional
        Colour-edge strength added to the watershed landscape (scaled to the distance range).
    radius, edge_scale : float, optional
        The markers' neighbourhood radius and the edges' scale; by default from this image's
        regions and edges. Tiles of one mosaic share the whole mosaic's (cliff_terrain.mosaic).

    Returns
    -------
    (rows, cols) int32 array
        Labels 1..n, 0 on flat ground.
    """
    mask = np.asarray(mask, dtype=bool)
    components, n, stats = _label4(mask, stats=True)  # with each component's bounding box and area
    if n == 0:
        return components
    dmax = label_max(distance, components)[1:]
    # Markers: pixels within a pixel of the largest distance around them (a grey dilation over
    # about a typical region's radius), so a necked blob splits at the neck while the flat ridge
    # of one long plant stays one marker. Much cheaper than h-maxima by reconstruction.
    smooth = cv2.GaussianBlur(distance.astype(np.float32), (0, 0), 1.0)
    radius = int(np.clip(np.median(dmax) if radius is None else radius, 3, 200))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    local_max = cv2.dilate(smooth, kernel)
    peaks = mask & (smooth >= local_max - 1.0) & (smooth >= 1.0)
    markers, n_markers = _label4(peaks)
    if n_markers <= n:  # nothing to split
        return components
    # Only components holding two or more markers need a watershed (flooded in groups, see
    # _flood_components); the rest keep their component.
    marker_component = np.zeros(n_markers + 1, dtype=np.int64)
    marker_component[markers[peaks]] = components[peaks]  # every marker lies in one component
    split = np.bincount(marker_component[1:], minlength=n + 1) > 1
    split[0] = False
    if edges is not None:
        e = np.asarray(edges, dtype=np.float32)
        # The edge strength's 99th percentile over the mask, from every 7th pixel.
        if edge_scale is None:
            sample = e.ravel()[::7][mask.ravel()[::7]]
            edge_scale = 0.5 * float(np.percentile(dmax, 90)) / (float(np.percentile(sample, 99)) + 1e-6)
        landscape = np.multiply(e, np.float32(edge_scale))
        landscape -= smooth
    else:
        landscape = np.negative(smooth)
    flooded = _flood_components(landscape, markers, components, split, stats)
    # Number the result 1..n without gaps: the components left whole first, in their order, then
    # the watershed's basins in marker order (each basin holds at least its marker).
    whole = ~split
    whole[0] = False
    component_label = np.zeros(n + 1, dtype=np.int32)
    component_label[whole] = np.arange(1, int(whole.sum()) + 1, dtype=np.int32)
    basin = split[marker_component]
    basin[0] = False
    basin_label = np.zeros(n_markers + 1, dtype=np.int32)
    basin_label[basin] = np.arange(1, int(basin.sum()) + 1, dtype=np.int32) + int(whole.sum())
    # Outside the flooded area `flooded` is 0; inside it the component's own label is 0.
    labels = component_label[components]
    labels += basin_label[flooded]
    return labels


# build_relief's worker learns through this when the watershed's kernel (its longest step, which
# releases the GIL) starts: a scheduling concern of the pipeline, so not a public parameter.
_watershed_hook = threading.local()


@contextlib.contextmanager
def _before_watershed(callback):
    """Within the block, call `callback()` in this thread just before a watershed's kernels run."""
    _watershed_hook.callback = callback
    try:
        yield
    finally:
        _watershed_hook.callback = None


# The flooded components go in groups of at least this many pixels (at most _FLOOD_GROUPS groups):
# below it, threads would cost more than they save. Segmenting broccoli 01 at 1000 px: 103 ms in
# one group, 72 ms in four, the same labels (on four real photos at 1000 px, and at 12 MP).
_FLOOD_GROUP_PIXELS = 50_000
_FLOOD_GROUPS = 4
_FLOOD_THREADS = min(os.cpu_count() or 1, _FLOOD_GROUPS)


def _flood_components(landscape, markers, components, flooded, stats):
    """``_flood(landscape, markers, flooded[components])``, groups of components in parallel.

    The watershed floods each connected component of its mask from that component's own markers,
    and the kernel's queue orders pixels by (level, order of entry), so a component floods the same
    whether or not others are flooded in the same call - but for one case: the markers all enter
    first, in a tie, and where two marker pixels of one component have the same level the queue
    (a heap) breaks the tie by its layout, which depends on every marker in the call. So the
    components are flooded in groups chosen from the image alone (about equal numbers of pixels,
    in order of each component's top row, so that the groups' bands of rows overlap little), each
    group in its own thread on its band (the kernel releases the GIL): the labels do not depend on
    the machine's number of cores, and each group's are exactly scikit-image's watershed of it
    (tested, plateaus included).

    `flooded` marks the component labels to flood (index 0, the ground, False); `stats` is
    ``cv2.connectedComponentsWithStats``'s for `components`.
    """
    labels = np.flatnonzero(flooded)
    area = stats[labels, cv2.CC_STAT_AREA].astype(np.int64)
    n_groups = min(_FLOOD_GROUPS, len(labels), max(1, int(area.sum()) // _FLOOD_GROUP_PIXELS))
    if n_groups < 2:
        return _flood(landscape, markers, flooded[components])
    order = np.argsort(stats[labels, cv2.CC_STAT_TOP], kind="stable")
    share = np.cumsum(area[order]) / area.sum()
    cuts = np.searchsorted(share, np.arange(1, n_groups) / n_groups)
    bands = []
    for group in np.split(labels[order], cuts):
        if len(group):
            top = stats[group, cv2.CC_STAT_TOP]
            bands.append((group, int(top.min()), int((top + stats[group, cv2.CC_STAT_HEIGHT]).max())))

    # Every group is prepared here, before the hook: the preparation needs the GIL, which the
    # caller's own work (the hook's) then holds; the kernels need none.
    kernels = []
    for group, r0, r1 in bands:
        in_group = np.zeros(len(flooded), dtype=bool)
        in_group[group] = True
        kernels.append(_flood_kernel(landscape[r0:r1], markers[r0:r1], in_group[components[r0:r1]]))
    on_watershed = getattr(_watershed_hook, "callback", None)
    if on_watershed is not None:
        on_watershed()
    with ThreadPoolExecutor(
        min(_FLOOD_THREADS, len(bands)), thread_name_prefix="cliff_terrain_flood"
    ) as pool:
        list(pool.map(lambda kernel: kernel[0](), kernels))
    out = np.zeros(components.shape, dtype=np.int32)
    for (_, r0, r1), (_, part) in zip(bands, kernels, strict=True):
        out[r0:r1] += part  # the groups' masks are disjoint; each part is 0 outside its own
    return out


def _flood(landscape, markers, mask):
    """``skimage.segmentation.watershed(landscape, markers, mask=mask)``, 4-connected.

    The same preparation and the same flooding kernel as scikit-image's, called in two steps
    (:func:`_flood_kernel`) so that the callback of :func:`_before_watershed` runs after the
    preparation (numpy steps that need the GIL) and just before the kernel (which releases it).
    """
    run, output = _flood_kernel(landscape, markers, mask)
    on_watershed = getattr(_watershed_hook, "callback", None)
    if on_watershed is not None:
        on_watershed()
    run()
    return output


def _flood_kernel(landscape, markers, mask):
    """scikit-image's watershed prepared: ``(run, output)``, where ``run()`` floods `output`.

    As scikit-image's wrapper: float64 image, int8 mask and int32 markers (inside the mask), padded
    by a pixel of zeros so that the kernel never steps past the border. Falls back to the public
    function (preparation included in ``run``) if scikit-image's internals move.
    """
    if _watershed_raveled is None:
        output = np.zeros(mask.shape, dtype=np.int32)

        def run_public():
            output[...] = segmentation.watershed(landscape, markers, mask=mask)

        return run_public, output
    rows, cols = mask.shape
    image = np.zeros((rows + 2, cols + 2), dtype=np.float64)
    image[1:-1, 1:-1] = landscape
    flat_mask = np.zeros((rows + 2, cols + 2), dtype=np.int8)
    flat_mask[1:-1, 1:-1] = mask
    flat_mask = flat_mask.ravel()
    output = np.zeros((rows + 2, cols + 2), dtype=np.int32)
    np.multiply(markers, mask, out=output[1:-1, 1:-1], casting="unsafe")
    footprint, offset = _validate_connectivity(2, 1, None)
    neighbours = _offsets_to_raveled_neighbors(image.shape, footprint, center=offset)
    marker_locations = np.flatnonzero(output)
    strides = np.array(image.strides, dtype=np.intp) // image.itemsize

    def run():
        _watershed_raveled(
            image.ravel(), marker_locations, neighbours, flat_mask, strides, 0.0, output.ravel(), False
        )

    return run, output[1:-1, 1:-1]


def _label4(mask, *, stats=False):
    """4-connected components of `mask` -> (int32 labels 0..n, n), numbered in raster order.

    The same labels as ``scipy.ndimage.label`` with its default structure, several times faster.
    With `stats`, also ``cv2.connectedComponentsWithStats``'s (n + 1, 5) table (bounding box, area).
    """
    mask = np.ascontiguousarray(mask)
    mask = mask.view(np.uint8) if mask.dtype == bool else mask.astype(np.uint8)  # a bool mask: no copy
    if stats:
        count, labels, table, _ = cv2.connectedComponentsWithStats(mask, connectivity=4, ltype=cv2.CV_32S)
        return labels, count - 1, table
    count, labels = cv2.connectedComponents(mask, connectivity=4, ltype=cv2.CV_32S)
    return labels, count - 1


def label_max(values, labels):
    """Largest value of each region: ``out[k] = max(values[labels == k])`` for k >= 1.

    For values >= 0 (distances). ``out[0]`` (ground, not a region) and labels without pixels
    are 0. Ground is skipped: on a field it is most of the pixels. ``np.maximum.at`` is some
    40x faster than ``scipy.ndimage.maximum`` (which sorts).
    """
    labels = np.asarray(labels).ravel()
    out = np.zeros(int(labels.max(initial=0)) + 1, dtype=np.float32)
    inside = np.flatnonzero(labels)
    np.maximum.at(out, labels[inside], np.asarray(values, dtype=np.float32).ravel()[inside])
    return out
