"""Which pixels are plants: the vegetation index, its plant/soil threshold and the bare soil.

ExG + NGRDI for colour photos, (NIR - B) / (NIR + B) for false-colour NIR frames (see
:func:`vegetation_index`); Otsu's threshold kept within a prior band unless the photo is clearly
two-class (see :func:`index_threshold`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._threads import map_row_bands
from .._validate import check_choice, check_rgb
from ..errors import CliffTerrainError
from .histogram import VALLEY_BINS, otsu_threshold, valley_ratio
from .separation import chroma_map, colour_separation, red_separation

INDICES = ("auto", "green", "nir")

# Threshold bands (Otsu's threshold is clipped into them unless the photo is clearly two-class):
# bare soil and grey objects sit at or below 0, pale or bluish plants and yellow senescent canopy
# above about 0.15. The lower end is a floor in every case.
_GREEN_BAND = (0.06, 0.14)
_NIR_BAND = (0.12, 0.3)
# NDVI of a multispectral orthomosaic (reflectance): the same rule on the published NDVI ranges
# (USGS, "NDVI, the foundation for remote sensing phenology"): barren ground, water and shade at 0.1
# or less, sparse vegetation and senescing crops from about 0.2. The floor is a floor in every case.
NDVI_FLOOR = 0.1
_NDVI_BAND = (NDVI_FLOOR, 0.2)
# A photo is clearly two-class when the histogram at Otsu's threshold is at most this fraction of
# its mean between the two class means (0: an empty valley; about 1: no valley at all). On real
# annotated photos (README, "Validation on real fields") dark-soil fields whose own threshold is
# right measured 0.09-0.38, closed canopies that Otsu splits in two 0.75-1.11.
TWO_CLASS_VALLEY = 0.5
# A class is split again at a valley of its own only when it has at least one pixel per bin of the
# histogram the valley is read from: fewer give no density to read a valley in.
MIN_CLASS_PIXELS = VALLEY_BINS
# ...or when its two sides differ plainly in colour (for NDVI: in red reflectance, see
# separation.red_separation): Ashman's D of the CIELAB chroma C* of the pixels
# on either side of Otsu's split, D = sqrt(2) |m1 - m2| / sqrt(s1^2 + s2^2) (medians, robust
# spreads), is at least this much. 2 is Ashman et al.'s (1994) own bound for two cleanly separated
# classes, not a fitted number; leave-one-source-out on the annotated sets picks it from every
# fold (see bench/mask_sources.py). Green leaves are chromatic and grey-brown soil is not, however
# dark and wet, and however much blur and mixed pixels fill the valley between them; the sunlit and
# shaded halves of a closed canopy are both green (-0.4 to 1.8 on the annotated closed wheat
# canopies; 2.1-5.6 on dark-soil carrot photos).
COLOUR_SEPARATION = 2.0
# A photo whose index spans less than this between its 0.5th and 99.5th percentiles (about two
# 8-bit steps of ExG) has no usable colour: nothing in it can be told apart, the prior decides.
UNIFORM_SPREAD = 0.01
# The index is computed in bands of about this many pixels (see vegetation_index).
_BAND_PIXELS = 262_144


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
    image = np.ascontiguousarray(check_rgb("image", image))
    check_choice("index", index, INDICES)
    if index == "auto":
        index = "nir" if _looks_false_colour_nir(image) else "green"
    kernel = _green_index if index == "green" else _nir_index
    vi = np.empty(image.shape[:2], np.float32)

    def band(r0, r1):
        vi[r0:r1] = kernel(image[r0:r1])

    # In bands of about 256k pixels: the chain of steps below stays in the cache (3x faster than
    # whole-image passes at 12 MP), on threads.
    map_row_bands(band, image.shape[0], _BAND_PIXELS // max(1, image.shape[1]))
    return vi, index


def _planes(image):
    """Contiguous float32 red, green and blue planes, and 1 / (R + G + B)."""
    red, green, blue = (plane.astype(np.float32) for plane in cv2.split(image))
    inv_total = red + green
    inv_total += blue
    inv_total += np.float32(1e-6)
    np.divide(np.float32(1.0), inv_total, out=inv_total)
    return red, green, blue, inv_total


def _excess_green(green, inv_total):
    # ExG = 2g - r - b = 3 G / (R + G + B) - 1 on chromatic coordinates.
    exg = green * np.float32(3.0)
    exg *= inv_total
    exg -= np.float32(1.0)
    return exg


def _green_index(image):
    # Every step one pass written in place: fresh arrays for the temporaries would cost as much
    # again (allocation and page faults).
    red, green, blue, inv_total = _planes(image)
    vi = _excess_green(green, inv_total)
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
    return vi


def _nir_index(image):
    red, _, blue = (plane.astype(np.float32) for plane in cv2.split(image))
    return (red - blue) / (red + blue + np.float32(1e-6))


def _looks_false_colour_nir(rgb):
    # A colour photo of a field has green among its pixels, and blue is its weakest channel
    # (brown soil, green and yellow plants). A NIR-modified camera (NIR in the red channel) shows
    # plants red and soil lilac: no green anywhere and green the weakest channel of most pixels.
    n = rgb.shape[0] * rgb.shape[1]
    step = max(1, n // 200_000)
    px = rgb.reshape(-1, 3)[::step]
    _, green, _, inv_total = _planes(np.ascontiguousarray(px).reshape(-1, 1, 3))
    exg_s = _excess_green(green, inv_total).ravel()
    px = px[px.sum(axis=1) > 30]  # black no-data borders say nothing
    # Nor do grey pixels (R = G = B), where every channel is the weakest: a greyscale photo, or the
    # grey soil of a colour one, was taken for a NIR frame (and its plants measured by NIR - B).
    px = px[px.max(axis=1) > px.min(axis=1)]
    if px.shape[0] == 0:
        return False
    green_weakest = float(np.mean(px[:, 1] <= px.min(axis=1)))
    return float(np.percentile(exg_s, 99)) < 0.02 and green_weakest > 0.5


# The blur's reach (pixels): cv2's sigma-1 Gaussian on float32 has a 9-pixel kernel (the windowed
# measure reads this many around its windows: cliff_terrain.measure.window_tasks).
BLUR_REACH = 4


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
    separation: float = float("nan")
    note: str = ""


def index_threshold(values, *, index="green", chroma=None, red=None):
    """The plant/soil threshold of a vegetation index: the photo's own when clearly two-class.

    Otsu's threshold is the photo's own. The prior is Otsu's threshold kept within the band of
    `index`. The photo's own wins when Otsu's threshold lies above the band, the band's threshold is
    not in an empty valley (it would cut into a class) and the photo is clearly two-class by either
    of two tests:

    * ``"valley"``: the density at Otsu's threshold is at most ``TWO_CLASS_VALLEY`` (0.5) times the
      mean density between the two class means (an almost empty valley);
    * ``"colour"``: the two sides of Otsu's split differ plainly in colour: Ashman's D of their
      CIELAB chroma C* (`chroma`, the upper side the more chromatic) is at least
      ``COLOUR_SEPARATION`` (2, Ashman's bound), and the band's threshold lies in the body of a
      class (the density there at least the mean between the class means). Green plants over
      grey-brown soil pass however dark and wet the soil and however much JPEG blur and mixed
      pixels fill the valley; the sunlit and shaded halves of a closed canopy, both green, do not.

    NDVI (``index="ndvi"``) follows the same rule with the band ``(NDVI_FLOOR, 0.2)`` (0.1: barren
    ground, water, shade; 0.2: sparse or senescing vegetation, the published NDVI ranges), the colour
    test read in the red band: Ashman's D of the red reflectance (`red`) on either side of Otsu's
    split, the upper side the darker (``"photo (red)"``, see
    :func:`~cliff_terrain.photo_heights.separation.red_separation`). Leaves absorb red, soil does
    not; the sunlit and shaded halves, or the dense and thin parts, of a closed canopy that NDVI
    tells apart absorb it alike. Either test passes wherever Otsu's threshold lies: a soil's NDVI
    may lie above the band (moist or weedy soil between rows, 0.2-0.4), so that the band is no
    fallback for a clearly two-class NDVI map.

    Otherwise the prior stands: one class (bare soil, or a closed canopy that Otsu would split into
    sunlit and shaded leaves), or two classes whose valley holds the prior too (then either
    threshold gives the same mask but for the blurred rims, and the prior keeps every figure
    measured with it). The band's lower end is a floor in both cases: soil and grey objects score
    at or below 0. When Otsu's threshold lies *below* the floor and most of its upper class lies
    below the floor too (yellow, senescent canopy over brown soil, or straw and residue over soil),
    colour alone cannot tell which is plant: the floor stands and ``note`` says so. That split,
    below the floor, divides soil from straw, residue, paler soil or shade and says nothing of the
    plants; so its upper class is split again (multi-level Otsu, one level more), and where that
    class has an empty valley of its own (the same ``TWO_CLASS_VALLEY`` test, its threshold above the
    floor and kept within the band unless the band would cut into a class), the plants among residue
    are a third class and only they rise (``"photo (upper valley)"``). Without such a valley the
    upper class is one class (pale plants, or residue alone) and the floor stands.

    Parameters
    ----------
    values : array of float
        Index values of the pixels with data (any shape; a sample is taken from large arrays).
    index : {"green", "nir", "ndvi"}, optional
        Which index, for its prior band. ``"ndvi"``: a multispectral orthomosaic's NDVI (see
        :func:`cliff_terrain.photo_heights.indices.nir_index_map`), band ``(NDVI_FLOOR, 0.2)``.
    chroma : array of float, optional
        CIELAB chroma of the same pixels, in the same order (see :func:`~cliff_terrain.photo_heights.separation.chroma_map`); without it
        (false-colour and NDVI frames) only the valley test applies.
    red : array of float, optional
        Red reflectance of the same pixels, in the same order (``index="ndvi"``): the colour test of
        an NDVI map. Without it only the valley test applies.

    Returns
    -------
    ThresholdRule
        ``threshold``, ``index``, ``source`` (``"photo"``, ``"photo (colour)"``, ``"photo (red)"``,
        ``"photo (upper valley)"``, ``"band"``, or ``"uniform"`` when the index has no spread: the
        band's threshold then decides alone; for NDVI the floor), ``valley`` (the density ratio of
        the photo's own split; NaN when there is no spread),
        ``separation`` (the chroma's Ashman D, for NDVI the red reflectance's; NaN without `chroma`
        or `red`) and ``note`` (empty, or why the photo could not decide).

    Examples
    --------
    Soil around 0.2 (dark and wet) and plants around 0.8, an empty valley between them:

    >>> rng = np.random.default_rng(0)
    >>> vi = np.concatenate([rng.normal(0.2, 0.05, 9000), rng.normal(0.8, 0.1, 1000)])
    >>> rule = index_threshold(vi)
    >>> rule.source, bool(0.35 < rule.threshold < 0.65)
    ('photo', True)

    The same classes blurred into each other (no valley), the soil grey and the plants green:

    >>> vi = np.concatenate([rng.normal(0.17, 0.16, 5500), rng.normal(0.7, 0.18, 4500)])
    >>> chroma = np.concatenate([rng.normal(6, 3, 5500), rng.normal(40, 8, 4500)])
    >>> index_threshold(vi).source, index_threshold(vi, chroma=chroma).source
    ('band', 'photo (colour)')

    One class only (a closed canopy): Otsu's threshold would split it, the band keeps it whole.

    >>> rule = index_threshold(rng.normal(0.5, 0.1, 10000), chroma=rng.normal(40, 8, 10000))
    >>> rule.source, rule.threshold
    ('band', 0.14)

    Shade, residue and a few green plants: Otsu splits shade from residue, below the floor, and the
    residue's own valley parts the plants from it; without plants the floor stands.

    >>> shade, residue = rng.normal(-0.3, 0.06, 3000), rng.normal(-0.03, 0.04, 6700)
    >>> rule = index_threshold(np.concatenate([shade, residue, rng.normal(0.35, 0.08, 300)]))
    >>> rule.source, rule.threshold, rule.note.startswith("undecided")
    ('photo (upper valley)', 0.14, True)
    >>> rule = index_threshold(np.concatenate([shade, residue, rng.normal(-0.03, 0.04, 300)]))
    >>> rule.source, rule.threshold
    ('band', 0.06)

    NDVI: plants and soil blurred into each other, the leaves dark in red and the soil not, then a
    closed canopy whose denser half NDVI would call plant (alike in red):

    >>> ndvi = np.concatenate([rng.normal(0.25, 0.12, 5500), rng.normal(0.65, 0.15, 4500)])
    >>> red = np.concatenate([rng.normal(0.14, 0.03, 5500), rng.normal(0.04, 0.01, 4500)])
    >>> index_threshold(ndvi, index="ndvi", red=red).source
    'photo (red)'
    >>> rule = index_threshold(rng.normal(0.55, 0.1, 10000), index="ndvi", red=rng.normal(0.1, 0.02, 10000))
    >>> rule.source, rule.threshold
    ('band', 0.2)
    """
    check_choice("index", index, ("green", "nir", "ndvi"))
    flat = np.asarray(values, dtype=np.float32).ravel()
    # The colour test's values: the chroma of a colour photo, the red reflectance of an NDVI map.
    colour, colour_name = (red, "red") if index == "ndvi" else (chroma, "chroma")
    if colour is not None:
        colour = np.asarray(colour, dtype=np.float32).ravel()
        if colour.shape != flat.shape:
            raise CliffTerrainError(
                f"`{colour_name}` must have {flat.size} values (one per index value), got {colour.size}"
            )
    keep = np.isfinite(flat) if colour is None else np.isfinite(flat) & np.isfinite(colour)
    flat = flat[keep]
    if colour is not None:
        colour = colour[keep]
    if flat.size > 400_000:  # a sample gives the same threshold at a fraction of the cost
        step = flat.size // 400_000
        flat = flat[::step]
        colour = None if colour is None else colour[::step]
    # float64: numpy 2 refuses 128 histogram bins over a float32 range of a few ulps.
    flat = flat.astype(np.float64)
    low, high = {"green": _GREEN_BAND, "nir": _NIR_BAND, "ndvi": _NDVI_BAND}[index]
    otsu = otsu_threshold(flat)
    if flat.size == 0 or float(np.subtract(*np.percentile(flat, (99.5, 0.5)))) < UNIFORM_SPREAD:
        # Nothing to tell apart: the prior alone decides (a green frame is canopy seen close, a
        # brown or grey one bare soil), and the record says that the photo could not.
        value = float(np.clip(otsu, low, high)) if index != "ndvi" else NDVI_FLOOR
        note = (
            "uniform: the photo has one colour, nothing in it can be told apart; the prior decides "
            "(green rises whole, soil and grey stay flat)"
        )
        return ThresholdRule(value, index, "uniform", float("nan"), float("nan"), note)
    banded = float(np.clip(otsu, low, high))
    valley, at_band = valley_ratio(flat, otsu, (otsu, banded))
    if index == "ndvi":
        separation = float("nan") if colour is None else red_separation(colour, flat > otsu)
        # Clearly two-class wherever Otsu's threshold lies: an NDVI map's soil may lie above the band
        # (moist or weedy soil), where the band would raise it.
        if valley <= TWO_CLASS_VALLEY:
            return ThresholdRule(max(otsu, low), index, "photo", valley, separation)
        if separation >= COLOUR_SEPARATION:
            return ThresholdRule(max(otsu, low), index, "photo (red)", valley, separation)
        at_band = float("inf")  # the band's threshold is the prior here, not a second valley
    else:
        separation = float("nan") if colour is None else colour_separation(colour, flat > otsu)
    # Two classes whose valley the band misses (it cuts into one of them): the photo's own.
    if otsu > high and not at_band <= TWO_CLASS_VALLEY:
        if valley <= TWO_CLASS_VALLEY:
            return ThresholdRule(otsu, index, "photo", valley, separation)
        # By colour only where the band's threshold lies in the body of a class, the histogram
        # there at least its mean between the class means (1 on the valley's scale: no dip at
        # all): the soil's own peak, as on dark, wet soil. On the flank of a shallow valley (mixed
        # rims of plots on a coarse orthophoto) both thresholds give the same plants but for rims.
        if separation >= COLOUR_SEPARATION and at_band >= 1.0:
            return ThresholdRule(otsu, index, "photo (colour)", valley, separation)
    upper = flat > otsu
    below_floor = float(np.count_nonzero(upper & (flat <= low))) / max(1, int(np.count_nonzero(upper)))
    if otsu < low and below_floor > 0.5:
        # Otsu's split below the floor divides soil from straw, residue or paler soil and says
        # nothing of the plants. Split its upper class again (multi-level Otsu, one level more) and
        # take that split where the class has an empty valley of its own (the same test, the same
        # bound): the plants among residue are a third class. Without such a valley the upper class
        # is one class (pale plants, or residue alone), and the floor stands. Only here: a split
        # above the floor's upper class is plants (sunlit and shaded leaves), not to be split again.
        third = None if index == "ndvi" else _upper_valley(flat[upper], low, high)
        above = (
            f"the floor ({low})"
            if third is None
            else f"an empty valley within that class ({third[0]:.3f}, valley {third[1]:.2f})"
        )
        note = (
            "undecided: most of the upper class of the photo's own split lies below the index "
            "floor (yellow, senescent canopy, or straw and residue, over soil?); colour alone "
            "cannot tell which is plant, so that class stays flat and only what lies above "
            f"{above} rises"
        )
        if third is not None:
            return ThresholdRule(third[0], index, "photo (upper valley)", valley, separation, note)
    elif otsu > high and not at_band <= TWO_CLASS_VALLEY:
        note = (
            "one class: neither an empty valley nor a colour difference splits the photo; the "
            "prior band decides (a closed canopy rises whole, bare soil stays flat)"
        )
        if index == "ndvi":
            note = (
                "one class: neither an empty valley nor a difference in red reflectance splits the "
                f"NDVI map; the prior band decides (NDVI above {high} rises: a closed or senescent "
                "canopy rises whole; bare soil with NDVI above it would rise too)"
            )
    else:
        note = ""
    return ThresholdRule(banded, index, "band", valley, separation, note)


def _upper_valley(values, low, high):
    """``(threshold, valley)`` splitting `values` (the upper class of a split below the floor) at an
    empty valley above `low`, or None: Otsu's threshold of `values` where the density there is at
    most ``TWO_CLASS_VALLEY`` of its mean between the class means, kept within the band unless the
    band's own threshold would cut into a class (as :func:`index_threshold` does with the whole
    photo). ``valley`` is that density ratio, the one the split was accepted on."""
    if values.size < MIN_CLASS_PIXELS:
        return None
    split = otsu_threshold(values)
    banded = float(np.clip(split, low, high))
    valley, at_band = valley_ratio(values, split, (split, banded))
    if not (split > low and valley <= TWO_CLASS_VALLEY):
        return None
    return (split if split > high and not at_band <= TWO_CLASS_VALLEY else banded), valley


def photo_threshold(vi, image, *, index, valid=None, red=None):
    """:func:`index_threshold` of a photo's index map `vi` over its `valid` pixels, with the colour
    test on the photo's chroma (not for false-colour NIR frames, whose colours are not the plants'),
    or for an NDVI map on its `red` reflectance (same grid); the one place the segmentation, the bare
    soil and the orthophoto's plant mask take it."""
    chroma = chroma_map(image) if index == "green" else None
    red = None if red is None or index != "ndvi" else np.asarray(red, dtype=np.float32)
    if valid is None:
        return index_threshold(vi, index=index, chroma=chroma, red=red)
    return index_threshold(
        vi[valid],
        index=index,
        chroma=None if chroma is None else chroma[valid],
        red=None if red is None else red[valid],
    )
