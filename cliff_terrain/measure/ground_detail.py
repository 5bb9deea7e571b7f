"""The ground's detail: what bare soil says beyond a smooth ground, from fine to coarse scales.

Ridges, beds and furrows are interpolated by normalized convolution (Knutsson and Westin 1993),
with local quadratic fits at the finest scales so that soil on both flanks of a ridge gives its
crest under the plants between them. Used by :func:`cliff_terrain.measure.ground.fit_ground`'s
``"detailed"`` candidate, which keeps the detail's broad part and, under the canopy, the finer
part's level (:func:`canopy_level`).
"""

from __future__ import annotations

import numpy as np

from .._threads import map_row_bands

# Kernel-weighted evidence fraction at which a local estimate is fully trusted.
DETAIL_CONFIDENCE = 0.1
# One-sided trimming of the detail: residuals this many robust deviations above are not ground.
_TRIM_ABOVE = 2.5
_TRIM_BELOW = 5.0


def detail_above(dsm, trend, exposed, sigma, block, *, smallest=None):
    """Exposed soil's height above the trend, interpolated from fine to coarse (normalized convolution).

    Everything runs on a grid `factor` times coarser (a third of the finest sigma per cell: the
    detail is smooth at that scale), then is enlarged once. With `smallest` (pixels), only the
    scales from `smallest` up, by normalized convolution alone: the broad part of the detail.
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
    if smallest is not None:
        scales = [s for s in scales if s * factor >= smallest]
    for s in reversed(scales):  # coarse to fine: each finer scale overrides where it has soil
        if smallest is None and s <= QUADRATIC_UP_TO * scales[0]:
            # The finest scales fit a local quadratic: soil on both flanks of a ridge then gives
            # the crest under the plants between them, which a weighted mean would put too low.
            local, den = _local_quadratic(residual, weight, s)
        else:
            den = blur(weight, s)
            num = blur(numerator, s)
            with np.errstate(invalid="ignore", divide="ignore"):
                local = np.where(den > 1e-6, num / np.maximum(den, 1e-6), 0.0)
        confidence = np.clip(den / DETAIL_CONFIDENCE, 0.0, 1.0)
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
# Pixels of a band of the solve: its 36 + 6 float32 planes (about 2.7 MB) fit in a core's cache.
_BAND_PIXELS = 16_384
# A neighbour's kernel weight below which the window is the pixel alone (float32 holds 7 digits).
_NEGLIGIBLE_WEIGHT = 1e-12


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
    total = gauss.sum() ** 2
    if gauss[radius - 1] < _NEGLIGIBLE_WEIGHT:
        # A window narrower than the pixel (the ground's finest scale, 0.15 m, on a grid of 1.4 m is
        # 0.1 px: its neighbours weigh 1e-19): the fit is the pixel itself, its value where it has
        # soil. The same numbers as the systems' (their couplings fall below float32's precision),
        # without filtering 21 moments and solving them: half the quadratics' time on such grids.
        # (Such a window is never on a reduced grid: that takes a sigma of 3 px.)
        estimate = (wz / (w + np.float32(1e-9))).astype(np.float32)
        return estimate, (w / np.float32(total)).astype(np.float32)
    kernels = {a: (gauss * u**a).astype(np.float32) for a in range(5)}
    estimate = np.empty(w.shape, np.float32)
    fraction = np.empty(w.shape, np.float32)
    # The moments too are made a chunk of rows at a time, each with `radius` rows of halo (the
    # filter's zero border only at the grid's own edges): the same numbers as on the whole grid,
    # but 21 planes of a chunk instead of the grid's (0.6 GB at 7 MP, the fit's peak), and the
    # chunks run on the cores (a chunk writes its own rows). A chunk is at least 8 halos tall so
    # the halos cost at most a quarter more filtering.
    band = max(1, _BAND_PIXELS // max(1, w.shape[1]))
    chunk = band * -(-max(band, 8 * radius) // band)

    def fit_chunk(c0, c1):
        h0, h1 = max(0, c0 - radius), min(w.shape[0], c1 + radius)
        moments = _moments(w[h0:h1], wz[h0:h1], kernels, rows=slice(c0 - h0, c1 - h0))
        # The systems are solved a band of rows at a time: the same arithmetic per pixel as on
        # the whole grid, but its (n, n, rows, cols) normal equations stay in the cache.
        for r0 in range(0, c1 - c0, band):
            estimate[c0 + r0 : c0 + r0 + band] = _solve_band(moments, slice(r0, r0 + band))
        fraction[c0:c1] = moments["w", 0, 0] / np.float32(total)

    map_row_bands(fit_chunk, w.shape[0], chunk)
    if factor > 1:
        estimate = cv2.resize(estimate, (cols, rows), interpolation=cv2.INTER_LINEAR)
        fraction = cv2.resize(fraction, (cols, rows), interpolation=cv2.INTER_LINEAR)
    return estimate, fraction


def _moments(w, wz, kernels, *, rows):
    """{(key, a, b): plane} of the local quadratic's moments of weights `w` ("w") and weighted values
    `wz` ("z"), filtered with zero borders, kept at `rows` (the rest is halo)."""
    import cv2

    moments = {}

    def moment(image, a, b, key):
        if (key, a, b) not in moments:
            filtered = cv2.sepFilter2D(
                image, cv2.CV_32F, kernels[a], kernels[b], borderType=cv2.BORDER_CONSTANT
            )
            moments[key, a, b] = filtered[rows]

    for a1, b1 in _QUADRATIC_BASIS:
        moment(wz, a1, b1, "z")
        for a2, b2 in _QUADRATIC_BASIS:
            moment(w, a1 + a2, b1 + b2, "w")
    return moments


def _solve_band(moments, rows):
    """The local quadratic's value at rows `rows` from its `moments` (see :func:`_local_quadratic`)."""
    n = len(_QUADRATIC_BASIS)
    m00 = moments["w", 0, 0][rows]
    normal = np.empty((n, n, *m00.shape), dtype=np.float32)
    right = np.empty((n, *m00.shape), dtype=np.float32)
    for i, (a1, b1) in enumerate(_QUADRATIC_BASIS):
        right[i] = moments["z", a1, b1][rows]
        for j, (a2, b2) in enumerate(_QUADRATIC_BASIS):
            normal[i, j] = moments["w", a1 + a2, b1 + b2][rows]
    damping = _QUADRATIC_DAMPING * np.maximum(m00, 1e-6)
    for i in range(1, n):
        normal[i, i] += damping
    normal[0, 0] += 1e-9
    return _solve_first(normal, right).astype(np.float32)


def _solve_first(normal, right):
    """First unknown of many small symmetric positive definite systems, (n, n, ...) and (n, ...),
    solved in place by Gaussian elimination vectorized over the pixels (numpy's batched solve
    costs microseconds per system)."""
    a, b = normal, right
    n = a.shape[0]
    factor = np.empty_like(b[0])
    product = np.empty_like(a[0])
    for k in range(n - 1, 0, -1):  # eliminate from the last unknown up; the first one is left
        pivot = a[k, k]
        for i in range(k):
            # Row i less factor times row k, in place; column k itself is never read again.
            np.divide(a[i, k], pivot, out=factor)
            np.multiply(factor, a[k, :k], out=product[:k])
            np.subtract(a[i, :k], product[:k], out=a[i, :k])
            np.multiply(factor, b[k], out=product[0])
            np.subtract(b[i], product[0], out=b[i])
    return b[0] / a[0, 0]


def evidence_offset(values, evidence, sigma, *, widen=False, valid=None):
    """`values` of the `evidence` pixels spread over the raster by normalized convolution at `sigma`
    px: each pixel's kernel-weighted mean of the evidence, trusted in proportion to the evidence's
    kernel-weighted share around it (fully at `DETAIL_CONFIDENCE`), 0 for what it does not trust.

    With `widen`, what a pixel does not trust at one scale comes from twice the scale, and so on,
    until every `valid` pixel (default: every pixel) trusts what it has or the scale is as large as
    the raster; only then is 0 taken. The scales are blended from fine to coarse in one pass (two
    rasters beside each scale's own). The smooth ground uses one scale
    (:func:`~cliff_terrain.measure.ground.ground_candidates`); the lowest surface's blocks without
    soil are filled widening (:class:`~cliff_terrain.measure.ground_blocks.BlockLevels`).

    Examples
    --------
    Evidence on the left only, 0.3: at one scale the right knows nothing (0); widening, it takes it.

    >>> values = np.full((50, 400), 0.3, np.float32)
    >>> evidence = np.zeros((50, 400), bool); evidence[:, :40] = True
    >>> round(float(evidence_offset(values, evidence, 10.0)[25, 390]), 3)
    0.0
    >>> out = evidence_offset(values, evidence, 10.0, widen=True)
    >>> round(float(out[25, 20]), 3), round(float(out[25, 390]), 3)
    (0.3, 0.3)
    """
    from .._validate import check_float

    sigma = check_float("sigma", sigma, minimum=0.0, strict_minimum=True)
    weight = evidence.astype(np.float32)
    values = np.where(evidence, values, 0.0).astype(np.float32)
    out, remaining = 0.0, 1.0  # the blend so far; the share of each pixel no scale has given yet
    largest = max(values.shape)
    while True:
        den = blur(weight, sigma)
        num = blur(values * weight, sigma)
        with np.errstate(invalid="ignore", divide="ignore"):
            local = np.where(den > 1e-6, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        confidence = np.clip(den / DETAIL_CONFIDENCE, 0.0, 1.0).astype(np.float32)
        if not widen:
            return confidence * local
        out = out + remaining * confidence * local
        remaining = remaining * (1.0 - confidence)
        left = remaining if valid is None else remaining[valid]
        if sigma >= largest or not left.size or float(left.max()) == 0.0:
            return out
        sigma *= 2.0


def blur(image, sigma):
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


def canopy_level(dsm, smooth, detailed, evidence):
    """`smooth` lifted by the finer detail's level under the canopy: ``(ground, level in metres)``.

    The finer detail (`detailed` - `smooth`, where `smooth` holds the broad detail) is measured
    where there is soil; under a canopy it is extrapolated from the soil beside the plants, and on
    a real potato trial it varied from plot to plot more than the smooth ground's own errors did
    (standard deviation of its effect on the plots' p90 2.0-2.2 cm on two dates, against 1.2-1.7
    cm, correlated with them at 0.17-0.57): noise more than ridges. What holds is its level: the
    median detail beneath the upper half of the canopy (the pixels that are not evidence, above
    their median height over `smooth`), where the heights users read (p90, a plant's top) are
    taken. `smooth` plus that one number is the ground everywhere: a constant cannot put a group
    of plots too high.

    Examples
    --------
    >>> dsm = np.array([[0.0, 0.0, 0.5, 0.6]], np.float32)
    >>> smooth = np.zeros_like(dsm)
    >>> detailed = np.array([[0.0, 0.0, 0.01, 0.03]], np.float32)
    >>> ground, level = canopy_level(dsm, smooth, detailed, np.array([[True, True, False, False]]))
    >>> round(level, 3), ground.tolist() == [[level] * 4]
    (0.03, True)
    """
    above = dsm - smooth
    canopy = np.isfinite(above) & ~evidence
    level = 0.0
    if canopy.any():
        upper = canopy & (above > np.median(above[canopy]))
        if upper.any():
            level = float(np.median((detailed - smooth)[upper]))
    return (smooth + np.float32(level)).astype(np.float32), level
