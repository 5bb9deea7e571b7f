"""Blender: Color By a vegetation index of a multispectral relief (issue 27), and render_views.py
--color-by NDVI. The 5-band orthophoto is generated as tests/test_multispectral.py writes it."""

from __future__ import annotations

import numpy as np
import pytest
from test_multispectral import odm_bands, render_views, write_odm

pytestmark = pytest.mark.blender

NAMES = ("Blue", "Green", "Red", "RedEdge", "NIR")


@pytest.fixture(scope="module")
def odm5(tmp_path_factory):
    bands, alpha, tags = odm_bands()
    return write_odm(tmp_path_factory.mktemp("odm5") / "odm5.tif", bands, alpha, tags, NAMES)


def test_color_by_offers_the_indices_of_the_reliefs_bands(scene, odm5):
    import bpy

    from cliff_terrain.io.raster.bands import read_bands
    from cliff_terrain.photo_heights.indices import index_map

    settings = scene.cliff_terrain
    settings.filepath = str(odm5)
    settings.max_size = 200
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    assert "NDVI" in obj["cliff_terrain"]["indices"] and "NDRE" in obj["cliff_terrain"]["indices"]
    settings.color_index = "NDVI"
    settings.color_by = "INDEX"
    legend = obj["cliff_terrain_legend"].to_dict()
    assert legend["mode"] == "INDEX" and legend["title"] == "NDVI"
    ndvi = index_map(read_bands(odm5), "NDVI")
    low, high = np.nanpercentile(ndvi, (2, 98))
    assert legend["low"] == pytest.approx(low, abs=0.03) and legend["high"] == pytest.approx(high, abs=0.03)
    mesh = obj.data
    colours = np.empty(len(mesh.vertices) * 4, np.float32)
    mesh.color_attributes.active_color.data.foreach_get("color_srgb", colours)
    # Viridis: high NDVI (plants) yellow-green, low NDVI (soil) purple-blue: green rises with the index.
    assert np.ptp(colours.reshape(-1, 4)[:, 1]) > 0.5
    settings.color_index = "NDRE"
    assert obj["cliff_terrain_legend"]["title"] == "NDRE"
    settings.color_by = "PHOTO"
    assert "cliff_terrain_legend" not in obj


def test_color_by_index_is_not_offered_for_an_rgb_photo(scene, tmp_path):
    import bpy
    from PIL import Image

    photo = tmp_path / "p.png"
    image = np.full((64, 64, 3), (120, 90, 60), np.uint8)
    image[20:40, 20:40] = (40, 160, 40)
    Image.fromarray(image).save(photo)
    settings = scene.cliff_terrain
    settings.filepath = str(photo)
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    assert list(bpy.context.active_object["cliff_terrain"]["indices"]) == []
    with pytest.raises(TypeError, match="INDEX"):
        settings.color_by = "INDEX"


def test_render_views_color_by_ndvi_renders_the_map(tmp_path, odm5):
    from PIL import Image

    out = tmp_path / "out"
    done = render_views(odm5, "--color-by", "NDVI", "--max-size", "200", "--samples", "1", "--out", out)
    assert done.returncode == 0, done.stderr[-2000:]
    photo = np.asarray(Image.open(out / "xy.png").convert("RGB"), dtype=np.float64)
    ndvi = np.asarray(Image.open(out / "xy_ndvi.png").convert("RGB"), dtype=np.float64)
    assert photo.shape == ndvi.shape and np.abs(photo - ndvi).mean() > 20
    bad = render_views(odm5, "--color-by", "EVI", "--out", tmp_path / "bad")
    assert bad.returncode == 2 and "--color-by" in bad.stderr
