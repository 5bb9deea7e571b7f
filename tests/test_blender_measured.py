"""Blender: Build Relief from an orthophoto with its surface model (issue 13), and the panel's figures."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO, grey_copy
from PIL import Image

from cliff_terrain.measure.canopy import cover_pixels

pytestmark = pytest.mark.blender

EX2 = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"


def ex2(name):
    path = EX2 / name
    if not path.is_file():
        pytest.skip(f"shared OpenDroneMap pair {path} not found (../shared is absent)")
    return str(path)


def test_build_from_the_sidebar_fields_measures_heights(scene):
    import bpy

    from cliff_terrain.build import build_relief

    settings = scene.cliff_terrain
    settings.filepath = ex2("odm_orthophoto.tif")
    settings.dsm = ex2("dsm.tif")
    settings.height_source = "measured"
    settings.max_size = 300
    settings.two_sided = False
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    info = obj["cliff_terrain"]
    assert info["units"] == "m" and info["crs"] == 32616 and info["ground"] == "estimated"
    # The object sits at the world origin; its record holds the map offset of its (0, 0).
    assert tuple(obj.location) == (0.0, 0.0, 0.0)
    reference = build_relief(
        settings.filepath, dsm=settings.dsm, height_source="measured", max_size=300, two_sided=False
    )
    rows = reference.heights.shape[0]
    a, b, c, d, e, f = reference.georeference["transform"]
    assert (b, d) == (0.0, 0.0)  # north-up: the grid's bottom-left corner is (c, f + e * rows)
    assert list(info["map_offset"]) == pytest.approx([c, f + e * rows], abs=1e-6)
    z = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", z)
    np.testing.assert_allclose(z.reshape(-1, 3), reference.mesh.vertices, atol=1e-4)  # metres, no rescale
    chm = reference.canopy.chm[reference.mask & np.isfinite(reference.canopy.chm)]
    assert info["canopy_p90_cm"] == pytest.approx(np.percentile(chm, 90) * 100, abs=0.05)
    # Cover counts the pixels with data only (the orthophoto's no-data corners are neither plant nor soil).
    has_data = np.isfinite(reference.canopy.chm)
    # cover counts the index's plant pixels (cover_pixels), not the relief's filled mask
    plants = cover_pixels(reference)
    assert plants is reference.cover_mask and (plants != reference.mask).any()
    assert info["cover"] == pytest.approx((plants & has_data).sum() / has_data.sum())

    from cliff_terrain_addon.panels.sidebar import key_figure_lines, relief_info

    lines = key_figure_lines(relief_info(obj))
    assert lines[0].startswith(f"Plants {reference.n_regions}, cover ")
    assert lines[1] == f"Canopy height p50 {info['canopy_p50_cm']:.1f} cm, p90 {info['canopy_p90_cm']:.1f} cm"


def test_a_grey_photo_says_in_the_sidebar_that_the_surface_decided_the_soil(scene, tmp_path):
    import bpy

    settings = scene.cliff_terrain
    settings.filepath = str(grey_copy(ex2("odm_orthophoto.tif"), tmp_path / "grey.tif"))
    settings.dsm = ex2("dsm.tif")
    settings.height_source = "measured"
    settings.max_size = 300
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    note = obj["cliff_terrain"]["soil_note"]
    assert note == "the photo shows no plants"

    from cliff_terrain_addon.panels.sidebar import key_figure_lines, relief_info

    assert key_figure_lines(relief_info(obj))[-1] == f"Soil from the surface: {note}"
    # The photo as it is: the colour's soil, and no such line.
    settings.filepath = ex2("odm_orthophoto.tif")
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj["cliff_terrain"]["soil_note"] == ""
    assert not any(line.startswith("Soil from") for line in key_figure_lines(relief_info(obj)))


def test_measured_heights_without_a_dsm_is_reported(scene):
    import bpy

    settings = scene.cliff_terrain
    settings.filepath = ex2("odm_orthophoto.tif")
    settings.height_source = "measured"
    settings.max_size = 100
    # The sidebar's labels, not the core's parameter names (`height_source`, `dsm`).
    with pytest.raises(RuntimeError, match="Height Source 'measured' needs a Surface Model"):
        bpy.ops.cliff_terrain.build_relief()
    assert not bpy.data.objects


def run_render_views(*args):
    import subprocess
    import sys

    command = [sys.executable, str(REPO / "render_views.py"), *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=600)


def test_render_views_plots_need_a_dsm(tmp_path):
    done = run_render_views(
        ex2("odm_orthophoto.tif"), "--plots", tmp_path / "p.geojson", "--out", tmp_path / "o"
    )
    assert done.returncode == 2 and "--plots needs --dsm" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_render_views_with_dsm_and_plots(tmp_path):
    import json

    from cliff_terrain.io.raster.geotiff import read_orthophoto

    ortho = read_orthophoto(ex2("odm_orthophoto.tif"))
    x0, y0 = ortho.transform[0, 2] + 20, ortho.transform[1, 2] - 20
    ring = [[x0, y0], [x0 + 10, y0], [x0 + 10, y0 - 10], [x0, y0 - 10], [x0, y0]]
    doc = {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32616"}},
        "features": [
            {
                "type": "Feature",
                "properties": {"plot": "A1"},
                "geometry": {"type": "Polygon", "coordinates": [ring]},
            }
        ],
    }
    (tmp_path / "plots.geojson").write_text(json.dumps(doc))
    out = tmp_path / "out"
    args = ("--dsm", ex2("dsm.tif"), "--plots", tmp_path / "plots.geojson", "--max-size", 200, "--samples", 1)
    done = run_render_views(ex2("odm_orthophoto.tif"), *args, "--out", out)
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["units"] == "m" and metrics["params"]["height_source"] == "measured"
    # The texture is the photo (Blender reads float TIFFs unscaled; the core's pixels are used).
    assert metrics["psnr_xy_flat"] > 30
    header, row = (out / "plots.csv").read_text().splitlines()
    # The plot's own attribute named "plot" is kept (renamed) after the 0-based index column.
    assert header.startswith("plot,plot_attr,area_m2,cover,height_mean_m") and row.startswith("0,A1,")
    area = float(row.split(",")[2])
    # 10 m x 10 m on a grid of ~0.55 m pixels (200 px across 107 m): whole pixels, about 18 x 18.
    assert area == pytest.approx(100.0, rel=0.15)
    # One definition per number: `cliff-terrain heights` on the same orthophoto, DSM and grid prints
    # the same plants, cover and canopy heights as render_views.py, under the same keys.
    import subprocess
    import sys

    heights_out = tmp_path / "heights"
    command = [
        sys.executable,
        "-m",
        "cliff_terrain",
        "heights",
        ex2("odm_orthophoto.tif"),
        "--dsm",
        ex2("dsm.tif"),
    ]
    done = subprocess.run(
        [*command, "--max-size", "200", "--out", str(heights_out)], capture_output=True, text=True, cwd=REPO
    )
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((heights_out / "summary.json").read_text())
    assert metrics["plants"] > 20
    for key in ("plants", "cover", "canopy_height_p50_m", "canopy_height_p90_m", "plant_height_median_m"):
        assert summary[key] == pytest.approx(metrics[key], rel=1e-6), key
    assert summary["threshold"] == metrics["params"]["threshold"]
    # And both are what the CHM says: the p90 of the canopy height over the plant pixels.
    from cliff_terrain.io.raster.geotiff import read_surface

    chm = read_surface(heights_out / "chm.tif").data
    with Image.open(out / "mask.png") as image:
        plants = np.asarray(image) > 0
    values = chm[plants & np.isfinite(chm)]
    assert summary["canopy_height_p90_m"] == pytest.approx(np.percentile(values, 90), rel=1e-5)
