"""Canopy cover counts the photo's plant pixels (``Segmentation.index_pixels``), the same in memory
and in windows, not the holes the relief fills inside its plants."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
import tifffile
from conftest import REPO

from cliff_terrain.io.photo import load_image
from cliff_terrain.io.raster.geotiff import geotiff_tags, read_orthophoto
from cliff_terrain.photo_heights.vegetation import blurred_index

SHARED = REPO.parent / "shared" / "data"
PAIR = SHARED / "dsm" / "fieldimager_ex2"
PLOTS = REPO / "tests" / "data" / "odm_plots_by_hand.geojson"


def test_cover_counts_the_index_above_the_threshold_not_the_filled_mask():
    # Segmentation.index_pixels: the blurred index above the photo's threshold, no-data included,
    # before the relief drops specks and fills holes; the relief's cover_mask is that array (the
    # index is not computed a second time) and differs from the mask where holes were filled.
    from cliff_terrain.build import build_relief
    from cliff_terrain.photo_heights.segmentation import segment

    photo = SHARED / "uav" / "broccoli" / "01_clip_raw_test.jpg"
    if not photo.is_file():
        pytest.skip(f"the shared UAV photos are not at {photo.parent}")
    rgb, _ = load_image(photo, max_size=900)
    valid = np.zeros(rgb.shape[:2], bool)
    valid[10:-10, 20:-20] = True
    seg = segment(rgb, valid=valid)
    vi, _ = blurred_index(rgb, index=seg.index)
    np.testing.assert_array_equal(seg.index_pixels, vi > seg.threshold)
    assert (seg.mask & ~seg.index_pixels).any()  # holes filled inside plants
    assert not (seg.mask & ~valid).any() and (seg.index_pixels & ~valid).any()
    assert segment(rgb, method="paper", filtered=rgb).index_pixels is None
    relief = build_relief(photo, max_size=900, mesh=None)
    vi, _ = blurred_index(relief.working, index="green")
    threshold = relief.params["threshold"]["value"]  # rounded to 4 digits: the pixels near it aside
    near = np.abs(vi - threshold) < 1e-4
    np.testing.assert_array_equal(relief.cover_mask[~near], (vi > threshold)[~near])
    assert (relief.mask & ~relief.cover_mask).any()


def _heights(tmp_path, name, ortho, *extra):
    out = tmp_path / name
    command = [sys.executable, "-m", "cliff_terrain", "heights", str(ortho), "--dsm", str(PAIR / "dsm.tif")]
    command += ["--plots", str(PLOTS), "--out", str(out), "--no-progress", *extra]
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=600)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    with open(out / "plots.csv") as stream:
        return list(csv.DictReader(stream)), json.loads((out / "summary.json").read_text())


def test_dull_leaves_inside_plants_count_alike_in_memory_and_in_windows(tmp_path):
    # The shared pair with dull, yellowing spots inside its plants (index 0.11, below the plant
    # threshold but not soil-coloured): the relief fills them as holes inside a plant, the windows
    # cannot fill holes across windows. Cover counted the relief's mask in memory until 2026-12-06:
    # on a real potato trial's day 100, 66.4 % in memory against 53.6 % in windows, and one plot
    # 1.0 against 0.86.
    from cliff_terrain.build import build_relief
    from cliff_terrain.measure.canopy import cover_pixels, plant_mask

    if not PAIR.is_dir():
        pytest.skip(f"the shared OpenDroneMap pair is not at {PAIR}")
    photo = read_orthophoto(PAIR / "odm_orthophoto.tif")
    rgb = photo.data.copy()
    inner = cv2.erode(plant_mask(rgb, valid=photo.valid).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    rr, cc = np.mgrid[: rgb.shape[0], : rgb.shape[1]]
    spots = inner & (rr % 16 < 8) & (cc % 16 < 8)
    level = rgb[spots].max(axis=-1).astype(np.float32)
    rgb[spots] = np.clip(level[:, None] * [1.0, 1.0, 0.7], 0, 255).astype(np.uint8)
    dull = tmp_path / "dull.tif"
    alpha = photo.valid.astype(np.uint8) * 255
    tifffile.imwrite(
        dull, np.dstack([rgb, alpha]), photometric="rgb", extrasamples=[2],
        extratags=geotiff_tags(photo.transform, photo.crs),
    )  # fmt: skip
    relief = build_relief(dull, dsm=PAIR / "dsm.tif", height_source="measured", mesh=None)
    filled = relief.mask & ~cover_pixels(relief)
    assert filled[spots].mean() > 0.4  # the relief fills many spots (0.57): they rise with their plant
    rows_m, summary_m = _heights(tmp_path, "memory", dull)
    rows_w, summary_w = _heights(tmp_path, "windows", dull, "--windowed")
    assert rows_w == rows_m
    assert summary_w["cover"] == summary_m["cover"]
    valid = relief.canopy is not None and np.isfinite(relief.canopy.chm)
    relief_cover = np.count_nonzero(relief.mask & valid) / np.count_nonzero(valid)
    assert summary_m["cover"] < relief_cover - 0.005  # the filled spots are not counted
