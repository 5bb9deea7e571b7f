"""The adaptive mesh in Blender: the Build Relief operator, the evaluation's slope map, and
render_views.py ``--mesh adaptive`` (top views against the photo and against the grid's)."""

import importlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cliff_terrain import synthetic_field

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[1]
UAV = ROOT.parent / "shared" / "data" / "uav"
BROCCOLI = UAV / "broccoli" / "01_clip_raw_test.jpg"  # no EXIF: normalised units
MAIZE = UAV / "plantcv_dsm" / "rgb.tif"  # GeoTIFF, 2.2 cm/px: metres
ADDON = "cliff_terrain_addon"

needs_uav = pytest.mark.skipif(not UAV.is_dir(), reason=f"real UAV images not found at {UAV}")


@pytest.fixture(scope="module")
def core(addon):
    return importlib.import_module(f"{ADDON}.cliff_terrain")


def build(**kwargs):
    result = bpy.ops.cliff_terrain.build_relief(
        **{k: (str(v) if k == "filepath" else v) for k, v in kwargs.items()}
    )
    assert result == {"FINISHED"}
    return bpy.context.active_object


def mesh_arrays(mesh):
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    sizes = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    corners = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    uvs = np.empty(2 * len(mesh.loops), dtype=np.float32)
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", uvs)
    return co.reshape(-1, 3), sizes, corners, uvs.reshape(-1, 2)


@needs_uav
def test_the_operator_builds_the_cores_adaptive_mesh(core, scene):
    obj = build(filepath=BROCCOLI, max_size=300, mesh="adaptive")
    record = obj["cliff_terrain"]
    ref = core.build_relief(str(BROCCOLI), max_size=300, mesh="adaptive")
    assert record["params"]["mesh"] == "adaptive"
    assert record["max_error"] == pytest.approx(ref.max_error) and ref.max_error > 0
    assert record["front_faces"] == ref.mesh.n_front_faces
    co, sizes, corners, uvs = mesh_arrays(obj.data)
    scale = record["blender_units_per_unit"]
    np.testing.assert_allclose(co, ref.mesh.vertices * scale, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(sizes, ref.mesh.face_sizes)
    np.testing.assert_array_equal(corners, ref.mesh.corner_verts)
    np.testing.assert_array_equal(uvs, ref.mesh.uvs)
    # Blender finds nothing to repair, and every edge has two faces (a closed solid).
    assert obj.data.validate(verbose=False) is False
    assert len(obj.data.edges) == ref.mesh.edge_face_counts().size
    assert np.all(ref.mesh.edge_face_counts() == 2)
    # Blender draws the quads the TIN's triangles were paired into as those same triangles
    # (cliff_terrain.mesh.quads): its own triangulation of the front is the core's.
    obj.data.calc_loop_triangles()
    n_front_tris = len(ref.mesh.front_triangles())
    tris = np.empty(3 * len(obj.data.loop_triangles), dtype=np.int32)
    obj.data.loop_triangles.foreach_get("vertices", tris)
    owner = np.empty(len(obj.data.loop_triangles), dtype=np.int32)
    obj.data.loop_triangles.foreach_get("polygon_index", owner)
    front = tris.reshape(-1, 3)[owner < ref.mesh.n_front_faces]
    assert len(front) == n_front_tris and (sizes[: ref.mesh.n_front_faces] == 4).mean() > 0.6

    def rotated(t):  # each triangle from its smallest vertex, orientation kept
        k = np.argmin(t, axis=1)
        return np.sort(
            np.stack([t[np.arange(len(t)), (k + i) % 3] for i in range(3)], axis=1).view("i4,i4,i4"), axis=0
        )

    np.testing.assert_array_equal(rotated(front), rotated(ref.mesh.front_triangles().astype(np.int32)))
    # Fewer triangles and faces than the grid the same settings give (10x at the default size:
    # test_tin.py; at 300 px the plants' edges are a larger share of the grid).
    grid = build(filepath=BROCCOLI, max_size=300, mesh="grid")
    assert 2 * grid["cliff_terrain"]["front_faces"] >= 5 * n_front_tris
    assert grid["cliff_terrain"]["front_faces"] >= 5 * record["front_faces"]
    assert grid["cliff_terrain"]["max_error"] == 0.0


@needs_uav
def test_max_error_reaches_the_core_and_zero_means_automatic(core, scene):
    auto = build(filepath=MAIZE, mesh="adaptive", max_error=0.0)
    assert auto["cliff_terrain"]["units"] == "m"
    # Heights inflated from the photo: half a processing pixel.
    assert auto["cliff_terrain"]["max_error"] == pytest.approx(0.5 * auto["cliff_terrain"]["pixel_size"])
    assert auto["cliff_terrain"]["max_error_rule"].startswith("half a pixel (inflated heights, ")
    coarse = build(filepath=MAIZE, mesh="adaptive", max_error=0.05)
    assert coarse["cliff_terrain"]["max_error"] == pytest.approx(0.05)
    assert coarse["cliff_terrain"]["max_error_rule"] == "given"
    assert len(coarse.data.polygons) < len(auto.data.polygons)


def test_the_slope_map_of_an_adaptive_relief_samples_its_triangles(core, scene):
    views = importlib.import_module(f"{ADDON}.scene.views")
    mesh_data = importlib.import_module(f"{ADDON}.scene.mesh_data")
    rows, cols = np.indices((30, 40))
    heights = np.clip(9.0 - np.hypot(rows - 15, cols - 20), 0, None).astype(np.float32)
    arrays = core.adaptive_mesh(heights, max_error=0.05)
    obj = bpy.data.objects.new("relief", mesh_data.mesh_from_arrays("relief", arrays, scale=0.25))
    z = views.front_corner_heights(obj, heights.shape, arrays.n_front_faces) / 0.25
    assert z.shape == (31, 41)
    # The pixel corners of a cone: within the error bound plus the cone's rise over half a diagonal.
    corner_r, corner_c = np.indices((31, 41)) - 0.5
    cone = np.clip(9.0 - np.hypot(corner_r - 15, corner_c - 20), 0, None)
    assert np.abs(z - cone).max() <= 0.05 + np.sqrt(0.5) + 1e-6
    assert np.abs(z - cone).mean() < 0.2


def _render(photo, out, *args):
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "render_views.py"),
            str(photo),
            "--out",
            str(out),
            "--samples",
            "8",
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return json.loads((out / "metrics.json").read_text())


@pytest.mark.slow
def test_render_views_adaptive_keeps_the_top_views(tmp_path):
    image, _ = synthetic_field(shape=(240, 320), seed=1)
    photo = tmp_path / "field.png"
    Image.fromarray(image).save(photo)
    grid = _render(photo, tmp_path / "grid", "--mesh", "grid")
    adaptive = _render(photo, tmp_path / "adaptive", "--mesh", "adaptive")
    assert adaptive["params"]["mesh"] == "adaptive" and adaptive["max_error"] > 0
    assert grid["max_error"] is None
    assert adaptive["faces"] * 5 < grid["faces"]
    # The flat top view is still the photo pixel for pixel; the lit one loses at most 0.5 dB.
    assert adaptive["psnr_xy_flat"] >= 40.0
    flat = np.asarray(Image.open(tmp_path / "adaptive" / "xy_flat.png").convert("RGB")).astype(float)
    assert 10 * np.log10(255.0**2 / np.mean((flat - image) ** 2)) == pytest.approx(adaptive["psnr_xy_flat"])
    assert adaptive["psnr_xy"] >= grid["psnr_xy"] - 0.5
    assert adaptive["ssim_xy"] >= grid["ssim_xy"] - 0.01
    assert (tmp_path / "adaptive" / "scene.blend").stat().st_size * 2 < (
        tmp_path / "grid" / "scene.blend"
    ).stat().st_size


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--max-error", "0"], "argument --max-error: must be > 0.0, got 0.0"),
        (["--max-error", "nan"], "argument --max-error: must be finite, got nan"),
        (["--mesh", "tin"], "argument --mesh: invalid choice: 'tin'"),
    ],
)
def test_bad_mesh_options_fail_before_blender_starts(tmp_path, args, fragment):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "render_views.py"), str(tmp_path / "x.png"), *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert proc.returncode == 2 and fragment in proc.stderr, proc.stderr


def test_a_mosaic_comes_in_as_adaptive_tiles_under_one_georeferenced_empty(addon, scene, tmp_path):
    import tifffile

    image, _ = synthetic_field(shape=(600, 700), seed=6)
    keys = (1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32633, 3076, 0, 1, 9001)
    path = tmp_path / "mosaic.tif"
    tifffile.imwrite(
        path,
        image,
        tile=(128, 128),
        photometric="rgb",
        compression="zlib",
        extratags=[
            (33550, 12, 3, (0.02, 0.02, 0.0), True),
            (33922, 12, 6, (0.0, 0.0, 0.0, 500000.0, 5200000.0, 0.0), True),
            (34735, 3, len(keys), keys, True),
        ],
    )
    assert bpy.ops.cliff_terrain.import_mosaic(filepath=str(path), tile=256, overlap=96) == {"FINISHED"}
    root = bpy.context.active_object
    info = root["cliff_terrain_mosaic"]
    assert root.type == "EMPTY" and info["crs"] == 32633
    assert list(info["origin"]) == [500000.0, 5200000.0] and info["gsd"] == pytest.approx(0.02)
    # No Max Error given: half a mosaic pixel, and the rule is recorded.
    assert info["max_error"] == pytest.approx(0.01)
    assert info["max_error_rule"] == "half a pixel (inflated heights, 2 cm pixels)"
    tiles = sorted(root.children, key=lambda o: o.name)
    assert len(tiles) == 3 * 3
    covered = 0.0
    for obj in tiles:
        r0, r1, c0, c1 = obj["cliff_terrain_tile"]["core"]
        co, sizes, _, uvs = mesh_arrays(obj.data)
        assert set(np.unique(sizes)) == {3, 4}  # adaptive (triangles paired into quads), one-sided
        assert co[:, 0].max() == pytest.approx((c1 - c0) * 0.02) and co[:, 1].max() == pytest.approx(
            (r1 - r0) * 0.02
        )
        assert obj.location.x == pytest.approx(c0 * 0.02) and obj.location.y == pytest.approx(
            (600 - r1) * 0.02
        )
        covered += (r1 - r0) * (c1 - c0)
        textures = [n for n in obj.active_material.node_tree.nodes if n.type == "TEX_IMAGE"]
        images = [n.image for n in textures]
        assert images and tuple(images[0].size) == (c1 - c0, r1 - r0)
        # One-sided tiles clamp their texture: repeating it would draw a line along each border.
        assert textures[0].extension == "EXTEND"
        assert max(images[0].size) <= 16384
    assert covered == 600 * 700
    assert sum(len(o.data.polygons) for o in tiles) < 0.2 * 2 * 600 * 700
    # The tiles close into one surface: no crack where a plant crosses a tile border.
    from test_seams import cracks, welded_open_edges

    fan_triangles = importlib.import_module(f"{ADDON}.cliff_terrain.mesh.quads").fan_triangles
    parts = []
    for obj in tiles:
        co, sizes, corners, _ = mesh_arrays(obj.data)
        parts.append((co + np.array(obj.location), fan_triangles(sizes, corners)))
    edges, points = welded_open_edges(parts, 0.02)
    assert len(edges) > 0 and len(cracks(edges, points, 700, 600)) == 0
