"""The extension inside Blender (bpy wheel, in this process): settings, the Build Relief operator,
the numpy-to-Blender mesh transfer, material, safety on errors, undo, and registration cycles.

The repository root is loaded as a package (``cliff_terrain_addon``) and registered, as Blender
would load the installed extension (the ``addon``, ``scene`` and ``datablock_counts`` fixtures are
in conftest.py). bpy can be imported once per process and keeps its state, so every test starts
from ``read_factory_settings(use_empty=True)`` (registered classes survive it).
The installed-zip path is covered by test_blender_build.py.
"""

import dataclasses
import functools
import importlib
import tomllib
import types
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_UAV as UAV
from conftest import load_script

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[1]
BROCCOLI = UAV / "broccoli" / "01_clip_raw_test.jpg"  # 1500x1500, no EXIF: normalised units
MAIZE = UAV / "plantcv_dsm" / "rgb.tif"  # 261x284 GeoTIFF, 2.2 cm/px: metres
ADDON = "cliff_terrain_addon"  # the package name conftest.load_addon registers

needs_uav = pytest.mark.skipif(not UAV.is_dir(), reason=f"real UAV images not found at {UAV}")


@pytest.fixture(scope="module")
def core(addon):
    """The core package as the add-on imports it (``cliff_terrain_addon.cliff_terrain``)."""
    return importlib.import_module(f"{ADDON}.cliff_terrain")


def vertex_positions(mesh):
    out = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", out)
    return out.reshape(-1, 3)


def corner_uvs(mesh, name="UVMap"):
    out = np.empty(len(mesh.loops) * 2, dtype=np.float32)
    mesh.uv_layers[name].uv.foreach_get("vector", out)
    return out.reshape(-1, 2)


def faces(mesh):
    sizes = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    corners = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    return sizes, corners


def build(**kwargs):
    result = bpy.ops.cliff_terrain.build_relief(
        **{k: (str(v) if k == "filepath" else v) for k, v in kwargs.items()}
    )
    assert result == {"FINISHED"}
    return bpy.context.active_object


# ---- mesh transfer, on the core's grid mesh (no photo) ----


def test_mesh_from_arrays_reproduces_grid_mesh(addon, core, scene):
    mesh_data = importlib.import_module(f"{ADDON}.scene.mesh_data")
    rng = np.random.default_rng(7)
    heights = rng.random((23, 37)).astype(np.float32) * 4.0
    arrays = core.grid_mesh(heights, pixel_size=0.5, two_sided=True)
    mesh = mesh_data.mesh_from_arrays("grid", arrays, scale=2.0)

    np.testing.assert_array_equal(vertex_positions(mesh), arrays.vertices * np.float32(2.0))
    sizes, corners = faces(mesh)
    np.testing.assert_array_equal(sizes, arrays.face_sizes)
    np.testing.assert_array_equal(corners, arrays.corner_verts)
    np.testing.assert_array_equal(corner_uvs(mesh), arrays.uvs)
    assert [uv.name for uv in mesh.uv_layers] == ["UVMap"] and mesh.uv_layers.active.name == "UVMap"
    # Blender finds nothing to repair, and the solid is closed: every edge has two faces.
    assert mesh.validate(verbose=False) is False
    assert len(mesh.edges) == arrays.edge_face_counts().size
    assert np.all(arrays.edge_face_counts() == 2)
    sharp = np.empty(len(mesh.polygons), dtype=bool)
    mesh.attributes["sharp_face"].data.foreach_get("value", sharp)
    assert not sharp[: arrays.n_front_faces].any() and sharp[arrays.n_front_faces :].all()
    # The core's edges are the ones Blender derives itself when it is not given any.
    derived = mesh_data.mesh_from_arrays(
        "derived", dataclasses.replace(arrays, edges=None, corner_edges=None)
    )
    assert sorted(map(tuple, np.sort(mesh_edges(mesh), 1).tolist())) == sorted(
        map(tuple, np.sort(mesh_edges(derived), 1).tolist())
    )


def mesh_edges(mesh):
    out = np.empty(len(mesh.edges) * 2, dtype=np.int32)
    mesh.edges.foreach_get("vertices", out)
    return out.reshape(-1, 2)


def test_an_adaptive_mesh_shades_its_level_triangles_flat(addon, core, scene):
    """Bare soil beside a dome: the soil's large level triangles touch the dome's rim, and smooth
    shading would tilt them with the rim's normals. Flat-shaded, every corner of a level triangle
    points straight up, while the dome's smooth faces shade with their vertices' normals, the
    average over all their faces, flat ones included (as Blender 4.2-5.0 do; custom normals on
    5.1+, which would split them at the flat faces)."""
    mesh_data = importlib.import_module(f"{ADDON}.scene.mesh_data")
    rows, cols = np.indices((60, 80))
    heights = np.sqrt(np.clip(20.0**2 - (rows - 30) ** 2 - (cols - 40) ** 2, 0, None)).astype(np.float32)
    arrays = core.adaptive_mesh(heights, max_error=0.2)
    mesh = mesh_data.mesh_from_arrays("tin", arrays)
    sharp = np.empty(len(mesh.polygons), dtype=bool)
    mesh.attributes["sharp_face"].data.foreach_get("value", sharp)
    n_front = arrays.n_front_faces
    assert sharp[n_front:].all() and 0 < arrays.flat_faces[:n_front].sum() < n_front
    np.testing.assert_array_equal(sharp, arrays.flat_faces)
    if mesh_data.KEEP_VERTEX_NORMALS:
        # Blender 5.1+: the vertex normals kept as custom normals on the vertices. (The renderers
        # shade the flat faces flat; `corner_normals` gives every corner its vertex's normal.)
        assert mesh.normals_domain == "POINT"
        kept = np.empty(3 * len(mesh.vertices), dtype=np.float32)
        mesh.attributes["custom_normal"].data.foreach_get("vector", kept)
        expected = _angle_weighted_normals(arrays)
        np.testing.assert_allclose(kept.reshape(-1, 3), expected, atol=2e-4)  # float32 in Blender
        return
    assert "custom_normal" not in mesh.attributes
    normals = np.empty(3 * len(mesh.loops), dtype=np.float32)
    mesh.corner_normals.foreach_get("vector", normals)
    sizes = arrays.face_sizes[:n_front]  # triangles and the quads they were paired into
    front_z = normals.reshape(-1, 3)[: sizes.sum(), 2]
    corner_sharp = np.repeat(sharp[:n_front], sizes)
    np.testing.assert_allclose(front_z[corner_sharp], 1.0, atol=1e-6)
    assert front_z[~corner_sharp].min() < 0.5  # the dome's rim stays smooth and steep


def _angle_weighted_normals(arrays):
    """Unit vertex normals of a MeshArrays: per face, Newell's normal times the corner's angle."""
    vertices = arrays.vertices.astype(np.float64)
    sizes = np.asarray(arrays.face_sizes)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    face = np.repeat(np.arange(len(sizes)), sizes)
    at = np.arange(len(arrays.corner_verts)) - starts[face]
    nxt = starts[face] + (at + 1) % sizes[face]
    prv = starts[face] + (at - 1) % sizes[face]
    here, after, before = (vertices[arrays.corner_verts[k]] for k in (np.arange(len(face)), nxt, prv))
    face_normals = np.zeros((len(sizes), 3))
    np.add.at(face_normals, face, np.cross(here, after))
    face_normals /= np.linalg.norm(face_normals, axis=1, keepdims=True)
    a, b = after - here, before - here
    angle = np.arccos(np.clip((a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1), -1, 1))
    out = np.zeros_like(vertices)
    np.add.at(out, arrays.corner_verts, face_normals[face] * angle[:, None])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def test_mesh_from_arrays_one_sided_and_bad_indices(addon, core, scene, datablock_counts):
    mesh_data = importlib.import_module(f"{ADDON}.scene.mesh_data")
    arrays = core.grid_mesh(np.zeros((3, 4)), two_sided=False)
    mesh = mesh_data.mesh_from_arrays("flat", arrays)
    assert (len(mesh.vertices), len(mesh.polygons)) == (4 * 5, 12)
    assert "sharp_face" not in mesh.attributes
    assert mesh.validate(verbose=False) is False

    before = datablock_counts()
    arrays.corner_verts[5] = arrays.n_vertices  # one past the last vertex
    with pytest.raises(ValueError, match="corner_verts"):
        mesh_data.mesh_from_arrays("broken", arrays)
    assert datablock_counts() == before


def test_a_mesh_allocated_for_other_sizes_is_not_filled(addon, core, scene):
    mesh_data = importlib.import_module(f"{ADDON}.scene.mesh_data")
    topology = mesh_data.checked_topology(core.grid_mesh(np.zeros((3, 4))))
    mesh = mesh_data.allocate_mesh("other", core.grid_sizes((3, 5)))
    with pytest.raises(
        ValueError, match=r"mesh 'other' has room for \(40, 140, 32, 70\) vertices, corners, faces"
    ):
        mesh_data.fill_topology(mesh, topology)
    right = mesh_data.allocate_mesh("right", core.grid_sizes((3, 4)))
    mesh_data.fill_topology(right, topology)
    mesh_data.set_positions(right, core.grid_mesh(np.zeros((3, 4))).vertices)
    assert right.validate(verbose=False) is False


# ---- the operator on real photos ----


@needs_uav
def test_build_matches_core_in_normalised_units(addon, core, scene):
    obj = build(filepath=BROCCOLI, max_size=96, mesh="grid")
    ref = core.build_relief(str(BROCCOLI), max_size=96, mesh="grid")
    assert ref.units == "px"  # no EXIF and no GSD given
    mesh = obj.data

    # Longest side 10 Blender units, the rest scaled alike.
    rows, cols = ref.mesh.grid_shape
    scale = 10.0 / max(rows, cols)
    np.testing.assert_allclose(
        vertex_positions(mesh), ref.mesh.vertices * np.float32(scale), rtol=1e-6, atol=1e-6
    )
    assert max(obj.dimensions.x, obj.dimensions.y) == pytest.approx(10.0, rel=1e-6)

    sizes, corners = faces(mesh)
    np.testing.assert_array_equal(sizes, ref.mesh.face_sizes)
    np.testing.assert_array_equal(corners, ref.mesh.corner_verts)
    uvs = corner_uvs(mesh)
    np.testing.assert_array_equal(uvs, ref.mesh.uvs)
    n_front_corners = 4 * ref.mesh.n_front_faces
    assert np.all(uvs[:n_front_corners] >= 0.0) and np.all(uvs[:n_front_corners] <= 1.0)
    assert mesh.validate(verbose=False) is False
    assert obj.name == BROCCOLI.stem and mesh.name == BROCCOLI.stem
    # The relief rises (corner heights average pixels, so they stay under the peak).
    assert 0.0 < vertex_positions(mesh)[:, 2].max() <= ref.max_height * scale * (1 + 1e-6)


@needs_uav
def test_walls_and_base_are_marked_by_u_above_one(addon, scene):
    # The material tells walls and base from the top by U > 1, so every back corner needs it.
    obj = build(filepath=BROCCOLI, max_size=40, mesh="grid")
    n_front_corners = 4 * (obj["cliff_terrain"]["grid_rows"] * obj["cliff_terrain"]["grid_cols"])
    uvs = corner_uvs(obj.data)
    assert n_front_corners < len(uvs)
    assert np.all(uvs[:n_front_corners, 0] <= 1.0)
    back_u = uvs[n_front_corners:, 0]
    assert np.all(back_u > 1.0), (
        f"{np.count_nonzero(back_u <= 1.0)} of {back_u.size} back corners have u <= 1"
    )


@needs_uav
def test_build_records_its_settings_on_the_object(addon, core, scene):
    obj = build(filepath=BROCCOLI, max_size=80, profile="poisson", exaggeration=2.5, segmentation="paper")
    ref = core.build_relief(
        str(BROCCOLI), max_size=80, profile="poisson", exaggeration=2.5, segmentation="paper"
    )
    info = obj["cliff_terrain"].to_dict()
    assert info["version"] == core.__version__
    assert Path(info["source"]) == BROCCOLI
    assert info["units"] == "px" and info["size_mode"] == "normalised"
    assert info["blender_units_per_unit"] == pytest.approx(10.0 / max(ref.mesh.grid_shape))
    assert info["pixel_size"] == pytest.approx(ref.pixel_size)
    assert (info["grid_rows"], info["grid_cols"]) == ref.mesh.grid_shape
    assert info["regions"] == ref.n_regions > 0
    assert info["max_height"] == pytest.approx(ref.max_height)
    assert (info["image_width"], info["image_height"]) == (1500, 1500)
    # "auto" resolved as the core resolves it, and why; the bound and the rule that chose it.
    assert (info["mesh"], info["mesh_rule"]) == (ref.mesh_kind, ref.mesh_rule)
    assert info["mesh_rule"].startswith("auto: ")
    assert info["max_error"] == pytest.approx(ref.max_error or 0.0)
    assert info["max_error_rule"] == (ref.max_error_rule or "")
    assert info["params"] == {
        "segmentation": "paper",
        "profile": "poisson",
        "max_size": 80,
        "exaggeration": 2.5,
        "max_height": 0.0,  # 0: the canopy height estimated from the photo
        "gsd": 0.0,
        "two_sided": True,
        "mesh": "auto",
        "max_error": 0.0,  # 0: the adaptive mesh's automatic error
        "dsm": 0.0,  # no surface model (ID properties hold no None)
        "dtm": 0.0,
        "height_source": "inflated",
    }


@needs_uav
def test_build_in_metres_with_a_given_gsd(addon, core, scene):
    obj = build(filepath=BROCCOLI, max_size=64, gsd=0.004)
    info = obj["cliff_terrain"]
    assert info["units"] == "m" and info["blender_units_per_unit"] == 1.0
    # 1500 px at 4 mm/px = 6 m, whatever the processing size.
    assert obj.dimensions.x == pytest.approx(6.0, rel=1e-5)
    assert obj.dimensions.y == pytest.approx(6.0, rel=1e-5)


@needs_uav
def test_build_in_metres_from_geotiff(addon, core, scene):
    obj = build(filepath=MAIZE, max_size=100, two_sided=False, mesh="grid")
    meta = core.load_image(str(MAIZE))[1]
    assert meta.gsd_source == "geotiff"
    assert obj["cliff_terrain"]["units"] == "m"
    # Pixels stay square: x is exact, y is off by the resize's rounding (under one grid pixel).
    pixel = obj["cliff_terrain"]["pixel_size"]
    assert obj.dimensions.x == pytest.approx(meta.width * meta.gsd_m_per_px, rel=1e-5)
    assert obj.dimensions.y == pytest.approx(meta.height * meta.gsd_m_per_px, abs=pixel)
    # One-sided: front grid only, all UVs in [0, 1].
    rows, cols = obj["cliff_terrain"]["grid_rows"], obj["cliff_terrain"]["grid_cols"]
    assert len(obj.data.vertices) == (rows + 1) * (cols + 1)
    uvs = corner_uvs(obj.data)
    assert uvs.min() >= 0.0 and uvs.max() <= 1.0
    # A TIFF is one Blender may read differently: checked (so decoded) at build time.
    image = obj.material_slots[0].material.node_tree.nodes.active.image
    assert image.has_data and tuple(image.size) == (meta.width, meta.height)


@needs_uav
def test_material_uses_full_resolution_photo_and_darkens_the_back(addon, scene):
    obj = build(filepath=BROCCOLI, max_size=48)
    assert len(obj.material_slots) == 1
    tree = obj.material_slots[0].material.node_tree
    by_type = {}
    for node in tree.nodes:
        by_type.setdefault(node.bl_idname, []).append(node)
    (tex,) = by_type["ShaderNodeTexImage"]
    assert Path(bpy.path.abspath(tex.image.filepath)) == BROCCOLI
    # A JPEG is left to load when shown (the core read it already); then it is the whole photo.
    assert not tex.image.has_data
    assert tuple(tex.image.size) == (1500, 1500)  # the photo, not the 48 px grid
    assert tex.image.has_data
    assert tex.extension == "REPEAT" and tree.nodes.active == tex

    def source(node, socket_id):
        (socket,) = [s for s in node.inputs if s.identifier == socket_id]
        assert socket.is_linked, f"{node.bl_idname}.{socket_id} is not linked"
        link = socket.links[0]
        return link.from_node, link.from_socket.identifier

    (uv_map,) = by_type["ShaderNodeUVMap"]
    assert uv_map.uv_map == "UVMap"
    assert source(tex, "Vector") == (uv_map, "UV")
    # Walls and base: a soil colour mixed in where U > 1, then darker and greyer there.
    (shade,) = by_type["ShaderNodeHueSaturation"]
    (soil,) = by_type["ShaderNodeMix"]
    assert source(shade, "Color") == (soil, "Result_Color")
    assert source(soil, "A_Color") == (tex, "Color")
    assert shade.inputs["Saturation"].default_value < 1.0 and shade.inputs["Value"].default_value < 1.0
    is_back, _ = source(shade, "Fac")
    assert is_back.operation == "GREATER_THAN" and is_back.inputs[1].default_value == 1.0
    amount, _ = source(soil, "Factor_Float")
    assert amount.operation == "MULTIPLY" and source(amount, "Value") == (is_back, "Value")
    split, socket = source(is_back, "Value")
    assert socket == "X" and source(split, "Vector") == (uv_map, "UV")
    (bsdf,) = by_type["ShaderNodeBsdfPrincipled"]
    assert source(bsdf, "Base Color") == (shade, "Color")


@needs_uav
def test_exif_rotated_photo_is_textured_from_the_decoded_pixels(addon, core, scene, tmp_path):
    # Blender ignores EXIF orientation, so the texture must come from the core's oriented pixels.
    from PIL import Image

    rotated = tmp_path / "rotated.jpg"
    with Image.open(BROCCOLI) as photo:
        exif = Image.Exif()
        exif[0x0112] = 6  # stored landscape, shown rotated 90 degrees clockwise
        photo.crop((0, 0, 300, 200)).save(rotated, quality=95, exif=exif)
    rgb, meta = core.load_image(str(rotated))
    assert (meta.orientation, meta.width, meta.height) == (6, 200, 300)

    obj = build(filepath=rotated, max_size=50)
    image = obj.active_material.node_tree.nodes.active.image
    assert image.packed_file is not None  # saved with the .blend, not re-read from the file
    assert tuple(image.size) == (200, 300)
    pixels = np.empty(300 * 200 * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(300, 200, 4)[::-1]  # Blender's rows run bottom-up
    np.testing.assert_array_equal(np.round(pixels[..., :3] * 255).astype(np.uint8), rgb)
    assert obj["cliff_terrain"]["image_width"] == 200


@needs_uav
def test_second_build_is_a_second_object_and_user_objects_are_untouched(addon, scene):
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    cube = bpy.context.active_object
    cube_vertices = vertex_positions(cube.data).copy()
    first = build(filepath=BROCCOLI, max_size=40)
    second = build(filepath=BROCCOLI, max_size=40)
    assert first != second and first.data != second.data
    assert {o.name for o in bpy.data.objects} == {"Cube", first.name, second.name}
    np.testing.assert_array_equal(vertex_positions(cube.data), cube_vertices)
    assert len(cube.data.materials) == 0
    # The photo is loaded once and shared.
    assert (
        first.active_material.node_tree.nodes.active.image
        == second.active_material.node_tree.nodes.active.image
    )
    assert bpy.context.active_object == second and second.select_get() and not cube.select_get()


@needs_uav
def transformed(points, *, rotation, translation, scale):
    """`points` scaled, rotated by Euler angles in X, Y, Z order (Blender's default), then moved."""
    ax, ay, az = rotation
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return (points.astype(np.float64) * np.asarray(scale)) @ (rz @ ry @ rx).T + np.asarray(translation)


def test_object_transform_applies_like_a_numpy_reference(addon, scene):
    obj = build(filepath=BROCCOLI, max_size=40)
    before = vertex_positions(obj.data).copy()
    uvs_before = corner_uvs(obj.data).copy()
    rotation, translation, scale = (0.3, -0.2, 1.1), (1.0, -2.0, 0.5), (2.0, 1.5, 0.25)
    obj.location = translation
    obj.rotation_euler = rotation
    obj.scale = scale
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    expected = transformed(before, rotation=rotation, translation=translation, scale=scale)
    np.testing.assert_allclose(vertex_positions(obj.data), expected, atol=1e-5)
    np.testing.assert_array_equal(corner_uvs(obj.data), uvs_before)


@needs_uav
def test_parameters_not_given_come_from_the_scene_settings(addon, scene):
    # Blender runs invoke only with a window event, so headless this goes through execute, which
    # fills the parameters the same way.
    settings = scene.cliff_terrain
    settings.filepath = str(BROCCOLI)
    settings.max_size = 32
    settings.two_sided = False
    settings.profile = "poisson"
    settings.mesh = "grid"
    assert bpy.ops.cliff_terrain.build_relief("INVOKE_DEFAULT") == {"FINISHED"}
    params = bpy.context.active_object["cliff_terrain"]["params"]
    assert (params["max_size"], params["two_sided"], params["profile"]) == (32, False, "poisson")
    assert params["mesh"] == "grid"
    assert len(bpy.context.active_object.data.vertices) == 33 * 33
    # An explicit value wins over the scene's; the last run's value does not.
    assert bpy.ops.cliff_terrain.build_relief(max_size=24) == {"FINISHED"}
    assert bpy.context.active_object["cliff_terrain"]["params"]["max_size"] == 24
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    assert bpy.context.active_object["cliff_terrain"]["params"]["max_size"] == 32


# ---- safety ----


def test_missing_file_is_reported_and_changes_nothing(addon, scene, tmp_path, datablock_counts):
    before = datablock_counts()
    missing = tmp_path / "no_such_photo.jpg"
    with pytest.raises(RuntimeError, match=r"(?s)Error: .*no_such_photo\.jpg"):
        bpy.ops.cliff_terrain.build_relief(filepath=str(missing))
    assert datablock_counts() == before


def test_bad_setting_is_reported_with_the_core_message(addon, scene, tmp_path, datablock_counts):
    # A file that exists but is no image.
    junk = tmp_path / "notes.jpg"
    junk.write_text("not a photo")
    before = datablock_counts()
    with pytest.raises(RuntimeError, match=r"notes\.jpg"):
        bpy.ops.cliff_terrain.build_relief(filepath=str(junk))
    assert datablock_counts() == before


@needs_uav
def test_failure_after_the_object_exists_removes_every_new_datablock(
    addon, scene, monkeypatch, datablock_counts
):
    relief_object = importlib.import_module(f"{ADDON}.scene.relief_object")

    def fail(*args, **kwargs):
        # By now the mesh, the photo, the material and the linked object exist.
        assert len(bpy.data.objects) == 1 and bpy.data.objects[0].users_collection
        raise RuntimeError("injected failure while recording")

    monkeypatch.setattr(relief_object, "write_record", fail)
    before = datablock_counts()
    with pytest.raises(RuntimeError, match="injected failure while recording"):
        bpy.ops.cliff_terrain.build_relief(filepath=str(BROCCOLI), max_size=32)
    assert datablock_counts() == before
    assert len(bpy.context.scene.collection.all_objects) == 0


@needs_uav
def test_failure_keeps_a_photo_that_was_already_loaded(addon, scene, monkeypatch):
    image = bpy.data.images.load(str(BROCCOLI))
    # The build's material is made by scene.datablocks.textured_object.
    datablocks = importlib.import_module(f"{ADDON}.scene.datablocks")

    def fail(name, photo, **settings):
        raise RuntimeError("injected failure")

    monkeypatch.setattr(datablocks, "relief_material", fail)
    with pytest.raises(RuntimeError, match="injected failure"):
        bpy.ops.cliff_terrain.build_relief(filepath=str(BROCCOLI), max_size=32)
    assert list(bpy.data.images) == [image]
    assert len(bpy.data.meshes) == 0


@needs_uav
def test_undo_removes_the_relief(addon, scene):
    # Headless, Blender pushes no undo step after an operator (its own primitive_cube_add neither):
    # the step the UI pushes after an UNDO operator is pushed here by hand.
    bpy.ops.mesh.primitive_cube_add()
    bpy.ops.ed.undo_push(message="before build")
    before = {
        kind: sorted(b.name for b in getattr(bpy.data, kind)) for kind in ("objects", "meshes", "images")
    }
    obj = build(filepath=BROCCOLI, max_size=32)
    name = obj.name
    bpy.ops.ed.undo_push(message="Build Relief")
    bpy.ops.ed.undo()
    after = {
        kind: sorted(b.name for b in getattr(bpy.data, kind)) for kind in ("objects", "meshes", "images")
    }
    assert after == before
    assert len(bpy.data.materials) == 0
    bpy.ops.ed.redo()
    assert name in bpy.data.objects and bpy.data.objects[name].get("cliff_terrain") is not None


# ---- registration ----


def test_register_unregister_cycles_leave_nothing(addon):
    names = ("CLIFF_TERRAIN_OT_build_relief", "CLIFF_TERRAIN_PT_sidebar")
    settings_class = addon.operators.properties.CliffTerrainSettings
    assert hasattr(bpy.types.Scene, "cliff_terrain")
    for _ in range(2):
        addon.unregister()
        assert not hasattr(bpy.types.Scene, "cliff_terrain")
        assert "cliff_terrain" not in bpy.types.Scene.bl_rna.properties
        assert not any(hasattr(bpy.types, name) for name in names)
        assert not settings_class.is_registered
        assert "build_relief" not in dir(bpy.ops.cliff_terrain)
        addon.register()
        assert all(hasattr(bpy.types, name) for name in names) and settings_class.is_registered
        assert bpy.context.scene.cliff_terrain.max_size == 1000
    panel = bpy.types.CLIFF_TERRAIN_PT_sidebar
    assert (panel.bl_space_type, panel.bl_region_type, panel.bl_category) == (
        "VIEW_3D",
        "UI",
        "Cliff Terrain",
    )


class LayoutRecorder:
    """Records what a panel's draw() asks of its layout (Blender draws no UI headless).

    Blender draws a wrong property name as a warning label instead of raising, so the names a panel
    uses are checked here against the real RNA.
    """

    def __init__(self, log, parent=None):
        self.log, self.parent = log, parent
        self.enabled = True

    def is_enabled(self):
        return self.enabled and (self.parent is None or self.parent.is_enabled())

    def _child(self, *args, **kwargs):
        return LayoutRecorder(self.log, self)

    column = row = box = split = grid_flow = _child

    def separator(self, **kwargs):
        pass

    def prop(self, data, name, **kwargs):
        self.log.append(("prop", data, name, self.is_enabled()))

    def operator(self, idname, **kwargs):
        self.log.append(("operator", idname, None, self.is_enabled()))

    def label(self, text="", **kwargs):
        self.log.append(("label", text, None, self.is_enabled()))


def draw_panel(context):
    """What the sidebar and each of its sub-panels (all expanded) ask of their layouts."""
    log = []
    for name in PANELS:
        cls = getattr(bpy.types, name)
        layout = LayoutRecorder(log)
        panel = types.SimpleNamespace(layout=layout)
        if hasattr(cls, "draw_settings"):
            panel.draw_settings = functools.partial(cls.draw_settings, panel)
        cls.draw(panel, context)
    return log


# The sidebar, then its sub-panels in the order they show.
PANELS = (
    "CLIFF_TERRAIN_PT_sidebar",
    "CLIFF_TERRAIN_PT_photo",
    "CLIFF_TERRAIN_PT_heights",
    "CLIFF_TERRAIN_PT_mesh",
    "CLIFF_TERRAIN_PT_plots",
    "CLIFF_TERRAIN_PT_figures",
    "CLIFF_TERRAIN_PT_season",
)


def test_panel_draws_real_settings_and_greys_out_build_without_a_photo(addon, scene, tmp_path):
    log = draw_panel(bpy.context)
    drawn = [(data, name) for kind, data, name, _ in log if kind == "prop"]
    assert drawn and all(data == scene.cliff_terrain for data, _ in drawn)
    names = {name for _, name in drawn}
    assert names <= set(scene.cliff_terrain.bl_rna.properties.keys())
    assert {"filepath", "segmentation", "profile", "max_size", "exaggeration", "gsd", "two_sided"} <= names
    builds = [
        enabled
        for kind, idname, _, enabled in log
        if kind == "operator" and idname == "cliff_terrain.build_relief"
    ]
    assert builds == [False]  # no photo chosen
    scene.cliff_terrain.filepath = str(tmp_path / "missing.jpg")
    assert [
        e for k, i, _, e in draw_panel(bpy.context) if k == "operator" and i.endswith("build_relief")
    ] == [False]
    photo = tmp_path / "photo.jpg"
    photo.write_bytes(b"")
    scene.cliff_terrain.filepath = str(photo)
    assert [
        e for k, i, _, e in draw_panel(bpy.context) if k == "operator" and i.endswith("build_relief")
    ] == [True]
    # The Render Views, Evaluate, Import Mosaic and Season Animation buttons are drawn too (their
    # own poll greys them out).
    others = [i for k, i, _, _ in log if k == "operator" and i != "cliff_terrain.build_relief"]
    assert sorted(others) == [
        "cliff_terrain.add_plot_grid",
        "cliff_terrain.evaluate",
        "cliff_terrain.export_plots",
        "cliff_terrain.fit_plot_grid",
        "cliff_terrain.import_mosaic",
        "cliff_terrain.plot_table",
        "cliff_terrain.probe_height",
        "cliff_terrain.render_views",
        "cliff_terrain.season_animation",
    ]


@needs_uav
def test_panel_shows_the_active_relief_and_results(addon, scene):
    obj = build(filepath=BROCCOLI, max_size=40)
    labels = [text for kind, text, _, _ in draw_panel(bpy.context) if kind == "label"]
    assert obj.name in labels
    assert any(f"{obj['cliff_terrain']['regions']} regions" in text for text in labels)
    assert not any("PSNR" in text for text in labels)
    scene.cliff_terrain.psnr, scene.cliff_terrain.ssim = 27.5, 0.91
    labels = [text for kind, text, _, _ in draw_panel(bpy.context) if kind == "label"]
    assert "PSNR 27.50 dB" in labels and "SSIM 0.910" in labels


def test_build_needs_object_mode(addon, scene):
    bpy.ops.mesh.primitive_cube_add()
    bpy.ops.object.mode_set(mode="EDIT")
    with pytest.raises(RuntimeError, match="poll"):
        bpy.ops.cliff_terrain.build_relief(filepath=str(BROCCOLI))
    bpy.ops.object.mode_set(mode="OBJECT")


def test_settings_match_the_brief_and_the_core(addon, core, scene):
    settings = scene.cliff_terrain
    rna = settings.bl_rna.properties
    assert rna["filepath"].subtype == "FILE_PATH" and rna["output_dir"].subtype == "DIR_PATH"
    # The core's range, from the one module that holds it (the panel stopped at 8000 once).
    assert (rna["max_size"].hard_min, rna["max_size"].hard_max, rna["max_size"].default) == (16, 16384, 1000)
    segmentation = importlib.import_module(f"{ADDON}.cliff_terrain.photo_heights.segmentation")
    heights = importlib.import_module(f"{ADDON}.cliff_terrain.photo_heights.inflate")
    assert tuple(item.identifier for item in rna["segmentation"].enum_items) == segmentation.METHODS
    assert tuple(item.identifier for item in rna["profile"].enum_items) == heights.PROFILES
    assert settings.relief_params().gsd is None
    settings.gsd = 0.02
    assert settings.relief_params().gsd == pytest.approx(0.02)
    for name in ("psnr", "ssim", "exaggeration", "two_sided"):
        assert name in rna


def test_the_sidebar_properties_are_the_cores_declarations(addon, scene):
    settings = importlib.import_module(f"{ADDON}.cliff_terrain.settings")
    rna = scene.cliff_terrain.bl_rna.properties
    operator = bpy.ops.cliff_terrain.build_relief.get_rna_type().properties
    shown = [name for name, parameter in settings.PARAMETERS.items() if parameter.sidebar]
    assert "height_source" in shown and "heights" not in rna  # one name for the height source
    for name in shown:
        parameter, prop = settings.PARAMETERS[name], rna[name]
        assert name in operator and operator[name].description == prop.description
        assert prop.name == parameter.label
        assert prop.description.lower().startswith(parameter.help.lower())
        if parameter.unset:  # what 0 or an empty path stands for
            assert prop.description.endswith(f" = {parameter.unset}")
        if parameter.kind == "choice":
            assert tuple(item.identifier for item in prop.enum_items) == settings.ids(parameter.choices)
            assert [item.description for item in prop.enum_items] == [c[2] for c in parameter.choices]
            assert prop.default == parameter.default
        elif parameter.kind == "path":
            assert prop.subtype == "FILE_PATH" and prop.default == ""
        elif parameter.kind == "bool":
            assert prop.default is parameter.default
        else:
            assert prop.default == (parameter.default or 0)
            low = parameter.minimum if parameter.sidebar_minimum is None else parameter.sidebar_minimum
            assert prop.hard_min == pytest.approx(low)
            if parameter.maximum is not None:
                assert prop.hard_max == parameter.maximum
            if parameter.soft_maximum is not None:
                assert prop.soft_max == pytest.approx(parameter.soft_maximum)
            assert prop.unit == ("LENGTH" if parameter.unit == "m" else "NONE")


def test_manifest_follows_the_core_and_bundles_no_numpy(core):
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["id"] == "cliff_terrain" and manifest["version"] == core.__version__
    assert manifest["blender_version_min"] == "4.2.0" and manifest["type"] == "add-on"
    assert not manifest["tagline"].endswith((".", "!", "?"))
    assert not manifest["permissions"]["files"].endswith((".", "!", "?"))
    wheels = [Path(w).name for w in manifest["wheels"]]
    assert wheels and not any(w.lower().startswith("numpy-") for w in wheels)
    # Every platform gets exactly one wheel of each bundled package for each of Blender's Pythons
    # (3.11: Blender 4.2-5.0; 3.13: Blender 5.1+ and Linux distributions' Blender).
    tool = load_script(ROOT / "tools" / "build_extension.py", "_build_extension")
    blender_ext = tool.load_blender_ext(tool.blender_ext_path())
    assert tuple(tool.PYTHONS) == ("3.11", "3.13")
    for platform in manifest["platforms"]:
        for python in tool.PYTHONS:
            usable = [
                w
                for w in wheels
                if blender_ext.blender_platform_compatible_with_wheel_platform_from_filepath(platform, w)
                and tool.python_tag_matches(w, python)
            ]
            names = sorted(tool.wheel_name_version(w)[0] for w in usable)
            assert names == sorted(tool.normalize(p) for p in tool.PACKAGES), (platform, python)


def test_kept_render_settings_come_back_and_name_what_cannot(addon, scene):
    render_settings = importlib.import_module(f"{ADDON}.scene.render_settings")
    before = (scene.render.engine, scene.render.resolution_x, scene.view_settings.view_transform)
    messages = []
    with render_settings.KeptRenderSettings(scene, log=messages.append) as kept:
        render_settings.configure(scene, "CYCLES", size=(64, 48))
        assert (scene.render.resolution_x, scene.view_settings.view_transform) == (64, "Standard")
    assert (scene.render.engine, scene.render.resolution_x, scene.view_settings.view_transform) == before
    assert kept.not_restored == [] and messages == []
    # A value Blender refuses (as an engine another add-on provided and that is gone): named, not dropped.
    with render_settings.KeptRenderSettings(scene, log=messages.append) as kept:
        kept.values.append(("render", scene.render, "engine", "NO_SUCH_ENGINE"))
    assert kept.not_restored == ["render.engine"]
    assert messages == ["render settings not put back: render.engine"]
    # The user's world (an HDRI, say) comes back after the rig's sky replaced it.
    mine = bpy.data.worlds.new("My HDRI world")
    scene.world = mine
    with render_settings.KeptRenderSettings(scene):
        scene.world = bpy.data.worlds.new("Cliff Terrain Sky")
    assert scene.world == mine
