"""The bad-input corpus of issue #6, end to end through both front doors: the Build Relief operator
(bpy wheel, in this process) and render_views.py (a subprocess with this interpreter).

One table. Each case writes its input under the test's folder and says what must happen:

* refused, with a message a user understands that names the file: an ERROR report from the operator
  (a RuntimeError for scripts) with no datablock, orphan or change to the user's objects left
  behind; status 2 and one line on stderr from the script, no traceback, and no file written;
* built, with the sizes the input and ``max_size`` imply and the relief its content implies (plants
  from the synthetic field's known truth, flat soil, a dome over all-canopy, flat no-data): the
  operator's object (a second build is a second object; the user's cube and the first relief are
  untouched; no orphan data) and every output of the script, whose flat top view must be the photo.

The core's side of the same corpus (ImageReadError / ImageTooLargeError messages) is in
test_image_io.py.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from conftest import RENDER_VIEWS_OUTPUTS
from PIL import Image

from cliff_terrain import synthetic_field

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "render_views.py"
# Every case is built with this processing size (it only matters for the 100 MP photo).
MAX_SIZE = 500

# The content of every photo that should show plants: a synthetic field whose 8 plants are known.
FIELD, TRUTH = synthetic_field(shape=(72, 96), n_rows=2, radius_range=(5.0, 8.0), seed=1)
ROWS, COLS = FIELD.shape[:2]
# Left columns of the RGBA photo that are transparent (no-data).
NO_DATA_COLS = 24
# The 100 MP photo: a field drawn at 420 x 600 and enlarged 20 times to 8400 x 12000.
BIG_FIELD, BIG_TRUTH = synthetic_field(shape=(420, 600), seed=2)
BIG_SCALE = 20
BIG_ROWS, BIG_COLS = BIG_SCALE * BIG_FIELD.shape[0], BIG_SCALE * BIG_FIELD.shape[1]


# ---- what must happen ----


@dataclass(frozen=True)
class Refused:
    """Refused: the message (operator and script) holds `message` and the file's name.

    render_views.py checks a missing path or a directory itself, before Blender starts, in its own
    words (`cli_message`); everything else reaches the core and is refused with the core's message.
    """

    message: str
    cli_message: str | None = None


@dataclass(frozen=True)
class Built:
    """Built from a `size` = (width, height) photo (as viewed) on a `grid` = (rows, cols) grid.

    `regions` is the exact number of raised regions (0: the relief is flat), or None for "at least
    one"; `covered`: every pixel rises; `flat_cols`: that many grid columns from the left stay flat.
    """

    size: tuple[int, int]
    grid: tuple[int, int]
    regions: int | None
    covered: bool = False
    flat_cols: int = 0


@dataclass(frozen=True)
class Case:
    id: str
    make: Callable[[Path], Path]  # writes the input into the folder, returns its path
    expect: Refused | Built
    shared: bool = False  # made once per module (the 100 MP photo), not per test


# ---- the inputs ----


def field_texture(colour, seed):
    """A (ROWS, COLS) photo of one material: `colour` with furrows and blotches of brightness."""
    rng = np.random.default_rng(seed)
    blotches = cv2.GaussianBlur(rng.normal(0.0, 1.0, (ROWS, COLS)), (0, 0), 1.5)
    furrows = np.sin(np.arange(COLS) * (2 * np.pi * 4 / COLS))
    brightness = 1.0 + 0.2 * blotches / blotches.std() + 0.15 * furrows
    rgb = np.asarray(colour, dtype=np.float64) * brightness[..., None] + rng.normal(0.0, 3.0, (ROWS, COLS, 3))
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


def save(path, rgb, **options):
    Image.fromarray(rgb).save(path, **options)
    return path


def make_empty(folder):
    path = folder / "empty.jpg"
    path.write_bytes(b"")
    return path


def make_not_an_image(folder):
    path = folder / "notes.jpg"
    path.write_bytes(b"These are field notes, not a photo.\n" * 20)
    return path


def make_truncated_jpeg(folder):
    whole = save(folder / "whole.jpg", FIELD, quality=90)
    path = folder / "cut.jpg"
    path.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])
    return path


def make_truncated_tiff(folder):
    # A plain RGB TIFF cut short: Pillow's libtiff printed "TIFFFillStrip: Read error" on stderr and
    # the error said "corrupt or unsupported", until 2026-12-06.
    whole = folder / "whole.tif"
    tifffile.imwrite(whole, FIELD, photometric="rgb", compression="zlib")
    path = folder / "cut.tif"
    path.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    return path


def make_missing(folder):
    return folder / "no_such_photo.jpg"


def make_directory(folder):
    path = folder / "photo.jpg"
    path.mkdir()
    return path


def make_png_claiming_200000_squared(folder):
    """A PNG whose header (correct CRC) claims 200000 x 200000 RGB pixels, with almost no data."""

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path = folder / "bomb.png"
    header = struct.pack(">IIBBBBB", 200_000, 200_000, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b"\x00" * 64))
        + chunk(b"IEND", b"")
    )
    return path


def make_one_pixel(folder):
    return save(folder / "dot.png", np.full((1, 1, 3), (40, 140, 40), np.uint8))


def make_two_by_two(folder):
    # Four shades of leaf green: all canopy at the smallest size an image may have.
    greens = np.array([[[40, 140, 40], [50, 150, 45]], [[35, 130, 50], [45, 145, 40]]], np.uint8)
    return save(folder / "tiny.png", greens)


def make_strip(folder):
    # Two rows of bare soil: the thinnest photo there is.
    return save(folder / "strip.png", field_texture((125, 90, 62), seed=5)[:2, :64])


def make_greyscale(folder):
    path = folder / "grey.png"
    Image.fromarray(FIELD).convert("L").save(path)
    return path


def make_rgba(folder):
    alpha = np.full((ROWS, COLS), 255, np.uint8)
    alpha[:, :NO_DATA_COLS] = 0  # outside the surveyed area; the field's colours stay under it
    return save(folder / "ortho.png", np.dstack([FIELD, alpha]))


def make_sixteen_bit(folder):
    path = folder / "field16.png"
    cv2.imwrite(str(path), FIELD[..., ::-1].astype(np.uint16) * 257)  # OpenCV writes BGR
    assert path.read_bytes()[24] == 16  # the IHDR's bit depth
    return path


def make_cmyk(folder):
    path = folder / "cmyk.jpg"
    Image.fromarray(FIELD).convert("CMYK").save(path, quality=95)
    return path


def make_exif_rotated(folder):
    """A JPEG stored on its side (72 wide, 96 tall) whose EXIF orientation 6 shows the field upright."""
    exif = Image.Exif()
    exif[0x0112] = 6  # shown rotated 90 degrees clockwise
    return save(folder / "rotated.jpg", np.ascontiguousarray(np.rot90(FIELD, 1)), quality=95, exif=exif)


def make_uniform(folder):
    return save(folder / "uniform.png", np.full((ROWS, COLS, 3), (120, 90, 60), np.uint8))


def make_all_soil(folder):
    return save(folder / "soil.png", field_texture((125, 90, 62), seed=3))


def make_all_canopy(folder):
    return save(folder / "canopy.png", field_texture((55, 125, 45), seed=4))


def make_non_ascii_path(folder):
    sub = folder / "vuelo 3 – ñandú 写真"
    sub.mkdir()
    return save(sub / "campo de maíz.png", FIELD)


def make_100_megapixels(folder):
    """12000 x 8400 JPEG (100.8 MP), written once per module (about 1 s and 3 MB)."""
    path = folder / "field 100MP.jpg"
    if not path.exists():
        big = cv2.resize(BIG_FIELD, (BIG_COLS, BIG_ROWS), interpolation=cv2.INTER_LINEAR)
        save(path, big, quality=85)
    return path


FIELD_BUILT = Built(size=(COLS, ROWS), grid=(ROWS, COLS), regions=TRUTH.n_plants)

CASES = [
    Case("empty", make_empty, Refused("the file is empty (0 bytes)")),
    Case("not-an-image.jpg", make_not_an_image, Refused("it is not a JPEG, PNG, TIFF, WebP or BMP image")),
    Case("truncated-jpeg", make_truncated_jpeg, Refused("the file is truncated")),
    Case("truncated-tiff", make_truncated_tiff, Refused("is truncated: the file has")),
    Case("missing", make_missing, Refused("no such file", cli_message="image not found")),
    Case(
        "directory",
        make_directory,
        Refused("it is a directory, not an image file", cli_message="image is not a file"),
    ),
    Case(
        "png-claims-200000x200000",
        make_png_claiming_200000_squared,
        Refused("is 200000x200000 pixels (40000.0 MP)"),
    ),
    Case("1x1", make_one_pixel, Refused("it is 1x1 pixels; an image needs at least 2x2")),
    Case("2x2", make_two_by_two, Built(size=(2, 2), grid=(2, 2), regions=1, covered=True)),
    Case("2x64-strip", make_strip, Built(size=(64, 2), grid=(2, 64), regions=0)),
    # Grey has no excess green: documented (cliff_terrain.photo_heights.segmentation) as flat, like bare soil.
    Case("greyscale", make_greyscale, Built(size=(COLS, ROWS), grid=(ROWS, COLS), regions=0)),
    Case(
        "rgba-no-data",
        make_rgba,
        Built(size=(COLS, ROWS), grid=(ROWS, COLS), regions=None, flat_cols=NO_DATA_COLS),
    ),
    Case("16-bit", make_sixteen_bit, FIELD_BUILT),
    Case("cmyk-jpeg", make_cmyk, FIELD_BUILT),
    Case("exif-rotated", make_exif_rotated, FIELD_BUILT),
    # No regions in one colour: a flat relief (as the core's test_uniform_colour_has_no_regions).
    Case("uniform-colour", make_uniform, Built(size=(COLS, ROWS), grid=(ROWS, COLS), regions=0)),
    Case("all-soil", make_all_soil, Built(size=(COLS, ROWS), grid=(ROWS, COLS), regions=0)),
    Case(
        "all-canopy",
        make_all_canopy,
        Built(size=(COLS, ROWS), grid=(ROWS, COLS), regions=1, covered=True),
    ),
    Case("spaces-and-non-ascii-path", make_non_ascii_path, FIELD_BUILT),
    Case(
        "100-megapixels",
        make_100_megapixels,
        # Reduced to MAX_SIZE on its longer side, the aspect kept.
        Built(
            size=(BIG_COLS, BIG_ROWS),
            grid=(round(BIG_ROWS * MAX_SIZE / BIG_COLS), MAX_SIZE),
            regions=BIG_TRUTH.n_plants,
        ),
        shared=True,
    ),
]


@pytest.fixture(scope="module")
def shared_folder(tmp_path_factory):
    return tmp_path_factory.mktemp("shared inputs")


def make_input(case, tmp_path, shared_folder):
    return case.make(shared_folder if case.shared else tmp_path)


def by_table(test):
    return pytest.mark.parametrize("case", CASES, ids=[case.id for case in CASES])(test)


# ---- checks shared by both routes ----


def check_refusal(message, case, photo, *, cli):
    expected = case.expect.cli_message if cli and case.expect.cli_message else case.expect.message
    assert expected in message, message
    assert photo.name in message, message  # the user learns which file
    assert "Traceback" not in message and "Cliff Terrain failed" not in message, message


def check_relief(expect, heights, regions, *, corners):
    """`heights`: per grid pixel (rows, cols), or per pixel corner (rows + 1, cols + 1)."""
    if expect.regions is not None:
        assert regions == expect.regions
    if expect.regions == 0:
        assert not heights.any(), f"a flat relief has heights up to {heights.max()}"
    else:
        assert regions >= 1 and heights.max() > 0.0
    if expect.covered:
        # Corner heights on the border join the walls; every pixel (every inner corner) rises.
        inner = heights[1:-1, 1:-1] if corners else heights
        assert inner.size and (inner > 0.0).all(), inner.min()
    if expect.flat_cols:
        # Corners left of column `flat_cols` touch only no-data pixels.
        assert not heights[:, : expect.flat_cols].any()
        assert heights[:, expect.flat_cols :].max() > 0.0


# ---- (a) the Build Relief operator, in this process ----


def build(photo):
    # The grid: the checks below read its vertex layout.
    result = bpy.ops.cliff_terrain.build_relief(filepath=str(photo), max_size=MAX_SIZE, mesh="grid")
    assert result == {"FINISHED"}
    return bpy.context.active_object


def add_user_cube():
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(30.0, -4.0, 1.5), rotation=(0.1, 0.2, 0.3))
    cube = bpy.context.active_object
    cube.scale = (1.5, 0.5, 2.0)
    return cube


def object_state(obj):
    """Everything a build must not change about an existing object."""
    co = np.empty(3 * len(obj.data.vertices), dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    return (
        obj.name,
        obj.data.name,
        tuple(obj.location),
        tuple(obj.rotation_euler),
        tuple(obj.scale),
        co.tobytes(),
        len(obj.data.polygons),
        tuple(m.name if m else None for m in obj.data.materials),
        tuple(c.name for c in obj.users_collection),
    )


def orphans():
    return [
        f"{kind}:{block.name}"
        for kind in ("meshes", "materials", "images", "textures")
        for block in getattr(bpy.data, kind)
        if block.users == 0
    ]


def corner_heights(obj, grid):
    """z of the front vertices, (rows + 1, cols + 1): they come first, row by row from the top."""
    rows, cols = grid
    n = (rows + 1) * (cols + 1)
    co = np.empty(3 * len(obj.data.vertices), dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    return co[2 : 3 * n : 3].reshape(rows + 1, cols + 1)


def check_relief_object(obj, expect, photo):
    rows, cols = expect.grid
    info = obj["cliff_terrain"]
    assert obj.name == obj.data.name == photo.stem
    assert (info["grid_rows"], info["grid_cols"]) == expect.grid
    assert (info["image_width"], info["image_height"]) == expect.size
    assert info["units"] == "px" and Path(info["source"]) == photo
    # Two-sided: (rows + 1) (cols + 1) front vertices and a ring of base vertices.
    assert len(obj.data.vertices) == (rows + 1) * (cols + 1) + 2 * (rows + cols)
    assert obj.data.validate(verbose=False) is False
    # Normalised units: the longer side is 10 Blender units and the photo's aspect is kept.
    assert max(obj.dimensions.x, obj.dimensions.y) == pytest.approx(10.0, rel=1e-5)
    assert obj.dimensions.x / obj.dimensions.y == pytest.approx(cols / rows, rel=1e-5)
    # The texture is the whole photo as viewed (EXIF orientation applied), not the processing grid.
    image = obj.active_material.node_tree.nodes.active.image
    assert tuple(image.size) == expect.size
    check_relief(expect, corner_heights(obj, expect.grid), info["regions"], corners=True)


@by_table
def test_build_operator(case, scene, datablock_counts, tmp_path, shared_folder, capfd):
    photo = make_input(case, tmp_path, shared_folder)
    cube = add_user_cube()
    user = object_state(cube)
    before = datablock_counts()

    if isinstance(case.expect, Refused):
        with pytest.raises(RuntimeError) as failure:
            bpy.ops.cliff_terrain.build_relief(filepath=str(photo), max_size=MAX_SIZE, mesh="grid")
        message = str(failure.value)
        assert message.startswith("Error: ") and len(message.strip().splitlines()) == 1, message
        check_refusal(message, case, photo, cli=False)
        assert datablock_counts() == before
        assert orphans() == []
        assert object_state(cube) == user
        assert bpy.context.active_object == cube and cube.select_get()
        assert "Traceback" not in capfd.readouterr().err
        return

    first = build(photo)
    check_relief_object(first, case.expect, photo)
    assert object_state(cube) == user
    assert orphans() == []
    relief = object_state(first)
    # Building again makes a new object and changes neither the first relief nor the cube.
    second = build(photo)
    assert second not in (first, cube) and second.data != first.data
    assert second["cliff_terrain"]["regions"] == first["cliff_terrain"]["regions"]
    assert object_state(first) == relief and object_state(cube) == user
    assert datablock_counts()["objects"] == before["objects"] + 2
    assert orphans() == []
    assert "Traceback" not in capfd.readouterr().err


def test_undo_removes_a_relief_textured_from_decoded_pixels(scene, tmp_path):
    # The EXIF-rotated photo is the case whose texture is made from the core's pixels and packed
    # (not a file Blender reads): undo must remove that image with the object, mesh and material.
    # Headless, Blender pushes no undo step after an operator: the UI's step is pushed here by hand.
    photo = make_exif_rotated(tmp_path)
    add_user_cube()
    bpy.ops.ed.undo_push(message="before build")

    def names():
        return {
            kind: sorted(b.name for b in getattr(bpy.data, kind))
            for kind in ("objects", "meshes", "materials", "images")
        }

    before = names()
    obj = build(photo)
    assert obj.active_material.node_tree.nodes.active.image.packed_file is not None
    name = obj.name
    bpy.ops.ed.undo_push(message="Build Relief")
    assert names() != before
    bpy.ops.ed.undo()
    assert names() == before
    bpy.ops.ed.redo()
    assert bpy.data.objects[name]["cliff_terrain"]["image_width"] == COLS


# ---- (b) render_views.py, as a subprocess with this interpreter ----


def render_views(photo, *args):
    return subprocess.run(
        # The grid: the checks read its vertex count.
        [
            sys.executable,
            str(SCRIPT),
            str(photo),
            "--max-size",
            str(MAX_SIZE),
            "--samples",
            "1",
            "--mesh",
            "grid",
            *args,
        ],
        capture_output=True,
        text=True,
        encoding="utf-8",
        errors="replace",
        timeout=600,
        cwd=ROOT,
    )


def files_under(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@by_table
def test_render_views(case, tmp_path, shared_folder):
    photo = make_input(case, tmp_path, shared_folder)
    out = photo.with_name(f"{photo.stem}_relief")  # the default output folder, beside the photo
    before = files_under(photo.parent)
    proc = render_views(photo)

    if isinstance(case.expect, Refused):
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2, proc.stderr
        assert len(lines) == 1 and lines[0].startswith("render_views.py: error: "), proc.stderr
        check_refusal(lines[0], case, photo, cli=True)
        assert files_under(photo.parent) == before and not out.exists()
        return

    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(RENDER_VIEWS_OUTPUTS)
    metrics = json.loads((out / "metrics.json").read_text())
    expect = case.expect
    rows, cols = expect.grid
    assert metrics["processing_size"] == [cols, rows]
    # One view pixel per grid cell, enlarged for a tiny or thin photo until the views are 16 pixels
    # across (SSIM compares them with the photo through a 7x7 window).
    enlarge = max(1.0, 16 / min(rows, cols))
    assert metrics["render_size"] == [round(cols * enlarge), round(rows * enlarge)]
    assert (metrics["image"]["width"], metrics["image"]["height"]) == expect.size
    assert metrics["vertices"] == (rows + 1) * (cols + 1) + 2 * (rows + cols)
    heights = tifffile.imread(out / "height.tif")
    assert heights.shape == (rows, cols)
    check_relief(expect, heights, metrics["regions"], corners=False)
    assert metrics["max_height"] == pytest.approx(float(heights.max()))
    # The flat top view is the texture seen straight down: it must be the photo as the core reads
    # it (orientation, colour mode, no-data), whatever the file's format (null: identical).
    assert metrics["psnr_xy_flat"] is None or metrics["psnr_xy_flat"] >= 35.0, metrics["psnr_xy_flat"]


@pytest.mark.parametrize(
    ("cols", "args", "message"),
    [
        # 16 pixels along a 2 x 64 strip leave its top views 1 pixel across.
        (
            64,
            ["--resolution", "16"],
            "--resolution 16 makes the top views 1 pixel across the 64 x 2 grid; comparing them with "
            "the photo needs at least 7: use --resolution 224 or more",
        ),
        # By default views are enlarged to 16 pixels across, but at most to 16384 pixels long.
        (
            8200,
            ["--max-size", "8200"],
            "the photo is too thin to render: even 16384 pixels long, the top views are 4 pixels across "
            "the 8200 x 2 grid; comparing them with the photo needs at least 7",
        ),
    ],
    ids=["given-resolution", "default-resolution"],
)
def test_render_views_refuses_views_too_thin_to_compare(tmp_path, cols, args, message):
    photo = save(tmp_path / "strip.png", np.full((2, cols, 3), (125, 90, 62), np.uint8))
    before = files_under(tmp_path)
    proc = render_views(photo, *args)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0] == f"render_views.py: error: {message}"
    assert files_under(tmp_path) == before


# ---- (c) the measuring commands (cliff-terrain heights, plots, season, traits), as subprocesses ----
#
# Issue #40's corpus: every case exits 2 with one line on stderr, the `cliff-terrain COMMAND: error:`
# line that names the file (or option) and what is wrong, and nothing else: no library warning, no
# log line, no traceback. Nothing is written or overwritten. Real inputs where there are some: the
# shared OpenDroneMap pair and the Lamberton soybean season.

SHARED = ROOT.parent / "shared" / "data"
ODM_PAIR = SHARED / "dsm" / "fieldimager_ex2"
SOYBEAN = SHARED / "uav" / "lamberton_soybean"
ORTHO, DSM = ODM_PAIR / "odm_orthophoto.tif", ODM_PAIR / "dsm.tif"
ORIGIN = "296600,4888200"  # inside the ODM pair's orthophoto


def _cut(source, path, fraction=0.5):
    path.write_bytes(source.read_bytes()[: int(source.stat().st_size * fraction)])
    return path


def _heights(folder, *, dsm=DSM, plots=None, out=None):
    extra = ["--plots", plots] if plots else []
    return ["heights", ORTHO, "--dsm", dsm, *extra, "--out", out or folder / "out"]


def _plots(folder, *args):
    return ["plots", ORTHO, "--plot-size", "2x2", *args, "--out", folder / "plots.geojson"]


def _lone_shapefile(folder):
    import shapefile

    with shapefile.Writer(str(folder / "lone")) as writer:
        writer.field("plot", "N")
        writer.poly([[[296600, 4888200], [296600, 4888190], [296610, 4888190], [296600, 4888200]]])
        writer.record(1)
    (folder / "lone.dbf").unlink()
    (folder / "lone.shx").unlink()
    return folder / "lone.shp"


def _all_no_data(folder):
    with tifffile.TiffFile(DSM) as tif:
        page = tif.pages[0]
        keep = [(t.code, t.dtype, t.count, t.value, True) for t in page.tags.values() if t.code >= 33550]
        shape = page.shape
    path = folder / "nodata.tif"
    tifffile.imwrite(path, np.full(shape, -3.4e38, np.float32), extratags=keep)
    return path


def _season_with_a_truncated_date(folder):
    season = folder / "season"
    season.mkdir()
    for date in ("20180815", "20180829"):
        (season / f"{date}_Lamberton_clipped.tif").write_bytes(
            (SOYBEAN / f"{date}_Lamberton_clipped.tif").read_bytes()
        )
    _cut(SOYBEAN / "20180822_Lamberton_clipped.tif", season / "20180822_Lamberton_clipped.tif")
    return season


def _corrupt(folder):
    data = bytearray(DSM.read_bytes())
    rng = np.random.default_rng(1)
    data[2000::97] = rng.integers(0, 256, len(data[2000::97]), dtype=np.uint8).tobytes()
    path = folder / "corrupt.tif"
    path.write_bytes(bytes(data))
    return path


def _write(folder, name, content):
    path = folder / name
    path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
    return path


# id -> (args made in the folder, the file the line names, what it says)
COMMAND_CASES = {
    "empty-plot-file": (
        lambda f: _heights(f, plots=_write(f, "plots.geojson", b"")),
        "plots.geojson",
        "is empty (0 bytes)",
    ),
    "broken-plot-file": (
        lambda f: _heights(
            f, plots=_write(f, "plots.geojson", '{"type": "FeatureCollection", "features": [')
        ),
        "plots.geojson",
        "is not valid JSON",
    ),
    "feature-less-plot-file": (
        lambda f: _heights(
            f, plots=_write(f, "plots.geojson", '{"type": "FeatureCollection", "features": []}')
        ),
        "plots.geojson",
        "holds no polygon",
    ),
    "shapefile-without-dbf-shx": (
        lambda f: _heights(f, plots=_lone_shapefile(f)),
        "lone.shp",
        "lacks lone.shx and lone.dbf beside it",
    ),
    "truncated-dsm": (
        lambda f: _heights(f, dsm=_cut(DSM, f / "half.tif")),
        "half.tif",
        f"is truncated: the file has {DSM.stat().st_size // 2} bytes, its image data needs {DSM.stat().st_size}",
    ),
    "corrupt-dsm": (
        lambda f: _heights(f, dsm=_corrupt(f)),
        "corrupt.tif",
        "cannot decode",
    ),
    "all-no-data-dsm": (
        lambda f: _heights(f, dsm=_all_no_data(f)),
        "nodata.tif",
        "holds no data (every pixel is no-data)",
    ),
    "jpeg-as-dsm": (
        lambda f: _heights(f, dsm=save(f / "dsm.jpg", FIELD, quality=90)),
        "dsm.jpg",
        "is a JPEG image, not a TIFF",
    ),
    "out-names-a-file": (
        lambda f: _heights(f, out=_write(f, "results", "my notes\n")),
        "results",
        "`--out` '",
    ),
    "grid-0x5": (
        lambda f: _plots(f, "--grid", "0x5", "--origin", ORIGIN),
        "--grid",
        "needs at least one column and one row, got '0x5'",
    ),
    "three-corners": (
        lambda f: _plots(f, "--grid", "3x5", "--corners", "1,1", "2,2", "3,3"),
        "--corners",
        "expected 4 arguments",
    ),
    "binary-field-book": (
        lambda f: _plots(
            f,
            "--grid",
            "3x5",
            "--origin",
            ORIGIN,
            "--field-book",
            _write(f, "book.csv", bytes(range(256)) * 4),
        ),
        "book.csv",
        "is not a text CSV",
    ),
    "empty-season-folder": (
        lambda f: [
            "season",
            (f / "flights").mkdir() or f / "flights",
            "--plots",
            SOYBEAN / "plots.geojson",
            "--out",
            f / "out",
        ],
        "flights",
        "no images in folder",
    ),  # fmt: skip
    "traits-without-a-season": (
        lambda f: ["traits", (f / "flights").mkdir() or f / "flights"],
        "season.csv",
        "does not exist: run `cliff-terrain season` first",
    ),
    "one-truncated-date": (
        lambda f: [
            "season",
            _season_with_a_truncated_date(f),
            "--plots",
            SOYBEAN / "plots.geojson",
            "--out",
            f / "out",
            "--workers",
            "0",
        ],
        "20180822_Lamberton_clipped.tif",
        "is truncated",
    ),  # fmt: skip
}


def _tree(folder):
    return {
        str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
        for p in sorted(folder.rglob("*"))
    }


@pytest.mark.parametrize("case", list(COMMAND_CASES))
def test_measuring_commands_refuse_bad_input_in_one_line(case, tmp_path):
    if not (ORTHO.is_file() and (SOYBEAN / "plots.geojson").is_file()):
        pytest.skip(f"the shared data are not at {SHARED}")
    make, name, words = COMMAND_CASES[case]
    args = make(tmp_path)
    before = _tree(tmp_path)
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    # Exactly one line: no warning, log line or traceback before or after it.
    assert done.stderr.endswith("\n") and done.stderr.count("\n") == 1, done.stderr
    line = done.stderr.rstrip("\n")
    assert line.startswith(f"cliff-terrain {args[0]}: error: "), line
    assert name in line and words in line, line
    assert done.stdout == ""
    assert _tree(tmp_path) == before  # nothing written, nothing overwritten


def test_a_measurement_that_succeeds_prints_its_summary_line_and_nothing_else(tmp_path):
    # The ODM pair's GDAL_NODATA (-3.4e38, not a float32) makes tifffile log a line on every read.
    if not ORTHO.is_file():
        pytest.skip(f"the shared data are not at {SHARED}")
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *map(str, _heights(tmp_path)), "--no-progress"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert done.stdout.count("\n") == 1 and "wrote chm.tif" in done.stdout, done.stdout
