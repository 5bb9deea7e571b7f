"""Blender: inspecting a relief. Probe Height reads the relief's own height raster under a point (a
relief rebuilt by the core, independently of the add-on, is the reference), Colour By switches the
material and the Solid colours to a height colouring, and the sidebar's sub-panels draw."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO

pytestmark = pytest.mark.blender

ODM = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2" / "odm_orthophoto.tif"
BROCCOLI = REPO.parent / "shared" / "data" / "uav" / "broccoli"


def _photo(folder):
    if not folder.is_dir():
        pytest.skip(f"{folder} not found (../shared is absent)")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in {".jpg", ".jpeg", ".png", ".tif"})[0]


def _world_points(obj, relief, n, seed):
    """`n` world (x, y) at random pixel centres of the relief's grid, half on plants, and their pixels."""
    rng = np.random.default_rng(seed)
    rows, cols = relief.heights.shape
    plants = np.argwhere(relief.mask)
    picks = [tuple(plants[i]) for i in rng.choice(len(plants), n // 2, replace=False)]
    picks += [(int(rng.integers(rows)), int(rng.integers(cols))) for _ in range(n - n // 2)]
    info = obj["cliff_terrain"]
    size = info["pixel_size"] * info["blender_units_per_unit"]
    from mathutils import Vector

    points = []
    for row, col in picks:
        # Anywhere inside the pixel, not only its centre.
        u, v = rng.uniform(0.05, 0.95, 2)
        local = Vector(((col + u) * size, (rows - 1 - row + v) * size, 0.0))
        world = obj.matrix_world @ local
        points.append((world.x, world.y))
    return points, picks


@pytest.mark.parametrize("mesh", ["grid", "adaptive"])
def test_probe_reports_the_relief_heights_under_the_point(scene, mesh):
    import bpy

    from cliff_terrain import build_relief

    photo = _photo(BROCCOLI)
    settings = scene.cliff_terrain
    settings.filepath = str(photo)
    settings.max_size = 300
    settings.mesh = mesh
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    # Moved and turned as a user would: the probe works in world coordinates.
    obj.location = (3.0, -2.0, 0.5)
    obj.rotation_euler = (0.0, 0.0, 0.4)
    bpy.context.view_layer.update()
    reference = build_relief(str(photo), max_size=300, mesh=None)
    top = float(reference.heights.max())
    points, pixels = _world_points(obj, reference, 20, seed=1)
    for (x, y), (row, col) in zip(points, pixels, strict=True):
        assert bpy.ops.cliff_terrain.probe_height(location=(x, y)) == {"FINISHED"}
        values = obj["cliff_terrain_probe"].to_dict()
        assert abs(values["height"] - float(reference.heights[row, col])) <= 0.01 * top
        assert values["unit"] == reference.units
        assert values["region"] == int(reference.labels[row, col])
        assert values["ground"] == 0.0
        if values["region"]:
            inside = reference.heights[reference.labels == values["region"]]
            assert values["region_p90"] == pytest.approx(np.percentile(inside, 90), rel=1e-5)
            assert values["region_area"] == pytest.approx(inside.size * reference.pixel_size**2)


def test_probe_with_a_surface_model_reports_ground_and_canopy_in_metres(scene):
    import bpy

    from cliff_terrain import build_relief

    if not ODM.is_file():
        pytest.skip(f"shared OpenDroneMap pair {ODM} not found (../shared is absent)")
    settings = scene.cliff_terrain
    settings.filepath, settings.dsm = str(ODM), str(ODM.with_name("dsm.tif"))
    settings.height_source = "measured"
    settings.max_size = 250
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    reference = build_relief(
        str(ODM), max_size=250, mesh=None, dsm=str(ODM.with_name("dsm.tif")), height_source="measured"
    )
    points, pixels = _world_points(obj, reference, 6, seed=2)
    for (x, y), (row, col) in zip(points, pixels, strict=True):
        assert bpy.ops.cliff_terrain.probe_height(location=(x, y)) == {"FINISHED"}
        values = obj["cliff_terrain_probe"].to_dict()
        assert values["unit"] == "m"
        ground = float(reference.canopy.ground[row, col])
        if np.isfinite(ground):
            assert values["ground"] == pytest.approx(ground, abs=1e-4)
            assert values["canopy_height"] == pytest.approx(float(reference.canopy.chm[row, col]), abs=1e-4)
            # The ground's standard error there, as chm_err.tif holds it, and in the probe's line.
            err = float(reference.canopy.sigma[row, col])
            assert values["ground_err"] == pytest.approx(err, abs=1e-6) and err > 0
            from cliff_terrain_addon.scene.probe import length_text, probe_lines

            assert f"± {length_text(err, 'm')}" in probe_lines(values)[1]
        assert abs(values["height"] - float(reference.heights[row, col])) <= 0.01 * float(
            reference.heights.max()
        )


def test_probe_off_the_relief_is_an_error_naming_the_point(scene):
    import bpy

    photo = _photo(BROCCOLI)
    scene.cliff_terrain.filepath = str(photo)
    scene.cliff_terrain.max_size = 100
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    with pytest.raises(RuntimeError, match=r"no relief under \(500\.000, 500\.000\)"):
        bpy.ops.cliff_terrain.probe_height(location=(500.0, 500.0))


def test_colour_by_height_colours_the_material_and_back(scene):
    import bpy

    from cliff_terrain.figures.legends import height_colours

    photo = _photo(BROCCOLI)
    settings = scene.cliff_terrain
    settings.filepath = str(photo)
    settings.max_size = 200
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    settings.color_by = "HEIGHT"
    mesh = obj.data
    attribute = mesh.color_attributes.active_color
    assert attribute is not None and attribute.domain == "POINT"
    colours = np.empty(len(mesh.vertices) * 4, np.float32)
    attribute.data.foreach_get("color_srgb", colours)
    colours = colours.reshape(-1, 4)[:, :3]
    z = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.attributes["position"].data.foreach_get("vector", z)
    z = z.reshape(-1, 3)[:, 2]
    top = obj["cliff_terrain"]["max_height"] * obj["cliff_terrain"]["blender_units_per_unit"]
    expected = height_colours(np.clip(z / top, 0, 1))
    np.testing.assert_allclose(colours, expected, atol=1.5 / 255)
    # The highest and lowest points differ in colour: the base colour depends on height.
    assert np.abs(colours[z.argmax()] - colours[z.argmin()]).sum() > 0.5
    tree = obj.active_material.node_tree
    base = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled").inputs["Base Color"]
    mix = base.links[0].from_node
    assert mix.name == "Cliff Terrain Colour By"
    factor = next(s for s in mix.inputs if s.identifier == "Factor_Float")
    attribute_node = next(
        link.from_node
        for link in tree.links
        if link.to_node == mix and link.from_node.bl_idname == "ShaderNodeVertexColor"
    )
    assert attribute_node.layer_name == attribute.name and factor.default_value == 1.0
    assert obj["cliff_terrain_legend"]["high"] == pytest.approx(obj["cliff_terrain"]["max_height"])
    settings.color_by = "PHOTO"
    assert factor.default_value == 0.0 and "cliff_terrain_legend" not in obj
    # Plot Trait is offered only once some relief has measured plots (Plots > Measure Plots).
    with pytest.raises(TypeError, match="PLOT_TRAIT"):
        settings.color_by = "PLOT_TRAIT"


def test_sidebar_sub_panels_are_registered_under_the_main_panel(addon):
    import bpy

    children = {
        name: getattr(bpy.types, name).bl_label
        for name in dir(bpy.types)
        if name.startswith("CLIFF_TERRAIN_PT_")
        and getattr(getattr(bpy.types, name), "bl_parent_id", "") == "CLIFF_TERRAIN_PT_sidebar"
    }
    assert set(children.values()) == {"Photo & Models", "Heights", "Mesh", "Plots", "Figures", "Season"}
    # The Blender guide's table of sub-panels names the ones registered.
    guide = (REPO / "docs" / "blender.md").read_text()
    table = guide.split("| Sub-panel | What it holds |\n", 1)[1].split("\n\n", 1)[0]
    listed = {line.split("|")[1].strip().strip("*") for line in table.splitlines()[1:]}
    assert listed == set(children.values())


def test_the_blender_guide_script_runs_as_pasted(scene, tmp_path, capsys):
    import re

    from PIL import Image

    from cliff_terrain import synthetic_field

    text = (REPO / "docs" / "blender.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL) if "probe_height(" in b]
    field = tmp_path / "field.png"
    image, _ = synthetic_field(seed=3)
    Image.fromarray(image).save(field)
    exec(compile(block.replace("/path/to/field.jpg", str(field)), "docs/blender.md", "exec"), {})
    out = capsys.readouterr().out
    assert "'height':" in out and "'unit':" in out and "'region':" in out


def test_probe_reads_a_relief_rebuilt_under_the_same_name_with_other_heights(scene):
    # The probe's cache was keyed by the relief's name and its mask: rebuilt with exaggeration 3
    # (same mask, other heights), it answered with the first build's heights.
    import bpy

    from cliff_terrain import build_relief

    photo = _photo(BROCCOLI)
    settings = scene.cliff_terrain
    settings.filepath = str(photo)
    settings.max_size = 200
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    name = obj.name
    reference = build_relief(str(photo), max_size=200, mesh=None)
    points, pixels = _world_points(obj, reference, 2, seed=3)
    (x, y), (row, col) = points[0], pixels[0]
    assert bpy.ops.cliff_terrain.probe_height(location=(x, y)) == {"FINISHED"}
    first = obj["cliff_terrain_probe"]["height"]
    assert first == pytest.approx(float(reference.heights[row, col]), abs=0.01 * reference.heights.max())
    bpy.data.objects.remove(obj)
    settings.exaggeration = 3.0
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.name == name
    assert bpy.ops.cliff_terrain.probe_height(location=(x, y)) == {"FINISHED"}
    assert first > 0 and obj["cliff_terrain_probe"]["height"] == pytest.approx(3 * first, rel=0.02)


def test_a_project_folder_moved_with_its_blend_still_finds_its_photo(scene, tmp_path):
    # Every path was stored absolute: a project folder moved (or copied to a colleague) lost its
    # texture, and Probe and Measure failed "cannot read image". A path given relative to the
    # .blend is now recorded and loaded as given.
    import shutil

    import bpy

    photo = _photo(BROCCOLI)
    project = tmp_path / "trial"
    (project / "photos").mkdir(parents=True)
    shutil.copy(photo, project / "photos" / photo.name)
    bpy.ops.wm.save_as_mainfile(filepath=str(project / "trial.blend"))
    settings = bpy.context.scene.cliff_terrain
    settings.filepath = f"//photos/{photo.name}"
    settings.max_size = 200
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj["cliff_terrain"]["source"] == f"//photos/{photo.name}"
    assert bpy.ops.cliff_terrain.probe_height(location=(1.0, 1.0)) == {"FINISHED"}
    before, name = obj["cliff_terrain_probe"].to_dict(), obj.name
    bpy.ops.wm.save_as_mainfile(filepath=str(project / "trial.blend"))
    # Render Views' job renders a copy saved in a temporary folder: its records hold the paths
    # resolved (Blender remaps the images' relative paths, not the records'); this file keeps "//".
    from cliff_terrain_addon.scene.record import absolute_paths

    (tmp_path / "job").mkdir()
    with absolute_paths():
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "job" / "scene.blend"), copy=True)
    assert obj["cliff_terrain"]["source"] == f"//photos/{photo.name}"
    moved = tmp_path / "moved"
    shutil.move(project, moved)
    bpy.ops.wm.open_mainfile(filepath=str(moved / "trial.blend"))
    obj = bpy.data.objects[name]
    images = [image for image in bpy.data.images if image.filepath]
    assert images and all((moved / image.filepath[2:]).is_file() for image in images)
    assert bpy.ops.cliff_terrain.probe_height(location=(1.0, 1.0)) == {"FINISHED"}
    assert obj["cliff_terrain_probe"].to_dict() == before
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "job" / "scene.blend"))
    source = bpy.data.objects[name]["cliff_terrain"]["source"]
    assert source == str(project / "photos" / photo.name)  # where the photo was when the job started


def test_an_applied_transform_is_refused_in_one_line_and_a_turned_relief_is_not_scored(scene):
    # Applying a scale moved the vertices the probe reads pixels through: "outside the relief" on
    # the relief, and Color By Height the wrong heights. A rotated relief's top view, compared with
    # the photo, scored 7.6 dB as a fact.
    import bpy

    photo = _photo(BROCCOLI)
    settings = scene.cliff_terrain
    settings.filepath = str(photo)
    settings.max_size = 120
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    assert bpy.ops.cliff_terrain.evaluate.poll() and bpy.ops.cliff_terrain.render_views.poll()
    obj.scale = (2.0, 2.0, 2.0)  # scaled, not applied: still read through its frame
    bpy.context.view_layer.update()
    assert bpy.ops.cliff_terrain.probe_height(location=(3.0, 3.0)) == {"FINISHED"}
    obj.rotation_euler = (0.0, 0.0, 0.5)
    bpy.context.view_layer.update()
    assert not bpy.ops.cliff_terrain.evaluate.poll() and not bpy.ops.cliff_terrain.render_views.poll()
    obj.rotation_euler = (0.0, 0.0, 0.0)
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    with pytest.raises(RuntimeError, match="no longer lies in the frame it was built in"):
        bpy.ops.cliff_terrain.probe_height(location=(3.0, 3.0))
    settings.color_by = "HEIGHT"  # the relief keeps its photo rather than wrong colours
    assert "cliff_terrain_legend" not in obj
