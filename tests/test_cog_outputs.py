"""heights' rasters in the layout a GIS opens quickly (issue 40): tiled, Deflate-compressed with a
predictor, with reduced-resolution overviews; and the package's own readers still read them."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
import tifffile
from conftest import REPO

from cliff_terrain.io.raster._tiff_window import TiffRaster
from cliff_terrain.io.raster.geotiff import COG_TILE, read_surface, write_geotiff

ODM_PAIR = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"


def block_nanmean(data):
    """2 x 2 means of the valid pixels, NaN where none: written here, independently of the package."""
    rows, cols = ((data.shape[0] + 1) // 2 * 2, (data.shape[1] + 1) // 2 * 2)
    padded = np.full((rows, cols), np.nan, np.float64)
    padded[: data.shape[0], : data.shape[1]] = data
    blocks = padded.reshape(rows // 2, 2, cols // 2, 2).transpose(0, 2, 1, 3).reshape(rows // 2, cols // 2, 4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN blocks
        return np.nanmean(blocks, axis=2)


def check_layout(path, expect_levels):
    with tifffile.TiffFile(path) as tif:
        pages = list(tif.pages)
        assert len(pages) == expect_levels
        full = pages[0].asarray()
        for i, page in enumerate(pages):
            assert page.is_tiled and (page.tilelength, page.tilewidth) == (COG_TILE, COG_TILE)
            assert page.compression == tifffile.COMPRESSION.ADOBE_DEFLATE
            assert page.predictor == tifffile.PREDICTOR.FLOATINGPOINT
            assert page.subfiletype == (0 if i == 0 else 1)  # reduced-resolution images: overviews
        # Each overview halves the one above (rounded up) and holds its valid pixels' means.
        level = full.astype(np.float64)
        for page in pages[1:]:
            level = block_nanmean(level)
            np.testing.assert_allclose(page.asarray(), level, rtol=1e-6, equal_nan=True)
        if len(pages) > 1:  # the last overview fits one tile, the one above it does not
            assert max(pages[-1].shape) <= COG_TILE < max(pages[-2].shape)
    return full


def test_heights_writes_tiled_compressed_rasters_with_overviews_that_read_back(tmp_path):
    if not (ODM_PAIR / "odm_orthophoto.tif").is_file():
        pytest.skip(f"the shared OpenDroneMap pair is not at {ODM_PAIR}")
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", "heights", str(ODM_PAIR / "odm_orthophoto.tif"), "--dsm",
         str(ODM_PAIR / "dsm.tif"), "--out", str(out), "--no-progress"],
        capture_output=True, text=True, cwd=REPO,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    for name in ("chm.tif", "ground_support.tif"):
        full = check_layout(out / name, expect_levels=2)  # 550 x 535: one overview of 275 x 268
        surface = read_surface(out / name)
        assert surface.shape == (550, 535) and surface.crs == 32616
        np.testing.assert_array_equal(np.isnan(surface.data), np.isnan(full))
        np.testing.assert_array_equal(surface.data[np.isfinite(full)], full[np.isfinite(full)])
        # The windowed reader decodes the tiles a window overlaps: the same pixels.
        with TiffRaster(out / name) as tiff:
            window = tiff.read_window(300, 550, 500, 535)[..., 0]
        np.testing.assert_array_equal(window, full[300:550, 500:535])


def test_a_large_raster_gets_overviews_down_to_one_tile(tmp_path):
    rng = np.random.default_rng(3)
    data = rng.normal(1.0, 0.3, (2100, 1300)).astype(np.float32)
    data[:40, :] = np.nan  # no data along the top, as outside a flight
    data[1000:1003, 700:703] = np.nan
    write_geotiff(
        tmp_path / "big.tif", data, transform=[[0.01, 0, 5e5], [0, -0.01, 4e6]], crs=32616, nodata=float("nan"),
        overviews=True,
    )  # fmt: skip
    full = check_layout(tmp_path / "big.tif", expect_levels=4)  # 2100, 1050, 525, 263 rows
    np.testing.assert_array_equal(full, data)
    assert read_surface(tmp_path / "big.tif").data.tobytes() == data.tobytes()
