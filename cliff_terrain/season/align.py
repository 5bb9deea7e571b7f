"""Dates that line up: each date's orthophoto shift against a reference date, by phase correlation.

Orthophotos of different flights are rarely co-registered to a few centimetres: the same plot sits a
few pixels apart from one date to the next, and a plot's statistics then mix in its neighbour or its
alley. The shift is measured on the vegetation index (plants and soil, the structure every date
shares), every date resampled through its georeference onto the first date's grid, so dates of
different extents or sizes compare (:func:`season_shifts`, :func:`grid_shift`).
"""

from __future__ import annotations

import os

import numpy as np

# The alignment grid: each photo's index at most this many pixels on its longest side (the relief's
# default grid). On the soybean season (2.7 cm grid pixels) finer grids correlated less from one date
# to the next (0.43 against 0.70 for the first two dates at the photos' own 1.6 cm): the band-pass
# below then holds texture that changes between flights more than the plants and plot edges.
ALIGN_SIZE = 1000
# Shifts searched up to this far (metres): misregistrations between flights are centimetres to a
# metre or two; further, the repeating plots and crop rows could be mistaken for one another.
MAX_SHIFT_M = 2.0
# Below this correlation a date has too little in common with the reference (bare soil after the
# harvest, a flooded field) for its shift to be trusted: it is left as it is, and flagged.
MIN_SCORE = 0.1


def grid_index(rgb):
    """The segmentation's green vegetation index of an RGB grid (the same index on every date)."""
    from ..photo_heights.vegetation import vegetation_index

    vi, _ = vegetation_index(rgb, index="green")
    return np.asarray(vi, dtype=np.float64)


def index_grid(path, *, size=ALIGN_SIZE):
    """A photo's vegetation index on its alignment grid: (index, transform), NaN where it has no data."""
    import cv2

    from ..io.photo import load_image
    from ..io.raster.geotiff import read_georeference

    rgb, meta = load_image(path)
    transform, _ = read_georeference(path)
    rows, cols = rgb.shape[:2]
    scale = min(1.0, size / max(rows, cols))
    shape = (max(1, round(rows * scale)), max(1, round(cols * scale)))
    if shape != (rows, cols):
        rgb = cv2.resize(rgb, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    index = grid_index(rgb)
    valid = getattr(meta, "valid_mask", None)  # an orthophoto's alpha: no data is not soil
    if valid is not None:
        valid = cv2.resize(valid.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0
        index[~valid] = np.nan
    grid = np.asarray(transform, dtype=np.float64) @ np.diag([cols / shape[1], rows / shape[0], 1.0])
    return index, grid


def resample(index, transform, to_transform, shape):
    """`index` (with its pixel -> map `transform`) sampled at the pixel centres of another grid
    (bilinear; NaN where a neighbour has no data or lies outside)."""
    import cv2

    rows, cols = shape
    a = np.linalg.inv(transform) @ np.asarray(to_transform, dtype=np.float64)
    # Grid pixel (col, row) -> source pixel, both counted from pixel centres (OpenCV's convention).
    inverse = a[:2].copy()
    inverse[:, 2] += 0.5 * (a[:2, 0] + a[:2, 1]) - 0.5
    valid = np.isfinite(index)

    def warp(image, outside):
        return cv2.warpAffine(
            image,
            inverse,
            (cols, rows),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=outside,
        )

    values = warp(np.where(valid, index, 0.0), np.nan)
    values[warp(valid.astype(np.float64), 0.0) < 0.999] = np.nan  # only where every neighbour has data
    return values


def season_shifts(paths, *, size=ALIGN_SIZE, max_shift_m=MAX_SHIFT_M, neighbours=2):
    """Each photo's shift (map x, y in metres) against the season's consensus, and its correlation.

    Dates are compared with their `neighbours` next dates (a field changes least between flights
    close in time: a late, senescent date shares little with an early, green one). The shifts are
    the least-squares solution of those pairwise shifts, weighted by their correlation, and are
    then taken from the consensus of the dates (:func:`_consensus`), so the georeference most dates
    agree on is the truth and no single date moves the others. A date with no pair scoring ``MIN_SCORE`` keeps a zero shift.

    Returns
    -------
    list of dict
        Per photo, in order: ``shift`` ((x, y) metres: where its content lies from where the
        consensus puts it) and ``score`` (its best pair's correlation).
    """
    from concurrent.futures import ThreadPoolExecutor

    n = len(paths)

    def compare(pair):
        """Date j's content from date i's (map metres), and the correlation."""
        i, j = pair
        reference, grid = grids[i]
        pixel = float(np.sqrt(abs(np.linalg.det(grid[:2, :2]))))
        moving = resample(*grids[j], grid, reference.shape)
        shift, score = grid_shift(reference, moving, max_shift=max_shift_m / pixel)
        return grid[:2, :2] @ shift[::-1], score

    # Threads: decoding, OpenCV and the FFTs release the GIL, and the tasks wait for this.
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        grids = list(pool.map(lambda path: _index_grid_or_none(path, size), paths))
        pairs = [
            (i, j)
            for i in range(n)
            for j in range(i + 1, min(n, i + 1 + neighbours))
            if grids[i] is not None and grids[j] is not None
        ]
        compared = list(pool.map(compare, pairs))
    equations, weights, targets = [], [], []
    best = np.zeros(n)
    for (i, j), (target, score) in zip(pairs, compared, strict=True):
        best[i], best[j] = max(best[i], score), max(best[j], score)
        if score >= MIN_SCORE:
            row = np.zeros(n)
            row[i], row[j] = -1.0, 1.0
            equations.append(row)
            weights.append(score)
            targets.append(target)
    trusted = best >= MIN_SCORE
    shifts = np.zeros((n, 2))
    if equations:
        a = np.asarray(equations) * np.asarray(weights)[:, None]
        b = np.asarray(targets) * np.asarray(weights)[:, None]
        # Dates without a trusted pair are pinned at zero; the rest up to a common offset.
        pin = np.eye(n)[~trusted]
        gauge = np.ones((1, n)) * 1e-6
        solution, *_ = np.linalg.lstsq(
            np.vstack([a, pin, gauge]), np.vstack([b, np.zeros((len(pin) + 1, 2))]), rcond=None
        )
        first = next(g for g in grids if g is not None)[1]
        pixel = float(np.sqrt(abs(np.linalg.det(first[:2, :2]))))
        shifts[trusted] = solution[trusted] - _consensus(solution[trusted], pixel)
    return [{"shift": shifts[k], "score": float(best[k])} for k in range(n)]


def _index_grid_or_none(path, size):
    """:func:`index_grid`, or None for a photo that cannot be read: its task reports why, and the
    other dates are aligned without it."""
    try:
        return index_grid(path, size=size)
    except Exception:  # noqa: BLE001 - the image's own task raises the same error, with its rows
        return None


def _consensus(shifts, pixel):
    """The offset the season's georeference agrees on: the mean shift of the dates within three
    median deviations (at least two pixels) of the median, so one date moved far (a wrong
    georeference) does not move the others, and a steady drift is centred."""
    deviation = np.hypot(*(shifts - np.median(shifts, axis=0)).T)
    keep = deviation <= max(3.0 * float(np.median(deviation)), 2.0 * pixel)
    return shifts[keep].mean(axis=0)


def grid_shift(reference, moving, *, moving_valid=None, max_shift=None):
    """(rows, cols) by which `moving`'s content lies displaced from `reference`'s, in grid pixels, and
    the correlation there (1: the same pattern; a date with little left in common scores low).

    Both are index grids of one shape; NaN in `reference` (outside it, or no data) and
    ``~moving_valid`` (the photo's no-data) are left out. The grids are band-passed (a difference of
    Gaussians, 1 and 4 pixels: plot edges and plants, not the season's slow change of cover); the
    whole-pixel shift is the peak of their masked normalised cross-correlation (Padfield 2012, by
    FFT) among the shifts within `max_shift` pixels that keep half the data overlapping, and a
    parabola through the peak and its neighbours gives the fraction.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = rng.random((64, 80))
    >>> b = np.roll(a, (3, -5), axis=(0, 1))
    >>> shift, score = grid_shift(a, b)
    >>> np.round(shift, 1).tolist(), score > 0.9
    ([3.0, -5.0], True)
    """

    reference = np.asarray(reference, dtype=np.float64)
    moving = np.asarray(moving, dtype=np.float64)
    masks = [np.isfinite(reference), np.isfinite(moving)]
    if moving_valid is not None:
        masks[1] &= np.asarray(moving_valid, dtype=bool)
    bands = []
    for k, (grid, mask) in enumerate(zip((reference, moving), masks, strict=True)):
        # Smoothed within the data only (normalised convolution): the edge of the no-data is no edge
        # of the field, and pixels near it are left out.
        # float32: half the memory traffic of the blurs and FFTs; the correlations' sums are of
        # zero-mean bands, far from float32's limits (on the soybean season the shifts agree with float64's to 1e-5 px).
        weight = mask.astype(np.float32)
        values = np.where(mask, grid, 0.0).astype(np.float32)
        weight_fine, weight_coarse = _blur(weight, 1.0), _blur(weight, 4.0)
        band = _blur(values, 1.0) / np.maximum(weight_fine, 1e-9) - _blur(values, 4.0) / np.maximum(
            weight_coarse, 1e-9
        )
        masks[k] = mask & (weight_coarse > 0.99)
        bands.append(np.where(masks[k], band, 0.0))
    rows, cols = reference.shape
    limit = max(rows, cols) if max_shift is None else max_shift
    ncc, overlap = _masked_ncc(bands, masks, limit)
    dr = np.fft.fftfreq(ncc.shape[0], 1.0 / ncc.shape[0])[:, None]  # the shift of each row of the map
    dc = np.fft.fftfreq(ncc.shape[1], 1.0 / ncc.shape[1])[None, :]
    enough = overlap >= 0.5 * min(masks[0].sum(), masks[1].sum())
    allowed = enough & (np.abs(dr) <= limit) & (np.abs(dc) <= limit)
    peak = np.unravel_index(np.argmax(np.where(allowed, ncc, -np.inf)), ncc.shape)
    shift = [float(dr[peak[0], 0]), float(dc[0, peak[1]])]
    for axis in (0, 1):  # the fraction: a parabola through the peak and one pixel either way
        before, after = list(peak), list(peak)
        before[axis] = (peak[axis] - 1) % ncc.shape[axis]
        after[axis] = (peak[axis] + 1) % ncc.shape[axis]
        c_minus, c_0, c_plus = ncc[tuple(before)], ncc[peak], ncc[tuple(after)]
        curvature = c_minus - 2.0 * c_0 + c_plus
        if curvature < 0:
            shift[axis] += float(np.clip(0.5 * (c_minus - c_plus) / curvature, -0.5, 0.5))
    return np.asarray(shift), float(ncc[peak])


def _blur(image, sigma):
    """A Gaussian blur (kernel to 4 sigma, mirrored borders: scipy.ndimage.gaussian_filter's), by
    OpenCV: the band-pass was most of a season's alignment with SciPy's."""
    import cv2

    return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def _masked_ncc(bands, masks, max_shift):
    """Normalised cross-correlation of masked grids for every shift s up to `max_shift` pixels (the
    moving grid's pixel x + s against the reference's x), by FFT, and the number of pixels
    overlapping; both indexed by s modulo the padded shape (``numpy.fft.fftfreq`` order).

    Padding each axis to its length plus `max_shift` keeps those shifts free of wrap-around (a
    shift s can only meet s +- the padded length, which no pair of pixels spans); the whole
    range of shifts would need twice the length, and the FFTs were most of a season's alignment.
    """
    from scipy import fft

    f, g = bands
    mf, mg = (m.astype(np.float32) for m in masks)
    shape = [fft.next_fast_len(n + min(int(np.ceil(max_shift)), n - 1) + 1, real=True) for n in f.shape]

    def spectrum(a):
        return fft.rfft2(a, shape)

    def correlate(a_spec, b_spec):  # sum over x of a(x + s) b(x)
        return fft.irfft2(a_spec * np.conj(b_spec), shape)

    F, G, Mf, Mg = spectrum(f), spectrum(g), spectrum(mf), spectrum(mg)
    F2, G2 = spectrum(f * f), spectrum(g * g)
    overlap = np.maximum(np.round(correlate(Mg, Mf)), 0.0)
    n = np.maximum(overlap, 1.0)
    g_f = correlate(G, Mf)
    mg_f = correlate(Mg, F)
    numerator = correlate(G, F) - g_f * mg_f / n
    var_g = correlate(G2, Mf) - g_f**2 / n
    var_f = correlate(Mg, F2) - mg_f**2 / n
    denominator = np.sqrt(np.maximum(var_g, 0.0) * np.maximum(var_f, 0.0))
    tiny = np.finfo(denominator.dtype).tiny  # float32 here: 1e-300 would be 0
    ncc = np.where(
        denominator > 1e-12 * max(float(denominator.max()), tiny),
        numerator / np.maximum(denominator, tiny),
        -1.0,
    )
    return ncc, overlap


def smallest_plot_width(plot_set):
    """The shortest side over the plots' outer rings (metres): the scale a date's shift is judged by."""
    sides = np.concatenate(
        [np.hypot(*np.diff(np.asarray(rings[0], dtype=np.float64), axis=0).T) for rings in plot_set.polygons]
    )
    sides = sides[sides > 0]  # a closed ring repeats its first point
    return float(sides.min()) if sides.size else float("nan")
