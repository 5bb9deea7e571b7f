"""disk_maximum: OpenCV's elliptical grey dilation, to the bit, by a staircase of thin dilations."""

import cv2
import numpy as np
import pytest
from conftest import uav_image
from scipy import ndimage

import cliff_terrain._threads as threads
import cliff_terrain.photo_heights.disk_max as disk_max
from cliff_terrain import CliffTerrainError, load_image, segment
from cliff_terrain.photo_heights.disk_max import disk_maximum
from cliff_terrain.photo_heights.labels import distance_map


def _ellipse(radius):
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


@pytest.mark.parametrize("radius", [0, 1, 2, 4, 5, 6, 7, 9, 12, 20, 33, 47, 64, 101])
def test_disk_maximum_is_opencvs_and_scipys_elliptical_dilation(radius):
    # 311 rows: several bands of 96 and more, the last one short; plateaus (rounded values) make
    # ties, where a wrong reach would show.
    rng = np.random.default_rng(radius)
    image = np.round(rng.random((311, 173)) * 20).astype(np.float32)
    got = disk_maximum(image, radius)
    assert got.dtype == np.float32 and got.shape == image.shape
    np.testing.assert_array_equal(got, cv2.dilate(image, _ellipse(radius)))
    # An independent implementation of the same definition (outside the image ignored).
    footprint = _ellipse(radius).astype(bool)
    expected = ndimage.maximum_filter(image, footprint=footprint, mode="constant", cval=-np.inf)
    np.testing.assert_array_equal(got, expected)


def test_every_radius_the_watershed_uses_takes_the_fast_path():
    # split_regions clips the radius to 3..200: from 5 up, each kernel must be a staircase of
    # centred runs (else disk_maximum silently falls back to OpenCV's slow dilation).
    for radius in range(disk_max._DIRECT_BELOW, 201):
        steps = disk_max._staircase(radius)
        assert steps is not None, radius
        # By increasing width and decreasing height: the order _staircase_max chains them in.
        widths, heights = zip(*steps, strict=True)
        assert widths[0] == 0 and heights[0] == radius and widths[-1] == radius
        assert list(widths) == sorted(widths) and list(heights) == sorted(heights, reverse=True)
        # The union of the staircase's centred rectangles is OpenCV's kernel, point for point.
        union = np.zeros((2 * radius + 1, 2 * radius + 1), bool)
        for w, h in steps:
            union[radius - h : radius + h + 1, radius - w : radius + w + 1] = True
        np.testing.assert_array_equal(union, _ellipse(radius).astype(bool), err_msg=f"radius {radius}")


def test_on_a_real_fields_distance_map_one_thread_or_many(monkeypatch):
    # What split_regions dilates: the blurred distance map of a real photo's plants, at the
    # mosaic's radius (20 px) and the photo's own, on threads and on one.
    image, _ = load_image(uav_image("broccoli/01_clip_raw_test.jpg"), max_size=1200)
    smooth = cv2.GaussianBlur(distance_map(segment(image).mask).astype(np.float32), (0, 0), 1.0)
    for radius in (8, 20):
        expected = cv2.dilate(smooth, _ellipse(radius))
        np.testing.assert_array_equal(disk_maximum(smooth, radius), expected)
        monkeypatch.setattr(threads, "MAX_THREADS", 1)
        np.testing.assert_array_equal(disk_maximum(smooth, radius), expected)
        monkeypatch.undo()


def test_bad_input_is_named():
    with pytest.raises(CliffTerrainError, match=r"`radius` must be >= 0, got -1"):
        disk_maximum(np.zeros((4, 4), np.float32), -1)
    with pytest.raises(CliffTerrainError, match=r"`radius` must be an integer, got 2.5"):
        disk_maximum(np.zeros((4, 4), np.float32), 2.5)
    with pytest.raises(CliffTerrainError, match=r"`image` must be 2-D \(rows, cols\), got shape \(4, 4, 3\)"):
        disk_maximum(np.zeros((4, 4, 3), np.float32), 6)
