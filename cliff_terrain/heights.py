"""Heights (the paper's Algorithm 3): inflate each region from its distance map."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import linalg as splinalg

from ._validate import check_choice, check_float
from .errors import CliffTerrainError
from .segmentation import distance_map, label_max, region_interiors

PROFILES = ("circular", "poisson")


def inflate(labels, *, profile="circular", exaggeration=1.0, distance=None):
    """Heights of every region, in pixels.

    Parameters
    ----------
    labels : (rows, cols) int array
        0 on flat ground, 1..n for the regions.
    profile : {"circular", "poisson"}, optional
        ``"circular"``: the paper's H = sqrt(Dmax^2 - (Dmax - D)^2), with D the Euclidean distance
        to the region's edge and Dmax its largest value in the region: a circular cross-section
        that rises vertically at the edge. ``"poisson"``: solve the Poisson equation
        laplace(h) = -4 inside the regions with h = 0 on their boundary and take sqrt(h) (after
        Baran & Lehtinen's notes on inflating curves): smooth, no creases along the medial axis.
        Both give a hemisphere of radius r for a disc of radius r.
    exaggeration : float, optional
        Factor applied to the heights (> 0).
    distance : (rows, cols) float array, optional
        ``distance_map(labels)`` if already computed (circular profile only).

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
    labels = labels.astype(np.int32, copy=False)
    mask = labels > 0
    if not mask.any():
        return np.zeros(labels.shape, dtype=np.float32)
    if profile == "circular":
        if distance is None:
            distance = distance_map(labels)
        h = circular_profile(labels, distance)
    else:
        h = poisson_profile(region_interiors(labels))
    if exaggeration != 1.0:
        h *= np.float32(exaggeration)
    return h


def circular_profile(labels, distance):
    """H = sqrt(Dmax^2 - (Dmax - D)^2) per region (Dmax = the region's largest distance)."""
    labels = np.asarray(labels)
    # On the region pixels only: ground, most of a field, stays 0.
    inside = np.flatnonzero(labels.ravel())
    lab = labels.ravel()[inside]
    d = np.asarray(distance, dtype=np.float32).ravel()[inside]
    dm = label_max(d, lab)[lab]
    np.minimum(d, dm, out=d)
    h = np.sqrt(np.maximum(dm * dm - (dm - d) ** 2, 0.0))
    h[d <= 0] = 0.0
    out = np.zeros(labels.shape, dtype=np.float32)
    out.ravel()[inside] = h
    return out


def poisson_profile(mask):
    """sqrt(h) where laplace(h) = -4 in `mask` and h = 0 outside (5-point stencil, pixel units).

    A sparse linear system over the masked pixels only, solved directly.
    """
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
