"""Segmentation: plants found on the synthetic oracle and on real, georeferenced soybean plots."""

import json
import re

import numpy as np
import pytest
import tifffile
from conftest import uav_image
from skimage.draw import polygon

from cliff_terrain import (
    CliffTerrainError,
    build_relief,
    load_image,
    quaternion_filter,
    resize_longest,
    segment,
    synthetic_field,
    vegetation_index,
)
from cliff_terrain.photo_heights.watershed import split_regions


def test_vegetation_mode_finds_every_synthetic_plant():
    image, truth = synthetic_field(shape=(600, 900), seed=7)
    seg = segment(image, filtered=quaternion_filter(image))
    assert abs(seg.n_regions - truth.n_plants) <= 0.05 * truth.n_plants
    # Each true centre lies in a region, and each region holds one centre.
    rc = np.round(truth.centres).astype(int)
    hit = seg.labels[rc[:, 0], rc[:, 1]]
    assert np.all(hit > 0)
    assert np.unique(hit).size == truth.n_plants
    iou = (seg.mask & truth.mask).sum() / (seg.mask | truth.mask).sum()
    assert iou > 0.9


def test_paper_mode_thresholds_brightness_and_raises_the_bright_soil():
    # The synthetic plants are darker than the soil: taken literally, Algorithm 2 raises the soil.
    image, truth = synthetic_field(shape=(300, 450), n_rows=3, seed=2)
    seg = segment(image, method="paper", filtered=quaternion_filter(image))
    assert seg.index == "grey"
    soil = ~truth.mask
    assert (seg.mask & soil).sum() > 0.5 * soil.sum()
    # The vegetation mode leaves that soil flat.
    veg = segment(image, filtered=quaternion_filter(image))
    assert (veg.mask & soil).sum() < 0.02 * soil.sum()


def test_touching_plants_are_split_by_the_watershed():
    rr, cc = np.mgrid[:80, :140]
    mask = (np.hypot(rr - 40, cc - 45) <= 25) | (np.hypot(rr - 40, cc - 92) <= 25)
    from cliff_terrain import distance_map

    labels = split_regions(mask, distance_map(mask))
    assert labels.max() == 2
    assert labels[40, 45] != labels[40, 92]
    # A long single leaf (an ellipse) is not broken into beads.
    leaf = ((rr - 40) / 10.0) ** 2 + ((cc - 70) / 60.0) ** 2 <= 1
    assert split_regions(leaf, distance_map(leaf)).max() == 1


def test_vegetation_index_orders_plants_soil_and_grey():
    px = np.array(
        [[[52, 128, 44], [114, 144, 145], [200, 190, 60], [150, 112, 80], [128, 128, 128], [60, 70, 95]]],
        np.uint8,
    )
    vi, name = vegetation_index(px)
    green, bluish_broccoli, yellow_canopy, soil, grey, blue_tarp = vi[0]
    assert name == "green"
    assert min(green, bluish_broccoli, yellow_canopy) > 0.15
    assert max(soil, grey, blue_tarp) < 0.02


def test_false_colour_nir_frame_is_detected(shared_uav):
    from cliff_terrain import load_image, resize_longest

    image, _ = load_image(uav_image("seneca_nir/IMG_0505.jpg"), max_size=400)
    vi, name = vegetation_index(resize_longest(image, 400))
    assert name == "nir"
    rgb, _ = load_image(uav_image("broccoli/01_clip_raw_test.jpg"), max_size=400)
    assert vegetation_index(resize_longest(rgb, 400))[1] == "green"


def test_grey_pixels_do_not_make_a_photo_a_nir_frame(shared_uav):
    # Grey pixels (R = G = B) have every channel the weakest: a greyscale orthophoto, and a colour
    # photo of sparse seedlings on grey gravel, were read as false-colour NIR frames, whose index
    # (R - B) / (R + B) is 0 on green leaves. The NIR frame stays one with grey pixels among it.
    from cliff_terrain import load_image, resize_longest

    rng = np.random.default_rng(0)
    grey = np.repeat(rng.integers(60, 200, (200, 300), dtype=np.uint8)[..., None], 3, axis=2)
    assert vegetation_index(grey)[1] == "green"
    seedlings = grey.copy()
    seedlings[::40, ::40] = (60, 140, 50)  # 0.06 % of the pixels: a seedling every 40 pixels
    vi, name = vegetation_index(seedlings)
    assert name == "green" and vi[::40, ::40].min() > 0.15 and np.median(vi) < 0.02
    nir, _ = load_image(uav_image("seneca_nir/IMG_0505.jpg"), max_size=400)
    nir = resize_longest(nir, 400).copy()
    half = rng.integers(60, 200, (nir.shape[0] // 2, nir.shape[1]), dtype=np.uint8)
    nir[: nir.shape[0] // 2] = half[..., None]  # half of it grey
    assert vegetation_index(nir)[1] == "nir"


def _plot_mask(tif, shape):
    """Rasterise the plot polygons (EPSG:32615) onto a grid of `shape` over the GeoTIFF."""
    page = tifffile.TiffFile(tif).pages[0]
    sx, sy, _ = page.tags["ModelPixelScaleTag"].value
    tie = page.tags["ModelTiepointTag"].value
    rows0, cols0 = page.shape[:2]
    plots = json.loads((tif.parent / "plots.geojson").read_text())
    mask = np.zeros(shape, bool)
    for feature in plots["features"]:
        xy = np.asarray(feature["geometry"]["coordinates"][0])
        cols = (xy[:, 0] - tie[3]) / sx * shape[1] / cols0
        rows = (tie[4] - xy[:, 1]) / sy * shape[0] / rows0
        r, c = polygon(rows, cols, shape)
        mask[r, c] = True
    return mask


@pytest.mark.parametrize("date", ["20180815", "20180822", "20180905", "20180914"])
def test_relief_stands_on_the_soybean_plots(date):
    tif = uav_image(f"lamberton_soybean/{date}_Lamberton_clipped.tif")
    relief = build_relief(tif, max_size=1000)
    plots = _plot_mask(tif, relief.heights.shape)
    inside = relief.heights[plots].sum() / relief.heights.sum()
    assert inside >= 0.9, f"only {inside:.1%} of the relief volume is on the plots"


def test_bare_stubble_stays_flat():
    tif = uav_image("lamberton_soybean/20180925_Lamberton_clipped.tif")
    relief = build_relief(tif, max_size=1000)
    assert relief.mask.mean() < 0.01


def test_segment_rejects_bad_arguments():
    img = np.zeros((10, 10, 3), np.uint8)
    with pytest.raises(CliffTerrainError, match="`method` must be one of 'vegetation', 'paper', got 'otsu'"):
        segment(img, method="otsu")
    with pytest.raises(CliffTerrainError, match="`filtered` is required when `method` is 'paper', got None"):
        segment(img, method="paper")
    with pytest.raises(CliffTerrainError, match=r"`filtered` must have the shape of `image` \(10, 10, 3\)"):
        segment(img, filtered=np.zeros((5, 5, 3), np.float32))
    with pytest.raises(CliffTerrainError, match="`index` must be one of 'auto', 'green', 'nir', got 'ndvi'"):
        vegetation_index(img, index="ndvi")
    with pytest.raises(CliffTerrainError, match=r"`image` must have shape \(rows, cols, 3\), got \(10, 10\)"):
        segment(np.zeros((10, 10), np.uint8))


def test_cleaning_matches_scipy_and_skimage():
    # The OpenCV speck removal and hole filling give exactly what bwareaopen + imfill (SciPy's
    # 8-connected labels with their sizes, binary_fill_holes) give. Not scikit-image's
    # remove_small_objects: 0.26 changed its size parameter.
    from scipy import ndimage as ndi

    from cliff_terrain.photo_heights.holes import clean_mask

    rng = np.random.default_rng(0)
    for i in range(12):
        mask = rng.random((60, 80)) > 0.55
        if i % 2:
            mask = ndi.binary_opening(mask)
        labels, _ = ndi.label(mask, structure=np.ones((3, 3)))
        sizes = np.bincount(labels.ravel())
        expected = ndi.binary_fill_holes(mask & (sizes[labels] >= 5))
        np.testing.assert_array_equal(clean_mask(mask, 5), expected)


def test_colour_edges_are_the_distance_from_the_grey_axis():
    from cliff_terrain.photo_heights.watershed import colour_edges

    rng = np.random.default_rng(1)
    f = rng.normal(size=(9, 11, 3)).astype(np.float32)
    grey = f.mean(axis=2, keepdims=True)
    np.testing.assert_allclose(colour_edges(f), np.linalg.norm(f - grey, axis=2), rtol=1e-5, atol=1e-6)


def test_inner_boundaries_match_scikit_image():
    from skimage.segmentation import find_boundaries

    from cliff_terrain.photo_heights.labels import inner_boundaries

    image, _ = synthetic_field(shape=(240, 360), seed=5)
    labels = segment(image).labels
    labels[100:140, 100:200] = labels.max() + 1  # touching regions too
    expected = find_boundaries(labels, mode="inner", connectivity=1) & (labels > 0)
    np.testing.assert_array_equal(inner_boundaries(labels), expected)


@pytest.mark.parametrize(("seed", "threads"), [(seed, threads) for seed in range(4) for threads in (1, 2, 4)])
def test_components_flooded_in_groups_are_one_watershed_to_the_pixel(seed, threads, monkeypatch):
    """Components flooded one at a time in threads, each on its bounding box, give exactly
    scikit-image's single watershed: plateaus (few levels) are where the queue's order decides.
    The markers' own levels differ: between equal ones the heap's layout decides (see
    _flood_components)."""
    import cv2
    from skimage.segmentation import watershed

    import cliff_terrain.photo_heights.watershed as flooding

    monkeypatch.setattr(flooding, "_POOL_PIXELS", 1)
    monkeypatch.setattr(flooding, "_FLOOD_THREADS", threads)
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(60, 160)), int(rng.integers(60, 160)))
    landscape = rng.integers(0, 3, shape).astype(np.float64)
    # Blobs of random sizes (many touch, some share rows), a few markers in each.
    mask = np.zeros(shape, bool)
    for _ in range(30):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        mask[
            max(r - rng.integers(1, 12), 0) : r + rng.integers(1, 12), max(c - 8, 0) : c + rng.integers(1, 8)
        ] = True
    count, components, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=4)
    markers = np.zeros(shape, np.int32)
    seeds = mask & (rng.random(shape) < 0.03)
    markers[seeds] = np.arange(1, int(seeds.sum()) + 1)
    landscape[seeds] = -rng.permutation(int(seeds.sum()))  # below the plateaus, all different
    flooded = rng.random(count) < 0.8
    flooded[0] = False
    assert flooded.sum() >= 4, "enough components for the threads"
    result = flooding._flood_components(landscape, markers, components, flooded, stats)
    expected = watershed(landscape, markers, mask=flooded[components], connectivity=1)
    np.testing.assert_array_equal(result, expected)


def test_a_real_photo_splits_the_same_with_one_thread_or_several(monkeypatch):
    import cliff_terrain.photo_heights.watershed as flooding

    image, _ = load_image(uav_image("caliterra/IMG_9370.jpg"))
    image = resize_longest(image, 1500)
    parallel = segment(image, filtered=quaternion_filter(image))
    monkeypatch.setattr(flooding, "_FLOOD_THREADS", 1)
    np.testing.assert_array_equal(segment(image, filtered=quaternion_filter(image)).labels, parallel.labels)
    assert parallel.n_regions > 100


@pytest.mark.parametrize("seed", range(8))
def test_the_region_distance_from_the_flood_is_the_whole_images_map(seed):
    """`split_regions(return_distance=True)` measures each split component on its bounding box
    only; blobs that touch diagonally, the frame and narrow necks are where a crop could go wrong.
    Values may differ by one float32 rounding (OpenCV's transform of another array), no more."""
    from cliff_terrain.photo_heights.labels import distance_map

    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(40, 120)), int(rng.integers(40, 120)))
    mask = np.zeros(shape, bool)
    for _ in range(25):  # overlapping discs and bars: necks, diagonal contacts, blobs on the frame
        r, c, radius = rng.integers(0, shape[0]), rng.integers(0, shape[1]), rng.integers(2, 10)
        rr, cc = np.ogrid[: shape[0], : shape[1]]
        mask |= (rr - r) ** 2 + (cc - c) ** 2 <= radius**2
        mask[r : r + 2, c : c + rng.integers(3, 30)] = True
    distance = distance_map(mask)
    labels, region_distance = split_regions(mask, distance, radius=3, return_distance=True)
    assert labels.max() > label_count(mask), "the watershed split something"
    np.testing.assert_array_max_ulp(region_distance, distance_map(labels), maxulp=1)
    np.testing.assert_array_equal(labels, split_regions(mask, distance, radius=3))


def label_count(mask):
    from cliff_terrain.photo_heights.labels import label4

    return label4(mask)[1]


def test_the_region_distance_without_ground_or_without_a_split():
    from cliff_terrain.photo_heights.labels import distance_map

    # No flat pixel: the map measures to the frame, as distance_map does for a full mask.
    full = np.ones((30, 61), bool)
    rr, cc = np.mgrid[:30, :61]
    peaks = np.maximum(20 - np.hypot(rr - 15, cc - 15), 20 - np.hypot(rr - 15, cc - 45)).astype(np.float32)
    labels, region_distance = split_regions(full, peaks, radius=3, return_distance=True)
    assert labels.max() == 2
    # OpenCV's exact transform itself rounds differently by a float32 ulp with its buffers' alignment.
    np.testing.assert_array_max_ulp(region_distance, distance_map(labels), maxulp=1)
    # Nothing split: the mask's own map, not a copy.
    one = np.zeros((30, 30), bool)
    one[5:20, 5:20] = True
    distance = distance_map(one)
    labels, region_distance = split_regions(one, distance, return_distance=True)
    assert labels.max() == 1 and region_distance is distance
    labels, region_distance = split_regions(
        np.zeros((9, 9), bool), np.zeros((9, 9), np.float32), return_distance=True
    )
    assert labels.max() == 0 and not region_distance.any()


@pytest.mark.parametrize("method", ["vegetation", "paper"])
def test_real_photos_region_distance_is_the_labels_distance_map(shared_uav, method):
    """On real photos (at 1000 px, both modes) the inflation's D computed with the watershed is
    ``distance_map(labels)`` to within one float32 rounding."""
    from cliff_terrain.photo_heights.labels import distance_map

    photos = sorted(
        p for p in shared_uav.rglob("*") if p.suffix.lower() in (".jpg", ".tif") and "plantcv" not in str(p)
    )
    assert len(photos) >= 10
    split = 0
    for photo in photos:
        image = resize_longest(load_image(photo)[0], 1000)
        seg = segment(image, method=method, filtered=quaternion_filter(image))
        np.testing.assert_array_max_ulp(seg.region_distance, distance_map(seg.labels), maxulp=1)
        split += seg.region_distance is not seg.distance
    assert split >= 5, "the watershed split regions on most photos"


@pytest.mark.parametrize("seed", range(6))
def test_flood_is_scikit_images_watershed(seed):
    from skimage.segmentation import watershed

    from cliff_terrain.photo_heights.watershed import _flood

    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 60)), int(rng.integers(1, 60)))
    # Few levels: plateaus, where the order of the queue decides.
    landscape = rng.integers(0, 4, shape).astype(np.float32)
    mask = rng.random(shape) < 0.8
    markers = np.zeros(shape, np.int32)
    seeds = rng.random(shape) < 0.05
    markers[seeds] = rng.integers(1, 9, int(seeds.sum()))
    flooded = _flood(landscape, markers, mask)
    np.testing.assert_array_equal(flooded, watershed(landscape, markers, mask=mask))


def test_the_flood_kernel_is_scikit_images_own_and_its_neighbour_order():
    # The kernel is loaded from its file (not through skimage.segmentation's slow __init__): it must
    # be the compiled kernel itself, not the public fallback, and visit neighbours in skimage's order.
    from skimage.morphology._util import _offsets_to_raveled_neighbors, _validate_connectivity
    from skimage.segmentation import _watershed_cy

    import cliff_terrain.photo_heights.watershed as flooding

    assert flooding._watershed_raveled is not None
    assert flooding._watershed_raveled.__module__ == _watershed_cy.__name__
    assert flooding._watershed_raveled.__qualname__ == _watershed_cy.watershed_raveled.__qualname__
    footprint, centre = _validate_connectivity(2, 1, None)
    for shape in [(3, 3), (5, 7), (100, 3), (3, 100), (4098, 3002)]:
        np.testing.assert_array_equal(
            flooding._neighbour_offsets(shape), _offsets_to_raveled_neighbors(shape, footprint, center=centre)
        )


def test_otsu_is_scikit_images_on_real_indices_and_odd_histograms(shared_uav):
    from skimage.filters import threshold_otsu

    from cliff_terrain.photo_heights.histogram import _otsu
    from cliff_terrain.photo_heights.vegetation import blurred_index

    samples = []
    for path in sorted(shared_uav.rglob("*")):
        if path.suffix.lower() in (".jpg", ".jpeg", ".png", ".tif", ".tiff"):
            try:
                image, _ = load_image(path, max_size=600)
            except CliffTerrainError:
                continue  # not an RGB photo (a DSM, a single band)
            samples.append(blurred_index(resize_longest(image, 600))[0].ravel())
    assert len(samples) >= 10
    rng = np.random.default_rng(3)
    samples += [
        rng.normal(0, 1, 5000),  # one class
        np.concatenate([rng.normal(-1, 0.2, 3000), rng.normal(2, 0.5, 800)]),  # two
        np.array([0.0, 1.0]),  # two values
        np.concatenate([np.zeros(500), np.full(3, 1e-9)]),  # a range of a few ulps around 0
        rng.integers(0, 5, 1000).astype(np.float64),  # few levels: empty bins between
    ]
    for values in samples:
        values = values.astype(np.float64)
        assert _otsu(values) == float(threshold_otsu(values))


def _dark_wet_soil_field(seed=0):
    """Green plants on dark, wet soil whose excess green is high (0.2-0.4): the band's clamp raises it."""
    rng = np.random.default_rng(seed)
    rows, cols = 240, 320
    soil = np.array([38.0, 46.0, 30.0])  # dark, slightly greenish: index about 0.3
    rgb = soil * (1.0 + 0.15 * rng.standard_normal((rows, cols, 1))) + rng.normal(0, 2.0, (rows, cols, 3))
    truth = np.zeros((rows, cols), bool)
    rr, cc = np.mgrid[:rows, :cols]
    for r in range(30, rows, 60):
        for c in range(30, cols, 60):
            truth |= np.hypot(rr - r, cc - c) < 14 + 4 * rng.random()
    leaves = np.array([55.0, 150.0, 45.0]) * (1.0 + 0.1 * rng.standard_normal((rows, cols, 1)))
    rgb[truth] = leaves[truth]
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8), truth


def test_dark_wet_soil_gets_the_photos_own_threshold():
    from cliff_terrain.evaluate.mask_quality import mask_agreement
    from cliff_terrain.photo_heights.vegetation import _GREEN_BAND

    image, truth = _dark_wet_soil_field()
    vi, _ = vegetation_index(image)
    assert np.percentile(vi[~truth], 50) > _GREEN_BAND[1]  # the soil itself lies above the band
    seg = segment(image)
    assert seg.threshold_source == "photo" and seg.threshold > _GREEN_BAND[1]
    assert mask_agreement(seg.mask, truth)["iou"] > 0.9
    # The relief stands on the plants, and the choice is recorded in the relief's parameters.
    relief = build_relief(image, mesh=None)
    on_plants = relief.heights[truth].sum() / relief.heights.sum()
    assert on_plants > 0.95
    assert relief.params["threshold"]["source"] == "photo"
    assert relief.params["threshold"]["value"] == pytest.approx(seg.threshold, abs=1e-4)


def test_a_closed_canopy_is_not_split_into_sunlit_and_shaded_leaves():
    # Leaves only, from sunlit yellow-green to shaded deep green through every shade between (as in
    # the annotated wheat plots of the README's validation): Otsu's threshold would cut the canopy
    # in two; the histogram has no valley there, so the band keeps the whole canopy.
    import cv2

    rng = np.random.default_rng(1)
    field = cv2.GaussianBlur(rng.standard_normal((240, 320)), (0, 0), 6.0)
    shade = 1.0 / (1.0 + np.exp(-field / field.std() * 1.5))
    sunlit, shaded = np.array([150.0, 180.0, 60.0]), np.array([30.0, 90.0, 35.0])
    rgb = sunlit * (1 - shade[..., None]) + shaded * shade[..., None] + rng.normal(0, 3.0, (240, 320, 3))
    image = np.clip(np.round(rgb), 0, 255).astype(np.uint8)
    from cliff_terrain.photo_heights.histogram import otsu_threshold
    from cliff_terrain.photo_heights.vegetation import blurred_index

    vi, _ = blurred_index(image)
    assert otsu_threshold(vi) > 0.3  # Otsu alone would call the sunlit half of the canopy soil
    seg = segment(image)
    assert seg.threshold_source == "band" and seg.valley > 0.5
    assert seg.mask.mean() > 0.99


def _maize_on_dark_wet_soil(shape=(480, 720), seed=0):
    """Maize rows on dark, wet soil with a faint green cast, blurred and JPEG-compressed: the mixed
    pixels fill the index histogram's valley (as on the unseen photo of issue #39, whose soil
    spread -0.04-0.38 and plants 0.46-0.93). Returns the image and the true plant mask."""
    import cv2

    rng = np.random.default_rng(seed)
    rows, cols = shape
    yy, xx = np.mgrid[:rows, :cols]
    truth = np.zeros(shape, bool)
    for r0 in range(30, rows, 80):  # rows of leaves, 16-36 px wide, the soil between them open
        centre = r0 + 6 * np.sin(xx / 23.0 + r0)
        truth |= np.abs(yy - centre) < 13 + 5 * np.sin(xx / 9.0 + r0 * 0.3)
    clods = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), 4)
    soil = np.array([66.0, 68.0, 58.0]) * (1 + 0.18 * (clods / clods.std())[..., None])
    soil = soil + rng.normal(0, 4, shape + (3,))
    light = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), 3)
    leaves = np.array([70.0, 125.0, 45.0]) * (1 + 0.75 * light[..., None]) + rng.normal(0, 5, shape + (3,))
    rgb = cv2.GaussianBlur(np.where(truth[..., None], leaves, soil).astype(np.float32), (0, 0), 2.0)
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    _, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 55])
    return np.ascontiguousarray(cv2.imdecode(jpeg, cv2.IMREAD_COLOR)[..., ::-1]), truth


def test_maize_on_dark_wet_soil_without_a_valley_is_split_by_its_colour():
    from cliff_terrain.evaluate.mask_quality import mask_agreement, volume_fraction
    from cliff_terrain.photo_heights.separation import chroma_map
    from cliff_terrain.photo_heights.vegetation import (
        _GREEN_BAND,
        COLOUR_SEPARATION,
        TWO_CLASS_VALLEY,
        blurred_index,
        index_threshold,
    )

    image, truth = _maize_on_dark_wet_soil()
    vi, _ = blurred_index(image)
    # The soil reaches well above the band and no valley separates it from the plants...
    assert np.percentile(vi[~truth], 90) > 2 * _GREEN_BAND[1]
    by_index = index_threshold(vi)
    assert by_index.source == "band" and by_index.valley > TWO_CLASS_VALLEY
    assert mask_agreement(vi > by_index.threshold, truth)["iou"] < 0.8  # the band raises the soil
    # ...but grey-brown soil and green leaves differ plainly in chroma: the photo's own split.
    rule = index_threshold(vi, chroma=chroma_map(image))
    assert rule.source == "photo (colour)" and rule.separation >= COLOUR_SEPARATION
    relief = build_relief(image, mesh=None)
    assert mask_agreement(relief.mask, truth)["iou"] > 0.85
    assert volume_fraction(relief.heights, truth) >= 0.9
    record = relief.params["threshold"]
    assert record["source"] == "photo (colour)" and record["value"] == pytest.approx(rule.threshold, abs=1e-4)
    assert record["colour_separation"] == pytest.approx(rule.separation, abs=1e-3)
    assert record["colour_test"] == {"statistic": "ashman_d_chroma", "min": COLOUR_SEPARATION}


def test_a_closed_canopy_does_not_pass_the_colour_test():
    # Sunlit and shaded leaves are both green: their chroma does not separate them, the band stands.
    import cv2

    from cliff_terrain.photo_heights.vegetation import COLOUR_SEPARATION

    rng = np.random.default_rng(1)
    field = cv2.GaussianBlur(rng.standard_normal((240, 320)), (0, 0), 6.0)
    shade = 1.0 / (1.0 + np.exp(-field / field.std() * 1.5))
    sunlit, shaded = np.array([150.0, 180.0, 60.0]), np.array([30.0, 90.0, 35.0])
    rgb = sunlit * (1 - shade[..., None]) + shaded * shade[..., None] + rng.normal(0, 3.0, (240, 320, 3))
    seg = segment(np.clip(np.round(rgb), 0, 255).astype(np.uint8))
    assert seg.threshold_source == "band" and seg.separation < COLOUR_SEPARATION
    assert seg.mask.mean() > 0.99


def test_a_uniform_photo_builds_and_says_the_prior_decided(tmp_path, capsys):
    from cliff_terrain.cli import main as cli

    # One colour: nothing can be told apart, the prior band alone decides. Soil stays flat; a green
    # frame is canopy seen close and rises whole.
    for colour, covered in (((40, 160, 40), True), ((120, 90, 60), False), ((128, 128, 128), False)):
        relief = build_relief(np.full((60, 80, 3), colour, np.uint8), mesh=None)
        assert bool(relief.mask.all()) is covered and bool(relief.mask.any()) is covered
        assert relief.params["threshold"]["source"] == "uniform"
        assert relief.params["threshold"]["note"].startswith("uniform:")
    from PIL import Image

    Image.fromarray(np.full((60, 80, 3), (40, 160, 40), np.uint8)).save(tmp_path / "green.png")
    assert cli(["relief", str(tmp_path / "green.png"), "--out", str(tmp_path / "out")]) == 0
    assert "uniform:" in capsys.readouterr().out
    summary = json.loads((tmp_path / "out" / "relief.json").read_text())
    assert summary["threshold"]["source"] == "uniform" and summary["threshold"]["note"].startswith("uniform:")


def test_yellow_canopy_over_brown_soil_is_undecided_not_guessed():
    # Ripe, yellow wheat (index below 0) over brown soil: colour tells two classes apart but not
    # which is plant (straw and residue look the same). The floor stands and the record says so.
    rng = np.random.default_rng(3)
    truth = np.zeros((200, 300), bool)
    truth[:, 60:240] = True
    soil, straw = np.array([120.0, 85.0, 60.0]), np.array([200.0, 175.0, 95.0])
    rgb = np.where(truth[..., None], straw, soil) * (1 + 0.05 * rng.standard_normal((200, 300, 1)))
    relief = build_relief(np.clip(rgb, 0, 255).astype(np.uint8), mesh=None)
    record = relief.params["threshold"]
    assert record["source"] == "band" and record["note"].startswith("undecided:")
    # The note says what still rises: whatever lies above the floor, the threshold taken.
    assert record["note"].endswith(f"only what lies above the floor ({record['value']}) rises")
    assert relief.mask.mean() < 0.05  # nothing raised that the photo cannot justify


def _residue_photo(rng):
    """Stover's frames in small: grey residue, pale straw stalks and their bluish shade, and 3 %
    green plants; returns the photo and the plants', shade's and straw's masks."""
    rows, cols = 240, 320
    yy, xx = np.mgrid[:rows, :cols]
    plants = np.zeros((rows, cols), bool)
    for r0 in range(30, rows, 60):
        for c0 in range(30, cols, 60):
            dr, dc = rng.integers(-8, 8, 2)
            plants |= (yy - r0 - dr) ** 2 + (xx - c0 - dc) ** 2 < rng.integers(5, 9) ** 2
    shade = ((xx + yy) % 23 < 5) & ~plants
    straw = ((xx - 2 * yy) % 31 < 9) & ~plants & ~shade
    rgb = np.select(
        [plants[..., None], shade[..., None], straw[..., None]],
        [np.array([96.0, 126, 70]), np.array([40.0, 44, 58]), np.array([150.0, 142, 100])],
        np.array([92.0, 90, 86]),
    )
    rgb = rgb * (1 + 0.08 * rng.standard_normal((rows, cols, 1))) + 4 * rng.standard_normal((rows, cols, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8), plants, shade, straw


def test_green_plants_among_straw_residue_rise_and_the_residue_stays_flat():
    # The index's low tail is the straw's shade, where Otsu's split falls: it divides shade from
    # residue. The upper class of that split is mostly residue below the floor (undecided); within it
    # an empty valley parts the plants from the residue, and only the plants rise. At the floor the
    # pale straw rose.
    from cliff_terrain.evaluate.mask_quality import mask_agreement, volume_fraction

    rgb, plants, shade, straw = _residue_photo(np.random.default_rng(5))

    relief = build_relief(rgb, mesh=None)
    record = relief.params["threshold"]
    assert record["source"] == "photo (upper valley)" and record["note"].startswith("undecided:")
    assert record["value"] > 0.06
    # The note names the threshold taken and the valley it was accepted on (at most 0.5).
    found = re.search(
        r"only what lies above an empty valley within that class \(([\d.]+), valley ([\d.]+)\) rises$",
        record["note"],
    )
    assert found and float(found[1]) == pytest.approx(record["value"], abs=5e-4) and float(found[2]) <= 0.5
    assert mask_agreement(relief.mask, plants)["iou"] > 0.85
    assert volume_fraction(relief.heights, plants) > 0.9
    # Straw rises only as the rims of plants that touch a stalk (the index is blurred by 1 px).
    from scipy import ndimage

    near_plants = ndimage.binary_dilation(plants, iterations=3)
    assert not relief.mask[straw & ~near_plants].any()
    # The floor, last round's threshold for this photo, raised the straw with the plants.
    floor = segment(rgb, threshold=0.06).labels > 0
    assert mask_agreement(floor, plants)["iou"] < 0.6 and floor[straw].mean() > 0.05


def test_a_split_above_the_floor_is_not_split_again():
    # Dark soil, then sunlit and shaded leaves (two leaf modes with an empty valley between them).
    # Otsu's split parts soil from leaves below the floor, but its upper class lies above the floor:
    # it is the plants, and splitting it again would call the shaded leaves soil.
    from cliff_terrain.photo_heights.vegetation import index_threshold

    rng = np.random.default_rng(2)
    soil, shaded, sunlit = (
        rng.normal(-0.25, 0.04, 5000),
        rng.normal(0.10, 0.02, 2500),
        rng.normal(0.38, 0.04, 2500),
    )
    rule = index_threshold(np.concatenate([soil, shaded, sunlit]))
    assert rule.source == "band" and rule.threshold == pytest.approx(0.06) and rule.note == ""
    assert (shaded > rule.threshold).mean() > 0.97 and (soil > rule.threshold).mean() == 0


@pytest.mark.parametrize(
    "name",
    [
        "broccoli/01_clip_raw_test.jpg",
        "broccoli/2021a_grid_x03_y05-20220120171000-rze68yw.jpg",
        "caliterra/IMG_9370.jpg",
        "seneca_nir/IMG_0505.jpg",
        "plantcv_dsm/rgb.tif",
        "lamberton_soybean/20180815_Lamberton_clipped.tif",
        "lamberton_soybean/20180925_Lamberton_clipped.tif",
    ],
)
def test_the_shared_photos_keep_the_thresholds_they_were_checked_with(name):
    # None of these photos has a two-class histogram whose own threshold lies above the band: the
    # rule leaves their masks (and every figure checked on them) as they were.
    from cliff_terrain.photo_heights.histogram import otsu_threshold
    from cliff_terrain.photo_heights.vegetation import _GREEN_BAND, _NIR_BAND, blurred_index

    image, meta = load_image(uav_image(name), max_size=1000)
    image = resize_longest(image, 1000)
    valid = meta.valid_mask
    if valid is not None and valid.shape != image.shape[:2]:
        import cv2

        valid = cv2.resize(valid.astype(np.uint8), image.shape[1::-1], interpolation=cv2.INTER_NEAREST) > 0
    seg = segment(image, valid=valid)
    vi, index = blurred_index(image)
    low, high = _GREEN_BAND if index == "green" else _NIR_BAND
    otsu = otsu_threshold(vi if valid is None else vi[valid])
    assert seg.threshold == pytest.approx(float(np.clip(otsu, low, high)), abs=1e-6)


def _write_georeferenced(folder, rgb, dsm, gsd):
    """`folder`/ortho.tif and dsm.tif: the photo and its surface on one UTM 16N grid of `gsd` metres."""
    from test_measured_heights import UTM16N, geokeys, write_tiff

    from cliff_terrain.io.raster.geotiff import write_geotiff

    tie = (500000.0, 4000000.0)
    write_tiff(folder / "ortho.tif", rgb, scale=(gsd, gsd), tie=tie, keys=geokeys(UTM16N), photometric="rgb")
    transform = [[gsd, 0, tie[0]], [0, -gsd, tie[1]]]
    write_geotiff(folder / "dsm.tif", np.asarray(dsm, np.float32), transform=transform, crs=UTM16N)


def _write_yellow_field(folder, stands):
    """`folder`/ortho.tif and dsm.tif: yellow canopy (or straw: the same colour) in strips over brown
    soil on a sloping field, 2 cm pixels; the canopy stands 0.7 m, straw lies on the ground.
    Returns the strips' mask."""
    rng = np.random.default_rng(4)
    rows, cols, gsd = 200, 300, 0.02
    truth = np.zeros((rows, cols), bool)
    for c0 in range(20, cols, 70):
        truth[:, c0 : c0 + 40] = True
    soil, straw = np.array([120.0, 85.0, 60.0]), np.array([200.0, 175.0, 95.0])
    rgb = np.where(truth[..., None], straw, soil) * (1 + 0.05 * rng.standard_normal((rows, cols, 1)))
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    rr, cc = np.mgrid[:rows, :cols]
    ground = 250.0 + 0.004 * rr + 0.002 * cc  # a slope of 0.2-0.1 m/m... across the field
    dsm = ground + (0.7 * truth if stands else 0.0) + rng.normal(0, 0.01, (rows, cols))
    _write_georeferenced(folder, rgb, dsm, gsd)
    return truth


@pytest.mark.parametrize("stands", [True, False], ids=["senescent-canopy", "straw-on-the-ground"])
def test_a_dsm_decides_what_colour_cannot(tmp_path, stands):
    # Yellow canopy (or straw: the same colour) over brown soil, a georeferenced orthophoto and its
    # DSM on a sloping field. Canopy stands 0.7 m above the ground and rises; straw lies on it and
    # stays flat, still undecided.
    from cliff_terrain.evaluate.mask_quality import mask_agreement

    truth = _write_yellow_field(tmp_path, stands)

    alone = build_relief(tmp_path / "ortho.tif", mesh=None)
    assert alone.params["threshold"]["note"].startswith("undecided:")
    relief = build_relief(tmp_path / "ortho.tif", dsm=tmp_path / "dsm.tif", mesh=None)
    record = relief.params["threshold"]
    if stands:
        assert record["source"] == "photo (dsm)" and record["note"].startswith("decided by the DSM")
        assert mask_agreement(relief.mask, truth)["iou"] > 0.9
        # The ground is fitted on the soil, not on the canopy: the canopy stands about 0.7 m.
        assert np.median(relief.canopy.chm[truth & relief.mask]) == pytest.approx(0.7, abs=0.1)
    else:
        assert record["source"] == "band" and "the DSM does not show it" in record["note"]
        assert relief.mask.mean() < 0.05


@pytest.mark.parametrize("stands", [True, False], ids=["senescent-canopy", "residue-on-the-ground"])
def test_a_dsm_tests_the_class_below_the_upper_valley_without_the_plants(tmp_path, stands):
    # The residue photo, georeferenced, with a DSM where the green plants stand 0.4 m. The class
    # between the two splits (grey residue and pale straw) either lies on the ground, with the shade
    # (the upper valley stands and only the plants rise), or stands 0.6 m (a senescent canopy: the
    # DSM raises the whole class above the photo's own split, green plants with it).
    rng = np.random.default_rng(5)
    rgb, plants, shade, straw = _residue_photo(rng)
    rows, cols, gsd = *rgb.shape[:2], 0.02
    rr, cc = np.mgrid[:rows, :cols]
    middle = ~plants & ~shade
    dsm = (
        250.0
        + 0.004 * rr
        + 0.4 * plants
        + (0.6 * middle if stands else 0.0)
        + rng.normal(0, 0.01, (rows, cols))
    )
    _write_georeferenced(tmp_path, rgb, dsm, gsd)

    alone = build_relief(tmp_path / "ortho.tif", mesh=None).params["threshold"]
    assert alone["source"] == "photo (upper valley)"
    relief = build_relief(tmp_path / "ortho.tif", dsm=tmp_path / "dsm.tif", mesh=None)
    record = relief.params["threshold"]
    if stands:
        assert record["source"] == "photo (dsm)" and record["note"].startswith("decided by the DSM")
        assert relief.mask[middle].mean() > 0.9 and relief.mask[plants].mean() > 0.9
    else:
        assert record["source"] == "photo (upper valley)" and record["value"] == alone["value"]
        assert record["note"].startswith("undecided:") and "the DSM does not show it" in record["note"]
        assert relief.mask[straw].mean() < 0.05 and relief.mask[plants].mean() > 0.85
