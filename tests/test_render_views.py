"""render_views.py end to end (as a subprocess with this interpreter and its bpy wheel), and the Render
Views / Evaluate operators: every output is written, the top views are pixel-aligned with the photo
(PSNR recomputed here with numpy), the lit view keeps the photo's colours while its shading shows the
relief, existing files are never replaced, and bad input ends with status 2 and one line on stderr.
"""

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from conftest import RENDER_VIEWS_OUTPUTS, blender_only_site
from conftest import SHARED_UAV as UAV
from PIL import Image

from cliff_terrain import synthetic_field
from cliff_terrain.figures.writer import FIGURES, MAPS

pytestmark = pytest.mark.blender
if importlib.util.find_spec("bpy") is None:
    pytest.skip("the bpy wheel (Blender as a Python module) is not installed", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "render_views.py"
MAIZE = UAV / "plantcv_dsm" / "rgb.tif"  # 261 x 284 RGBA GeoTIFF (transparent no-data corners), 2.2 cm/px

LUMA = np.array([0.2126, 0.7152, 0.0722])


def run(*args, timeout=600, env=None, python=None):
    return subprocess.run(
        [python or sys.executable, *args], capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT
    )


def read(path):
    with Image.open(path) as image:
        return np.asarray(image)


def numpy_psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return np.inf if mse == 0 else 10 * np.log10(255.0**2 / mse)


def slope_from_heights(heights, pixel_size):
    """Slope in degrees per pixel, by central differences (independent of the views' own measure)."""
    gy, gx = np.gradient(heights.astype(np.float64), pixel_size)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def check_error(proc, *fragments):
    """Status 2, exactly one line on stderr starting with the program's name, no traceback."""
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("render_views.py: error: "), lines
    assert "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """The synthetic field (240 x 320, under the default processing size) rendered with defaults."""
    folder = tmp_path_factory.mktemp("field")
    image, truth = synthetic_field(shape=(240, 320), seed=1)
    photo = folder / "field.png"
    Image.fromarray(image).save(photo)
    proc = run(str(SCRIPT), str(photo))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return photo, folder / "field_relief", image, truth, proc


@pytest.fixture(scope="module")
def maize(tmp_path_factory):
    if not MAIZE.is_file():
        pytest.skip(f"real UAV image not found at {MAIZE} (../shared is absent)")
    out = tmp_path_factory.mktemp("maize") / "views"
    proc = run(str(SCRIPT), str(MAIZE), "--out", str(out))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, proc


def test_every_output_is_written_beside_the_photo_by_default(field):
    photo, out, image, _, proc = field
    assert out == photo.parent / "field_relief"
    for name in RENDER_VIEWS_OUTPUTS:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    # Progress is printed per stage, Blender's own per-sample lines are not.
    for stage in ("starting Blender", "pipeline: segment", "rendering xy_flat", "rendering mesh", "done"):
        assert stage in proc.stdout
    assert "Sample 1/" not in proc.stdout
    rows, cols = image.shape[:2]
    for name in ("xy.png", "xy_flat.png", "filtered.png"):
        assert read(out / name).shape == (rows, cols, 3), name
    assert read(out / "mask.png").shape == read(out / "distance.png").shape == (rows, cols)
    side = read(out / "xz.png")
    assert side.shape[1] == cols and side.shape[2] == 4
    assert (side[..., 3] == 0).any() and (side[..., 3] == 255).any()  # the profile against nothing
    with open(out / "scene.blend", "rb") as stream:
        magic = stream.read(7)
    assert magic == b"BLENDER" or magic[:4] == b"\x28\xb5\x2f\xfd"  # plain or zstd-compressed


def test_metrics_json_holds_the_table_figures_sizes_and_timings(field):
    _, out, image, truth, _ = field
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("psnr_xy", "ssim_xy", "psnr_xy_flat", "ssim_xy_flat", "shading_contrast", "reference"):
        assert key in metrics
    assert metrics["regions"] == truth.n_plants
    assert metrics["units"] == "px" and metrics["gsd_m_per_px"] is None
    rows, cols = image.shape[:2]
    assert metrics["render_size"] == [cols, rows]
    # The default mesh, "auto", says what it made and why: below 1.5 MP the grid, which builds at
    # least as fast (settings.AUTO_GRID_BELOW_PIXELS), so no bound; one vertex per pixel corner and a
    # face per pixel on the front (the grid's exact counts: test_bad_input_table.py).
    assert metrics["mesh"] == "grid" and metrics["mesh_rule"].startswith("auto: grid (")
    assert metrics["max_error"] is None and metrics["max_error_rule"] is None
    assert metrics["params"]["mesh"] == "auto"
    assert metrics["vertices"] >= (rows + 1) * (cols + 1) and metrics["faces"] >= rows * cols
    timings = metrics["timings_s"]
    # Every render and the pipeline were timed (rounded to 1 ms, none of them is that fast) ...
    renders = ("render_xy", "render_xy_flat", "render_xz", "render_view3d", "render_mesh")
    assert all(timings[stage] > 0.0 for stage in ("pipeline", *renders)), timings
    # ... one after the other, within the whole run (each figure rounded by up to 0.5 ms).
    stages = ("pipeline", "blender_object", *renders, "metrics", "maps", "save_blend")
    assert timings["total"] >= sum(timings[stage] for stage in stages) - 0.0005 * (len(stages) + 1)
    assert metrics["versions"]["cliff_terrain"]
    assert metrics["versions"]["blender"].split(".")[0] in ("4", "5")
    heights = tifffile.imread(out / "height.tif")
    assert heights.dtype == np.float32 and heights.shape == (rows, cols)
    assert heights.max() == pytest.approx(metrics["max_height"])
    mask = read(out / "mask.png") > 0
    assert not (heights[~mask] > 0).any()  # only the segmented plants rise


def test_flat_top_view_is_the_photo_pixel_for_pixel(field):
    _, out, image, _, _ = field
    flat = read(out / "xy_flat.png")
    metrics = json.loads((out / "metrics.json").read_text())
    value = numpy_psnr(image, flat)
    assert value >= 40.0
    assert value == pytest.approx(metrics["psnr_xy_flat"], abs=1e-6)
    assert metrics["ssim_xy_flat"] >= 0.98
    # Aligned, not merely similar: the photo shifted by one pixel matches far worse.
    for shifted in (np.roll(image, 1, axis=0), np.roll(image, 1, axis=1)):
        assert numpy_psnr(shifted, flat) < value - 10.0


def test_lit_top_view_keeps_colours_and_shades_the_slopes(field):
    _, out, image, _, _ = field
    metrics = json.loads((out / "metrics.json").read_text())
    lit, flat = read(out / "xy.png").astype(np.float64), read(out / "xy_flat.png").astype(np.float64)
    assert numpy_psnr(image, lit) == pytest.approx(metrics["psnr_xy"], abs=1e-6)
    assert metrics["psnr_xy"] >= 20.0 and metrics["ssim_xy"] >= 0.90
    # Level ground renders at its albedo; slopes are visibly lighter or darker.
    slope = slope_from_heights(tifffile.imread(out / "height.tif"), 1.0)
    diff = np.abs(lit @ LUMA - flat @ LUMA)
    sloped, level = diff[slope >= 15].mean(), diff[slope < 2].mean()
    assert level < 3.0
    assert sloped > 5.0 + level
    assert metrics["shading_contrast"] > 5.0


def test_real_orthophoto_in_metres(maize):
    out, _ = maize
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["units"] == "m" and metrics["gsd_m_per_px"] == pytest.approx(0.022, abs=0.001)
    assert metrics["psnr_xy_flat"] >= 40.0 and metrics["ssim_xy_flat"] >= 0.98
    assert metrics["psnr_xy"] >= 20.0 and metrics["ssim_xy"] >= 0.90
    assert metrics["shading_contrast"] > 5.0
    # The photo's transparent no-data corners (59 % of it) render black, as the core reads them.
    alpha = tifffile.imread(MAIZE)[..., 3]
    flat = read(out / "xy_flat.png")
    assert flat.shape[:2] == alpha.shape == (284, 261)
    assert np.mean(flat[alpha == 0].max(axis=1) == 0) > 0.999
    assert flat[alpha == 255].mean() > 60


def test_existing_outputs_are_never_overwritten(field):
    photo, out, _, _, _ = field
    before = {name: (out / name).read_bytes() for name in ("xy.png", "metrics.json", "height.tif")}
    stamps = {name: (out / name).stat().st_mtime_ns for name in RENDER_VIEWS_OUTPUTS}
    proc = run(str(SCRIPT), str(photo), "--exaggeration", "3")
    check_error(proc, str(out / "xy.png"), "--overwrite")
    assert proc.stdout == ""  # refused before any work, Blender not even started
    assert {name: (out / name).stat().st_mtime_ns for name in RENDER_VIEWS_OUTPUTS} == stamps
    assert {name: (out / name).read_bytes() for name in before} == before


def test_existing_tables_are_never_overwritten(tmp_path, field):
    """With a surface model the script also writes regions.csv (and plots.csv with --plots): an
    earlier table in --out is refused before any work, like the views."""
    photo = field[0]
    (tmp_path / "regions.csv").write_text("a table from another run\n")
    proc = run(str(SCRIPT), str(photo), "--out", str(tmp_path), "--dsm", str(tmp_path / "no-such-dsm.tif"))
    check_error(proc, str(tmp_path / "regions.csv"), "--overwrite")
    assert (tmp_path / "regions.csv").read_text() == "a table from another run\n"


def srgb_area_resize(image, size):
    """The photo area-averaged in linear light to `size` (cols, rows): what a renderer's pixel holds."""
    c = image.astype(np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    small = cv2.resize(linear, size, interpolation=cv2.INTER_AREA)
    srgb = np.where(small <= 0.0031308, 12.92 * small, 1.055 * np.clip(small, 0, 1) ** (1 / 2.4) - 0.055)
    return np.round(255 * srgb).astype(np.uint8)


def test_overwrite_replaces_the_outputs_and_smaller_views_stay_aligned(tmp_path, field):
    photo, out, image, _, _ = field
    copy = tmp_path / "again"
    first = run(str(SCRIPT), str(photo), "--out", str(copy), "--resolution", "64", "--samples", "2")
    assert first.returncode == 0, first.stderr
    old = json.loads((copy / "metrics.json").read_text())
    # 320 x 240 at 90 pixels is 90 x 67.5: the frame is rounded to 90 x 68, the relief still fills it.
    second = run(
        str(SCRIPT), str(photo), "--out", str(copy), "--resolution", "90", "--samples", "2", "--overwrite"
    )
    assert second.returncode == 0, second.stderr
    new = json.loads((copy / "metrics.json").read_text())
    assert old["render_size"] == [64, 48] and new["render_size"] == [90, 68]
    flat = read(copy / "xy_flat.png")
    assert flat.shape == (68, 90, 3)
    assert numpy_psnr(srgb_area_resize(image, (90, 68)), flat) >= 40.0
    assert not (copy / "scene.blend1").exists()


def test_help_answers_without_blender(no_bpy):
    proc = run(str(SCRIPT), "--help", env=no_bpy, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: render_views.py")
    for option in ("--out", "--max-size", "--engine", "--resolution", "--overwrite", "--one-sided", "--gsd"):
        assert option in proc.stdout
    assert proc.stderr == ""


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (["missing.jpg"], ["image not found", "missing.jpg"]),
        (["missing.jpg", "--max-size", "3"], ["--max-size", "must be >= 16, got 3"]),
        (["missing.jpg", "--exaggeration", "0"], ["--exaggeration", "must be > 0.0"]),
        (["missing.jpg", "--max-height", "0"], ["--max-height", "must be > 0.0, got 0"]),
        (["missing.jpg", "--max-height", "nan"], ["--max-height", "must be finite, got nan"]),
        (["missing.jpg", "--engine", "OPENGL"], ["--engine", "OPENGL"]),
        (["missing.jpg", "--resolution", "many"], ["--resolution", "expected an integer, got 'many'"]),
        ([], ["IMAGE"]),
    ],
)
def test_bad_arguments_fail_before_blender_starts(no_bpy, args, fragments):
    check_error(run(str(SCRIPT), *args, env=no_bpy, timeout=60), *fragments)


def test_output_folder_that_is_a_file(tmp_path, no_bpy):
    photo = tmp_path / "p.png"
    Image.fromarray(np.zeros((32, 32, 3), np.uint8)).save(photo)
    (tmp_path / "out").write_text("a file")
    check_error(run(str(SCRIPT), str(photo), "--out", str(tmp_path / "out"), env=no_bpy), "not a folder")


def test_not_an_image_exits_2_and_writes_nothing(tmp_path):
    fake = tmp_path / "notes.jpg"
    fake.write_text("not a photo\n")
    proc = run(str(SCRIPT), str(fake))
    check_error(proc, "notes.jpg", "not a JPEG, PNG, TIFF")
    assert not (tmp_path / "notes_relief").exists()


def test_blender_without_the_extension_libraries_says_how_to_install_them(tmp_path):
    # As in a Blender without the extension: only bpy and numpy importable (python -S, no site).
    site = blender_only_site(tmp_path)
    photo = tmp_path / "p.png"
    Image.fromarray(np.zeros((32, 32, 3), np.uint8)).save(photo)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env["PYTHONPATH"] = str(site)
    proc = subprocess.run(
        [sys.executable, "-S", str(SCRIPT), str(photo)], capture_output=True, text=True, env=env, timeout=300
    )
    check_error(proc, "install the extension zip", "requirements.txt")
    assert not (tmp_path / "p_relief").exists()


# Start Blender as render_views.py does (_loader.py; argv[1] is the repository), with the view operators.
OPERATORS_HEAD = textwrap.dedent(
    r"""
    import json, sys
    sys.path.insert(0, sys.argv[1])
    import _loader
    bpy, addon, core = _loader.start_blender(usage="render_views.py")
    from cliff_terrain_addon.operators import render
    if not hasattr(bpy.types, "CLIFF_TERRAIN_OT_evaluate"):
        render.register()
    scene = bpy.context.scene
    """
)

OPERATORS = OPERATORS_HEAD + textwrap.dedent(
    r"""
    out = {"poll_empty": bpy.ops.cliff_terrain.evaluate.poll()}
    bpy.ops.cliff_terrain.build_relief(filepath=sys.argv[2])
    scene.cliff_terrain.output_dir = sys.argv[3]
    before = (scene.render.engine, scene.view_settings.view_transform, scene.render.resolution_x)
    out["evaluate"] = sorted(bpy.ops.cliff_terrain.evaluate())
    out["psnr"], out["ssim"] = scene.cliff_terrain.psnr, scene.cliff_terrain.ssim
    out["render"] = sorted(bpy.ops.cliff_terrain.render_views(samples=4))
    out["kept"] = before == (scene.render.engine, scene.view_settings.view_transform, scene.render.resolution_x)
    out["rig"] = sorted(o.name for o in bpy.data.collections["Cliff Terrain Views"].objects)
    print("RESULT " + json.dumps(out), flush=True)
    _loader.leave(0)
    """
)


def test_operators_render_and_evaluate_the_active_relief(field, tmp_path):
    photo, out, _, _, _ = field
    proc = run("-c", OPERATORS, str(ROOT), str(photo), str(tmp_path) + "/")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    result = json.loads(proc.stdout.split("RESULT ", 1)[1].splitlines()[0])
    assert result["poll_empty"] is False  # no relief selected yet
    assert result["evaluate"] == ["FINISHED"] and result["render"] == ["FINISHED"]
    # The same relief, light and samples as the script: the same figures.
    script = json.loads((out / "metrics.json").read_text())
    assert result["psnr"] == pytest.approx(script["psnr_xy"], abs=1e-3)
    assert result["ssim"] == pytest.approx(script["ssim_xy"], abs=1e-4)
    assert result["kept"] is True
    assert result["rig"] == [
        "Cliff Terrain Perspective",
        "Cliff Terrain Side",
        "Cliff Terrain Sun",
        "Cliff Terrain Top",
    ]
    written = tmp_path / "field"
    for name in ("xy.png", "xy_flat.png", "xz.png", "view3d.png", "mesh.png", "metrics.json"):
        assert (written / name).is_file(), name
    record = json.loads((written / "metrics.json").read_text())
    assert record["samples"] == 4
    # The maps and annotated figures of render_views.py too, from the relief rebuilt from its photo:
    # the same maps, and the same key figures.
    for name in (*MAPS, *FIGURES):
        assert (written / name).is_file(), name
    assert read(written / "mask.png").tolist() == read(out / "mask.png").tolist()
    for key in ("plants", "cover", "canopy_height_p50_px", "canopy_height_p90_px", "plant_height_median_px"):
        assert record[key] == pytest.approx(script[key], rel=1e-6), key
    assert record["figures"]["annotated"] == list(FIGURES)
    with Image.open(written / "summary.png") as summary:
        assert min(summary.size) > 400


FAILED_EVALUATION = OPERATORS_HEAD + textwrap.dedent(
    r"""
    from cliff_terrain_addon.scene import views
    from cliff_terrain_addon.cliff_terrain.errors import CliffTerrainError
    bpy.ops.cliff_terrain.build_relief(filepath=sys.argv[2], max_size=96)
    mine = bpy.data.worlds.new("My World")
    scene.world = mine

    def fails(*args, **kwargs):
        raise CliffTerrainError("the comparison failed")

    views.evaluate_relief = fails  # after both views are rendered
    try:
        out = {"evaluate": sorted(bpy.ops.cliff_terrain.evaluate(resolution=64))}
    except RuntimeError as exc:  # bpy.ops raises the operator's error report
        out = {"evaluate": str(exc).strip()}
    out["rig"] = "Cliff Terrain Views" in bpy.data.collections
    out["world"] = scene.world.name
    print("RESULT " + json.dumps(out), flush=True)
    _loader.leave(0)
    """
)


def test_a_failed_evaluation_leaves_neither_its_rig_nor_its_sky_behind(field, tmp_path):
    photo, *_ = field
    proc = run("-c", FAILED_EVALUATION, str(ROOT), str(photo))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    result = json.loads(proc.stdout.split("RESULT ", 1)[1].splitlines()[0])
    assert result == {"evaluate": "Error: the comparison failed", "rig": False, "world": "My World"}


CHANGED_PHOTO = OPERATORS_HEAD + textwrap.dedent(
    r"""
    import os, shutil
    from PIL import Image
    copy = os.path.join(sys.argv[3], "copy.png")
    shutil.copy(sys.argv[2], copy)
    bpy.ops.cliff_terrain.build_relief(filepath=copy, max_size=160)
    # The same photo mirrored: the same size and plants, another relief.
    with Image.open(sys.argv[2]) as photo:
        photo.transpose(Image.Transpose.FLIP_LEFT_RIGHT).save(copy)
    scene.cliff_terrain.output_dir = sys.argv[3]
    out = {"render": sorted(bpy.ops.cliff_terrain.render_views(samples=1))}
    print("RESULT " + json.dumps(out), flush=True)
    _loader.leave(0)
    """
)


def test_render_views_of_a_changed_photo_renders_and_warns(field, tmp_path):
    photo, *_ = field
    proc = run("-c", CHANGED_PHOTO, str(ROOT), str(photo), str(tmp_path))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    result = json.loads(proc.stdout.split("RESULT ", 1)[1].splitlines()[0])
    assert result["render"] == ["FINISHED"]
    assert "No annotated figures: the photo" in proc.stdout + proc.stderr
    assert "has changed since the relief was built" in proc.stdout + proc.stderr
    written = tmp_path / "copy"
    assert (written / "xy.png").is_file() and not (written / "summary.png").exists()
