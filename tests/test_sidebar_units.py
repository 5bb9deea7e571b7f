"""What the sidebar says about a relief's size and its GSD (one unit at a time), and the Render Views
job's fallback without a Blender window (bpy wheel; the real window is tests/app/gui_sidebar.py)."""

import importlib

import pytest
from conftest import ADDON
from conftest import SHARED_UAV as UAV

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.blender

BROCCOLI = UAV / "broccoli" / "01_clip_raw_test.jpg"  # no EXIF: relative units
MAIZE = UAV / "plantcv_dsm" / "rgb.tif"  # GeoTIFF, 2.2 cm/px: metres
needs_uav = pytest.mark.skipif(not UAV.is_dir(), reason=f"real UAV images not found at {UAV}")


@pytest.fixture
def sidebar(addon):
    return importlib.import_module(f"{ADDON}.panels.sidebar")


def build(path, **kwargs):
    assert bpy.ops.cliff_terrain.build_relief(filepath=str(path), **kwargs) == {"FINISHED"}
    return bpy.context.active_object


@needs_uav
def test_a_relief_in_metres_speaks_centimetres_and_names_its_gsd(sidebar, scene):
    obj = build(MAIZE)
    info = obj["cliff_terrain"].to_dict()
    lines = sidebar.relief_size_lines(sidebar.relief_info(obj))
    # The heights are metres (the GeoTIFF's 2.2 cm/px); under 1 m they read in cm, and nothing in px.
    assert lines[0] == f"Max height {info['max_height'] * 100:.3g} cm"
    assert lines[1].startswith("GSD 2.") and lines[1].endswith("cm/px (from the GeoTIFF)")
    assert not any(" px" in line or "normalised" in line for line in lines)


@needs_uav
def test_a_relief_without_gsd_speaks_relative_units_only(sidebar, scene):
    obj = build(BROCCOLI, max_size=64)
    info = obj["cliff_terrain"].to_dict()
    lines = sidebar.relief_size_lines(sidebar.relief_info(obj))
    # Blender units: the longest side is 10, so the height is the core's px times that scale.
    longest = max(info["grid_rows"], info["grid_cols"]) * info["pixel_size"]
    assert lines == [
        f"Max height {info['max_height'] * 10 / longest:.3g}",
        "Relative units (longest side = 10)",
    ]
    assert max(obj.dimensions[:2]) == pytest.approx(10.0, rel=1e-4)


@needs_uav
def test_gsd_note_says_where_the_ground_size_comes_from(sidebar, scene):
    class Layout:
        def __init__(self):
            self.lines = []

        def label(self, text, icon=None):
            self.lines.append(text)

    settings = scene.cliff_terrain
    for path, gsd, expected in [
        (MAIZE, 0.0, "GSD from photo: 2.2 cm/px"),
        (BROCCOLI, 0.0, "Photo has no GSD: relative units"),
        (BROCCOLI, 0.015, "GSD set by hand: 1.5 cm/px"),
        ("", 0.0, "0 = GSD from the photo"),
    ]:
        settings.filepath, settings.gsd = str(path), gsd
        layout = Layout()
        sidebar.gsd_note(layout, settings)
        assert layout.lines == [expected]


def test_no_background_job_without_a_blender_executable(addon, scene):
    # The bpy module has no window and no Blender binary to start: invoke renders in place instead.
    job = importlib.import_module(f"{ADDON}.operators.render_job")
    assert not job.can_run_in_background()
    assert job.rendered_views("/nonexistent") == []


def test_rendered_views_are_listed_in_view_order(addon, tmp_path):
    job = importlib.import_module(f"{ADDON}.operators.render_job")
    for name in ("mesh.png", "xy.png", "notes.txt", "xz.png", "extra.png", "xy_flat.png"):
        (tmp_path / name).write_bytes(b"")
    assert job.rendered_views(str(tmp_path)) == ["xy.png", "xy_flat.png", "xz.png", "mesh.png", "extra.png"]
