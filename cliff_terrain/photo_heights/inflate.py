"""Heights (the paper's Algorithm 3): inflate each region from its distance map."""

from __future__ import annotations

import numpy as np

from .._validate import check_choice, check_float
from ..errors import CliffTerrainError
from ..settings import PROFILES as _PROFILE_CHOICES
from ..settings import ids
from .labels import distance_map, label_max, region_interiors

PROFILES = ids(_PROFILE_CHOICES)


def resolve_profile(profile, segmentation="vegetation"):
    """The profile `profile` stands for with `segmentation`: ``"auto"`` is ``"plateau"``, or the
    paper's ``"circular"`` with ``segmentation="paper"`` (its Algorithms 2 and 3 together).

    Examples
    --------
    >>> resolve_profile("auto"), resolve_profile("auto", "paper"), resolve_profile("poisson")
    ('plateau', 'circular', 'poisson')
    """
    check_choice("profile", profile, PROFILES)
    if profile != "auto":
        return profile
    return "plateau" if segmentation == "vegetation" else "circular"


def inflate(
    labels, *, profile="circular", exaggeration=1.0, distance=None, max_height=None, mask_distance=None
):
    """Heights of every region, in pixels.

    Parameters
    ----------
    labels : (rows, cols) int array
        0 on flat ground, 1..n for the regions.
    profile : {"circular", "poisson", "plateau", "auto"}, optional
        ``"circular"``: the paper's H = sqrt(Dmax^2 - (Dmax - D)^2), with D the Euclidean distance
        to the region's edge and Dmax its largest value in the region: a circular cross-section
        that rises vertically at the edge. ``"poisson"``: solve the Poisson equation
        laplace(h) = -4 inside the regions with h = 0 on their boundary and take sqrt(h) (after
        Baran & Lehtinen's notes on inflating curves): smooth, no creases along the medial axis.
        Both give a hemisphere of radius r for a disc of radius r.
        ``"plateau"``: the circular profile with the canopy height as a ceiling: each region rises
        like the circular profile of radius min(Dmax, canopy height) and then stays level, so an
        isolated plant narrower than twice the canopy height is the paper's dome, while a closed
        canopy (merged plants, a plot) is a plateau at canopy height instead of a dome as tall as
        half its width (see :func:`plateau_profile`). ``"auto"`` is ``"plateau"`` here (it
        means the paper's ``"circular"`` only to :func:`~cliff_terrain.build.build_relief`
        with ``segmentation="paper"``).
    exaggeration : float, optional
        Factor applied to the heights (> 0).
    distance : (rows, cols) float array, optional
        ``distance_map(labels)`` if already computed (circular and plateau profiles).
    mask_distance : (rows, cols) float array, optional
        ``distance_map(labels > 0)`` if already computed (plateau profile; :func:`segment` keeps
        it as ``Segmentation.distance``).
    max_height : float, optional
        Canopy height in pixels (> 0, finite), before `exaggeration`. ``"plateau"``: the height of
        the plateau, by default :func:`typical_plant_radius` (the radius of a typical isolated plant).
        ``"circular"`` and ``"poisson"``: a cap (heights above it are cut level); none by default.

    Returns
    -------
    (rows, cols) float32 array
        Heights >= 0, 0 on flat ground.

    Examples
    --------
    >>> rr, cc = np.mgrid[:41, :41]
    >>> disc = ((rr - 20) ** 2 + (cc - 20) ** 2 <= 15**2).astype(int)
    >>> h = inflate(disc)
    >>> bool(abs(h.max() - 15) < 1.5)
    True
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise CliffTerrainError(f"`labels` must be a 2-D array, got shape {labels.shape}")
    if labels.dtype.kind not in "iub":
        raise CliffTerrainError(f"`labels` must hold integers, got dtype {labels.dtype}")
    check_choice("profile", profile, PROFILES)
    exaggeration = check_float("exaggeration", exaggeration, minimum=0.0, strict_minimum=True)
    max_height = check_float("max_height", max_height, minimum=0.0, strict_minimum=True, allow_none=True)
    labels = labels.astype(np.int32, copy=False)
    mask = labels > 0
    if not mask.any():
        return np.zeros(labels.shape, dtype=np.float32)
    if profile in ("plateau", "auto"):
        h = plateau_profile(labels, max_height, region_distance=distance, mask_distance=mask_distance)
    elif profile == "circular":
        if distance is None:
            distance = distance_map(labels)
        h = circular_profile(labels, distance)
    else:
        h = poisson_profile(region_interiors(labels))
    if max_height is not None and profile not in ("plateau", "auto"):
        np.minimum(h, np.float32(max_height), out=h)
    if exaggeration != 1.0:
        h *= np.float32(exaggeration)
    return h


def circular_profile(labels, distance):
    """H = sqrt(Dmax^2 - (Dmax - D)^2) per region (Dmax = the region's largest distance)."""
    labels = np.asarray(labels)
    # On the region pixels only: ground, most of a field, stays 0.
    inside = np.flatnonzero(labels.ravel() != 0)
    lab = labels.ravel()[inside]
    d = np.asarray(distance, dtype=np.float32).ravel()[inside]
    dm = label_max(d, lab)[lab]
    np.minimum(d, dm, out=d)
    h = np.sqrt(np.maximum(dm * dm - (dm - d) ** 2, 0.0))
    h[d <= 0] = 0.0
    out = np.zeros(labels.shape, dtype=np.float32)
    out.ravel()[inside] = h
    return out


def plateau_profile(labels, canopy=None, *, region_distance=None, mask_distance=None):
    """The circular profile levelled off at the canopy height: a closed canopy is a plateau.

    With D the distance to flat ground (of the whole mask: touching plants form one canopy, with
    no valley where the watershed split them), Dmax each region's largest D and c its radius:
    H = sqrt(c^2 - (c - min(D, c))^2). Regions have c = min(Dmax, canopy): narrow ones are the
    paper's domes, wide ones (plants merged in a canopy, rows, plots) rise like a dome of radius
    `canopy` at their rim and are level at `canopy` inside. With the estimated canopy height, an
    isolated plant (a region off the frame that touches no other and is about round: area at
    most twice the disc of radius Dmax) keeps c = Dmax, the paper's dome, whatever its size; a
    `canopy` given is a ceiling for every region.

    Parameters
    ----------
    labels : (rows, cols) int array
        0 on flat ground, 1..n for the regions.
    canopy : float, optional
        Canopy height in pixels; default :func:`typical_plant_radius` (estimated).
    region_distance : (rows, cols) float array, optional
        ``distance_map(labels)`` if already computed (for the default `canopy`).
    mask_distance : (rows, cols) float array, optional
        ``distance_map(labels > 0)`` if already computed.

    Returns
    -------
    (rows, cols) float32 array

    Examples
    --------
    >>> labels = np.zeros((60, 200), np.int32); labels[10:50, 10:190] = 1   # 40 px wide
    >>> h = plateau_profile(labels, 8.0)
    >>> float(h.max()), float(h[30, 100]), bool(0 < h[30, 10] < 8)
    (8.0, 8.0, True)
    """
    labels = np.asarray(labels, dtype=np.int32)
    out = np.zeros(labels.shape, dtype=np.float32)
    inside = np.flatnonzero(labels.ravel() != 0)
    if inside.size == 0:
        return out
    distance = distance_map(labels > 0) if mask_distance is None else mask_distance
    lab = labels.ravel()[inside]
    d = distance.ravel()[inside]
    regions = _Regions(labels, label_max(d, lab), lab)
    radius = regions.dmax.astype(np.float32)
    if canopy is None:  # estimated: isolated plants keep their domes, whatever their size
        if region_distance is None:
            region_distance = distance_map(labels)
        own_dmax = label_max(np.asarray(region_distance, dtype=np.float32).ravel()[inside], lab)
        canopy = _typical_radius(own_dmax, regions, labels.shape)
        np.minimum(radius, np.float32(canopy), out=radius, where=~regions.isolated_plant)
    else:  # given: nothing rises above it
        np.minimum(radius, np.float32(canopy), out=radius)
    c = radius[lab]
    np.minimum(d, c, out=d)
    # c^2 - (c - d)^2 = d (2c - d)
    c *= np.float32(2.0)
    c -= d
    c *= d
    out.ravel()[inside] = np.sqrt(np.maximum(c, np.float32(0.0)))
    return out


# Regions larger than this many times the disc of their largest inscribed radius are not single
# round plants (rows, merged canopy).
_COMPACT = 2.0
# An isolated region narrower than this share of the typical region is a weed or a speck.
_PLANT_SHARE = 0.5
# Canopy height when no region lies off the frame (a canopy over the whole photo): this fraction
# of the shorter side.
_FALLBACK_FRACTION = 0.02


class _Regions:
    """Per-region traits for the plateau profile: size, frame contact, contact with other regions."""

    def __init__(self, labels, dmax, lab):
        """`dmax` per label (0..n), `lab` the labels of the region pixels."""
        n = len(dmax) - 1
        self.dmax = np.asarray(dmax, dtype=np.float64)
        self.area = np.bincount(lab, minlength=n + 1).astype(np.float64)
        self.off_frame = np.ones(n + 1, dtype=bool)
        for edge in (labels[0], labels[-1], labels[:, 0], labels[:, -1]):
            self.off_frame[edge] = False
        self.off_frame[0] = False
        self.alone = np.ones(n + 1, dtype=bool)
        # Neighbours in the raveled image: right (the last column pairs with the next row's first,
        # which only concerns regions on the frame, never isolated) and below. Only the pixels
        # where the label changes are looked at.
        flat = np.ascontiguousarray(labels).ravel()
        for step in (1, labels.shape[1]):
            change = np.flatnonzero(flat[:-step] != flat[step:])
            a, b = flat[change], flat[change + step]
            both = (a > 0) & (b > 0)
            self.alone[a[both]] = False
            self.alone[b[both]] = False
        self.alone[0] = False
        round_ = self.area <= _COMPACT * np.pi * self.dmax**2
        self.isolated_plant = self.alone & round_ & self.off_frame


def typical_plant_radius(labels, distance=None):
    """The radius of a typical isolated plant, in pixels: the default canopy height of ``"plateau"``.

    The typical region is the area-weighted median of the regions' largest inscribed radii (Dmax,
    each region on its own: where the watershed split touching plants, each plant counts), over
    the regions off the frame. Isolated plants are the regions that touch neither the frame nor
    another region, are about round (area at most twice the disc of radius Dmax, so rows and
    merged canopy do not count) and are at least half as wide as the typical region (weeds and
    specks do not count). The result is their median Dmax; without any (all plants touch, as in
    closed rows), the typical region's; without regions off the frame (a canopy over the whole
    photo), 2 % of the image's shorter side; 0 without regions.

    Parameters
    ----------
    labels : (rows, cols) int array
        0 on flat ground, 1..n for the regions.
    distance : (rows, cols) float array, optional
        ``distance_map(labels)`` if already computed.

    Returns
    -------
    float

    Examples
    --------
    >>> rr, cc = np.mgrid[:80, :160]
    >>> labels = (np.hypot(rr - 40, cc - 30) <= 12).astype(np.int32)
    >>> labels[np.hypot(rr - 40, cc - 70) <= 16] = 2
    >>> labels[np.hypot(rr - 40, cc - 115) <= 20] = 3
    >>> labels[38:41, 150:153] = 4   # a speck
    >>> round(typical_plant_radius(labels))
    16
    """
    labels = np.asarray(labels, dtype=np.int32)
    inside = np.flatnonzero(labels.ravel() != 0)
    if inside.size == 0:
        return 0.0
    if distance is None:
        distance = distance_map(labels)
    lab = labels.ravel()[inside]
    dmax = label_max(np.asarray(distance, dtype=np.float32).ravel()[inside], lab)
    return _typical_radius(dmax, _Regions(labels, dmax, lab), labels.shape)


def _typical_radius(dmax, regions, shape):
    """:func:`typical_plant_radius` from each region's own Dmax and its :class:`_Regions`."""
    # Each region's own Dmax (touching plants split by the watershed count one by one).
    dmax = np.asarray(dmax, dtype=np.float64)
    off_frame = regions.off_frame
    if not off_frame.any():
        return _FALLBACK_FRACTION * min(shape)
    typical = _weighted_median(dmax[off_frame], regions.area[off_frame])
    isolated = regions.isolated_plant & off_frame & (dmax >= _PLANT_SHARE * typical)
    return float(np.median(dmax[isolated])) if isolated.any() else typical


def _weighted_median(values, weights):
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def poisson_profile(mask):
    """sqrt(h) where laplace(h) = -4 in `mask` and h = 0 outside (5-point stencil, pixel units).

    A sparse linear system over the masked pixels only, solved directly.
    """
    # Imported here: SciPy's sparse solvers cost every Build 0.1 s to import, only this profile uses them.
    from scipy import sparse
    from scipy.sparse import linalg as splinalg

    mask = np.asarray(mask, dtype=bool)
    rows, cols = mask.shape
    # The frame is not ground: a region cut by the border is not pinned to 0 there (zero flux,
    # like the circular profile's distance map). With no ground at all that would leave nothing
    # to pin the solution, so a full frame is pinned at the border instead.
    frame_is_ground = bool(mask.all())
    idx = -np.ones(mask.shape, dtype=np.int64)
    n = int(mask.sum())
    idx[mask] = np.arange(n)
    r, c = np.nonzero(mask)
    diag = np.zeros(n)
    rows_off, cols_off = [], []
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        # Neighbours off the frame mirror the pixel itself (they add nothing to the stencil) or,
        # for a full frame, are ground (they add to the diagonal only).
        diag += 1.0 if frame_is_ground else inside
        rr_i, cc_i = rr[inside], cc[inside]
        j = idx[rr_i, cc_i]
        src = np.nonzero(inside)[0]
        keep = j >= 0
        rows_off.append(src[keep])
        cols_off.append(j[keep])
    ro = np.concatenate(rows_off)
    co = np.concatenate(cols_off)
    a = sparse.csr_matrix(
        (
            np.concatenate([diag, -np.ones(ro.size)]),
            (np.concatenate([np.arange(n), ro]), np.concatenate([np.arange(n), co])),
        ),
        shape=(n, n),
    )
    # A sparse direct solve: exact, and on 2 cores faster than Jacobi-preconditioned CG, whose
    # iteration count grows with the widest region (measured 1.5 s vs 4 s for 0.4 M unknowns).
    sol = splinalg.spsolve(a.tocsc(), np.full(n, 4.0))
    if not np.all(np.isfinite(sol)):
        raise CliffTerrainError("the Poisson solve failed (singular system); try profile='circular'")
    h = np.zeros(mask.shape, dtype=np.float32)
    h[mask] = np.sqrt(np.maximum(sol, 0.0))
    return h
