"""Orthomosaics larger than memory: windows of a tiled GeoTIFF, the striped refusal, tiles without seams.

The big mosaic (>= 400 MP) is generated in a temporary folder and never committed.
"""

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
from conftest import uav_image
from scipy.ndimage import label as _label

from cliff_terrain import synthetic_field
from cliff_terrain.errors import CliffTerrainError, ImageTooLargeError
from cliff_terrain.io.photo import load_image
from cliff_terrain.io.raster.mosaic import MosaicReader
from cliff_terrain.mesh.quads import fan_triangles
from cliff_terrain.mosaic.tiles import (
    mosaic_settings,
    relief_tile,
    relief_tiles,
    tile_windows,
)

ROOT = Path(__file__).resolve().parents[1]
EPSG_UTM33N = 32633


def geo_tags(x0, y0, gsd, crs=EPSG_UTM33N):
    """GeoTIFF tags: north-up, top-left corner at (x0, y0), `gsd` metres per pixel, a projected CRS."""
    keys = (1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, crs, 3076, 0, 1, 9001)
    return [
        (33550, 12, 3, (gsd, gsd, 0.0), True),
        (33922, 12, 6, (0.0, 0.0, 0.0, x0, y0, 0.0), True),
        (34735, 3, len(keys), keys, True),
    ]


def write_mosaic(path, rgb, *, tile=(128, 128), gsd=0.01):
    kwargs = {"tile": tile} if tile else {"rowsperstrip": 16}
    tifffile.imwrite(
        path,
        rgb,
        photometric="rgb",
        compression="zlib",
        extratags=geo_tags(500000.0, 5200000.0, gsd),
        **kwargs,
    )
    return path


def label(mask):
    return _label(mask)[0]


def stitched(reader, tiles):
    mask = np.zeros(reader.shape, bool)
    heights = np.zeros(reader.shape, np.float32)
    labels = np.zeros(reader.shape, np.int64)
    offset = 0
    for tile in tiles:
        r0, r1, c0, c1 = tile.core
        mask[r0:r1, c0:c1], heights[r0:r1, c0:c1] = tile.mask, tile.heights
        # Labels made unique across tiles, so a plant split in two shows as two labels.
        labels[r0:r1, c0:c1] = np.where(tile.labels > 0, tile.labels + offset, 0)
        offset += int(tile.labels.max(initial=0))
    return mask, heights, labels


def test_a_window_decodes_only_the_tiles_it_overlaps(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (700, 900, 3), dtype=np.uint8)
    path = write_mosaic(tmp_path / "m.tif", rgb)
    with MosaicReader(path) as reader:
        assert reader.shape == (700, 900) and reader.tile_shape == (128, 128)
        assert reader.gsd == pytest.approx(0.01) and reader.crs == EPSG_UTM33N
        decoded = []
        original = reader.raster.decode_tile
        monkeypatch.setattr(
            reader.raster, "decode_tile", lambda index: decoded.append(index) or original(index)
        )
        window, valid = reader.read(130, 300, 250, 899)
        np.testing.assert_array_equal(window, rgb[130:300, 250:899])
        assert valid is None
        # Rows 130-299 are tile rows 1-2, columns 250-898 tile columns 1-7 (8 tiles across).
        assert sorted(decoded) == sorted(r * 8 + c for r in (1, 2) for c in range(1, 8))
        overview, _, step = reader.overview(max_pixels=50_000)
        np.testing.assert_array_equal(overview, rgb[::step, ::step])


def test_a_dark_window_of_a_12_bit_mosaic_is_scaled_as_the_whole_file(tmp_path):
    # A 12-bit camera's mosaic in 16-bit samples (0..4095): its depth is the file's, not the window's.
    # A window of dark soil (largest sample 1500, 11 bits) was scaled by 2047 instead of 4095: twice as
    # bright as the same pixels read whole, so its soil could pass for plants.
    from cliff_terrain.io.photo import open_image
    from cliff_terrain.io.raster.photo_samples import photo_bands

    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 4096, (256, 384, 3)).astype(np.uint16)
    rgb[:128, :128] = rng.integers(0, 1500, (128, 128, 3))  # one tile of dark soil
    path = write_mosaic(tmp_path / "m12.tif", rgb)
    whole, _ = photo_bands(rgb, "m12")  # as the file read whole
    assert whole[:128, :128].max() <= round(1500 * 255 / 4095)
    with MosaicReader(path) as reader:
        dark, _ = reader.read(0, 128, 0, 128)  # the first window read: the scale comes from the file
        assert reader.scale == 4095
        np.testing.assert_array_equal(dark, whole[:128, :128])
        np.testing.assert_array_equal(reader.overview()[0], whole)
    with MosaicReader(path, scale=4095) as reader:  # given by the caller (a worker's window)
        np.testing.assert_array_equal(reader.read(0, 128, 0, 128)[0], whole[:128, :128])
    with open_image(path) as photo:  # and in memory, a GeoTIFF photo by the same rule
        np.testing.assert_array_equal(photo.decode()[0], whole)


def test_a_glint_above_the_overview_grids_scale_saturates_instead_of_wrapping():
    # The scale comes from every step-th pixel (step 2 here, 4.2 MP): a 12-bit glint the grid misses,
    # above the 11 bits it saw, read (4095 / 2047) * 255 = 510, and the cast to 8 bits wrapped it
    # to 254 - 256 = dark. It saturates at white.
    from cliff_terrain.io.raster.photo_samples import overview_step, photo_bands

    rgb = np.full((2100, 2000, 3), 1500, np.uint16)
    assert overview_step(rgb.shape) == 2
    rgb[1, 1] = (4095, 3000, 2100)  # off the grid
    out, valid = photo_bands(rgb, "glint")
    assert valid is None and out[0, 0].tolist() == [187, 187, 187]  # 1500 of 2047
    assert out[1, 1].tolist() == [255, 255, 255]


def test_pixels_without_data_are_black_and_a_float_window_is_scaled_as_its_file(tmp_path):
    # Colour stored under alpha 0 (white here) bled into the relief's filters in memory, where
    # Pillow had composited it over black; a 0-255 float window of collar and a few values under 1
    # was read as if the file were 0-1.
    from cliff_terrain.io.raster.photo_samples import photo_bands

    rgba = np.full((4, 4, 4), 255, np.uint8)
    rgba[:2, :, 3] = 0
    rgb, valid = photo_bands(rgba, "rgba")
    assert not valid[:2].any() and valid[2:].all()
    assert (rgb[:2] == 0).all() and (rgb[2:] == 255).all()
    assert (rgba[:2, :, :3] == 255).all()  # the samples themselves untouched

    photo = np.zeros((256, 256, 3), np.float32)
    photo[128:, 128:] = 200.0  # a 0-255 float orthophoto: one window of it holds only 0.8 and collar
    photo[10, 10] = 0.8
    path = tmp_path / "float.tif"
    tifffile.imwrite(path, photo, photometric="rgb", tile=(128, 128), extratags=geo_tags(0.0, 0.0, 0.1))
    whole, _ = photo_bands(photo, "float")
    with MosaicReader(path) as reader:
        window, _ = reader.read(0, 128, 0, 128)
        assert reader.scale == 255.0
    np.testing.assert_array_equal(window, whole[:128, :128])
    assert window[10, 10].tolist() == [1, 1, 1]  # 0.8 of 255, not 0.8 of 1


def test_a_cmyk_geotiff_is_read_by_pillow_in_memory_and_refused_in_windows(tmp_path):
    # photo_bands would read C, M, Y as R, G, B and K as alpha (K 0: every pixel without data).
    from cliff_terrain.errors import ImageReadError
    from cliff_terrain.io.photo import open_image

    cmyk = np.zeros((64, 64, 4), np.uint8)
    cmyk[..., 0] = 200  # cyan: a bluish-green photo
    path = tmp_path / "cmyk.tif"
    tifffile.imwrite(path, cmyk, photometric="separated", extratags=geo_tags(0.0, 0.0, 0.1))
    with open_image(path) as photo:
        rgb, meta = photo.decode()
    assert meta.valid_fraction == 1.0 and rgb[0, 0].tolist() == [55, 255, 255]  # Pillow's conversion
    with pytest.raises(ImageReadError) as caught:
        MosaicReader(path)
    assert str(caught.value).startswith(f"mosaic {str(path)!r} is CMYK; windows read RGB or RGBA")
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("tile", [(64, 64), None])
def test_windows_read_from_several_threads_at_once_are_the_pixels(tmp_path, tile):
    # The next tile of a mosaic is read in a thread while this one's texture is read here.
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (600, 700, 3), dtype=np.uint8)
    path = write_mosaic(tmp_path / "m.tif", rgb, tile=tile)
    windows = [(r, r + 150, c, c + 200) for r in range(0, 450, 37) for c in range(0, 500, 41)]
    with MosaicReader(path) as reader, ThreadPoolExecutor(4) as pool:
        for (r0, r1, c0, c1), (window, _) in zip(
            windows, pool.map(lambda w: reader.read(*w), windows), strict=True
        ):
            np.testing.assert_array_equal(window, rgb[r0:r1, c0:c1])


def test_tiles_computed_one_ahead_come_in_order_raise_in_place_and_stop_when_dropped():
    from cliff_terrain.mosaic.tiles import _one_ahead

    assert list(_one_ahead(iter(range(5)))) == [0, 1, 2, 3, 4]
    assert list(_one_ahead(iter([]))) == []

    def failing():
        yield 1
        raise CliffTerrainError("tile 2 is broken")

    tiles = _one_ahead(failing())
    assert next(tiles) == 1
    with pytest.raises(CliffTerrainError, match="tile 2 is broken"):
        next(tiles)

    started = []

    def counted():
        for k in range(100):
            started.append(k)
            yield k

    tiles = _one_ahead(counted())
    assert next(tiles) == 0
    tiles.close()  # the caller stops: the tile in progress is finished, no other is started
    assert started == [0, 1]


def test_tile_meshes_closed_early_end_the_tile_computed_ahead_while_the_reader_is_open(tmp_path):
    # The Import Mosaic operator closes them before the reader when a tile fails in Blender.
    import threading

    from cliff_terrain.mosaic.meshes import tile_meshes

    def tile_threads():
        return [t for t in threading.enumerate() if t.name.startswith("cliff_terrain_tile")]

    rgb, _ = synthetic_field(shape=(300, 400), seed=4)
    path = write_mosaic(tmp_path / "field.tif", rgb, gsd=0.02)
    with MosaicReader(path) as reader:
        tiles = tile_meshes(reader, pixel_size=0.02, tile=128, overlap=32)
        assert next(tiles).core == (0, 128, 0, 128)
        assert tile_threads(), "the next tile is being computed"
        tiles.close()
        assert tile_threads() == []
        np.testing.assert_array_equal(reader.read(0, 10, 0, 10)[0], rgb[:10, :10])


def test_a_striped_mosaic_too_big_to_read_in_windows_says_how_to_tile_it(tmp_path):
    rgb = np.zeros((300, 400, 3), np.uint8)
    path = write_mosaic(tmp_path / "striped.tif", rgb, tile=None)
    with pytest.raises(ImageTooLargeError, match=r"striped \(untiled\).*gdal_translate -co TILED=YES"):
        MosaicReader(path, max_striped_pixels=100_000)
    # Small enough: read whole, served in windows.
    with MosaicReader(path, max_striped_pixels=200_000) as reader:
        window, _ = reader.read(10, 20, 30, 50)
        assert window.shape == (10, 20, 3)


def test_a_striped_planar_mosaic_reads_its_windows(tmp_path):
    # io's one TIFF reader gives windows pixel-interleaved whatever the file's layout.
    rgb = np.random.default_rng(3).integers(0, 256, (50, 60, 3), dtype=np.uint8)
    path = tmp_path / "planar.tif"
    tifffile.imwrite(path, np.moveaxis(rgb, -1, 0), planarconfig="separate", photometric="rgb")
    with MosaicReader(path) as reader:
        window, valid = reader.read(10, 30, 5, 40)
    np.testing.assert_array_equal(window, rgb[10:30, 5:40])
    assert valid is None


def test_a_mosaic_with_an_unreadable_no_data_value_is_refused_as_rasters_are(tmp_path):
    from cliff_terrain.errors import RasterReadError

    path = tmp_path / "nodata.tif"
    tags = [*geo_tags(500000.0, 5200000.0, 0.01), (42113, 2, 0, "n/a", True)]
    tifffile.imwrite(path, np.zeros((64, 64, 3), np.uint8), photometric="rgb", tile=(32, 32), extratags=tags)
    with pytest.raises(RasterReadError, match=r"nodata.tif' has an unreadable GDAL_NODATA value 'n/a'"):
        MosaicReader(path)


def _check_no_seams(rgb, tmp_path, *, tile, overlap):
    path = write_mosaic(tmp_path / "field.tif", rgb, tile=(64, 64))
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader, tile=tile)
        whole = relief_tile(
            reader, tile_windows(reader.shape, tile=max(reader.shape), overlap=0)[0], settings
        )
        tiles = list(relief_tiles(reader, tile=tile, overlap=overlap, settings=settings))
        assert len(tiles) > 4
        mask, heights, labels = stitched(reader, tiles)
    # Plants that cross a tile border.
    border = np.zeros(mask.shape, bool)
    border[tile::tile] = True
    border[:, tile::tile] = True
    crossing = np.unique(whole.labels[border & (whole.labels > 0)])
    # The promise holds for plants whose patch of canopy (connected mask) fits in the margin: a
    # wider patch is cut by some window's edge, and its split into regions may differ there.
    components = label(whole.mask)
    small = []
    for plant in crossing:
        patch = components == components[whole.labels == plant][0]
        rows, cols = np.nonzero(patch)
        if max(np.ptp(rows), np.ptp(cols)) < overlap:
            small.append(plant)
    assert len(small) >= 5, (len(small), len(crossing))
    for plant in small:
        pixels = whole.labels == plant
        top = float(whole.heights[pixels].max())
        # Same mask, one region per tile over exactly the same pixels, heights within 1 % of its height.
        assert mask[pixels].all()
        pieces = np.unique(labels[pixels])
        assert 0 not in pieces
        for piece in pieces:
            assert np.array_equal(labels == piece, pixels & (labels == piece))
        assert np.isin(labels, pieces).sum() == pixels.sum()
        assert np.abs(heights[pixels] - whole.heights[pixels]).max() <= 0.01 * top
    return whole, len(small), len(crossing)


def test_plants_across_tile_borders_match_the_whole_image_run(tmp_path):
    rgb, truth = synthetic_field(shape=(600, 900), seed=2)
    whole, n_small, n_crossing = _check_no_seams(rgb, tmp_path, tile=200, overlap=96)
    assert whole.labels.max() >= truth.n_plants * 0.8
    assert n_small == n_crossing  # every plant of the field is narrower than the margin


def test_a_real_photo_in_tiles_matches_the_whole_image_run(tmp_path):
    rgb, _ = load_image(uav_image("broccoli/01_clip_raw_test.jpg"), max_size=1000)
    # Broccoli heads are up to ~150 px across at this size: the margin must be wider.
    _check_no_seams(rgb, tmp_path, tile=300, overlap=200)


def _window_relief(reader, window, settings):
    """segment() and inflate() of the tile's whole window, cut to its core (what relief_tile computed
    before it limited the watershed and heights to the core's reach)."""
    from cliff_terrain.photo_heights.inflate import inflate
    from cliff_terrain.photo_heights.quaternion import quaternion_filter
    from cliff_terrain.photo_heights.segmentation import segment

    wr0, wr1, wc0, wc1 = window.window
    rgb, valid = reader.read(wr0, wr1, wc0, wc1)
    seg = segment(
        rgb,
        filtered=quaternion_filter(rgb),
        index=settings.index,
        min_region=settings.min_region,
        valid=valid,
        threshold=settings.threshold,
        radius=settings.radius,
        edge_scale=settings.edge_scale,
        soil=settings.soil,
    )
    heights = inflate(
        seg.labels,
        profile=settings.profile,
        exaggeration=settings.exaggeration,
        max_height=settings.max_height,
        mask_distance=seg.distance,
    )
    r0, r1, c0, c1 = window.core
    cut = (slice(r0 - wr0, r1 - wr0), slice(c0 - wc0, c1 - wc0))
    return seg.mask[cut], seg.labels[cut], heights[cut]


@pytest.mark.parametrize("source", ["field", "broccoli"])
def test_a_tile_equals_segment_and_inflate_of_its_whole_window(tmp_path, source):
    # relief_tile runs the watershed and heights only as far as the core's plants reach: the
    # same mask, the same regions (numbered differently) and exactly the same heights.
    if source == "field":
        rgb, _ = synthetic_field(shape=(600, 900), seed=2)
        tile, overlap = 200, 96
    else:
        rgb, _ = load_image(uav_image("broccoli/01_clip_raw_test.jpg"), max_size=1000)
        tile, overlap = 300, 200
    path = write_mosaic(tmp_path / "mosaic.tif", rgb, tile=(64, 64))
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader, tile=tile)
        for window in tile_windows(reader.shape, tile=tile, overlap=overlap):
            got = relief_tile(reader, window, settings)
            mask, labels, heights = _window_relief(reader, window, settings)
            np.testing.assert_array_equal(got.mask, mask)
            np.testing.assert_array_equal(got.heights, heights)
            pairs = np.unique(np.stack([got.labels.ravel(), labels.ravel()]), axis=1)
            assert len(np.unique(pairs[0])) == len(np.unique(pairs[1])) == pairs.shape[1]
            assert ((pairs[0] == 0) == (pairs[1] == 0)).all()


def test_tiles_without_plants_are_flat(tmp_path):
    rgb = np.empty((300, 400, 3), np.uint8)
    rgb[:] = (120, 90, 60)  # bare soil
    path = write_mosaic(tmp_path / "soil.tif", rgb)
    with MosaicReader(path) as reader:
        tiles = list(relief_tiles(reader, tile=128, overlap=32))
    assert len(tiles) == 12
    assert all(not t.mask.any() and not t.heights.any() for t in tiles)


def test_a_tile_runs_from_the_path_alone(tmp_path):
    rgb, _ = synthetic_field(shape=(300, 400), seed=4)
    path = write_mosaic(tmp_path / "field.tif", rgb)
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader, tile=200)
        window = tile_windows(reader.shape, tile=200, overlap=64)[1]
        expected = relief_tile(reader, window, settings)
    got = relief_tile(str(path), window, settings)  # what a Dask task would run
    np.testing.assert_array_equal(got.heights, expected.heights)


@pytest.mark.slow
def test_tiles_run_as_dask_tasks_in_order_and_equal_the_serial_ones(tmp_path):
    """`relief_tiles(client=...)`: each tile a task on a local cluster (2 processes), the tiles
    back in order and equal to the serial run's; a caller that stops early leaves no task behind."""
    from distributed import Client

    from cliff_terrain.season.cluster import local_cluster

    rgb, _ = synthetic_field(shape=(300, 400), seed=4)
    path = write_mosaic(tmp_path / "field.tif", rgb)
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader, tile=128)
        serial = list(relief_tiles(reader, tile=128, overlap=32, settings=settings))
        with local_cluster(2) as cluster, Client(cluster) as client:
            started = time.time()
            client.get_task_stream(start=started)
            tiles = list(relief_tiles(reader, tile=128, overlap=32, settings=settings, client=client))
            stream = client.get_task_stream(start=started)
            assert sum(task["key"].startswith("relief_tile") for task in stream) == len(serial) == 12
            first = relief_tiles(reader, tile=128, overlap=32, settings=settings, client=client)
            assert next(first).core == serial[0].core
            first.close()  # the caller stops: the tiles computed ahead are cancelled
            deadline = time.time() + 30
            while (
                client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks))
                and time.time() < deadline
            ):
                time.sleep(0.1)
            assert client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 0
            assert client.status == "running"
    assert [t.core for t in tiles] == [t.core for t in serial]
    for got, expected in zip(tiles, serial, strict=True):
        np.testing.assert_array_equal(got.labels, expected.labels)
        np.testing.assert_array_equal(got.heights, expected.heights)


def test_tile_meshes_are_the_tiles_reliefs_joined_without_cracks(tmp_path):
    """The core's loop the Import Mosaic operator only turns into objects: each tile's relief as
    an adaptive mesh in metres, stitched to its neighbours, with its part of the photo."""
    from test_seams import cracks, welded_open_edges

    from cliff_terrain.mosaic.meshes import tile_meshes

    rgb, _ = synthetic_field(shape=(300, 400), seed=4)
    path = write_mosaic(tmp_path / "field.tif", rgb, gsd=0.02)
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader, tile=128)
        expected = list(relief_tiles(reader, tile=128, overlap=32, settings=settings))
        with pytest.raises(CliffTerrainError, match=r"`max_error` must be"):
            tile_meshes(reader, max_error=0.0, pixel_size=0.02)
        tiles = list(
            tile_meshes(reader, max_error=0.005, pixel_size=0.02, tile=128, overlap=32, settings=settings)
        )
    assert [t.core for t in tiles] == [t.core for t in expected]
    parts = []
    for got, want in zip(tiles, expected, strict=True):
        np.testing.assert_array_equal(got.relief.heights, want.heights)
        r0, r1, c0, c1 = got.core
        np.testing.assert_array_equal(got.rgb, rgb[r0:r1, c0:c1])
        assert got.mesh.vertices[:, 2].max() == pytest.approx(0.02 * float(want.heights.max()), abs=0.005)
        parts.append(
            (
                got.mesh.vertices + np.array([c0 * 0.02, (300 - r1) * 0.02, 0.0]),
                fan_triangles(got.mesh.face_sizes, got.mesh.corner_verts),
            )
        )
    edges, points = welded_open_edges(parts, 0.02)
    assert len(edges) > 0 and len(cracks(edges, points, 400, 300)) == 0


def test_mosaic_tiles_default_to_half_a_pixel_and_keep_it(tmp_path):
    """Without `max_error`, each tile's front is within half a mosaic pixel (1 cm at 2 cm) of its
    heights at every pixel centre, and has fewer triangles than at a 5 mm bound."""
    from cliff_terrain.mesh.tin_sample import sample_front
    from cliff_terrain.mosaic.meshes import mosaic_max_error, tile_meshes

    assert mosaic_max_error(0.02) == (0.01, "half a pixel (inflated heights, 2 cm pixels)")
    with pytest.raises(CliffTerrainError, match=r"`max_error` must be > 0.0, got -1.0"):
        mosaic_max_error(0.02, -1)
    rgb, _ = synthetic_field(shape=(300, 400), seed=4)
    path = write_mosaic(tmp_path / "field.tif", rgb, gsd=0.02)
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader, tile=128)
        coarse = list(tile_meshes(reader, pixel_size=0.02, tile=128, overlap=32, settings=settings))
        fine = list(
            tile_meshes(reader, max_error=0.005, pixel_size=0.02, tile=128, overlap=32, settings=settings)
        )
    for tile in coarse:
        heights = tile.relief.heights.astype(np.float64) * 0.02
        surface = sample_front(tile.mesh.vertices, tile.mesh.front_triangles(), heights.shape)[1::2, 1::2]
        assert np.abs(surface - heights).max() <= 0.01 * (1 + 1e-5)
    assert sum(len(t.mesh.front_triangles()) for t in coarse) < sum(
        len(t.mesh.front_triangles()) for t in fine
    )


def test_a_client_that_is_not_one_is_refused_before_any_tile(tmp_path):
    rgb, _ = synthetic_field(shape=(100, 120), seed=4)
    with MosaicReader(write_mosaic(tmp_path / "field.tif", rgb)) as reader:
        with pytest.raises(CliffTerrainError, match=r"`client` must be a distributed.Client, got 'tcp://x'"):
            relief_tiles(reader, tile=64, client="tcp://x")


BIG_SCRIPT = textwrap.dedent(
    """
    import json, sys, time
    import numpy as np
    from cliff_terrain._memory import peak_rss
    from cliff_terrain.io.raster.mosaic import MosaicReader
    from cliff_terrain.mosaic.tiles import mosaic_settings, relief_tiles
    path, tiles_wanted = sys.argv[1], int(sys.argv[2])
    start = time.perf_counter()
    with MosaicReader(path) as reader:
        settings = mosaic_settings(reader)
        done, plants, pixels = 0, 0, 0
        for tile in relief_tiles(reader, settings=settings):
            plants += int(tile.labels.max(initial=0))
            pixels += tile.heights.size
            done += 1
            if done == tiles_wanted:
                break
        shape = reader.shape
    print(json.dumps({
        "shape": shape, "tiles": done, "plants": plants, "pixels": pixels,
        "seconds": time.perf_counter() - start,
        "peak_rss_gb": peak_rss() / 1e9,  # this process's own peak, not the test runner's
    }))
    """
)


def write_big_mosaic(path, rows, cols, tile=512):
    """A tiled GeoTIFF of rows x cols, written tile by tile from one synthetic field (never whole)."""
    field, _ = synthetic_field(shape=(2048, 2048), seed=5)

    def tiles():
        for r in range(0, rows, tile):
            for c in range(0, cols, tile):
                yield field[r % 2048 : r % 2048 + tile, c % 2048 : c % 2048 + tile]

    tifffile.imwrite(
        path,
        tiles(),
        shape=(rows, cols, 3),
        dtype=np.uint8,
        tile=(tile, tile),
        photometric="rgb",
        compression="zlib",
        compressionargs={"level": 1},
        extratags=geo_tags(500000.0, 5200000.0, 0.01),
        bigtiff=True,
    )


@pytest.mark.slow
def test_a_400_megapixel_mosaic_is_read_in_windows_within_4_gb(tmp_path):
    path = tmp_path / "big.tif"
    write_big_mosaic(path, 20480, 20480)  # 419 MP, 1.26 GB as RGB
    assert path.stat().st_size < 1e9  # compressed: never decoded whole here either
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # The overview reads every tile once; then the first tiles of the relief (all would take minutes).
    proc = subprocess.run(
        [sys.executable, "-c", BIG_SCRIPT, str(path), "3"],
        capture_output=True,
        text=True,
        env=env,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["shape"] == [20480, 20480] and result["tiles"] == 3
    assert result["plants"] > 0
    assert result["peak_rss_gb"] <= 4.0, result
