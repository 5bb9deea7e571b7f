"""Metrics against independent computations."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from cliff_terrain import CliffTerrainError, height_points, psnr, ssim, surface_distance


def test_psnr_against_the_definition():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (32, 40, 3), dtype=np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-9, 10, a.shape), 0, 255).astype(np.uint8)
    mse = np.mean((a.astype(float) - b) ** 2)
    assert psnr(a, b) == pytest.approx(10 * np.log10(255**2 / mse))
    assert psnr(a, a) == float("inf")
    # With floats the data range must be said, and it is used as given.
    assert psnr(a / 255.0, b / 255.0, data_range=1.0) == pytest.approx(psnr(a, b))


def _ssim_reference(x, y, data_range):
    # Wang et al. 2004 with a Gaussian window (sigma 1.5, truncated at 3.5 sigma) and population
    # statistics, written out directly; mean over the valid interior like MATLAB/scikit-image.
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    f = lambda z: gaussian_filter(z, 1.5, truncate=3.5)  # noqa: E731
    mx, my = f(x), f(y)
    vx, vy, cxy = f(x * x) - mx**2, f(y * y) - my**2, f(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    pad = 5
    return s[pad:-pad, pad:-pad].mean()


def test_ssim_against_a_direct_formula():
    rng = np.random.default_rng(1)
    x = gaussian_filter(rng.uniform(0, 255, (48, 64)), 2)
    y = np.clip(x + rng.normal(0, 12, x.shape), 0, 255)
    assert ssim(x, y, data_range=255) == pytest.approx(_ssim_reference(x, y, 255), abs=1e-6)
    rgb_x = np.stack([x, x * 0.5, x * 0.8], -1)
    rgb_y = np.stack([y, y * 0.5, y * 0.8], -1)
    per_channel = np.mean([_ssim_reference(rgb_x[..., k], rgb_y[..., k], 255) for k in range(3)])
    assert ssim(rgb_x, rgb_y, data_range=255) == pytest.approx(per_channel, abs=1e-6)


def test_surface_distance_against_brute_force():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(60, 3))
    b = rng.normal(size=(45, 3)) + 0.3
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    expected = (d.min(1).sum() + d.min(0).sum()) / (60 + 45)
    assert surface_distance(a, b) == pytest.approx(expected)
    assert surface_distance(a, b, reduction="max") == pytest.approx(max(d.min(1).max(), d.min(0).max()))
    flat = height_points(np.zeros((5, 6)), pixel_size=0.5)
    assert flat.shape == (30, 3) and flat[:, 0].max() == 2.5 and flat[:, 1].max() == 2.0
    assert surface_distance(flat, flat) == 0.0


def test_metrics_reject_bad_input():
    a = np.zeros((8, 8), np.uint8)
    with pytest.raises(
        CliffTerrainError, match=r"`test` must have the shape of `reference` \(8, 8\), got \(8, 9\)"
    ):
        psnr(a, np.zeros((8, 9), np.uint8))
    with pytest.raises(CliffTerrainError, match="`data_range` must be given for non-uint8 images"):
        psnr(a.astype(float), a.astype(float))
    with pytest.raises(CliffTerrainError, match="at least 7x7 pixels"):
        ssim(np.zeros((5, 5), np.uint8), np.zeros((5, 5), np.uint8))
    with pytest.raises(
        CliffTerrainError, match=r"`points_b` must have shape \(n, 3\) with n >= 1, got \(0, 3\)"
    ):
        surface_distance(np.zeros((3, 3)), np.zeros((0, 3)))
    with pytest.raises(CliffTerrainError, match="`reduction` must be one of 'mean', 'max', got 'median'"):
        surface_distance(np.zeros((3, 3)), np.zeros((3, 3)), reduction="median")
