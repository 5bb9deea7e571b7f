"""Image and surface metrics: PSNR, SSIM (the paper's Table 4) and the symmetric surface distance (Eq. 12)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from skimage.metrics import structural_similarity

from .._validate import check_float
from ..errors import CliffTerrainError


def _pair(reference, test, data_range):
    reference = np.asarray(reference)
    test = np.asarray(test)
    if reference.shape != test.shape:
        raise CliffTerrainError(
            f"`test` must have the shape of `reference` {reference.shape}, got {test.shape}"
        )
    if reference.size == 0:
        raise CliffTerrainError(f"`reference` must not be empty, got shape {reference.shape}")
    if data_range is None:
        if reference.dtype != np.uint8 or test.dtype != np.uint8:
            raise CliffTerrainError(
                f"`data_range` must be given for non-uint8 images, got None (dtypes {reference.dtype}, {test.dtype})"
            )
        data_range = 255.0
    data_range = check_float("data_range", data_range, minimum=0.0, strict_minimum=True)
    return reference.astype(np.float64), test.astype(np.float64), data_range


def psnr(reference, test, *, data_range=None):
    """Peak signal-to-noise ratio in dB.

    Parameters
    ----------
    reference, test : array
        Images of the same shape (any number of channels).
    data_range : float, optional
        The range the values can take (255 for 8-bit). Required unless both images are uint8:
        it is never guessed from the data.

    Returns
    -------
    float
        ``10 log10(data_range^2 / MSE)``; ``inf`` for identical images.

    Examples
    --------
    >>> a = np.zeros((4, 4), np.uint8); b = a.copy(); b[0, 0] = 16
    >>> round(psnr(a, b), 2)  # MSE 16^2 / 16 = 16: 10 log10(255^2 / 16)
    36.09
    """
    ref, tst, data_range = _pair(reference, test, data_range)
    mse = float(np.mean((ref - tst) ** 2))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range**2 / mse))


def ssim(reference, test, *, data_range=None):
    """Structural similarity (Wang et al. 2004), as MATLAB's ``ssim`` computes it.

    Gaussian window with sigma 1.5, population covariances, averaged over the colour channels.

    Parameters
    ----------
    reference, test : (rows, cols) or (rows, cols, channels) array
    data_range : float, optional
        As in :func:`psnr`.

    Returns
    -------
    float
        1.0 for identical images.

    Examples
    --------
    >>> a = np.tile(np.arange(32, dtype=np.uint8) * 8, (32, 1))
    >>> ssim(a, a)
    1.0
    """
    ref, tst, data_range = _pair(reference, test, data_range)
    if ref.ndim not in (2, 3) or min(ref.shape[:2]) < 7:
        raise CliffTerrainError(
            f"`reference` must be a 2-D or 3-D image of at least 7x7 pixels, got shape {ref.shape}"
        )
    return float(
        structural_similarity(
            ref,
            tst,
            data_range=data_range,
            channel_axis=2 if ref.ndim == 3 else None,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
        )
    )


def height_points(heights, *, pixel_size=1.0):
    """The points (x, y, z) of a height grid, for :func:`surface_distance`.

    Parameters
    ----------
    heights : (rows, cols) array
    pixel_size : float, optional
        Grid spacing in the heights' unit.

    Returns
    -------
    (rows * cols, 3) float64 array
        x = col * pixel_size, y = (rows - 1 - row) * pixel_size, z = height.
    """
    heights = np.asarray(heights, dtype=np.float64)
    if heights.ndim != 2:
        raise CliffTerrainError(f"`heights` must be a 2-D array, got shape {heights.shape}")
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    rows, cols = heights.shape
    rr, cc = np.mgrid[:rows, :cols]
    return np.column_stack([cc.ravel() * pixel_size, (rows - 1 - rr.ravel()) * pixel_size, heights.ravel()])


def surface_distance(points_a, points_b, *, reduction="mean"):
    """Symmetric surface distance between two sampled surfaces (the paper's Eq. 12).

    For every point of each surface, the distance to the nearest point of the other; the
    result averages (or takes the largest of) both sets together:
    ``(sum_a d(a, B) + sum_b d(b, A)) / (|A| + |B|)``.

    Parameters
    ----------
    points_a, points_b : (n, 3) array
        Surface samples, e.g. mesh vertices or :func:`height_points`.
    reduction : {"mean", "max"}, optional
        ``"mean"`` for the average symmetric surface distance, ``"max"`` for the symmetric
        Hausdorff distance.

    Returns
    -------
    float

    Examples
    --------
    >>> a = height_points(np.zeros((3, 3)))
    >>> surface_distance(a, a + [0, 0, 2.0])
    2.0
    """
    a = np.asarray(points_a, dtype=np.float64)
    b = np.asarray(points_b, dtype=np.float64)
    for name, p in (("points_a", a), ("points_b", b)):
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
            raise CliffTerrainError(f"`{name}` must have shape (n, 3) with n >= 1, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise CliffTerrainError(f"`{name}` must be finite, got NaN or infinity")
    if reduction not in ("mean", "max"):
        raise CliffTerrainError(f"`reduction` must be one of 'mean', 'max', got {reduction!r}")
    d_ab, _ = cKDTree(b).query(a)
    d_ba, _ = cKDTree(a).query(b)
    if reduction == "max":
        return float(max(d_ab.max(), d_ba.max()))
    return float((d_ab.sum() + d_ba.sum()) / (d_ab.size + d_ba.size))
