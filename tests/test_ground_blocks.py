"""The DSM's block percentiles (:mod:`cliff_terrain.measure.ground_blocks`) on the shapes real
rasters have: an orthomosaic's no-data outline on a slope, a block larger than the field, and a
flat or quantized surface (cases a review found on 2026-12-06)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from cliff_terrain.measure.ground import fit_ground
from cliff_terrain.measure.ground_blocks import naive_block_ground

PX = 0.05


def sloped_field(rows, cols, slope, *, outline=None):
    """Soil on a plane rising `slope` down the rows, 0.5 m plants on a 1.2 m grid, 5 mm noise; NaN
    outside `outline` (a function of rows, cols)."""
    rr, cc = np.mgrid[:rows, :cols]
    ground = 100.0 + slope * rr * PX
    plants = np.hypot(rr % 24 - 12, cc % 24 - 12) < 8
    noise = 0.005 * np.random.default_rng(0).standard_normal((rows, cols))
    dsm = (ground + 0.5 * plants + noise).astype(np.float32)
    inside = np.ones(dsm.shape, bool) if outline is None else outline(rr, cc)
    dsm[~inside] = np.nan
    return dsm, ~plants, ground, inside


@pytest.mark.parametrize("slope, before_cm", [(0.1, 15.7), (0.3, 55.3)])
def test_an_orthomosaics_no_data_corners_do_not_flatten_the_fields_plane(slope, before_cm):
    # A diamond of data in its raster, as a field flown at 45 degrees to north is: the corner blocks
    # have no data. They used to enter the field's plane at the median level, flattening it, and the
    # ground stood `before_cm` off on the bare soil at the field's edges, the check passing.
    dsm, soil, ground, inside = sloped_field(
        600, 600, slope, outline=lambda r, c: abs(r - 300) + abs(c - 300) < 300
    )
    fit = fit_ground(dsm, soil=soil, pixel_size=PX)
    error = np.abs(fit.ground - ground)
    bound = 0.01 if slope <= 0.1 else 0.03  # measured 0.7 and 2.3 cm: cut blocks still count at their centres
    assert error[fit.evidence].max() < bound
    assert error[inside].max() < bound


def test_a_block_larger_than_the_field_is_the_field_and_takes_its_memory():
    dsm, _, _, _ = sloped_field(200, 200, 0.0)
    whole = naive_block_ground(dsm, pixel_size=PX, block_m=200 * PX, percentile=2.0)
    tracemalloc.start()
    try:
        huge = naive_block_ground(dsm, pixel_size=PX, block_m=1500.0, percentile=2.0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(huge, whole)
    # Padded to the block's own size it took 30 000 x 30 000 floats (3.6 GB at 1000 m).
    assert peak < 20 * dsm.nbytes
    fit = fit_ground(dsm, soil=None, pixel_size=PX, block_m=1500.0)
    assert np.isfinite(fit.ground).all()


@pytest.mark.parametrize(
    "name",
    [
        "flat, all soil",
        "flat, no photo",
        "a noiseless bare slope",
        "plants on flat soil, heights in whole cm",
    ],
)
def test_a_flat_or_quantized_surface_gets_a_ground(name):
    # Every soil pixel within 2 cm: the soil band's histogram had fewer bins than its smoothing
    # kernel, and fit_ground raised IndexError.
    rr, cc = np.mgrid[:300, :300]
    plants = np.hypot(rr % 24 - 12, cc % 24 - 12) < 8
    flat = np.full((300, 300), 100.0, np.float32)
    dsm, soil, truth = {
        "flat, all soil": (flat, np.ones((300, 300), bool), flat),
        "flat, no photo": (flat, None, flat),
        "a noiseless bare slope": (
            (100.0 + 0.0025 * cc).astype(np.float32),
            np.ones((300, 300), bool),
            100.0 + 0.0025 * cc,
        ),
        "plants on flat soil, heights in whole cm": (
            (np.round((100.0 + 0.5 * plants) * 100) / 100).astype(np.float32),
            ~plants,
            flat,
        ),
    }[name]
    fit = fit_ground(dsm, soil=soil, pixel_size=PX)
    assert np.abs(fit.ground - truth).max() < 0.01, fit.method


def test_blocks_that_hold_soil_keep_their_level_and_the_others_take_their_neighbours():
    from cliff_terrain.measure.ground_blocks import block_levels

    rng = np.random.default_rng(3)
    rr, cc = np.mgrid[:105, :130]  # 20 x 20 px blocks: the last row and column of blocks cut short
    dsm = (0.002 * cc + 0.005 * rng.standard_normal(rr.shape)).astype(np.float32)
    closed = (rr >= 40) & (rr < 80) & (cc >= 40) & (cc < 80)  # four blocks wholly under a canopy
    dsm[closed] += 0.6
    blocks = block_levels(dsm, pixel_size=0.05, block_m=1.0)
    # Every block shows soil: the surface is the lowest surface's, to the bit.
    np.testing.assert_array_equal(blocks.surface(soil=np.ones(dsm.shape, bool)), blocks.surface())
    soil = ~closed
    # 2 % of a block is the percentile's share: one pixel short of it in the cut-short corner
    # block (5 x 10 pixels inside the raster) leaves it soil-less, exactly 2 % keeps it.
    corner = (rr >= 100) & (cc >= 120)
    soil_short = soil & ~corner
    assert blocks._soil_levels(soil_short)[5, 6] != blocks.levels[5, 6]
    soil_short[104, 129] = True  # 1 of its 50 pixels
    assert blocks._soil_levels(soil_short)[5, 6] == blocks.levels[5, 6]
    lowest, from_soil = blocks.surface(), blocks.surface(soil)
    # Under the canopy the blocks' own level is its top; from the soil around it, the field's.
    assert np.median((lowest - 0.002 * cc)[closed]) > 0.4
    assert np.abs(from_soil - 0.002 * cc)[closed].max() < 0.03
    # Blocks that hold soil keep their own level: away from the canopy's blocks nothing moves.
    far = (rr < 20) | (rr >= 100) | (cc < 20) | (cc >= 100)
    np.testing.assert_array_equal(from_soil[far], lowest[far])


def test_a_block_half_outside_the_outline_is_judged_by_its_pixels_with_data():
    from cliff_terrain.measure.ground_blocks import block_levels

    dsm = np.full((40, 40), 0.6, np.float32)  # a canopy everywhere, four 20 x 20 px blocks
    dsm[:, 30:] = np.nan  # the outline cuts the right-hand blocks in half: 200 pixels with data each
    soil = np.zeros(dsm.shape, bool)
    soil[:20, :20] = True  # the top-left block is bare
    dsm[soil] = 0.0
    soil[0, 20:25] = True  # 5 of the top-right block's 200 pixels with data (2.5 %; of its 400, 1.25 %)
    dsm[0, 20:25] = 0.0
    blocks = block_levels(dsm, pixel_size=0.05, block_m=1.0)
    levels = blocks._soil_levels(soil)
    assert levels[0, 1] == blocks.levels[0, 1]  # it holds soil: its own level
    assert levels[1, 0] != blocks.levels[1, 0] and levels[1, 1] != blocks.levels[1, 1]


def test_soil_less_blocks_take_the_soil_blocks_level_and_their_plane_beyond():
    from cliff_terrain.measure.ground_blocks import block_levels

    # A closed canopy 0.5 m tall rising 0.4 m along 30 m, bare soil only in a headland 3 m wide.
    # The field's plane goes through every block's level and this canopy tilts it (0.37 m at the
    # far end when the fill followed it); the soil-less blocks follow the plane through the blocks
    # that hold soil instead: over flat ground, flat; over a tilted one, its tilt. Never the
    # canopy's own lowest pixels.
    rr, cc = np.mgrid[:120, :600]
    canopy = cc >= 60
    for ground in (np.zeros(rr.shape), 0.003 * cc + 0.001 * rr):
        dsm = (ground + np.where(canopy, 0.5 + 0.4 * cc / 600, 0.0)).astype(np.float32)
        blocks = block_levels(dsm, pixel_size=0.05, block_m=1.0)
        assert np.median((dsm - blocks.surface())[canopy]) < 0.05  # alone: the canopy's top
        lowest = blocks.surface(soil=~canopy)
        assert np.abs(lowest - ground)[canopy].max() < 0.01
        # Fewer than three blocks with soil make no plane: the field's is kept.
        assert not blocks._soil_tilt(np.zeros(blocks.levels.shape, bool)).any()
    with pytest.raises(Exception, match="`soil` must have the surface's shape"):
        blocks.surface(soil=np.ones((5, 5), bool))


def test_soil_blocks_in_one_row_or_column_give_no_slope_across_it_at_any_elevation():
    from cliff_terrain.measure.ground_blocks import block_count, block_levels

    # A headland one block deep (a strip cut along a field's edge), at a real field's elevation: a
    # plane through one row of blocks has no slope across it. Fitted anyway, its noise took the
    # ground hundreds of metres off; the field's slope is kept across it instead, and the filled
    # blocks stay as near as the field's plane puts them (never the canopy's top).
    rng = np.random.default_rng(0)
    rr, cc = np.mgrid[:120, :600]
    layouts = {
        "one column": cc < 20,
        "one row": rr < 20,
        "a column and one stray block": (cc < 20) | ((rr < 20) & (cc >= 300) & (cc < 320)),
    }
    for name, soil in layouts.items():
        dsm = (250.0 + np.where(soil, 0.0, 0.5) + rng.normal(0, 0.01, rr.shape)).astype(np.float32)
        blocks = block_levels(dsm, pixel_size=0.05, block_m=1.0)
        tilt = blocks._soil_tilt(block_count(soil, blocks.block) > 0)
        # One position down the rows (30 across): a slope along the row only; and the other way.
        assert np.ptp(tilt, axis=0 if name == "one row" else 1).max() == 0, name
        lowest = blocks.surface(soil=soil)
        assert np.abs(lowest - 250.0)[~soil].max() < 0.4, name
