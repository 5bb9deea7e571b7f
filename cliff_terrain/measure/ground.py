"""The ground under the crop, from one flight: where the soil is really exposed, and the canopy height.

A digital surface model (DSM) is the top of everything: soil where it is bare, leaves where there
are plants. The ground under the plants is estimated from the DSM at the soil pixels of the
segmentation, in two steps:

1. **Trend**: in overlapping blocks of several metres (`block_m`), a plane is fitted to the
   exposed soil and re-fitted without the points far above it (leaves in shadow look like soil
   to a colour segmentation, and sit high), then the planes are blended bilinearly. This follows
   tilted and undulating fields at the block's scale.
2. **Detail**: what the exposed soil says beyond the trend (ridges, furrows, wheel tracks) is
   interpolated by normalized convolution, fine where soil is near and fading into the trend
   under a closed canopy.

Only soil at least `exposure_m` from any plant counts as exposed: small gaps in a canopy are
shadowed leaves more often than soil. On a dense potato canopy this is what separated a ground
35 cm too high (low percentiles of "soil" in ~0.5 m neighbourhoods) from one within 4 cm of the
two-flight reference (see the project notes).

The canopy height model is CHM = DSM - ground, negatives set to 0, NaN where the DSM has no data.
"""

from __future__ import annotations

import numpy as np

from .._validate import check_float
from ..errors import CliffTerrainError

DEFAULT_BLOCK_M = 5.0
DEFAULT_EXPOSURE_M = 0.06
DEFAULT_DETAIL_M = 0.15
# A block needs this many exposed soil pixels (and this fraction of itself) for a plane.
_MIN_BLOCK_POINTS = 30
_MIN_BLOCK_FRACTION = 0.002
# One-sided trimming: points this many robust standard deviations above the plane are not ground.
_TRIM_ABOVE = 2.5
_TRIM_BELOW = 5.0
# Kernel-weighted soil fraction at which the detail of a scale is fully trusted.
_DETAIL_CONFIDENCE = 0.1


def estimate_ground(
    dsm,
    *,
    soil,
    pixel_size,
    block_m=DEFAULT_BLOCK_M,
    exposure_m=DEFAULT_EXPOSURE_M,
    detail_m=DEFAULT_DETAIL_M,
):
    """The ground surface under a crop from its surface model and a soil mask.

    Parameters
    ----------
    dsm : (rows, cols) float array
        Surface heights in metres, NaN where there is no data.
    soil : (rows, cols) bool array
        Pixels the segmentation calls soil (not plant); no-data pixels are ignored.
    pixel_size : float
        Metres per pixel (> 0).
    block_m : float, optional
        Side of the blocks of the trend in metres; blocks overlap by half.
    exposure_m : float, optional
        Soil counts only this far (metres) from the nearest plant pixel.
    detail_m : float, optional
        Finest scale (Gaussian sigma, metres) of the detail; 0 keeps the trend only.

    Returns
    -------
    (rows, cols) float32 array
        Ground heights in metres, everywhere (also under no-data).

    Raises
    ------
    CliffTerrainError
        No soil with data to estimate the ground from.

    Examples
    --------
    >>> rows, cols = np.mgrid[:200, :200]
    >>> ground = 100.0 + 0.01 * cols                      # 1 cm/px tilt, 0.05 m pixels
    >>> plants = np.hypot(rows - 100, cols - 100) < 20
    >>> dsm = (ground + 0.5 * plants).astype(np.float32)
    >>> est = estimate_ground(dsm, soil=~plants, pixel_size=0.05)
    >>> bool(np.abs(est - ground).max() < 0.005)
    True
    """
    from scipy import ndimage

    dsm = np.asarray(dsm, dtype=np.float32)
    soil = np.asarray(soil, dtype=bool)
    if dsm.ndim != 2:
        raise CliffTerrainError(f"`dsm` must be a (rows, cols) array, got shape {dsm.shape}")
    if soil.shape != dsm.shape:
        raise CliffTerrainError(f"`soil` must have the shape of `dsm` {dsm.shape}, got {soil.shape}")
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    exposure_m = check_float("exposure_m", exposure_m, minimum=0.0)
    detail_m = check_float("detail_m", detail_m, minimum=0.0)
    finite = np.isfinite(dsm)
    soil = soil & finite
    exposed = soil
    reach = exposure_m / pixel_size
    if reach >= 1.0 and soil.any() and not soil.all():
        # Distance (px) from each pixel to the nearest plant pixel, computed coarse where it is cheap.
        exposed = soil & (_distance_to(~soil | ~finite, reach, ndimage) >= reach)
        if np.count_nonzero(exposed) < max(_MIN_BLOCK_POINTS, 1e-3 * soil.sum()):
            exposed = soil  # a canopy without wide gaps: all soil, trimming still drops leaves
    if not exposed.any():
        raise CliffTerrainError(
            "`soil` holds no pixel with surface data: cannot estimate the ground; give a DTM"
        )
    trend = _trend(dsm, exposed, max(8, round(block_m / pixel_size)))
    if detail_m <= 0:
        return trend
    return trend + _detail(dsm, trend, exposed, detail_m / pixel_size, block_m / pixel_size)


def _distance_to(obstacles, reach, ndimage):
    """Euclidean distance (px) to the nearest obstacle, exact up to `reach`, capped beyond it."""
    # Only whether a pixel is at least `reach` away matters: a dilation by a disc answers that.
    radius = int(np.ceil(reach))
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    import cv2

    disc = (np.hypot(yy, xx) < reach).astype(np.uint8)
    near = cv2.dilate(obstacles.astype(np.uint8), disc) > 0
    return np.where(near, 0.0, reach).astype(np.float32)


def _trend(dsm, exposed, block):
    """Robust planes in half-overlapping blocks of `block` px, blended bilinearly."""
    rows, cols = dsm.shape
    step = max(4, block // 2)
    centres_r = np.arange(step / 2, rows + step / 2, step)
    centres_c = np.arange(step / 2, cols + step / 2, step)
    planes = np.full((len(centres_r), len(centres_c), 3), np.nan)
    # The exposed soil on a regular lattice (about 2000 points a block at most): three
    # coefficients need no more, and one lattice for all blocks saves a search per block.
    stride = max(1, int(block / 45))
    ys, xs = np.nonzero(exposed[::stride, ::stride])
    ys, xs = ys * stride, xs * stride
    zs = dsm[ys, xs].astype(np.float64)
    min_points = max(_MIN_BLOCK_POINTS, int(_MIN_BLOCK_FRACTION * block * block / stride**2))
    half = block / 2
    row_order = np.argsort(ys, kind="stable")
    ys, xs, zs = ys[row_order], xs[row_order], zs[row_order]
    for i, rc in enumerate(centres_r):
        r0, r1 = int(max(0, rc - half)), int(min(rows, rc + half))
        a, b = np.searchsorted(ys, r0), np.searchsorted(ys, r1)
        band_y, band_x, band_z = ys[a:b], xs[a:b], zs[a:b]
        for j, cc in enumerate(centres_c):
            c0, c1 = int(max(0, cc - half)), int(min(cols, cc + half))
            pick = (band_x >= c0) & (band_x < c1)
            if np.count_nonzero(pick) < min_points:
                continue
            rr, ccs, z = band_y[pick], band_x[pick], band_z[pick]
            planes[i, j] = _robust_plane(z, (rr + 0.5 - rc) / step, (ccs + 0.5 - cc) / step)
    fitted = np.isfinite(planes[..., 0])
    if not fitted.any():
        # Too little soil for any block: one robust plane over the whole field.
        rr, ccs = np.nonzero(exposed)
        if rr.size > 50000:
            keep = np.linspace(0, rr.size - 1, 50000).astype(np.int64)
            rr, ccs = rr[keep], ccs[keep]
        a, b, c = _robust_plane(dsm[rr, ccs].astype(np.float64), (rr + 0.5) / step, (ccs + 0.5) / step)
        rr, ccs = np.mgrid[: len(centres_r), : len(centres_c)]
        planes[..., 0] = a + b * (centres_r[rr] / step) + c * (centres_c[ccs] / step)
        planes[..., 1], planes[..., 2] = b, c
        fitted[:] = True
    if not fitted.all():
        # Blocks without soil take the plane of the nearest block with, extended to their centre.
        from scipy import ndimage

        _, (ni, nj) = ndimage.distance_transform_edt(~fitted, return_indices=True)
        source = planes[ni, nj]
        di = (centres_r[:, None] - centres_r[ni]) / step
        dj = (centres_c[None, :] - centres_c[nj]) / step
        filled = source.copy()
        filled[..., 0] = source[..., 0] + source[..., 1] * di + source[..., 2] * dj
        planes = np.where(fitted[..., None], planes, filled)
    # Blend: each pixel takes the bilinear mix of the four surrounding blocks' planes, each plane
    # evaluated at the pixel. Computed at every `sub`-th pixel centre (planes are smooth), then
    # interpolated linearly in between.
    sub = max(1, step // 8)
    gr = np.arange(0, rows - 1 + sub, sub, dtype=np.float64) + 0.5
    gc = np.arange(0, cols - 1 + sub, sub, dtype=np.float64) + 0.5
    fi = np.clip((gr - centres_r[0]) / step, 0, len(centres_r) - 1)
    fj = np.clip((gc - centres_c[0]) / step, 0, len(centres_c) - 1)
    i0 = np.minimum(np.floor(fi).astype(np.int64), len(centres_r) - 1)
    j0 = np.minimum(np.floor(fj).astype(np.int64), len(centres_c) - 1)
    i1, j1 = np.minimum(i0 + 1, len(centres_r) - 1), np.minimum(j0 + 1, len(centres_c) - 1)
    wi, wj = fi - i0, fj - j0
    out = np.zeros((gr.size, gc.size))
    for ii, wi_ in ((i0, 1 - wi), (i1, wi)):
        for jj, wj_ in ((j0, 1 - wj), (j1, wj)):
            p = planes[ii[:, None], jj[None, :]]
            dr = (gr[:, None] - centres_r[ii][:, None]) / step
            dc = (gc[None, :] - centres_c[jj][None, :]) / step
            out += (wi_[:, None] * wj_[None, :]) * (p[..., 0] + p[..., 1] * dr + p[..., 2] * dc)
    if zs.size:
        # A steep plane fitted to a little soil, extended over blocks without any, must not run
        # away (on a real potato field it reached 12 m): the ground stays near the soil's heights.
        low, high = np.percentile(zs, (0.5, 99.5))
        margin = max(0.5, 0.5 * (high - low))
        np.clip(out, low - margin, high + margin, out=out)
    return upsample_linear(out.astype(np.float32), sub, (rows, cols))


def upsample_linear(coarse, sub, shape):
    """Values at every `sub`-th pixel (row, col = 0, sub, 2 sub, ...) interpolated to all pixels."""
    rows, cols = shape
    if sub == 1:
        return np.ascontiguousarray(coarse[:rows, :cols])

    def axis(n, size):
        f = np.arange(n, dtype=np.float64) / sub
        k0 = np.minimum(np.floor(f).astype(np.int64), size - 1)
        k1 = np.minimum(k0 + 1, size - 1)
        return k0, k1, (f - k0).astype(np.float32)

    c0, c1, wc = axis(cols, coarse.shape[1])
    across = coarse[:, c0] * (1 - wc) + coarse[:, c1] * wc
    r0, r1, wr = axis(rows, coarse.shape[0])
    return across[r0] * (1 - wr)[:, None] + across[r1] * wr[:, None]


def _robust_plane(z, r, c):
    """(a, b, c) of z = a + b r + c c fitted without the points far above (one-sided trimming)."""
    design = np.column_stack([np.ones_like(r), r, c])
    keep = np.ones(z.size, dtype=bool)
    coef = np.array([np.median(z), 0.0, 0.0])
    for _ in range(5):
        if np.count_nonzero(keep) < 3:
            break
        coef, *_ = np.linalg.lstsq(design[keep], z[keep], rcond=None)
        residual = z - design @ coef
        med = np.median(residual[keep])
        spread = max(1.4826 * np.median(np.abs(residual[keep] - med)), 1e-4)
        new_keep = (residual <= med + _TRIM_ABOVE * spread) & (residual >= med - _TRIM_BELOW * spread)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return coef


def _detail(dsm, trend, exposed, sigma, block):
    """Exposed soil's height above the trend, interpolated from fine to coarse (normalized convolution).

    Everything runs on a grid `factor` times coarser (a third of the finest sigma per cell: the
    detail is smooth at that scale), then is enlarged once.
    """
    import cv2

    residual = np.where(exposed, dsm - trend, 0.0).astype(np.float32)
    values = residual[exposed][:: max(1, int(exposed.sum() // 200000))]  # a sample gives the spread
    med = float(np.median(values))
    spread = max(1.4826 * float(np.median(np.abs(values - med))), 1e-4)
    # Leaves that passed for soil stand far above the soil's spread: they carry no weight.
    weight = exposed & (residual <= med + _TRIM_ABOVE * spread) & (residual >= med - _TRIM_BELOW * spread)
    weight = weight.astype(np.float32)
    rows, cols = residual.shape
    factor = max(1, int(sigma / 3))
    if factor > 1:
        # Pad to whole cells (padding carries no weight), then average the cells.
        pr, pc = -(-rows // factor) * factor, -(-cols // factor) * factor
        w_pad = np.zeros((pr, pc), np.float32)
        w_pad[:rows, :cols] = weight
        wz_pad = np.zeros((pr, pc), np.float32)
        np.multiply(residual, weight, out=wz_pad[:rows, :cols])
        small = (pc // factor, pr // factor)
        weight = cv2.resize(w_pad, small, interpolation=cv2.INTER_AREA)
        with np.errstate(invalid="ignore", divide="ignore"):
            residual = np.where(
                weight > 0, cv2.resize(wz_pad, small, interpolation=cv2.INTER_AREA) / weight, 0.0
            )
        residual = residual.astype(np.float32)
        sigma, block = sigma / factor, block / factor
    numerator = residual * weight
    estimate = np.zeros_like(residual)
    scales = [sigma * 3.0**k for k in range(6) if sigma * 3.0**k < block / 2] or [sigma]
    for s in reversed(scales):  # coarse to fine: each finer scale overrides where it has soil
        if s <= QUADRATIC_UP_TO * scales[0]:
            # The finest scales fit a local quadratic: soil on both flanks of a ridge then gives
            # the crest under the plants between them, which a weighted mean would put too low.
            local, den = _local_quadratic(residual, weight, s)
        else:
            den = _blur(weight, s)
            num = _blur(numerator, s)
            with np.errstate(invalid="ignore", divide="ignore"):
                local = np.where(den > 1e-6, num / np.maximum(den, 1e-6), 0.0)
        confidence = np.clip(den / _DETAIL_CONFIDENCE, 0.0, 1.0)
        estimate = confidence * local + (1.0 - confidence) * estimate
    estimate = estimate.astype(np.float32)
    if factor > 1:
        big = cv2.resize(
            estimate, (estimate.shape[1] * factor, estimate.shape[0] * factor), interpolation=cv2.INTER_LINEAR
        )
        estimate = np.ascontiguousarray(big[:rows, :cols])
    return estimate


# Ridge regression of the local quadratic's slope and curvature terms, relative to its weight.
_QUADRATIC_DAMPING = 0.05
QUADRATIC_UP_TO = 3.5  # scales up to this times the finest are fitted by quadratics
_QUADRATIC_BASIS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))


def _local_quadratic(values, weight, sigma):
    """Weighted local quadratic fit (Gaussian window `sigma` px) of `values` where `weight` > 0.

    Returns ``(value at each pixel, kernel-weighted fraction of weight)``. The moments are
    separable filters (monomial times Gaussian); large sigmas run on a reduced grid.
    """
    import cv2

    rows, cols = values.shape
    factor = max(1, int(sigma / 1.5))  # the fit is smooth at its scale: 1.5 samples per sigma do
    if factor > 1:
        size = (max(1, cols // factor), max(1, rows // factor))
        w = cv2.resize(weight, size, interpolation=cv2.INTER_AREA)
        wz = cv2.resize(values * weight, size, interpolation=cv2.INTER_AREA)
    else:
        w, wz = weight, values * weight
    s = sigma / factor
    radius = int(np.ceil(3 * s))
    u = np.arange(-radius, radius + 1, dtype=np.float64) / s  # offsets in sigmas: well conditioned
    gauss = np.exp(-0.5 * u**2)
    kernels = {a: (gauss * u**a).astype(np.float32) for a in range(5)}
    moments = {}

    def moment(image, a, b, key):
        if (key, a, b) not in moments:
            moments[key, a, b] = cv2.sepFilter2D(
                image, cv2.CV_32F, kernels[a], kernels[b], borderType=cv2.BORDER_CONSTANT
            )
        return moments[key, a, b]

    n = len(_QUADRATIC_BASIS)
    # (n, n, rows, cols): each step of the elimination is then a whole-image operation.
    normal = np.empty((n, n, *w.shape), dtype=np.float32)
    right = np.empty((n, *w.shape), dtype=np.float32)
    for i, (a1, b1) in enumerate(_QUADRATIC_BASIS):
        right[i] = moment(wz, a1, b1, "z")
        for j, (a2, b2) in enumerate(_QUADRATIC_BASIS):
            normal[i, j] = moment(w, a1 + a2, b1 + b2, "w")
    m00 = normal[0, 0].copy()
    damping = _QUADRATIC_DAMPING * np.maximum(m00, 1e-6)
    for i in range(1, n):
        normal[i, i] += damping
    normal[0, 0] += 1e-9
    estimate = _solve_first(normal, right).astype(np.float32)
    fraction = (m00 / gauss.sum() ** 2).astype(np.float32)
    if factor > 1:
        estimate = cv2.resize(estimate, (cols, rows), interpolation=cv2.INTER_LINEAR)
        fraction = cv2.resize(fraction, (cols, rows), interpolation=cv2.INTER_LINEAR)
    return estimate, fraction


def _solve_first(normal, right):
    """First unknown of many small symmetric positive definite systems, (n, n, ...) and (n, ...),
    solved in place by Gaussian elimination vectorized over the pixels (numpy's batched solve
    costs microseconds per system)."""
    a, b = normal, right
    n = a.shape[0]
    for k in range(n - 1, 0, -1):  # eliminate from the last unknown up; the first one is left
        pivot = a[k, k]
        for i in range(k):
            factor = a[i, k] / pivot
            a[i, : k + 1] -= factor * a[k, : k + 1]
            b[i] -= factor * b[k]
    return b[0] / a[0, 0]


def _blur(image, sigma):
    """Gaussian blur of `sigma` px; large sigmas on a reduced grid (cv2, fast on big rasters)."""
    import cv2

    if sigma < 0.3:
        return image
    factor = int(sigma // 3) if sigma > 6 else 1
    if factor > 1:
        rows, cols = image.shape
        small = cv2.resize(
            image, (max(1, cols // factor), max(1, rows // factor)), interpolation=cv2.INTER_AREA
        )
        small = cv2.GaussianBlur(small, (0, 0), sigma / factor, borderType=cv2.BORDER_REFLECT)
        return cv2.resize(small, (cols, rows), interpolation=cv2.INTER_LINEAR)
    return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


# Below this share of bare soil (of the pixels with data) one flight cannot carry a ground.
MIN_SOIL_FRACTION = 0.01
MIN_SOIL_PIXELS = 100


def ground_support(soil, *, pixel_size, block_m=DEFAULT_BLOCK_M):
    """How much bare soil carried the ground at each pixel: its share in a block around the pixel.

    The share of `soil` pixels in the `block_m` x `block_m` window centred on each pixel, the
    scale at which :func:`estimate_ground` fits its trend. 0 means that no soil lies within
    half a block: the ground there is interpolated from farther blocks. A block needs at least
    0.2 % of its pixels as soil (and 30 points) to fit a plane of its own.

    Parameters
    ----------
    soil : (rows, cols) bool array
        The soil the ground was estimated from.
    pixel_size : float
        Metres per pixel (> 0).
    block_m : float, optional
        Block side in metres.

    Returns
    -------
    (rows, cols) float32 array in [0, 1]

    Examples
    --------
    >>> soil = np.zeros((100, 100), bool); soil[:, :10] = True
    >>> support = ground_support(soil, pixel_size=0.1, block_m=2.0)
    >>> float(support[50, 9]), float(support[50, 50])
    (0.5, 0.0)
    """
    import cv2

    soil = np.asarray(soil, dtype=bool)
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    size = max(1, round(block_m / pixel_size)) | 1  # odd: centred on the pixel
    share = cv2.blur(soil.astype(np.float32), (size, size), borderType=cv2.BORDER_CONSTANT)
    # The window's part inside the raster: the border's missing pixels are not missing soil.
    inside = cv2.blur(np.ones(soil.shape, np.float32), (size, size), borderType=cv2.BORDER_CONSTANT)
    return np.clip(share / np.maximum(inside, 1e-6), 0.0, 1.0).astype(np.float32)


def check_enough_soil(soil, valid, *, source):
    """Refuse a single-flight ground carried by too little bare soil (:class:`GroundError`).

    `source` names the surface model in the message. Returns the soil's share of `valid`.
    """
    from ..errors import GroundError

    n_soil = int(np.count_nonzero(soil))
    n_valid = max(1, int(np.count_nonzero(valid)))
    share = n_soil / n_valid
    if n_soil < MIN_SOIL_PIXELS or share < MIN_SOIL_FRACTION:
        raise GroundError(
            f"{source}: only {n_soil} bare-soil pixels ({share:.2%} of the pixels with data) to estimate "
            f"the ground under the crop from; at least {MIN_SOIL_FRACTION:.0%} and {MIN_SOIL_PIXELS} "
            "pixels are needed, or the heights would be measured from the canopy. Give a terrain model "
            "(--dtm, `dtm=`)"
        )
    return share


def canopy_height(dsm, ground):
    """CHM = DSM - ground, negatives set to 0, NaN where either has no data.

    Examples
    --------
    >>> canopy_height(np.array([[1.5, np.nan, 0.9]]), np.array([[1.0, 1.0, 1.0]]))
    array([[0.5, nan, 0. ]], dtype=float32)
    """
    dsm = np.asarray(dsm, dtype=np.float32)
    ground = np.asarray(ground, dtype=np.float32)
    if dsm.shape != ground.shape:
        raise CliffTerrainError(f"`ground` must have the shape of `dsm` {dsm.shape}, got {ground.shape}")
    chm = dsm - ground
    np.maximum(chm, 0.0, out=chm)  # NaN stays NaN
    return chm


def naive_block_ground(dsm, *, pixel_size, block_m=DEFAULT_BLOCK_M, percentile=5.0):
    """The peer: a low percentile of the DSM alone in blocks, bilinearly interpolated (no segmentation).

    What one does without knowing which pixels are soil; kept for the benchmark.
    """
    import cv2

    dsm = np.asarray(dsm, dtype=np.float32)
    block = max(2, round(block_m / pixel_size))
    rows, cols = dsm.shape
    nb_r, nb_c = -(-rows // block), -(-cols // block)
    pad = np.full((nb_r * block, nb_c * block), np.nan, np.float32)
    pad[:rows, :cols] = dsm
    blocks = pad.reshape(nb_r, block, nb_c, block).transpose(0, 2, 1, 3).reshape(nb_r, nb_c, -1)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            levels = np.nanpercentile(blocks, percentile, axis=2).astype(np.float32)
    if np.isnan(levels).any():
        fill = np.nanmedian(levels) if np.isfinite(levels).any() else 0.0
        levels = np.where(np.isnan(levels), fill, levels).astype(np.float32)
    big = cv2.resize(levels, (nb_c * block, nb_r * block), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(big[:rows, :cols])
