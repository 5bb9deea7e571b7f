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
    filled only where they are plausibly inside a plant (see :func:`.holes.plant_holes`): soil enclosed
    by canopy, such as the strips between rows that join at their ends, stays flat.

The index and its threshold are in :mod:`.vegetation`, the holes filled in :mod:`.holes`, the
watershed in :mod:`.watershed`, the labels, distances and boundaries in :mod:`.labels`; this module
puts them together.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import check_choice, check_float, check_int, check_rgb
from ..errors import CliffTerrainError
from ..settings import SEGMENTATIONS, ids
from .histogram import otsu_threshold
from .holes import clean_mask
from .labels import distance_map, inner_boundaries
from .separation import surface_split
from .vegetation import COLOUR_SEPARATION, ThresholdRule, blurred_index, photo_threshold
from .watershed import colour_edges, split_regions

METHODS = ids(SEGMENTATIONS)


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
        ``"photo"`` (the photo's own: a clearly two-class index histogram), ``"photo (colour)"``
        (the photo's own: its two sides differ plainly in chroma), ``"photo (upper valley)"`` (the
        upper class of a split below the floor, split again at its own empty valley: plants among
        residue), ``"photo (dsm)"`` (see :func:`decide_by_surface`), ``"band"`` (Otsu's kept within
        the prior band), ``"otsu"`` (paper mode: Otsu's on the grey level) or ``"given"`` (the
        caller's, see :func:`segment`).
    valley : float
        The histogram at the threshold relative to its mean between the class means (see
        :func:`index_threshold`); NaN in paper mode.
    separation : float
        Ashman's D of the chroma between the two sides of Otsu's split (see
        :func:`~cliff_terrain.photo_heights.vegetation.colour_separation`); NaN where not measured.
    threshold_note : str
        Empty, or why the photo could not decide (see :func:`index_threshold`).
    distance : (rows, cols) float32
        ``distance_map(mask)``: each plant pixel's distance to flat ground (the watershed's, kept
        for the plateau profile).
    region_distance : (rows, cols) float32
        ``distance_map(labels)``: each region pixel's distance to the nearest pixel outside its
        region (computed with the watershed; the inflation's D). The same array as `distance`
        where the watershed split nothing.
    index_pixels : (rows, cols) bool or None
        The vegetation mode's index above `threshold`, before specks are dropped and holes filled
        (no-data pixels included): the plant pixels canopy cover counts, as the windowed measure
        does (:func:`cliff_terrain.measure.canopy.cover_pixels`). None in paper mode and when
        `mask` was given.
    """

    mask: np.ndarray
    labels: np.ndarray
    boundaries: np.ndarray
    threshold: float
    index: str
    distance: np.ndarray | None = None
    threshold_source: str = "band"
    valley: float = float("nan")
    region_distance: np.ndarray | None = None
    separation: float = float("nan")
    threshold_note: str = ""
    index_pixels: np.ndarray | None = None

    @property
    def n_regions(self) -> int:
        return int(self.labels.max(initial=0))


def segment(
    image,
    *,
    method="vegetation",
    filtered=None,
    index="auto",
    min_region=None,
    valid=None,
    threshold=None,
    radius=None,
    edge_scale=None,
    soil=None,
    index_map=None,
    red=None,
    mask=None,
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
    threshold : float, optional
        The threshold to apply (to the index, or to the grey level in ``"paper"`` mode) instead of
        the image's own; ``Segmentation.threshold_source`` is then ``"given"``. The tiles of one
        mosaic share the whole mosaic's (:mod:`cliff_terrain.mosaic.tiles`).
    radius, edge_scale : float, optional
        The watershed's marker radius and colour-edge scale (see :func:`split_regions`); by
        default from this image's regions and edges. Tiles of one mosaic share the whole mosaic's.
    soil : float, optional
        The soil's index for the hole rule (see :func:`.holes.plant_holes`); by default this image's
        :func:`.holes.soil_level`. Tiles of one mosaic share the whole mosaic's.
    index_map : (rows, cols) float array, optional
        NDVI of a multispectral orthomosaic on the image's grid (NaN = no data), used by
        ``"vegetation"`` instead of the colour index; its threshold is the photo's own (see
        :func:`index_threshold`). ``Segmentation.index`` is then ``"ndvi"``.
    red : (rows, cols) float array, optional
        The orthomosaic's red reflectance on the same grid, with `index_map`: the colour test of its
        threshold (see :func:`index_threshold`).
    mask : (rows, cols) bool array, optional
        The plants' mask as :func:`vegetation_mask` makes it (``"vegetation"``, with `threshold`
        given): only the watershed and what follows run (a mosaic's tile, whose mask comes from its
        whole window).

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
    threshold = check_float("threshold", threshold, allow_none=True)
    radius = check_float("radius", radius, minimum=0.0, allow_none=True)
    edge_scale = check_float("edge_scale", edge_scale, minimum=0.0, allow_none=True)
    soil = check_float("soil", soil, allow_none=True)
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
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if method != "vegetation" or threshold is None or index not in ("green", "nir", "ndvi"):
            raise CliffTerrainError(
                "`mask` needs method='vegetation', the `threshold` and the `index` it was made with, "
                f"got method={method!r}, threshold={threshold!r}, index={index!r}"
            )
        if mask.shape != image.shape[:2]:
            raise CliffTerrainError(f"`mask` must have shape {image.shape[:2]}, got {mask.shape}")
        rule = ThresholdRule(threshold, index, "given", float("nan"))
        index_pixels = None
    elif method == "paper":
        if filtered is None:
            raise CliffTerrainError("`filtered` is required when `method` is 'paper', got None")
        mask, rule = _paper_mask(filtered, valid, threshold)
        index_pixels = None
    else:
        mask, rule, index_pixels = vegetation_mask(
            image,
            index=index,
            valid=valid,
            threshold=threshold,
            min_region=min_region,
            soil=soil,
            index_map=index_map,
            red=red,
            return_index_pixels=True,
        )
    threshold, index_name, source, valley = rule.threshold, rule.index, rule.source, rule.valley
    if method == "paper":
        if valid is not None:
            mask &= valid
        mask = clean_mask(mask, min_region)  # the paper fills every hole (imfill)
    distance = distance_map(mask)
    edges = colour_edges(filtered) if (filtered is not None and method == "vegetation") else None
    labels, region_distance = split_regions(
        mask, distance, edges=edges, radius=radius, edge_scale=edge_scale, return_distance=True
    )
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
        region_distance=region_distance,
        separation=rule.separation,
        threshold_note=rule.note,
        index_pixels=index_pixels,
    )


def decide_by_surface(seg, image, surface, *, filtered=None, valid=None, index_map=None):
    """A :func:`segment` result whose threshold was undecided, decided by a surface model.

    The photo's own split (Otsu's threshold, below the index floor) is used when the pixels above
    it stand above the others on `surface` by Ashman's D >= ``COLOUR_SEPARATION`` (2), a plane
    fitted to the others (the ground) taken off first (see
    :func:`~cliff_terrain.photo_heights.separation.surface_separation`): senescent canopy stands, straw
    and residue lie on the ground. When `seg` split that class again at a valley of its own
    (``"photo (upper valley)"``: green plants among residue), the class between the two splits is
    tested, the plants above the upper one left out of both sides. Otherwise `seg` is returned with
    its note saying that the surface did not tell either.

    Parameters
    ----------
    seg : Segmentation
        The vegetation mode's result for `image`.
    image : (rows, cols, 3) uint8 array
    surface : (rows, cols) float array
        Heights on the image's grid (a DSM; NaN where there is none).
    filtered, valid, index_map : optional
        As :func:`segment`'s (`index_map`: the NDVI map `seg` was made from, when it was).

    Returns
    -------
    Segmentation
        ``threshold_source`` ``"photo (dsm)"`` when the surface decided.
    """
    import dataclasses

    if seg.index == "ndvi":
        if index_map is None:
            raise CliffTerrainError("`index_map` is required when `seg` was made from an NDVI map, got None")
        vi, valid = _blurred_ndvi(np.asarray(index_map, dtype=np.float32), valid)
    else:
        vi, _ = blurred_index(image, index=seg.index)
    upper = seg.threshold if seg.threshold_source == "photo (upper valley)" else None
    split, d = surface_split(vi, surface, valid=valid, upper=upper)
    if not d >= COLOUR_SEPARATION:
        note = seg.threshold_note + f"; the DSM does not show it standing above the rest either (D {d:.2f})"
        return dataclasses.replace(seg, threshold_note=note)
    decided = segment(
        image,
        method="vegetation",
        filtered=filtered,
        valid=valid,
        threshold=split,
        index=seg.index,
        index_map=index_map if seg.index == "ndvi" else None,
    )
    note = f"decided by the DSM: the class above the photo's own split stands above the rest (D {d:.2f})"
    return dataclasses.replace(
        decided,
        threshold_source="photo (dsm)",
        valley=seg.valley,
        separation=seg.separation,
        threshold_note=note,
    )


def vegetation_mask(
    image,
    *,
    index="auto",
    valid=None,
    threshold=None,
    min_region=0,
    soil=None,
    index_map=None,
    red=None,
    return_index_pixels=False,
):
    """The plants' mask of :func:`segment`'s ``"vegetation"`` mode, before the watershed.

    The index thresholded, the no-data pixels dropped, specks dropped and the holes plausibly inside
    a plant filled (see :func:`.holes.plant_holes`). Arguments as :func:`segment`'s (checked there).

    Returns
    -------
    mask : (rows, cols) bool array
    rule : ThresholdRule
    index_pixels : (rows, cols) bool array
        With `return_index_pixels` only: the index above the threshold, before anything is
        dropped or filled (``Segmentation.index_pixels``).
    """
    if index_map is not None:
        index_map = np.asarray(index_map, dtype=np.float32)
        if index_map.shape != image.shape[:2]:
            raise CliffTerrainError(f"`index_map` must have shape {image.shape[:2]}, got {index_map.shape}")
    if red is not None:
        red = np.asarray(red, dtype=np.float32)
        if index_map is None or red.shape != image.shape[:2]:
            raise CliffTerrainError(
                f"`red` needs `index_map` and shape {image.shape[:2]}, got shape {red.shape}"
                + ("" if index_map is not None else " without `index_map`")
            )
    mask, rule, vi = _vegetation_mask(image, index, valid, threshold, index_map, red)
    index_pixels = mask.copy() if return_index_pixels else None
    if valid is not None:
        mask &= valid
    # Vegetation mode fills only the holes plausibly inside a plant.
    mask = clean_mask(mask, min_region, vi=vi, threshold=rule.threshold, soil=soil)
    return (mask, rule, index_pixels) if return_index_pixels else (mask, rule)


def _paper_mask(filtered, valid, threshold=None):
    """``(mask, ThresholdRule)`` of the paper mode: Otsu's threshold on the grey level, or `threshold`."""
    grey = filtered.astype(np.float32).mean(axis=2)
    if threshold is None:
        rule = ThresholdRule(
            otsu_threshold(grey if valid is None else grey[valid]), "grey", "otsu", float("nan")
        )
    else:
        rule = ThresholdRule(threshold, "grey", "given", float("nan"))
    return grey > rule.threshold, rule


def _blurred_ndvi(index_map, valid):
    """NDVI blurred as the colour index is (no data lies below any plant), and its valid pixels."""
    finite = np.isfinite(index_map)
    valid = finite if valid is None else valid & finite
    return cv2.GaussianBlur(np.where(finite, index_map, np.float32(-1.0)), (0, 0), 1.0), valid


def _vegetation_mask(image, index, valid, threshold=None, index_map=None, red=None):
    """``(mask, ThresholdRule, blurred index)`` of the vegetation mode (at `threshold` if given)."""
    if index_map is None:
        vi, name = blurred_index(image, index=index)
    else:
        vi, valid = _blurred_ndvi(index_map, valid)
        name = "ndvi"
    if threshold is None:
        rule = photo_threshold(vi, image, index=name, valid=valid, red=red)
    else:
        rule = ThresholdRule(threshold, name, "given", float("nan"))
    return vi > rule.threshold, rule, vi
