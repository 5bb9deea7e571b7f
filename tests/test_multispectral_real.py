"""Multispectral reading and indices on a REAL orthomosaic: tests/data/multispectral/615.tif, a 5-band
float32 reflectance clip of one plot of seedling rows (PlantCV-geospatial's test data, MPL-2.0: see
SOURCES.md beside it). Its file names no band (order B, G, R, RE, NIR, from PlantCV's own test) and
marks no data with GDAL_NODATA -10000. The reference is tifffile and numpy, sharing no code with ours."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.io.raster.bands import read_bands
from cliff_terrain.photo_heights.indices import index_map

REPO = Path(__file__).resolve().parents[1]
CLIP = REPO / "tests" / "data" / "multispectral" / "615.tif"
ORDER = ("blue", "green", "red", "rededge", "nir")


def reference_bands():
    raw = tifffile.imread(CLIP).astype(np.float64)
    valid = ~(raw == -10000.0).all(axis=2)
    return {name: np.where(valid, raw[..., k], np.nan) for k, name in enumerate(ORDER)}, valid


def test_the_real_clip_reads_with_its_georeference_and_no_data():
    bands = read_bands(CLIP, names="B,G,R,RE,NIR")
    reference, valid = reference_bands()
    assert bands.names == ORDER and bands.shape == (177, 161)
    np.testing.assert_array_equal(bands.valid, valid)
    assert int(valid.sum()) == 11651  # 59 % of the clip is outside the rotated plot
    for k, name in enumerate(ORDER):
        np.testing.assert_allclose(bands.data[..., k][valid], reference[name][valid], rtol=1e-7)
    assert bands.crs == 32615 and bands.transform[0, 0] == pytest.approx(0.0356094, rel=1e-5)
    assert 0.0 < np.nanmin(bands.data) and np.nanmax(bands.data) < 0.25  # reflectance, not scaled


def test_a_file_that_names_no_band_asks_for_bands():
    with pytest.raises(CliffTerrainError, match="does not name its band.*--bands"):
        read_bands(CLIP)


@pytest.mark.parametrize(
    ("name", "formula"),
    [
        ("NDVI", lambda b: (b["nir"] - b["red"]) / (b["nir"] + b["red"])),
        ("NDRE", lambda b: (b["nir"] - b["rededge"]) / (b["nir"] + b["rededge"])),
        ("GNDVI", lambda b: (b["nir"] - b["green"]) / (b["nir"] + b["green"])),
        ("OSAVI", lambda b: (b["nir"] - b["red"]) / (b["nir"] + b["red"] + 0.16)),
        ("VARI", lambda b: (b["green"] - b["red"]) / (b["green"] + b["red"] - b["blue"])),
    ],
)
def test_indices_of_the_real_clip_equal_their_formula(name, formula):
    ours = index_map(read_bands(CLIP, names="B,G,R,RE,NIR"), name)
    reference, valid = reference_bands()
    expected = formula(reference)
    np.testing.assert_array_equal(np.isfinite(ours), np.isfinite(expected))
    np.testing.assert_allclose(ours[valid], expected[valid], atol=2e-6)


@pytest.mark.blender
def test_render_views_on_the_real_clip_shows_its_ndvi(tmp_path):
    """The relief of the real clip (true colour from the named bands), its regions' NDVI and the
    top view coloured by NDVI, whose viridis lightness follows the clip's own NDVI."""
    import csv

    import cv2
    from PIL import Image

    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, str(REPO / "render_views.py"), str(CLIP), "--bands", "B,G,R,RE,NIR"]
        + ["--indices", "NDVI", "--color-by", "NDVI", "--samples", "2", "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    reference, valid = reference_bands()
    ndvi = (reference["nir"] - reference["red"]) / (reference["nir"] + reference["red"])
    shown = np.asarray(Image.open(out / "xy_ndvi.png").convert("L"), dtype=np.float64)
    rows, cols = shown.shape
    inside = cv2.resize(valid.astype(np.uint8), (cols, rows), interpolation=cv2.INTER_NEAREST) > 0
    inside &= cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0  # off the plot's edge
    expected = cv2.resize(np.nan_to_num(ndvi), (cols, rows), interpolation=cv2.INTER_AREA)
    assert np.corrcoef(shown[inside], expected[inside])[0, 1] > 0.9
    # The true-colour top view: the plants (NDVI above the soil's) greener than the soil.
    photo = np.asarray(Image.open(out / "xy.png").convert("RGB"), dtype=np.float64)
    green_share = photo[..., 1] / np.maximum(photo.sum(axis=2), 1.0)
    plants, soil = inside & (expected > 0.5), inside & (expected < 0.3)
    assert green_share[plants].mean() > green_share[soil].mean() + 0.03
    with (out / "regions.csv").open() as f:
        regions = list(csv.DictReader(f))
    assert regions and all(0.3 < float(r["ndvi_plant_mean"]) < 0.9 for r in regions)


def test_build_relief_names_the_bands_of_an_unnamed_clip():
    from cliff_terrain import build_relief
    from cliff_terrain.io.raster.bands import rgb_rendering

    relief = build_relief(CLIP, bands="B,G,R,RE,NIR", mesh=None)
    assert relief.metadata.band_names == ORDER and relief.params["bands"] == ORDER
    texture, valid = rgb_rendering(read_bands(CLIP, names="B,G,R,RE,NIR"))
    np.testing.assert_array_equal(relief.image, texture)  # true colour: red, green, blue in place
    np.testing.assert_array_equal(relief.metadata.valid_mask, valid)
    with pytest.raises(CliffTerrainError, match="unknown band 'X'"):
        build_relief(CLIP, bands="B,G,R,X,NIR")


def test_the_real_clips_ndvi_threshold_is_its_own_by_the_red_bands_separation():
    """Seedling rows over soil: no empty NDVI valley, but the leaves are plainly darker in red. The
    record's D is checked against Ashman's D computed here from the raw bands (numpy, scikit-image's
    Otsu), and the plants it raises are the pixels above the photo's own NDVI split."""
    from skimage.filters import threshold_otsu

    from cliff_terrain import build_relief

    relief = build_relief(CLIP, bands="B,G,R,RE,NIR", mesh=None)
    rule = relief.params["threshold"]
    assert rule["index"] == "ndvi" and rule["source"] == "photo (red)"
    assert rule["colour_test"] == {"statistic": "ashman_d_red_reflectance", "min": 2.0}
    bands, valid = reference_bands()
    ndvi = (bands["nir"] - bands["red"]) / (bands["nir"] + bands["red"])
    blurred = cv2.GaussianBlur(np.where(valid, ndvi, -1.0).astype(np.float32), (0, 0), 1.0)[valid]
    split = threshold_otsu(blurred.astype(np.float64))
    red = bands["red"][valid]
    leaves, soil = red[blurred > split], red[blurred <= split]

    def spread(x):
        return 1.4826 * np.median(np.abs(x - np.median(x)))

    d = np.sqrt(2) * (np.median(soil) - np.median(leaves)) / np.hypot(spread(soil), spread(leaves))
    assert d > 2 and rule["colour_separation"] == pytest.approx(d, rel=0.02)
    assert rule["value"] == pytest.approx(split, abs=0.01)
    assert rule["valley"] > 0.5  # the valley test alone would not have taken the photo's own split
