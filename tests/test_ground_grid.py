"""The ground's grid (cliff_terrain.measure.ground_grid): no finer than 5 cm, in memory as in windows.

- each block of the ground grid takes its bare soil's mean height, else its data's, and has data
  when most of its pixels have (counted by hand on small arrays);
- on a synthetic 1 cm field whose true ground is known, the in-memory canopy fits its ground on
  the 5 cm grid, within a centimetre of the ground fitted on the full grid and about as near the
  truth, and the plots' p90 stay within 1.5 cm of the full grid's;
- the baseline asked for by name stays the naive peer to the digit, whatever the grid; chosen by
  the check it is the candidate the check measured;
- a no-data marker the file did not declare (-3.4e38) is no data on either grid.
"""

from __future__ import annotations

import numpy as np
import pytest

from cliff_terrain.measure.ground import naive_block_ground
from cliff_terrain.measure.ground_grid import fit_on_ground_grid, ground_factor, reduce_for_ground


def test_a_block_takes_its_soils_mean_else_its_datas_and_has_data_when_most_pixels_have():
    surface = np.array(
        [
            [1.0, 2.0, 5.0, 7.0, 9.0],
            [3.0, 6.0, 6.0, 8.0, 3.0],
            [1.0, np.nan, 2.0, 2.0, 4.0],
            [np.nan, np.nan, 2.0, 2.0, 4.0],
        ],
        np.float32,
    )
    soil = np.zeros(surface.shape, bool)
    soil[0, 0] = soil[1, 0] = True  # two of the first block's four pixels
    soil[1, 4] = True  # the edge block (one column) shows soil in its second row
    has_data = np.isfinite(surface)
    has_data[2, 2] = False  # the photo's no-data: three of four pixels left, still most
    coarse, bare, data = reduce_for_ground(surface, soil, has_data, 2)
    # [0, 0]: the soil's mean (1 + 3) / 2, not the block's 3.0; [0, 1]: no soil, the data's mean;
    # [0, 2]: the edge block's soil pixel alone (3, not the block's 6); [1, 0]: one pixel of four
    # has data: none; [1, 1]: the data's three pixels; [1, 2]: two of the edge block's two.
    expected = np.array([[2.0, 6.5, 3.0], [np.nan, 2.0, 4.0]], np.float32)
    np.testing.assert_array_equal(coarse, expected)
    assert bare.tolist() == [[True, False, True], [False, False, False]]
    assert data.tolist() == [[True, True, True], [False, True, True]]


def test_the_factor_takes_whole_pixels_up_to_5_cm_on_a_grid_100_pixels_across():
    assert ground_factor((4000, 3000), 0.01) == 5
    assert ground_factor((4000, 3000), 0.022) == 2  # soybean_pliman's 2.2 cm: a 4.4 cm grid
    assert ground_factor((1000, 300), 0.031) == 1  # ex1's 3.1 cm: its own grid
    assert ground_factor((1000, 300), 0.068) == 1  # the potato trial's 6.8 cm
    # A small, very fine photo keeps 100 pixels across for the soil's minimums (100 pixels).
    assert ground_factor((100, 100), 0.005) == 1 and ground_factor((250, 900), 0.005) == 2
    assert ground_factor((20000, 20000), 0.01, ground_pixels=8_000_000) == 8


@pytest.fixture(scope="module")
def field():
    from cliff_terrain.data.synthetic_surface import synthetic_surface
    from cliff_terrain.measure.canopy import plant_mask

    image, dsm, truth = synthetic_surface(shape=(600, 900), gsd=0.01, seed=3)
    return dsm, plant_mask(image), truth


def test_the_in_memory_ground_on_a_5_cm_grid_is_as_near_the_truth_as_the_full_grids(field):
    from cliff_terrain.io.raster.geotiff import GeoRaster
    from cliff_terrain.measure.canopy import measure_canopy

    dsm, plants, truth = field
    transform = np.array([[0.01, 0, 500_000.0], [0, -0.01, 5_000_000.0], [0, 0, 1]])
    canopy = measure_canopy(
        GeoRaster(dsm, transform, 32616, None, "dsm"), plants=plants, transform=transform, crs=32616
    )
    assert canopy.check["ground_pixel_m"] == pytest.approx(0.05)
    has = np.isfinite(dsm)
    full, _, _, check = fit_on_ground_grid(dsm, soil=~plants, has_data=has, pixel_size=0.01, factor=1)
    assert check["ground_pixel_m"] == 0.01 and check["method"] == canopy.check["method"]
    # Measured: the 5 cm grid's ground 0.9 cm above the full grid's (its blocks' soil means hold
    # the plants' edges), the truth 2.9 cm below it against 2.0 cm.
    assert np.median(np.abs(canopy.ground - full)[has]) < 0.012
    near_full = np.median(np.abs(full - truth.ground)[has])
    near_grid = np.median(np.abs(canopy.ground - truth.ground)[has])
    assert near_grid < near_full + 0.012
    assert canopy.sigma.shape == canopy.support.shape == dsm.shape
    # Per plot (1 m squares), the p90 within 1.5 cm of the full grid's.
    rows, cols = np.mgrid[: dsm.shape[0], : dsm.shape[1]]
    plot = (rows // 100) * 9 + cols // 100
    p90 = [
        np.nanpercentile(np.where(plot == k, dsm - g, np.nan), 90)
        for g in (canopy.ground, full)
        for k in range(54)
    ]
    assert np.max(np.abs(np.subtract(p90[:54], p90[54:]))) < 0.015


def test_the_baseline_on_the_ground_grid_is_the_naive_peer_to_the_digit(field):
    dsm, plants, _ = field
    has = np.isfinite(dsm)
    ground, _, _, check = fit_on_ground_grid(
        dsm, soil=~plants, has_data=has, pixel_size=0.01, factor=5, method="baseline"
    )
    assert check["method"] == "baseline" and check["ground_pixel_m"] == pytest.approx(0.05)
    expected = naive_block_ground(np.where(has, dsm, np.nan), pixel_size=0.01, percentile=2.0)
    np.testing.assert_array_equal(ground, expected)


def test_an_undeclared_no_data_marker_is_no_data_on_the_ground_grid(field):
    # OpenDroneMap's -3.4e38 where the file declares no no-data: a strip of it, on both grids and
    # for the baseline by name, leaves the ground on the field's surface (100-101 m here).
    dsm, plants, truth = field
    marked = dsm.copy()
    marked[:, 300:315] = -3.4e38
    has = np.ones(dsm.shape, bool)
    for factor in (1, 5):
        for method in ("auto", "baseline"):
            ground, sigma, _, _ = fit_on_ground_grid(
                marked, soil=~plants, has_data=has, pixel_size=0.01, factor=factor, method=method
            )
            assert np.nanmin(ground) > np.nanmin(truth.ground) - 0.5, (factor, method)
            assert np.nanmax(ground) < np.nanmax(dsm) and np.isfinite(sigma).all()


def test_the_baseline_chosen_by_the_check_is_the_candidate_it_measured(field, monkeypatch):
    # Chosen by the check (here made to choose it), the baseline is the ground grid's, upsampled:
    # the ground the check's error and support describe.
    from cliff_terrain.measure import ground as ground_module
    from cliff_terrain.measure.window_reading import upsample

    dsm, plants, _ = field
    real = ground_module.check_ground

    def prefer_baseline(*args, **kwargs):
        check, residuals = real(*args, **kwargs)
        return {**check, "chosen": "baseline"}, residuals

    monkeypatch.setattr(ground_module, "check_ground", prefer_baseline)
    has = np.isfinite(dsm)
    ground, _, _, check = fit_on_ground_grid(dsm, soil=~plants, has_data=has, pixel_size=0.01, factor=5)
    assert check["method"] == "baseline"
    coarse, _, _ = reduce_for_ground(np.where(has, dsm, np.nan), ~plants & has, has, 5)
    expected = naive_block_ground(coarse, pixel_size=0.05, percentile=2.0)
    np.testing.assert_array_equal(ground, upsample(expected, 5, 0, *dsm.shape[:1], 0, dsm.shape[1]))


def test_a_block_leaves_out_an_undeclared_no_data_marker():
    # The windowed path's first pass reduces the DSM as read (coarse_window): a -3.4e38 pixel the
    # file does not declare is left out of its block's mean, not averaged into it.
    surface = np.array([[1.0, 3.0, 2.0, 2.0], [-3.4e38, 2.0, 2.0, 2.0]], np.float32)
    coarse, _, data = reduce_for_ground(surface, np.zeros((2, 4), bool), np.ones((2, 4), bool), 2)
    np.testing.assert_array_equal(coarse, [[2.0, 2.0]])
    assert data.all()
