"""Dense canopies: soil enclosed by plants stays flat, and a closed canopy is a plateau at canopy height.

The oracle is ``synthetic_field(canopy="closed")``: rows of overlapping plants joined at their ends by
wide headland blocks, enclosing strips of soil, beside a row of isolated plants whose radius is the
canopy height. Its plant mask, soil strips and canopy height are known.
"""

import math

import cv2
import numpy as np
import pytest
from conftest import uav_image
from scipy import ndimage as ndi

from cliff_terrain import CliffTerrainError, build_relief, distance_map, inflate, segment
from cliff_terrain.data.synthetic import synthetic_field
from cliff_terrain.evaluate.mask_quality import mask_agreement, reference_mask, volume_fraction
from cliff_terrain.photo_heights.holes import plant_holes
from cliff_terrain.photo_heights.inflate import plateau_profile, typical_plant_radius
from cliff_terrain.photo_heights.quaternion import quaternion_filter


@pytest.fixture(scope="module")
def closed():
    image, truth = synthetic_field(canopy="closed", seed=0)
    return image, truth, build_relief(image, profile="plateau", two_sided=False)


def test_the_closed_field_encloses_soil_strips_between_joined_rows(closed):
    image, truth, _ = closed
    # The strips are soil (no plant pixel) that the frame cannot reach: the rows join at both ends.
    assert truth.strips.any() and not (truth.strips & truth.mask).any()
    filled = ndi.binary_fill_holes(truth.mask)
    np.testing.assert_array_equal(filled & ~truth.mask, truth.strips)
    n_strips = ndi.label(truth.strips)[1]
    assert n_strips >= 4
    # The isolated plants along the top touch nothing: each is its own component; their median
    # radius is the canopy height.
    top = truth.centres[:, 0] < 40
    assert ndi.label(truth.mask[: int(2 * truth.radii.max() + 6)])[1] == top.sum() >= 5
    assert truth.canopy_height == pytest.approx(np.median(truth.radii[top]))


def test_soil_strips_stay_flat_and_the_volume_stands_on_plants(closed):
    _, truth, relief = closed
    on_strips = 1.0 - volume_fraction(relief.heights, ~truth.strips)
    assert on_strips <= 0.01, f"{on_strips:.2%} of the volume stands on the enclosed soil strips"
    on_plants = volume_fraction(relief.heights, truth.mask)
    assert on_plants >= 0.90, f"only {on_plants:.1%} of the volume stands on plant pixels"
    # The mask itself: the strips are not filled.
    assert relief.mask[truth.strips].mean() < 0.05
    assert mask_agreement(relief.mask, truth.mask)["iou"] > 0.9


def test_the_closed_canopy_is_a_plateau_at_canopy_height(closed):
    _, truth, relief = closed
    # The core of the closed canopy: farther than two canopy heights from soil (the headlands).
    core = distance_map(truth.mask) >= 2 * truth.canopy_height
    assert core.sum() > 5000
    plateau = relief.heights[core]
    assert np.all(np.abs(plateau - truth.canopy_height) <= 0.1 * truth.canopy_height), (
        f"plateau {plateau.min():.1f}..{plateau.max():.1f} px, canopy height {truth.canopy_height:.1f} px"
    )
    # The paper's circular profile makes a dome of the same canopy, as tall as half its width.
    dome = build_relief(closed[0], profile="circular", two_sided=False).heights[core]
    assert np.median(dome) > 1.5 * truth.canopy_height


def test_isolated_plants_keep_the_papers_domes(closed):
    _, truth, relief = closed
    circular = inflate(relief.labels, profile="circular")
    top = np.zeros(truth.mask.shape, bool)
    top[: int(2 * truth.radii.max() + 6)] = True  # the isolated row
    np.testing.assert_allclose(relief.heights[top], circular[top], atol=1e-4)
    # Each of them is a hemisphere of its radius (to a pixel).
    for (r, c), radius in zip(truth.centres, truth.radii, strict=True):
        if r < 40:
            assert relief.heights[round(r), round(c)] == pytest.approx(radius, abs=1.5)


def test_leaf_gaps_and_highlights_are_filled_but_enclosed_soil_is_not():
    rr, cc = np.mgrid[:200, :300]
    image = np.empty((200, 300, 3), np.uint8)
    image[:] = (150, 112, 80)  # soil
    plant = np.hypot(rr - 100, cc - 75) <= 60
    image[plant] = (50, 140, 45)
    gap = np.hypot(rr - 80, cc - 60) <= 3  # soil seen through the leaves: small
    image[gap] = (150, 112, 80)
    highlight = np.hypot(rr - 115, cc - 95) <= 12  # a specular highlight: large but white
    image[highlight] = (235, 240, 235)
    ring = (np.abs(rr - 100) <= 70) & (np.abs(cc - 220) <= 70)
    image[ring] = (50, 140, 45)
    soil = (np.abs(rr - 100) <= 40) & (np.abs(cc - 220) <= 40)  # soil enclosed by canopy
    image[soil] = (150, 112, 80)
    seg = segment(image)
    assert seg.mask[gap].all() and seg.mask[highlight].all()
    # The blur of the index moves the soil's edge by a pixel; its interior stays flat.
    assert not seg.mask[ndi.binary_erosion(soil, iterations=2)].any()
    # The paper's Algorithm 2 fills every hole (imfill): its mask has none.
    paper = segment(image, method="paper", filtered=quaternion_filter(image))
    np.testing.assert_array_equal(ndi.binary_fill_holes(paper.mask), paper.mask)


def test_plant_holes_keeps_small_or_not_soil_coloured_holes():
    mask = np.zeros((60, 60), bool)
    mask[5:55, 5:55] = True
    mask[10:12, 10:12] = False  # small
    mask[20:50, 30:34] = False  # a strip: 5 % of the region
    holes = np.zeros_like(mask)
    holes[5:55, 5:55] = ~mask[5:55, 5:55]
    vi = np.where(mask, 0.4, -0.2).astype(np.float32)
    filled = plant_holes(mask, holes, vi, 0.1)
    assert filled[10:12, 10:12].all() and not filled[20:50, 30:34].any()
    vi[20:50, 30:34] = 0.05  # not soil-coloured (above the midpoint of soil and threshold)
    assert plant_holes(mask, holes, vi, 0.1)[20:50, 30:34].all()


def test_plateau_follows_the_circular_rim_then_levels_off():
    labels = np.zeros((80, 300), np.int32)
    labels[10:70, 10:290] = 1  # 60 px wide
    d = distance_map(labels > 0)
    h = plateau_profile(labels, 12.0)
    rim = (labels > 0) & (d < 12)
    np.testing.assert_allclose(h[rim], np.sqrt(12.0**2 - (12.0 - d[rim]) ** 2), rtol=1e-5)
    assert np.all(h[d >= 12] == pytest.approx(12.0))
    # A region narrower than the canopy height is the circular profile's dome.
    small = np.zeros((40, 40), np.int32)
    small[np.hypot(*np.mgrid[-20:20, -20:20]) <= 8] = 1
    np.testing.assert_allclose(plateau_profile(small, 30.0), inflate(small, profile="circular"), atol=1e-5)


def test_default_canopy_height_is_the_radius_of_a_typical_isolated_plant():
    _, truth = synthetic_field(seed=2)
    relief = build_relief(synthetic_field(seed=2)[0], profile="plateau", two_sided=False)
    estimate = typical_plant_radius(relief.labels)
    assert estimate == pytest.approx(np.median(truth.radii), rel=0.1)


def test_canopy_height_in_metres_with_a_gsd(closed):
    image, _, _ = closed
    relief = build_relief(image, profile="plateau", max_height=0.05, gsd=0.01, two_sided=False)
    assert relief.units == "m"
    assert relief.max_height == pytest.approx(0.05, rel=1e-5)
    # Without a GSD, pixels; as a cap on the circular profile.
    relief = build_relief(image, profile="circular", max_height=7, two_sided=False)
    assert relief.max_height == pytest.approx(7.0)


@pytest.mark.parametrize("bad", [0, -1.0, math.nan, math.inf, -math.inf])
def test_bad_max_height_is_refused_naming_it(bad):
    image, _ = synthetic_field(shape=(64, 64), n_rows=1, radius_range=(5, 8), spacing=20)
    with pytest.raises(CliffTerrainError, match=r"`max_height` must be"):
        build_relief(image, max_height=bad)
    with pytest.raises(
        CliffTerrainError, match=r"`max_height` must be .*" + str(float(bad)).replace("+", "")
    ):
        inflate(np.ones((5, 5), np.int32), profile="plateau", max_height=bad)
    with pytest.raises(CliffTerrainError, match=r"`max_height` must be a number, got 'tall'"):
        build_relief(image, max_height="tall")


def test_an_image_that_is_all_canopy_builds_a_plateau():
    rng = np.random.default_rng(0)
    image = np.clip(rng.normal((50, 140, 45), 12, (300, 400, 3)), 0, 255).astype(np.uint8)
    relief = build_relief(image, profile="plateau", two_sided=False)
    assert relief.mask.all()
    top = relief.max_height
    assert 0 < top < 0.1 * min(relief.heights.shape)  # not a dome half the frame high
    assert np.mean(relief.heights >= top - 1e-4) > 0.5  # mostly level
    relief = build_relief(image, profile="plateau", max_height=9, two_sided=False)
    assert relief.max_height == pytest.approx(9.0)


def test_an_image_without_plants_builds_a_flat_relief():
    rng = np.random.default_rng(1)
    image = np.clip(rng.normal((150, 112, 80), 8, (200, 300, 3)), 0, 255).astype(np.uint8)
    for max_height in (None, 5.0):
        relief = build_relief(image, profile="plateau", max_height=max_height, two_sided=False)
        assert relief.max_height == 0.0


def test_reference_masks_agree_with_the_drawn_plants():
    image, truth = synthetic_field(seed=4)
    for index in ("exg", "lab_a"):
        assert mask_agreement(reference_mask(image, index=index), truth.mask)["iou"] > 0.85


@pytest.mark.parametrize(
    "relative", ["broccoli/01_clip_raw_test.jpg", "lamberton_soybean/20180829_Lamberton_clipped.tif"]
)
def test_dense_real_canopies_agree_with_an_independent_mask_and_stay_on_it(relative):
    # Pale broccoli is lost by ExG; CIELAB a* with Otsu keeps it (an independent reference).
    relief = build_relief(uav_image(relative), max_size=1000, two_sided=False)
    valid = None
    if relief.metadata.valid_mask is not None:
        size = relief.working.shape[1::-1]
        valid = (
            cv2.resize(relief.metadata.valid_mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
        )
    reference = reference_mask(relief.working, index="lab_a", valid=valid)
    assert mask_agreement(relief.mask, reference)["iou"] > 0.8
    assert volume_fraction(relief.heights, reference) > 0.9


def test_auto_profile_is_the_plateau_for_vegetation_and_the_papers_circle_for_paper(closed):
    image, _, plateau = closed
    relief = build_relief(image, two_sided=False)  # profile="auto", the default
    assert relief.params["profile"] == "plateau"
    np.testing.assert_array_equal(relief.heights, plateau.heights)
    paper = build_relief(image, segmentation="paper", two_sided=False)
    assert paper.params["profile"] == "circular"
    # The build's D comes with the watershed, component by component, within a float32 rounding of
    # distance_map's (OpenCV's transform rounds by its buffers' alignment); a dome's rim, where H
    # is steep in D, turns that into at most Dmax ulps of D.
    np.testing.assert_allclose(paper.heights, inflate(paper.labels, profile="circular"), rtol=0, atol=1e-4)
