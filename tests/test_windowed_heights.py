"""The windowed heights (issue 40, cliff_terrain.measure.windowed): an orthophoto of any size measured
window by window, the ground on a bounded coarse grid, the plot table exact.

On the shared OpenDroneMap pair and on a synthetic field with a known canopy height:
- small windows give exactly what one window over the whole orthophoto gives (every plot column,
  every raster pixel), on the orthophoto's own ground grid and on a coarser one;
- against today's in-memory ``heights`` at the same resolution the plots' p90 agree within 1 cm
  (measured on the pair: at most 3.8 mm, median 0.3 mm; the grounds differ at the rasters' edges
  and where the segmentation's plants differ from the threshold's);
- on the synthetic field (1 cm pixels, the ground on 5 cm) the plots' p90 lie within 2 cm of the
  in-memory run's and as near the true canopy's p90 as it (median 1.1 cm against 0.9 cm);
- the rasters written window by window are the in-memory writer's, overviews included;
- the command picks the windowed path by itself when the in-memory run would pass the cap.
Peak memory and speed are measured in bench/bench_scale.py, never here.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import subprocess
import sys
import time

import numpy as np
import pytest
import tifffile
from conftest import REPO, empty_raster

from cliff_terrain.build import build_relief
from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.io.raster.geotiff import geotiff_tags, read_georeference, write_geotiff
from cliff_terrain.io.raster.geotiff_stream import RasterSpool, TileSpool, encode_block
from cliff_terrain.io.vector.plot_files import write_plots
from cliff_terrain.io.vector.plot_polygons import PlotSet, read_plots
from cliff_terrain.measure.window_reading import upsample
from cliff_terrain.measure.windowed import measure_windowed
from cliff_terrain.params import ReliefParams

PAIR = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"
ORTHO, DSM = PAIR / "odm_orthophoto.tif", PAIR / "dsm.tif"
PAIR_PLOTS = REPO / "tests" / "data" / "odm_plots_by_hand.geojson"  # 36 plots drawn by hand


def need_pair():
    if not ORTHO.is_file():
        pytest.skip(f"the shared OpenDroneMap pair is not at {PAIR}")


def need_plots():
    need_pair()
    if not PAIR_PLOTS.is_file():
        pytest.skip(f"the pair's plots are not at {PAIR_PLOTS}")


def windowed(tmp_path, name, ortho, dsm, plots, **kw):
    folder = tmp_path / name
    folder.mkdir()
    result = measure_windowed(ortho, dsm, plots=plots, folder=folder, **kw)
    rasters = {n: s.read_rows(0, s.shape[0]) for n, s in result.spools.items()}
    result.close()
    return result, rasters


def assert_same(a, b):
    (ra, rasters_a), (rb, rasters_b) = a, b
    assert ra.factor == rb.factor and ra.threshold == rb.threshold and ra.check == rb.check
    assert len(ra.rows) == len(rb.rows)
    for row_a, row_b in zip(ra.rows, rb.rows, strict=True):
        assert row_a.keys() == row_b.keys()
        for key in row_a:  # every column, to the bit (NaN equal to NaN)
            assert row_a[key] == row_b[key] or (row_a[key] != row_a[key] and row_b[key] != row_b[key]), key
    for name in rasters_a:
        np.testing.assert_array_equal(rasters_a[name], rasters_b[name])
    assert ra.plant_pixels == rb.plant_pixels and ra.valid_pixels == rb.valid_pixels


def assert_table_text(result, plots):
    """The table's text as the windows made it is the text made from the rows here, to the byte."""
    from cliff_terrain.io.vector.geojson import polygon_geometries, table_geojson
    from cliff_terrain.measure.field_plots import table_columns
    from cliff_terrain.measure.tables import table_csv

    columns, text = table_columns(plots, support=True, sigma=True), result.table_text
    assert len(text["csv"]) == len(text["features"]) == len(plots)
    assert table_csv(result.rows, columns, lines=text["csv"]) == table_csv(result.rows, columns)
    geometries = polygon_geometries(plots)
    made_there = table_geojson(result.rows, None, crs=result.crs, features=text["features"])
    assert made_there == table_geojson(result.rows, geometries, crs=result.crs)
    assert len(json.loads(made_there)["features"]) == len(plots)


@pytest.mark.parametrize("ground_pixels", [6_000_000, 100_000])
def test_small_windows_give_exactly_one_whole_windows_tables_on_the_real_pair(tmp_path, ground_pixels):
    need_plots()
    plots = read_plots(PAIR_PLOTS)
    whole = windowed(tmp_path, "whole", ORTHO, DSM, plots, window=4096, ground_pixels=ground_pixels)
    small = windowed(tmp_path, "small", ORTHO, DSM, plots, window=100, ground_pixels=ground_pixels)
    assert whole[0].windows == 1 and small[0].windows == 36
    # 6 MP: the orthophoto's own grid; 100 000 pixels: a grid 2 pixels to one (0.4 m).
    assert whole[0].factor == (1 if ground_pixels > 1e6 else 2)
    assert_same(whole, small)
    p90 = np.array([r["height_p90_m"] for r in small[0].rows])
    assert np.isfinite(p90).all() and 0.2 < np.median(p90) < 0.7
    assert sorted(r["plot"] for r in small[0].rows) == list(range(len(plots)))
    assert_table_text(small[0], plots)
    assert_table_text(whole[0], plots)


def run_heights(tmp_path, name, *extra, ortho=ORTHO, dsm=DSM, plots=PAIR_PLOTS):
    out = tmp_path / name
    command = [sys.executable, "-m", "cliff_terrain", "heights", str(ortho), "--dsm", str(dsm)]
    command += ["--plots", str(plots), "--out", str(out), "--no-progress", *extra]
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=600)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    with open(out / "plots.csv") as f:
        return out, list(csv.DictReader(f)), done.stdout


def column(rows, name):
    return np.array([float(r[name]) if r[name] != "" else np.nan for r in rows])


def test_the_windowed_command_agrees_with_the_in_memory_one_on_the_real_pair(tmp_path):
    need_plots()
    memory, rows_m, _ = run_heights(tmp_path, "memory")
    win, rows_w, stdout = run_heights(tmp_path, "windowed", "--windowed", "--window", "128")
    assert "windowed (25 windows)" in stdout
    # The same table to the last digit, every column of every plot: on the orthophoto's own grid
    # (0.3 MP, within the ground grid's budget) both paths resample the DSM with the same exact weights
    # (io.raster.bilinear; OpenCV's 1/32-pixel coordinates put p90s up to 1.2 mm apart), fit the
    # same ground on the same soil and take the same plants.
    assert rows_w == rows_m
    assert sorted(p.name for p in win.iterdir()) == [
        "chm.tif", "chm_err.tif", "ground_support.tif", "plots.csv", "plots.geojson", "summary.json",
    ]  # fmt: skip
    summary = json.loads((win / "summary.json").read_text())
    assert summary["windowed"]["ground_grid_factor"] == 1 and summary["ground_method"] == "detailed"
    seconds = summary["windowed"]["seconds"]  # where the time went, stage by stage
    assert list(seconds) == ["overview", "ground_grid", "ground_fit", "windows"]
    assert all(v >= 0 for v in seconds.values()) and seconds["windows"] > 0
    with tifffile.TiffFile(win / "chm.tif") as tif:  # tiled, Deflate, with an overview
        page = tif.pages[0]
        assert page.is_tiled and page.compression == 8 and len(tif.pages) == 2
        chm_w = page.asarray()
    for name in ("chm", "chm_err", "ground_support"):  # and the same rasters, pixel for pixel
        expected = tifffile.imread(memory / f"{name}.tif")
        got = chm_w if name == "chm" else tifffile.imread(win / f"{name}.tif")
        np.testing.assert_array_equal(got, expected, err_msg=name)
    assert np.isfinite(chm_w).mean() > 0.7
    # The resolution check (the 0.27 m DSM smooths these plants little) is the same in both.
    memory_summary = json.loads((memory / "summary.json").read_text())
    assert summary["resolution_check"] == memory_summary["resolution_check"]
    assert summary["resolution_check"]["passed"] is True


@pytest.mark.parametrize("extra", [(), ("--windowed", "--window", "256")])
def test_a_surface_model_too_coarse_for_the_plants_is_said_and_the_same_in_both_paths(tmp_path, extra):
    # The pair's DSM averaged to 1.35 m pixels: the plots read 14 cm low with a stated error of 3 cm,
    # exit 0 and no word (the held-out check even improves: a smoother surface predicts its soil).
    # One more doubling of the smoothing still lowers the median plot by more than that error.
    from cliff_terrain.io.raster.blocks import block_mean

    need_plots()
    with tifffile.TiffFile(DSM) as tif:
        heights = tif.pages[0].asarray().astype(np.float32)
    heights[~np.isfinite(heights) | (heights < -1e30)] = np.nan
    transform, crs = read_georeference(DSM)
    coarse = tmp_path / "coarse.tif"
    scaled = np.array(transform, float)
    scaled[:2, :2] *= 5
    write_geotiff(coarse, block_mean(heights, 5), transform=scaled, crs=crs, nodata=float("nan"))
    out, rows, stdout = run_heights(tmp_path, "coarse", *extra, dsm=coarse)
    _, fine_rows, _ = run_heights(tmp_path, "fine", *extra)
    low = column(fine_rows, "height_p90_m") - column(rows, "height_p90_m")
    stated = column(rows, "height_p90_err_m")
    assert np.nanmedian(low) > 0.1 and np.nanmedian(stated) < 0.05  # what the check is for
    check = json.loads((out / "summary.json").read_text())["resolution_check"]
    assert check["passed"] is False and check["surface_pixel_m"] == pytest.approx(1.352, abs=1e-3)
    assert check["stated_error_m"] < check["p90_drop_m"] < np.nanmedian(low)
    assert f"note: {check['note']}" in stdout and "1.35 m pixel" in check["note"]


def test_the_windowed_command_reads_a_ruler_as_the_in_memory_one_does(tmp_path):
    # A field book for the real pair's plots: 8 cm + 10 % above the DSM.
    need_plots()
    _, rows_m, _ = run_heights(tmp_path, "memory")
    p90 = column(rows_m, "height_p90_m")
    rng = np.random.default_rng(3)
    measured = 0.08 + 1.1 * p90 + rng.normal(0, 0.02, p90.size)
    book = tmp_path / "book.csv"
    known = np.flatnonzero(np.isfinite(measured))  # the last plot lies outside the DSM
    # By the plots' own ids (their attribute `plot`, 1-based; the table's `plot` is the 0-based index).
    book.write_text(
        "plot,height_m\n" + "".join(f"{rows_m[k]['plot_attr']},{measured[k]:.4f}\n" for k in known)
    )
    ruler = ("--ruler", str(book), "--calibrate")
    out_m, rows_m, stdout_m = run_heights(tmp_path, "memory_ruler", *ruler)
    out_w, rows_w, stdout_w = run_heights(tmp_path, "windowed_ruler", "--windowed", "--window", "128", *ruler)
    assert list(rows_m[0]) == list(rows_w[0])  # the ruler's columns in the same place
    for name in ("ruler_height_m", "height_calibrated_m", "height_calibrated_err_m"):
        assert np.isfinite(column(rows_w, name)[known]).all(), name
    np.testing.assert_allclose(column(rows_w, "ruler_height_m"), measured, atol=1e-4)  # NaN where none
    np.testing.assert_allclose(
        column(rows_w, "height_calibrated_m"), column(rows_m, "height_calibrated_m"), atol=0.01
    )
    for out, stdout in ((out_m, stdout_m), (out_w, stdout_w)):
        record = json.loads((out / "summary.json").read_text())["ruler"]
        assert record["plots_matched"] == known.size and record["calibration"]["n"] == known.size
        assert (
            f"against the ruler ({known.size} plots)" in stdout and "calibrated leave-one-out RMSE" in stdout
        )
        assert (out / "ruler.png").is_file()


@pytest.mark.parametrize("phase", [0, 2, 4, 6])
def test_a_coarse_block_gives_the_soil_it_shows_wherever_it_falls_on_the_rows(tmp_path, phase):
    # Rows of green plants 0.5 m tall and furrows of brown soil 0.1 m deep, 3 pixels wide in every
    # 7, on a level field; the blurred index leaves each furrow's middle pixel bare. Blocks of 8 x 8
    # pixels hold one or two of those columns depending on where they fall on the rows. Each block
    # gives its soil's height and colour (the ground's evidence wherever the full grid has some),
    # never the plants' mean: a share rule ("most of the block") gave the mixed heights, and which
    # blocks counted as soil moved with the rows' phase.
    from cliff_terrain.measure.window_tasks import CoarseTask, coarse_window

    rows, cols, gsd, factor = 48, 48, 0.05, 8
    furrow = (np.arange(cols) + phase) % 7 < 3
    rgb = np.where(furrow[None, :, None], np.array([120, 90, 60]), np.array([40, 140, 40]))
    rgb = np.broadcast_to(rgb, (rows, cols, 3)).astype(np.uint8)
    heights = np.where(furrow[None, :], -0.1, 0.5) + np.zeros((rows, 1))
    transform = np.array([[gsd, 0, 500_000.0], [0, -gsd, 5_000_000.0], [0, 0, 1]])
    tifffile.imwrite(tmp_path / "ortho.tif", rgb, photometric="rgb", extratags=geotiff_tags(transform, 32616))
    write_geotiff(tmp_path / "dsm.tif", heights.astype(np.float32), transform=transform, crs=32616)
    task = CoarseTask(
        str(tmp_path / "ortho.tif"), str(tmp_path / "dsm.tif"), transform, (rows, cols), factor, "green", 0.1,
        (0, rows, 0, cols),
    )  # fmt: skip
    coarse = coarse_window(task)
    assert coarse["dsm"].shape == (6, 6) and coarse["valid"].all()
    # Every block shows a furrow's middle: its height is the furrow's, and it is the ground's evidence.
    np.testing.assert_allclose(coarse["dsm"], -0.1, atol=1e-3)
    assert coarse["soil"].all() and "rgb" not in coarse


def test_a_coarser_ground_grid_takes_as_soil_what_the_whole_photo_calls_soil(tmp_path):
    # The shared pair's plants recoloured a yellowing green (R : G : B = 1 : 1 : 0.7, index 0.11:
    # below the plant threshold, 0.14, yet above the soil class's ceiling: not plant, not soil). On a
    # 2 x 2 ground grid the windows' blocks take as soil what bare_soil calls soil on the whole
    # photo; the in-memory fit on the same grid then gets the same evidence and heights, and the same
    # held-out check. Blocks that took every pixel below the threshold as soil stood on the leaves.
    need_plots()
    from cliff_terrain.io.raster.geotiff import read_orthophoto, read_surface, resample
    from cliff_terrain.measure.canopy import plant_mask
    from cliff_terrain.measure.ground_grid import fit_on_ground_grid
    from cliff_terrain.photo_heights.bare_soil import bare_soil

    photo = read_orthophoto(ORTHO)
    rgb = photo.data.copy()
    plants = plant_mask(rgb, valid=photo.valid)
    level = rgb[plants].max(axis=-1).astype(np.float32)
    rgb[plants] = np.clip(level[:, None] * [1.0, 1.0, 0.7], 0, 255).astype(np.uint8)
    yellowing = tmp_path / "yellowing.tif"
    alpha = (np.ones(photo.shape, bool) if photo.valid is None else photo.valid).astype(np.uint8) * 255
    tifffile.imwrite(
        yellowing, np.dstack([rgb, alpha]), photometric="rgb", extrasamples=[2],
        extratags=geotiff_tags(photo.transform, photo.crs),
    )  # fmt: skip
    result, _ = windowed(
        tmp_path, "w", yellowing, DSM, read_plots(PAIR_PLOTS), window=100, ground_pixels=100_000
    )
    assert result.factor == 2 and result.windows == 36
    surface = resample(read_surface(DSM), transform=photo.transform, shape=photo.shape)
    valid = read_orthophoto(yellowing).valid
    has_data = np.isfinite(surface) & valid
    soil = bare_soil(rgb, valid=valid, threshold=result.threshold)
    *_, check = fit_on_ground_grid(
        surface, soil=soil, has_data=has_data, pixel_size=result.pixel_size, factor=2, source="yellowing"
    )
    assert (soil & plants).sum() < 0.1 * plants.sum()  # the yellowing leaves are not soil (but rims)
    assert check["method"] == result.check["method"]
    # The same to the bit: the same DSM (io.raster.bilinear), the same soil, and a block half off the
    # DSM without data in both (until 2026-12-06 the windows counted the photo's pixels alone there:
    # 0.02-0.04 mm apart); with every pixel below the threshold as soil, 0.5 to 1 mm apart and 0.6 %
    # more evidence.
    for name, figures in check["candidates"].items():
        assert result.check["candidates"][name]["error_m"] == figures["error_m"], name
    assert result.check["evidence"]["share"] == check["evidence"]["share"]


def synthetic_trial(folder):
    """A synthetic field at 1 cm (its ground's grid then 5 cm), a 6 x 9 grid of 1 m plots, and the truth."""
    from cliff_terrain.data.synthetic_surface import synthetic_surface

    gsd = 0.01
    image, dsm, truth = synthetic_surface(shape=(600, 900), gsd=gsd, seed=3)
    transform = np.array([[gsd, 0, 500_000.0], [0, -gsd, 5_000_000.0], [0, 0, 1]])
    tifffile.imwrite(
        folder / "ortho.tif", image, tile=(128, 128), photometric="rgb", compression="zlib",
        extratags=geotiff_tags(transform, 32616),
    )  # fmt: skip
    write_geotiff(folder / "dsm.tif", dsm, transform=transform, crs=32616, nodata=float("nan"))  # striped
    polygons = []
    for i in range(6):
        for j in range(9):
            x0, y0 = 500_000.0 + j * 1.0 + 0.02, 5_000_000.0 - i * 1.0 - 0.02
            polygons.append([np.array([[x0, y0], [x0 + 0.96, y0], [x0 + 0.96, y0 - 0.96], [x0, y0 - 0.96]])])
    plots = PlotSet(polygons, [{"name": f"p{k}"} for k in range(len(polygons))], ("name",), 32616, "")
    write_plots(plots, folder / "plots.geojson", crs=32616)
    return read_plots(folder / "plots.geojson"), truth, transform


def test_a_synthetic_field_on_a_coarser_ground_grid_is_exact_across_windows_and_near_the_truth(tmp_path):
    from cliff_terrain.measure.field_plots import plot_table, rasterize_plots

    plots, truth, transform = synthetic_trial(tmp_path)
    ortho, dsm = tmp_path / "ortho.tif", tmp_path / "dsm.tif"
    whole = windowed(tmp_path, "whole", ortho, dsm, plots, window=1024)
    small = windowed(tmp_path, "small", ortho, dsm, plots, window=160)
    assert whole[0].factor == 5 and small[0].windows == 24  # 5 cm ground grid
    assert_same(whole, small)
    # The true canopy's p90 per plot (the same pixels, heights from the truth), and the in-memory
    # run's on the orthophoto's own 1 cm grid. Measured: windowed (5 cm ground) against the truth
    # median +1.1 cm, at most 6.3 cm; in memory +0.9 cm, at most 5.5 cm; the two within 1.5 cm.
    labels = rasterize_plots(plots, transform=transform, shape=truth.chm.shape)
    true_rows = plot_table(plots, labels, mask=truth.labels > 0, heights=truth.chm, pixel_area_m2=1e-4)
    relief = build_relief(ortho, ReliefParams(max_size=900, dsm=dsm, height_source="measured", mesh=None))
    memory_rows = plot_table(plots, labels, mask=relief.mask, heights=relief.canopy.chm, pixel_area_m2=1e-4)
    p90 = np.array([r["height_p90_m"] for r in small[0].rows])
    true_p90 = np.array([r["height_p90_m"] for r in true_rows])
    memory_p90 = np.array([r["height_p90_m"] for r in memory_rows])
    assert np.abs(p90 - true_p90).max() < 0.07 and np.median(np.abs(p90 - true_p90)) < 0.015
    assert np.abs(p90 - memory_p90).max() < 0.02
    # The same pixels (areas from the file's pixel size, 1.0000000000000002e-4 m², against 1e-4).
    np.testing.assert_allclose(
        [r["area_m2"] for r in small[0].rows], [r["area_m2"] for r in true_rows], rtol=1e-12
    )


def test_the_windowed_rasters_are_the_in_memory_writers_overviews_included(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.normal(size=(1300, 1100)).astype(np.float32)
    data[rng.random(data.shape) < 0.1] = np.nan
    transform = np.array([[0.1, 0, 1000.0], [0, -0.1, 2000.0], [0, 0, 1]])
    write_geotiff(
        tmp_path / "whole.tif", data, transform=transform, crs=32616, nodata=float("nan"), overviews=True
    )
    spool = RasterSpool(tmp_path, "chm", data.shape)
    for r0 in range(0, 1300, 300):  # windows out of order: columns right to left
        for c0 in reversed(range(0, 1100, 400)):
            spool.put(r0, c0, data[r0 : r0 + 300, c0 : c0 + 400])
    spool.write_geotiff(tmp_path / "streamed.tif", transform=transform, crs=32616, nodata=float("nan"))
    spool.close()
    with tifffile.TiffFile(tmp_path / "whole.tif") as a, tifffile.TiffFile(tmp_path / "streamed.tif") as b:
        assert len(a.pages) == len(b.pages) == 3
        for pa, pb in zip(a.pages, b.pages, strict=True):
            np.testing.assert_array_equal(pa.asarray(), pb.asarray())
            assert pa.tilewidth == pb.tilewidth == 512 and pa.compression == pb.compression
        tags = {t.code: t.value for t in a.pages[0].tags.values() if t.code >= 33550}
        assert tags == {t.code: t.value for t in b.pages[0].tags.values() if t.code >= 33550}
    assert not (tmp_path / "chm.raw").exists()


def test_windows_encoded_where_measured_write_the_same_file_byte_for_byte(tmp_path):
    # Windows of whole tiles come back compressed (encode_block, on the workers); the file written
    # from their bytes is RasterSpool's, which compresses every tile itself (tested above against
    # the in-memory writer), to the byte: same tiles, same overviews, same tags.
    rng = np.random.default_rng(1)
    data = rng.normal(size=(1300, 1100)).astype(np.float32)  # neither side a multiple of 512
    data[rng.random(data.shape) < 0.1] = np.nan
    transform = np.array([[0.1, 0, 1000.0], [0, -0.1, 2000.0], [0, 0, 1]])
    raw, encoded = RasterSpool(tmp_path, "raw", data.shape), TileSpool(tmp_path, "encoded", data.shape)
    for r0 in reversed(range(0, 1300, 512)):  # out of order, the edges' short tiles included
        for c0 in range(0, 1100, 1024):
            block = data[r0 : r0 + 512, c0 : c0 + 1024]
            raw.put(r0, c0, block)
            encoded.put(r0, c0, encode_block(block))
    np.testing.assert_array_equal(encoded.read_rows(300, 1300), data[300:])
    for spool in (raw, encoded):
        spool.write_geotiff(
            tmp_path / f"{spool.path}.tif", transform=transform, crs=32616, nodata=float("nan")
        )
        spool.close()
    assert (tmp_path / "encoded.tiles.tif").read_bytes() == (tmp_path / "raw.raw.tif").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["encoded.tiles.tif", "raw.raw.tif"]
    unaligned = TileSpool(tmp_path, "x", data.shape)
    with pytest.raises(ValueError, match=r"must start on a tile corner, not at \(0, 100\)"):
        unaligned.put(0, 100, encode_block(data[:512, 100:612]))
    with pytest.raises(
        ValueError, match=r"must be whole tiles but at the raster's edge, not 512 x 600 at \(0, 0\)"
    ):
        unaligned.put(0, 0, encode_block(data[:512, :600]))
    unaligned.close()


@pytest.mark.parametrize("levels", [2, 3])
def test_windows_that_encode_their_overviews_too_write_the_same_file_byte_for_byte(tmp_path, levels):
    # Windows of 1024 (2048) pixels give their first (and second) overview as whole tiles too, encoded
    # where they were measured: the one process writing the file then compresses a twelfth (a
    # forty-eighth) of the pixels instead of a third. The file is RasterSpool's to the byte.
    rng = np.random.default_rng(2)
    side = 512 << (levels - 1)
    data = rng.normal(size=(2 * side + 300, side + 700)).astype(np.float32)  # short tiles at both edges
    data[rng.random(data.shape) < 0.1] = np.nan
    transform = np.array([[0.1, 0, 1000.0], [0, -0.1, 2000.0], [0, 0, 1]])
    raw = RasterSpool(tmp_path, "raw", data.shape)
    encoded = TileSpool(tmp_path, "encoded", data.shape, levels=levels)
    assert isinstance(encoded.half, TileSpool)
    for r0 in reversed(range(0, data.shape[0], side)):
        for c0 in range(0, data.shape[1], side):
            block = data[r0 : r0 + side, c0 : c0 + side]
            raw.put(r0, c0, block)
            encoded.put(r0, c0, encode_block(block, levels=levels))
    for spool in (raw, encoded):
        spool.write_geotiff(
            tmp_path / f"{spool.path}.tif", transform=transform, crs=32616, nodata=float("nan")
        )
        spool.close()
    written = (tmp_path / "encoded.tiles.tif").read_bytes()
    assert written == (tmp_path / "raw.raw.tif").read_bytes()
    with tifffile.TiffFile(tmp_path / "encoded.tiles.tif") as tif:  # halving until one tile holds it
        assert len(tif.pages) == 1 + math.ceil(math.log2(max(data.shape) / 512))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["encoded.tiles.tif", "raw.raw.tif"]
    mixed = TileSpool(tmp_path, "mixed", data.shape, levels=levels)
    with pytest.raises(ValueError, match=f"a block encoded to 1 level\\(s\\) given to a spool of {levels}"):
        mixed.put(0, 0, encode_block(data[:side, :side]))
    mixed.close()


def test_with_a_terrain_model_encoded_and_raw_windows_give_the_same_chm(tmp_path):
    # A DTM instead of an estimated ground: only chm.tif, no error or support raster. Windows of
    # whole tiles (512, sent back compressed) and small ones (100) give the same CHM to the bit, and
    # it is the DSM minus the terrain model on the orthophoto's grid.
    need_plots()
    from cliff_terrain.io.raster.geotiff import read_surface

    dsm = read_surface(DSM)
    dtm_path = tmp_path / "dtm.tif"
    terrain = np.full(dsm.shape, np.nanpercentile(dsm.data, 2), np.float32)  # a flat ground
    write_geotiff(dtm_path, terrain, transform=dsm.transform, crs=dsm.crs)
    plots = read_plots(PAIR_PLOTS)
    runs = []
    for window in (512, 100):
        folder = tmp_path / f"w{window}"
        folder.mkdir()
        result = measure_windowed(ORTHO, DSM, dtm=dtm_path, plots=plots, folder=folder, window=window)
        assert list(result.spools) == ["chm"] and result.check is None and result.ground_source == "dtm"
        assert isinstance(result.spools["chm"], TileSpool if window == 512 else RasterSpool)
        runs.append((result, {n: s.read_rows(0, s.shape[0]) for n, s in result.spools.items()}))
        result.close()
    assert_same(*runs)
    chm = runs[0][1]["chm"]
    assert np.isfinite(chm).mean() > 0.8  # the ODM orthophoto has a no-data border
    p90 = np.array([r["height_p90_m"] for r in runs[0][0].rows])
    assert np.isfinite(p90).all()
    # The CHM is the surface above the flat ground: its median over the field is the DSM's median
    # minus the ground's level, whatever the resampling onto the orthophoto's grid.
    level = float(terrain[0, 0])
    assert np.nanmedian(chm) == pytest.approx(np.nanmedian(dsm.data) - level, abs=0.05)
    assert_table_text(runs[0][0], plots)


def test_the_ground_is_upsampled_with_its_pixel_centres_aligned():
    coarse = np.array([[0.0, 1.0, 2.0, 3.0], [4.0, 5.0, 6.0, 7.0], [8.0, 9.0, 10.0, 11.0]], np.float32)
    full = upsample(coarse, 4, 0, 12, 0, 16)
    # Full pixel i lies at coarse (i + 0.5) / 4 - 0.5: coarse centre k between full pixels 4k + 1 and
    # 4k + 2; held flat beyond the outer centres.
    u = np.clip((np.arange(16) + 0.5) / 4 - 0.5, 0, 3)
    v = np.clip((np.arange(12) + 0.5) / 4 - 0.5, 0, 2)
    np.testing.assert_allclose(full, 4 * v[:, None] + u[None, :], atol=1e-6)
    # A window's values are the whole grid's, to the bit.
    np.testing.assert_array_equal(upsample(coarse, 4, 5, 9, 3, 14), full[5:9, 3:14])


def test_local_workers_idle_beside_a_ground_grid_that_fills_its_budget(tmp_path):
    """bench/bench_scale.py's 66 MP field (15 x 15 copies at 0.2 m, 32 400 plots): its ground grid
    (7.4 MP) nearly fills the budget. With two local workers the whole process tree peaked at 1.56
    GiB (AMD EPYC, 2026-12-08: summed resident sets sampled at 10 Hz); the plan refused it at 4.19
    GiB while it counted the fit at the coefficient the grid is sized with (0.45 GiB/MP)."""
    from cliff_terrain.commands.memory_estimate import windowed_plan

    ortho = empty_raster(tmp_path / "ortho.tif", 8250, 8025, 0.2)
    dsm = empty_raster(tmp_path / "dsm.tif", 8250, 8025, 0.2, bands=1, dtype=np.float32)
    plans = [windowed_plan(ortho, (dsm,), window_px=1104, plots=32_400, workers=k) for k in (0, 1, 2)]
    # The same ground grid however many workers, each estimate above the next smaller count's and
    # above what the two-worker run took.
    assert len({budget for budget, _ in plans}) == 1
    estimates = [estimate for _, estimate in plans]
    assert estimates == sorted(estimates) and 1.56 < estimates[2] < 4.0


def test_a_refused_plan_names_a_cap_that_fits(tmp_path):
    """A larger cap enlarges the ground's grid too, so the estimate under one cap is not a cap that
    fits: the refusal names the least one that does, in tenths of a GiB."""
    import re

    from cliff_terrain.commands.memory_estimate import windowed_plan

    # 400 MP at 1 cm, its DSM at 3 cm, ten local workers: each holds its copy of the coarse ground.
    ortho = empty_raster(tmp_path / "ortho.tif", 20_000, 20_000, 0.01)
    dsm = empty_raster(tmp_path / "dsm.tif", 6667, 6667, 0.03, bands=1, dtype=np.float32)
    plan = functools.partial(windowed_plan, ortho, (dsm,), window_px=1024, plots=1000, workers=10)
    with pytest.raises(CliffTerrainError) as refused:
        plan(cap_gib=4.0)
    message = str(refused.value)
    estimate = float(re.search(r"needs about ([\d.]+) GiB under the 4 GiB cap", message).group(1))
    enough = float(re.search(r"give --max-memory ([\d.]+) or more", message).group(1))
    assert "use fewer --workers" in message and enough > 4.0
    _, at_enough = plan(cap_gib=enough)
    assert at_enough <= enough
    with pytest.raises(CliffTerrainError):
        plan(cap_gib=round(enough - 0.1, 1))
    # Raising the cap to the estimate alone is not enough: the grid, and each worker's copy, grow with it.
    assert estimate < enough - 0.1
    with pytest.raises(CliffTerrainError):
        plan(cap_gib=estimate)


def test_past_the_cap_the_command_measures_in_windows_instead_of_refusing(tmp_path):
    from cliff_terrain.cli import build_parser
    from cliff_terrain.commands.heights import _windowed
    from cliff_terrain.commands.memory_estimate import grid_estimate, windowed_plan

    synthetic_trial(tmp_path)
    ortho, dsm, plots = tmp_path / "ortho.tif", tmp_path / "dsm.tif", tmp_path / "plots.geojson"
    _, needs = windowed_plan(ortho, (dsm,), window_px=2100, cap_gib=4.0)
    # A second thread holds its own window and readers: counted.
    _, needs_two = windowed_plan(ortho, (dsm,), window_px=2100, cap_gib=4.0, threads=2)
    assert needs_two > needs
    # The ground grid is the files' and the cap's alone: threads, workers and the window change
    # what is held at once, never the ground, so every way of running gives the same tables.
    budgets = {
        windowed_plan(ortho, (dsm,), window_px=w, cap_gib=4.0, threads=t, workers=k)[0]
        for w, t, k in [(2100, 1, 0), (600, 1, 0), (2100, 3, 0), (2100, 1, 1), (2100, 1, 2)]
    }
    assert len(budgets) == 1
    # Parallelism that does not fit beside that ground is refused, naming what to change.
    with pytest.raises(CliffTerrainError, match="use fewer --workers"):
        windowed_plan(ortho, (dsm,), window_px=2100, cap_gib=needs + 0.05, workers=8)
    # A 100 MP orthophoto at 1 cm (its DSM at 3 cm): in memory it would pass the 4 GiB cap, in
    # windows it fits, and that is how it is measured; asked for on a coarser grid, in memory.
    big = empty_raster(tmp_path / "big.tif", 10_000, 10_000, 0.01)
    big_dsm = empty_raster(tmp_path / "big_dsm.tif", 3334, 3334, 0.03, bands=1, dtype=np.float32)
    in_memory, *_ = grid_estimate(big, [100.0, 3334**2 / 1e6], 10_000)
    _, in_windows = windowed_plan(big, (big_dsm,), window_px=2048, cap_gib=4.0)
    assert in_windows < 4.0 < in_memory
    parser = build_parser()

    def decide(*extra):
        return _windowed(
            parser.parse_args(["heights", str(big), "--dsm", str(big_dsm), "--out", "x", *extra])
        )

    assert decide() is True
    assert decide("--max-size", "6000") is False
    # A 12 MP orthophoto at 1 cm is measured in memory (its regions.csv with it): its ground is
    # fitted on 5 cm, so its estimate lies under the cap and above the 1.22 GiB that
    # bench/bench_heights_memory.py measured on the synthetic 1 cm field of that size.
    small = empty_raster(tmp_path / "small.tif", 3000, 4000, 0.01)
    small_dsm = empty_raster(tmp_path / "small_dsm.tif", 1000, 1334, 0.03, bands=1, dtype=np.float32)
    assert (
        _windowed(parser.parse_args(["heights", str(small), "--dsm", str(small_dsm), "--out", "x"])) is False
    )
    assert 1.22 <= grid_estimate(small, [12.0, 1.334], 4000)[0] < 4.0
    # The synthetic field in windows when asked: the summary's estimate and ground grid.
    out, table, stdout = run_heights(tmp_path, "auto", "--windowed", ortho=ortho, dsm=dsm, plots=plots)
    assert "windowed (1 windows)" in stdout and len(table) == 54
    summary = json.loads((out / "summary.json").read_text())
    assert needs <= summary["windowed"]["memory_estimate_gib"] <= 4.0  # one window or more at once
    assert summary["windowed"]["ground_grid_pixel_m"] == pytest.approx(0.05)
    assert not (out / "regions.csv").exists()
    # Under what even the windowed run needs: refused in one line, with the in-memory run's advice.
    command = [
        sys.executable,
        "-m",
        "cliff_terrain",
        "heights",
        str(ortho),
        "--dsm",
        str(dsm),
        "--no-progress",
    ]
    done = subprocess.run(
        [*command, "--out", str(tmp_path / "low"), "--max-memory", "0.3"],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "use --max-size" in done.stderr, (
        done.stderr
    )


def test_the_windowed_options_refuse_what_they_cannot_do_in_one_line(tmp_path):
    need_plots()
    base = [sys.executable, "-m", "cliff_terrain", "heights", str(ORTHO), "--dsm", str(DSM), "--no-progress"]
    cases = [
        (["--windowed", "--max-size", "300"], "--windowed measures at the orthophoto's own resolution"),
        (["--window", "256"], "--window 256 needs --windowed"),
        (
            ["--windowed", "--indices", "NDVI"],
            f"--indices and --band-files read the bands of '{ORTHO}' whole",
        ),
        (["--windowed", "--window", "8"], "`--window` must be >= 64, got 8"),
        (["--workers", "2"], "--workers 2 spreads the windows of --windowed over a cluster: add --windowed"),
        (["--windowed", "--workers", "-1"], "--workers must be 0 or more, got -1"),
        (
            ["--windowed", "--tls-cert", "c.pem"],
            "--tls-ca-file, --tls-cert and --tls-key are for a tls:// --scheduler",
        ),
        (["--windowed", "--scheduler", "tls://127.0.0.1:8786"], "needs --tls-ca-file, --tls-cert, --tls-key"),
    ]
    for extra, message in cases:
        done = subprocess.run(
            [*base, "--out", str(tmp_path / "x"), *extra], capture_output=True, text=True, cwd=REPO
        )
        assert done.returncode == 2 and done.stderr.count("\n") == 1 and message in done.stderr, (
            extra,
            done.stderr,
        )
        assert not (tmp_path / "x" / "summary.json").exists()


def test_an_8_bit_export_with_gdal_nodata_has_no_data_outside_the_flight_in_memory_as_in_windows(tmp_path):
    # The pair's orthophoto as an export without alpha writes it: 8-bit RGB, black outside the flight,
    # GDAL_NODATA 0. Pillow read it in memory and took the black for data (and soil): "only 0
    # bare-soil pixels", exit 2; the windows honoured GDAL_NODATA. Now both read it alike. (Without
    # GDAL_NODATA black is a colour: the dark soil of a real photo has pixels of exact zeros.)
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    need_plots()
    ortho = read_orthophoto(ORTHO)
    rgb = np.where(ortho.valid[..., None], ortho.data, 0).astype(np.uint8)
    assert (~ortho.valid).mean() > 0.05  # a real outline, not a few pixels
    path = tmp_path / "ortho_rgb8.tif"
    tifffile.imwrite(
        path, rgb, photometric="rgb", compression="zlib",
        extratags=geotiff_tags(ortho.transform, ortho.crs, nodata=0),
    )  # fmt: skip
    _, rows_m, _ = run_heights(tmp_path, "memory", ortho=path)
    _, rows_w, _ = run_heights(tmp_path, "windows", "--windowed", ortho=path)
    assert rows_w == rows_m
    # The same pixels with data as the float original's: the plots' areas with data and heights are
    # its within the rounding of the photo to 8 bits.
    _, rows_f, _ = run_heights(tmp_path, "float")
    np.testing.assert_allclose(column(rows_m, "height_p90_m"), column(rows_f, "height_p90_m"), atol=0.01)


def test_a_16_bit_rgba_orthophoto_gives_the_same_table_in_memory_as_in_windows(tmp_path):
    # The pair's photo as 16-bit RGBA (alpha 0 outside the flight). In memory Pillow read it, keeping
    # each sample's high byte, where the windows scale 16 bits by the depth used: plots' cover
    # differed by up to 0.17 points and p90 by 0.6 mm. Every GeoTIFF orthophoto is now read by one
    # rule (io.raster.photo_samples.photo_bands) in both paths.
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    need_plots()
    ortho = read_orthophoto(ORTHO)
    rgb16 = ortho.data.astype(np.uint16) * 256 + 100  # not a multiple of 257: Pillow's byte differs
    alpha = np.where(ortho.valid, 65535, 0).astype(np.uint16)
    path = tmp_path / "ortho_rgba16.tif"
    tifffile.imwrite(
        path, np.dstack([rgb16, alpha]), photometric="rgb", extrasamples=[2], compression="zlib",
        extratags=geotiff_tags(ortho.transform, ortho.crs),
    )  # fmt: skip
    _, rows_m, _ = run_heights(tmp_path, "memory", ortho=path)
    _, rows_w, _ = run_heights(tmp_path, "windows", "--windowed", "--window", "256", ortho=path)
    assert rows_w == rows_m
    assert np.isfinite(column(rows_m, "height_p90_m")).all()


def test_a_multispectral_orthophoto_is_refused_in_windows_in_one_line_naming_its_bands(tmp_path):
    # R, G, B and a fourth band GDAL describes as NIR (ExtraSamples unspecified): the windows took
    # the NIR for alpha and measured (exit 0) where the in-memory run asked for the bands' names.
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    need_pair()
    ortho = read_orthophoto(ORTHO)
    nir = np.clip(ortho.data[..., 1].astype(np.int16) * 2, 1, 255).astype(np.uint8)
    path = tmp_path / "ortho_rgbn.tif"
    metadata = (
        "<GDALMetadata>\n"
        + "".join(
            f'  <Item name="DESCRIPTION" sample="{i}" role="description">{d}</Item>\n'
            for i, d in enumerate(("Red", "Green", "Blue", "NIR"))
        )
        + "</GDALMetadata>\n"
    )
    tifffile.imwrite(
        path, np.dstack([ortho.data, nir]), photometric="rgb", extrasamples=[0], tile=(256, 256),
        extratags=geotiff_tags(ortho.transform, ortho.crs) + [(42112, "s", 0, metadata, True)],
    )  # fmt: skip
    out = tmp_path / "out"
    command = [sys.executable, "-m", "cliff_terrain", "heights", str(path), "--dsm", str(DSM)]
    command += ["--out", str(out), "--no-progress", "--windowed"]
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=600)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "is a multispectral orthomosaic (4 bands: red, green, blue, NIR)" in done.stderr
    assert "gdal_translate -b 1 -b 2 -b 3 -co TILED=YES" in done.stderr
    assert not out.exists()


def test_a_dsm_stored_in_centimetres_with_gdals_scale_and_offset_reads_in_metres_both_ways(tmp_path):
    # The pair's DSM as int16 centimetres above 200 m, GDAL's scale 0.01 and offset 200 in its
    # metadata: read as stored until 2026-12-06, the ground check missed by 86 cm and refused it
    # (and a float DSM with scale 0.5 measured every plant twice as tall).
    from cliff_terrain.io.raster.geotiff import read_surface

    need_plots()
    dsm = read_surface(DSM)
    stored = np.where(np.isfinite(dsm.data), np.round((dsm.data - 200.0) * 100.0), -32768).astype(np.int16)
    xml = (
        '<GDALMetadata><Item name="SCALE" sample="0" role="scale">0.01</Item>'
        '<Item name="OFFSET" sample="0" role="offset">200</Item></GDALMetadata>'
    )
    path = tmp_path / "dsm_cm.tif"
    tags = geotiff_tags(dsm.transform, dsm.crs, nodata=-32768) + [(42112, "s", 0, xml, True)]
    tifffile.imwrite(path, stored, compression="zlib", extratags=tags)
    back = read_surface(path)
    assert np.nanmax(np.abs(back.data - dsm.data)) <= 0.005 + 1e-4
    _, rows_m, _ = run_heights(tmp_path, "memory", dsm=path)
    _, rows_w, _ = run_heights(tmp_path, "windows", "--windowed", dsm=path)
    _, rows_f, _ = run_heights(tmp_path, "float")
    assert rows_w == rows_m
    np.testing.assert_allclose(column(rows_m, "height_p90_m"), column(rows_f, "height_p90_m"), atol=0.01)


def test_a_dsm_rotated_against_the_photo_is_refused_in_windows_in_one_line(tmp_path):
    # The windows read rows of the DSM as rows of the photo; the in-memory path warps a rotated DSM.
    plots, _, transform = synthetic_trial(tmp_path)
    angle = np.deg2rad(10.0)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    dsm = np.zeros((600, 900), np.float32)
    write_geotiff(tmp_path / "turned.tif", dsm, transform=transform @ turn, crs=32616, nodata=float("nan"))
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", "heights", str(tmp_path / "ortho.tif"),
         "--dsm", str(tmp_path / "turned.tif"), "--windowed", "--no-progress", "--out", str(out)],
        capture_output=True, text=True, cwd=REPO,
    )  # fmt: skip
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert f"'{tmp_path / 'turned.tif'}' is rotated against the orthophoto's grid" in done.stderr
    assert "measure it without --windowed or warp it north-up" in done.stderr
    assert not (out / "summary.json").exists()


def test_windows_on_three_threads_give_exactly_what_one_gives(tmp_path):
    need_plots()
    plots = read_plots(PAIR_PLOTS)
    one = windowed(tmp_path, "one", ORTHO, DSM, plots, window=128, ground_pixels=100_000)
    three = windowed(tmp_path, "three", ORTHO, DSM, plots, window=128, ground_pixels=100_000, threads=3)
    assert one[0].windows == three[0].windows == 25
    assert_same(one, three)


def test_an_unreachable_scheduler_exits_in_one_line_and_leaves_no_empty_out_folder(tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "new" / "out"
    command = [
        sys.executable,
        "-m",
        "cliff_terrain",
        "heights",
        str(ORTHO),
        "--dsm",
        str(DSM),
        "--no-progress",
    ]
    command += ["--out", str(out), "--windowed", "--scheduler", "tcp://127.0.0.1:9", "--timeout", "1"]
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=120)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "127.0.0.1:9" in done.stderr
    assert not out.exists() and (tmp_path / "new").is_dir()  # the parent stays: only what was empty goes


def test_a_dask_cluster_gives_exactly_what_this_process_gives(tmp_path):
    """Both passes' windows as tasks on two worker processes (the readers opened in the workers, the
    coarse ground scattered to them): every plot column and raster pixel equal to the in-process run,
    on the ground grid of the orthophoto's own pixels and on one 2 pixels to one. Joined by its
    address, as a scheduler elsewhere, the cluster also runs the ground check's five folds; a
    local cluster's client leaves them here, where the memory plan counts them."""
    need_plots()
    from distributed import Client, get_task_stream

    from cliff_terrain.season.cluster import local_cluster

    plots = read_plots(PAIR_PLOTS)
    with (
        local_cluster(2) as cluster,
        Client(cluster, set_as_default=False) as local,
        Client(cluster.scheduler_address, set_as_default=False) as remote,
    ):
        # 128: windows of raw rasters; 512: whole tiles, sent back compressed.
        for ground_pixels, window, count, client in (
            (6_000_000, 128, 25, local),
            (100_000, 128, 25, remote),
            (6_000_000, 512, 4, remote),
        ):
            name = f"{ground_pixels}-{window}"
            here = windowed(
                tmp_path, f"here{name}", ORTHO, DSM, plots, window=window, ground_pixels=ground_pixels
            )
            with get_task_stream(client=client) as stream:
                there = windowed(
                    tmp_path, f"there{name}", ORTHO, DSM, plots, window=window, ground_pixels=ground_pixels,
                    client=client,
                )  # fmt: skip
            folds = [task for task in stream.data if task["key"].startswith("fold_grounds")]
            assert len(folds) == (there[0].check["folds_used"] if client is remote else 0)
            assert there[0].windows == count
            assert_same(here, there)
            assert_table_text(there[0], plots)


def _nap(k, seconds):
    import time

    if seconds < 0:
        raise CliffTerrainError(f"window {k} is broken")
    time.sleep(seconds)
    return k


def test_windows_on_a_cluster_are_taken_as_they_finish_and_a_failure_stops_the_rest():
    # The passes place each window's result by its corner, so none waits for an older, slower one:
    # window 0 takes a second, the others finish first and are taken first.
    from distributed import Client, LocalCluster

    from cliff_terrain._dask import as_done

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        naps = [1.0, 0.0, 0.0, 0.0, 0.0]
        taken = list(as_done(client, _nap, ((k, s) for k, s in enumerate(naps)), ahead=3))
        assert sorted(taken) == [0, 1, 2, 3, 4] and taken[0] != 0 and taken.index(0) >= 2, taken

        # A failed window is raised when taken, with at most `ahead` windows sent beyond the one
        # taken; those not yet taken are cancelled: the scheduler forgets them at once (a window
        # already running finishes its nap on its thread, unseen).
        naps = [0.0, -1.0] + [2.0] * 20
        drawn = []

        def arguments():
            for k, s in enumerate(naps):
                drawn.append(k)
                yield k, s

        with pytest.raises(CliffTerrainError, match="window 1 is broken"):
            list(as_done(client, _nap, arguments(), ahead=3))
        assert len(drawn) <= 3 + 1, drawn
        for _ in range(20):  # released well before their 2 s are up
            if not any(client.processing().values()):
                break
            time.sleep(0.1)
        assert not any(client.processing().values())


def test_the_command_on_two_workers_writes_the_same_tables(tmp_path):
    # Windows of whole 512-pixel tiles: the workers send the rasters back compressed and the tables'
    # text made; every file is this process's, byte for byte.
    here, rows_here, _ = run_heights(tmp_path, "here", "--windowed", "--window", "512")
    there, rows_there, stdout = run_heights(
        tmp_path, "there", "--windowed", "--window", "512", "--workers", "2"
    )
    assert "windowed (4 windows)" in stdout
    assert rows_here == rows_there  # the CSV's text, every column
    for name in ("plots.csv", "plots.geojson", "chm.tif", "chm_err.tif", "ground_support.tif"):
        assert (here / name).read_bytes() == (there / name).read_bytes(), name


@pytest.mark.parametrize("stands", [True, False], ids=["senescent-canopy", "straw-on-the-ground"])
def test_the_windowed_threshold_is_decided_by_the_dsm_as_in_memory(tmp_path, stands, capsys):
    # test_segmentation's yellow canopy (or straw) over brown soil, the colour undecided: measured
    # in windows, the DSM decides as the in-memory segmentation does. A standing canopy is plant
    # (cover near the truth's share, its CHM about its 0.7 m); straw on the ground stays soil, and
    # the summary line says that its cover is the prior's, not a measurement (in memory too).
    from test_segmentation import _write_yellow_field

    from cliff_terrain.cli import main as cli

    truth = _write_yellow_field(tmp_path, stands)
    out = tmp_path / "out"
    code = cli(["heights", str(tmp_path / "ortho.tif"), "--dsm", str(tmp_path / "dsm.tif"), "--windowed",
                "--window", "64", "--out", str(out), "--no-progress"])  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    record = summary["threshold"]
    undecided = "the image cannot tell plants from soil here: a default threshold decided"
    if stands:
        assert code == 0
        assert record["source"] == "photo (dsm)" and record["note"].startswith("decided by the DSM")
        assert summary["cover"] == pytest.approx(truth.mean(), abs=0.05)
        chm = tifffile.imread(out / "chm.tif")
        assert np.nanmedian(chm[truth]) == pytest.approx(0.7, abs=0.1)
    else:
        assert code == 0 and record["source"] == "band"
        assert "the DSM does not show it" in record["note"] and summary["cover"] < 0.05
    line = capsys.readouterr().out
    assert (f"cover {summary['cover']:.1%} ({undecided}" in line) is not stands, line
    assert cli(["heights", str(tmp_path / "ortho.tif"), "--dsm", str(tmp_path / "dsm.tif"), "--out",
                str(tmp_path / "memory"), "--no-progress"]) == 0  # fmt: skip
    assert (undecided in capsys.readouterr().out) is not stands
    # A photo of one colour: the prior band decides, and the line says so whatever the DSM shows.
    transform, crs = read_georeference(tmp_path / "ortho.tif")
    brown = np.full((*truth.shape, 3), (120, 90, 60), np.uint8)
    write_geotiff(tmp_path / "brown.tif", brown, transform=transform, crs=crs)
    assert cli(["heights", str(tmp_path / "brown.tif"), "--dsm", str(tmp_path / "dsm.tif"), "--out",
                str(tmp_path / "brown"), "--no-progress"]) == 0  # fmt: skip
    assert undecided in capsys.readouterr().out
    assert json.loads((tmp_path / "brown" / "summary.json").read_text())["threshold"]["source"] == "uniform"


def test_the_plots_pixel_rings_and_boxes_are_each_plots_own(tmp_path):
    # Made for every plot at once: each ring and box as the plot alone gives them (one affine per
    # ring, its vertices' min and max), for hand-drawn plots, a plot in two parts and empty plots.
    from cliff_terrain.io.raster.geotiff import read_georeference
    from cliff_terrain.io.raster.transform import affine_inverse, apply_affine
    from cliff_terrain.measure.window_tasks import _plot_boxes

    need_plots()
    drawn = read_plots(PAIR_PLOTS)
    transform, _ = read_georeference(ORTHO)
    two_parts = [drawn.polygons[0][0], drawn.polygons[1][0] + 3.0]
    polygons = [[], *drawn.polygons, two_parts, []]
    plots = PlotSet(polygons, [{}] * len(polygons), (), drawn.crs, "")
    rings, boxes = _plot_boxes(plots, transform)
    inverse = affine_inverse(transform)
    assert len(rings) == len(boxes) == len(polygons)
    for polygon, got, box in zip(polygons, rings, boxes, strict=True):
        expected = [apply_affine(inverse, ring) for ring in polygon]
        assert len(got) == len(expected)
        for a, b in zip(got, expected, strict=True):
            np.testing.assert_array_equal(a, b)
        if polygon:
            vertices = np.concatenate(expected)
            np.testing.assert_array_equal(box, [*vertices.min(axis=0), *vertices.max(axis=0)])
        else:
            assert np.isnan(box).all()
    assert _plot_boxes(PlotSet([], [], (), None, ""), transform)[1].shape == (0, 4)


@pytest.mark.parametrize("extra", [(), ("--windowed", "--window", "256")])
def test_an_undeclared_no_data_value_is_no_surface_in_either_path(tmp_path, extra):
    # -9999 where the DSM has no data, not declared in GDAL_NODATA: mixed into its neighbours by the
    # resampling, it gave plausible heights that pulled the ground down (a potato field's canopy p90
    # at 19 m, exit 0). Now it is NaN, as a declared hole.
    from cliff_terrain.io.raster.surface_values import surface_data

    values = np.array([251.3, -9999.0, -32767.0, -3.4e38, np.nan, 1e6, -120.0], np.float32)
    assert surface_data(values).tolist() == [True, False, False, False, False, False, True]
    need_plots()
    with tifffile.TiffFile(DSM) as tif:
        heights = tif.pages[0].asarray().astype(np.float32)
    transform, crs = read_georeference(DSM)
    heights[~np.isfinite(heights) | (heights < -1e30)] = np.nan
    heights[100:200, 100:250] = np.nan
    declared = tmp_path / "declared.tif"
    write_geotiff(declared, heights, transform=transform, crs=crs, nodata=float("nan"))
    sentinel = tmp_path / "sentinel.tif"
    write_geotiff(
        sentinel, np.where(np.isnan(heights), np.float32(-9999), heights), transform=transform, crs=crs
    )
    # gdalwarp without -dstnodata fills outside the footprint with 0 and declares nothing: plants
    # measured 100 m tall. A float file with a corner at exactly 0 has its zeros taken as no data.
    assert np.isnan(heights[[0, 0, -1, -1], [0, -1, 0, -1]]).any()
    zeros = tmp_path / "zeros.tif"
    write_geotiff(zeros, np.where(np.isnan(heights), np.float32(0), heights), transform=transform, crs=crs)
    _, nan_rows, _ = run_heights(tmp_path, "nan", *extra, dsm=declared)
    _, sentinel_rows, _ = run_heights(tmp_path, "sentinel", *extra, dsm=sentinel)
    _, zero_rows, _ = run_heights(tmp_path, "zeros", *extra, dsm=zeros)
    assert nan_rows == sentinel_rows == zero_rows
    assert np.nanmax(column(sentinel_rows, "height_p90_m")) < 1.5  # potato, not 19 m trees


@pytest.mark.parametrize("extra", [(), ("--windowed", "--window", "256")])
def test_an_8_bit_orthophotos_black_collar_is_no_data_without_alpha_or_a_declared_value(tmp_path, extra):
    # The shared pair's orthophoto as 8-bit RGB without alpha (`gdal_translate -b 1 -b 2 -b 3`): its
    # 16 % black collar was taken for black soil, and the run was refused for want of bare soil.
    need_plots()
    with tifffile.TiffFile(ORTHO) as tif:
        page = tif.pages[0]
        colour = page.asarray()
        colour = np.moveaxis(colour, 0, -1) if page.planarconfig == 2 else colour
    rgb = np.clip(colour[..., :3], 0, 255).astype(np.uint8)
    assert (~rgb.any(axis=2)).mean() > 0.1  # the collar
    transform, crs = read_georeference(ORTHO)
    bare, declared = tmp_path / "bare.tif", tmp_path / "declared.tif"
    write_geotiff(bare, rgb, transform=transform, crs=crs)
    write_geotiff(declared, rgb, transform=transform, crs=crs, nodata=0)
    _, declared_rows, _ = run_heights(tmp_path, "declared", *extra, ortho=declared)
    _, bare_rows, _ = run_heights(tmp_path, "bare", *extra, ortho=bare)
    assert bare_rows == declared_rows


def test_overlapping_plots_are_each_measured_whole_as_alone():
    # Where plots overlap, the later took the pixels: the earlier was measured on part of its area
    # with no word said, and a plot a later copy covered was "outside the raster".
    from cliff_terrain.measure.field_plots import plot_layers, plot_table, rasterize_plots

    def square(x0, x1):
        return [np.array([[x0, 0.0], [x1, 0.0], [x1, -4.0], [x0, -4.0]])]

    rng = np.random.default_rng(1)
    heights = rng.uniform(0, 1, (4, 9))
    polygons = [square(0, 4), square(2, 6), square(0, 4), square(5, 9)]  # B overlaps A, C copies A
    plots = PlotSet(polygons, [{"id": k} for k in "ABCD"], ("id",), None, "")
    grid = {"transform": [[1, 0, 0], [0, -1, 0]], "shape": heights.shape}
    layers = plot_layers(plots, **grid)
    # C and D whole in the first; B in the second (C took its left half); A, under both, in the third.
    assert len(layers) == 3 and sum(layer.astype(bool).astype(int) for layer in layers).max() == 3
    table = plot_table(plots, layers, mask=heights > 0.5, heights=heights, pixel_area_m2=1.0)
    for k, polygon in enumerate(polygons):
        alone = PlotSet([polygon], [{"id": "ABCD"[k]}], ("id",), None, "")
        labels = rasterize_plots(alone, **grid)
        expected = plot_table(alone, labels, mask=heights > 0.5, heights=heights, pixel_area_m2=1.0)[0]
        assert {**table[k], "plot": 0} == expected, "ABCD"[k]
    # A row whose every plot reaches into the next (a buffer too wide): a few images, not one per plot.
    row = PlotSet([square(3 * k, 3 * k + 4) for k in range(60)], [{}] * 60, (), None, "")
    chain = plot_layers(row, transform=[[1, 0, 0], [0, -1, 0]], shape=(4, 190))
    assert len(chain) <= 3
    assert all(sum(int((layer == k + 1).sum()) for layer in chain) == 16 for k in range(60))
    # Without overlaps, the one image rasterize_plots gives.
    apart = PlotSet([polygons[0], polygons[3]], [{}, {}], (), None, "")
    (only,) = plot_layers(apart, **grid)
    np.testing.assert_array_equal(only, rasterize_plots(apart, **grid))


@pytest.mark.parametrize("extra", [(), ("--windowed", "--window", "256")])
def test_a_plot_file_exported_twice_gives_each_copy_its_plots_heights(tmp_path, extra):
    need_plots()
    doc = json.loads(PAIR_PLOTS.read_text())
    doc["features"] = doc["features"] + doc["features"]
    twice = tmp_path / "twice.geojson"
    twice.write_text(json.dumps(doc))
    _, once_rows, _ = run_heights(tmp_path, "once", *extra)
    _, twice_rows, _ = run_heights(tmp_path, "twice", *extra, plots=twice)
    n = len(once_rows)
    for copy in (twice_rows[:n], twice_rows[n:]):
        assert [{**r, "plot": ""} for r in copy] == [{**r, "plot": ""} for r in once_rows]
