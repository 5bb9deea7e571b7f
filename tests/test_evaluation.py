"""cliff_terrain.evaluate.views without Blender: colour curves, slopes, the shading measure, view sizes,
the reference image and the metrics' summary, each against an independent computation."""

import json
import math

import numpy as np
import pytest
from PIL import Image

from cliff_terrain import CliffTerrainError, psnr
from cliff_terrain.evaluate.views import (
    compare_top_views,
    json_safe,
    linear_to_srgb,
    metrics_summary,
    psnr_text,
    reference_image,
    resize_nearest,
    shading_measure,
    slope_degrees,
    srgb_to_linear,
    view_resolution,
)
from cliff_terrain.settings import MAX_RESOLUTION, MIN_VIEW_SIDE


def test_srgb_curve_round_trips_every_code_and_matches_the_standard():
    codes = np.arange(256, dtype=np.uint8)
    linear = srgb_to_linear(codes)
    assert linear.dtype == np.float32
    np.testing.assert_array_equal(linear_to_srgb(linear), codes)
    # IEC 61966-2-1 at a few codes: 0, the linear toe, mid grey, white.
    c = np.array([0, 10, 128, 255]) / 255.0
    expected = [0.0, c[1] / 12.92, ((c[2] + 0.055) / 1.055) ** 2.4, 1.0]
    np.testing.assert_allclose(linear[[0, 10, 128, 255]], expected, rtol=1e-6)


def test_slope_of_a_tilted_plane_is_its_angle():
    rows, cols, cell = 5, 7, 0.5
    x = np.arange(cols + 1) * cell
    z = np.tile(x * math.tan(math.radians(30.0)), (rows + 1, 1))
    np.testing.assert_allclose(slope_degrees(z, cell), 30.0, atol=1e-9)
    assert slope_degrees(z, cell).shape == (rows, cols)
    np.testing.assert_allclose(slope_degrees(np.zeros((4, 4)), 1.0), 0.0)


def test_resize_nearest_picks_pixel_centres():
    array = np.arange(6 * 8).reshape(6, 8)
    # Halving: output pixel i covers input pixels 2i and 2i+1, its centre falls on 2i+1.
    np.testing.assert_array_equal(resize_nearest(array, (4, 3)), array[1::2, 1::2])
    np.testing.assert_array_equal(resize_nearest(array, (8, 6)), array)


def test_shading_measure_separates_sloped_from_level_pixels():
    flat = np.full((4, 6, 3), 100, np.uint8)
    lit = flat.copy()
    slope = np.zeros((4, 6))
    slope[:, :2] = 30.0  # sloped: 10 grey levels brighter
    lit[:, :2] += 10
    slope[:, 2:4] = 8.0  # neither sloped nor level: not counted
    lit[:, 2:4] += 50
    lit[:, 4:] += 1  # level
    m = shading_measure(lit, flat, slope)
    assert m["shading_sloped"] == pytest.approx(10.0)
    assert m["shading_level"] == pytest.approx(1.0)
    assert m["shading_contrast"] == pytest.approx(9.0)
    assert m["sloped_fraction"] == pytest.approx(1 / 3)
    assert shading_measure(lit, flat, np.zeros((4, 6)))["shading_contrast"] is None


def test_view_resolution_enlarges_small_photos_and_refuses_thin_views():
    assert view_resolution(None, 300, 450) == 450  # one view pixel per grid cell
    assert view_resolution(0, 2, 2) == MIN_VIEW_SIDE  # enlarged until the shorter side has 16
    assert view_resolution(None, 2, 64) == MIN_VIEW_SIDE * 32
    assert view_resolution(100, 300, 450) == 100
    with pytest.raises(CliffTerrainError, match="Resolution 16 makes the top views 1 pixel across"):
        view_resolution(16, 2, 64, name="Resolution")
    with pytest.raises(CliffTerrainError, match=f"even {MAX_RESOLUTION} pixels long"):
        view_resolution(None, 1, 20000)


def test_reference_is_the_photo_averaged_in_linear_light(tmp_path):
    rng = np.random.default_rng(4)
    photo = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    path = tmp_path / "photo.png"
    Image.fromarray(photo).save(path)
    same, how = reference_image(path, (60, 40))
    np.testing.assert_array_equal(same, photo)
    assert "full resolution" in how
    half, _ = reference_image(path, (30, 20))
    # Independent: decode each code to linear light, mean over 2x2 blocks, encode.
    c = photo / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    block = linear.reshape(20, 2, 30, 2, 3).mean(axis=(1, 3))
    srgb = np.where(block <= 0.0031308, 12.92 * block, 1.055 * block ** (1 / 2.4) - 0.055)
    assert np.abs(half.astype(int) - np.round(255 * srgb).astype(int)).max() <= 1


def test_identical_views_read_as_identical_and_store_as_json():
    rng = np.random.default_rng(5)
    reference = rng.integers(0, 256, (32, 48, 3), dtype=np.uint8)
    lit = reference.copy()
    lit[::3] = lit[::3] // 2
    metrics = compare_top_views(reference, lit, reference.copy())
    assert metrics["psnr_xy"] == pytest.approx(psnr(reference, lit))
    assert math.isinf(metrics["psnr_xy_flat"]) and metrics["ssim_xy_flat"] == pytest.approx(1.0)
    line = metrics_summary(metrics)
    assert f"lit top view PSNR {metrics['psnr_xy']:.2f} dB" in line
    assert "flat PSNR identical, SSIM 1.0000" in line and "999" not in line
    stored = json.loads(json.dumps(json_safe(metrics)))
    assert stored["psnr_xy_flat"] is None and stored["psnr_xy"] == pytest.approx(metrics["psnr_xy"])
    # Blender's FloatProperty keeps float32's largest value of an infinite PSNR: still identical.
    assert psnr_text(float(np.float32(np.inf).astype(np.float64))) == "identical"
    assert psnr_text(float(np.finfo(np.float32).max)) == "identical"
    assert psnr_text(17.734) == "17.73 dB"
