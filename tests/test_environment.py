"""The core across library versions: OpenCV's API differences, and errors that blame the environment,
never the photo, naming the package and its version."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import SHARED_UAV
from PIL import Image, ImageOps

import cliff_terrain
from cliff_terrain import _deps
from cliff_terrain.errors import CliffTerrainError, DependencyError
from cliff_terrain.io.photo import _jpeg as jpeg
from cliff_terrain.io.photo import _open as image_io
from cliff_terrain.io.photo import load_image

ROOT = Path(__file__).resolve().parents[1]
# Optional here (the synthetic photos test the same paths): used when ../shared holds it.
BROCCOLI = SHARED_UAV / "broccoli" / "01_clip_raw_test.jpg"


def _jpeg(path, size=(161, 119), **save):
    rows, cols = size[1], size[0]
    y, x = np.mgrid[0:rows, 0:cols]
    rgb = np.stack([(x * 255 // cols), (y * 255 // rows), ((x + y) * 3 % 256)], axis=-1).astype(np.uint8)
    Image.fromarray(rgb).save(path, quality=90, **save)
    return path


def _pillow_pixels(path, reduction):
    with Image.open(path) as im:
        if reduction > 1:
            im.draft(im.mode, (im.size[0] // reduction, im.size[1] // reduction))
        return np.asarray(ImageOps.exif_transpose(im).convert("RGB"))


@pytest.fixture
def pillow_decodes(monkeypatch):
    """Names of the images Pillow's decoder was asked for (the fallback), as a list."""
    calls = []
    original = image_io.decode_pixels
    monkeypatch.setattr(image_io, "decode_pixels", lambda im, name: calls.append(name) or original(im, name))
    return calls


def _photos(tmp_path):
    photos = [_jpeg(tmp_path / "a.jpg"), _jpeg(tmp_path / "grey.jpg")]
    Image.open(photos[1]).convert("L").save(photos[1], quality=90)
    return photos + ([BROCCOLI] if BROCCOLI.is_file() else [])


def _check_same_as_pillow(photos):
    for path in photos:
        for max_size in (None, 40):
            rgb, meta = load_image(path, max_size=max_size)
            np.testing.assert_array_equal(rgb, _pillow_pixels(path, meta.reduction), err_msg=path.name)


def test_opencv_without_imread_color_rgb_decodes_bgr_and_swaps(tmp_path, monkeypatch, pillow_decodes):
    # OpenCV 4.10 and older (Debian 13's python3-opencv) have no IMREAD_COLOR_RGB.
    monkeypatch.delattr(cv2, "IMREAD_COLOR_RGB", raising=False)
    flags, swap = jpeg.cv2_colour_flags(2)
    assert swap and flags == cv2.IMREAD_REDUCED_COLOR_2 | cv2.IMREAD_IGNORE_ORIENTATION
    _check_same_as_pillow(_photos(tmp_path))
    assert pillow_decodes == []  # still OpenCV's one GIL-free call


@pytest.mark.skipif(
    not hasattr(cv2, "IMREAD_COLOR_RGB"),
    reason=f"OpenCV {cv2.__version__} has no IMREAD_COLOR_RGB (BGR is swapped)",
)
def test_opencv_5_refusing_rgb_beside_bgr_is_never_asked_for_both(tmp_path, monkeypatch, pillow_decodes):
    # OpenCV 5.0 raises "IMREAD_COLOR_BGR (IMREAD_COLOR) and IMREAD_COLOR_RGB can not be set at the same
    # time"; the reduced colour modes carry the BGR bit. The real OpenCV 5 runs this suite in .venv-bpy52.
    original = cv2.imdecode
    bgr, rgb_flag = cv2.IMREAD_COLOR_BGR, cv2.IMREAD_COLOR_RGB

    def strict_imdecode(buf, flags):
        if flags & bgr and flags & rgb_flag:
            raise cv2.error(
                "IMREAD_COLOR_BGR (IMREAD_COLOR) and IMREAD_COLOR_RGB can not be set at the same time"
            )
        return original(buf, flags)

    monkeypatch.setattr(cv2, "imdecode", strict_imdecode)
    for reduction in (1, 2, 4, 8):
        flags, swap = jpeg.cv2_colour_flags(reduction)
        assert not swap and flags & rgb_flag and not flags & bgr
    _check_same_as_pillow(_photos(tmp_path))
    assert pillow_decodes == []


def test_any_opencv_decode_error_falls_back_to_pillow_not_to_an_error(tmp_path, monkeypatch, pillow_decodes):
    def failing(buf, flags):
        raise cv2.error("OpenCV(9.9) loadsave.cpp: error: (-2:Unspecified error) some new restriction")

    monkeypatch.setattr(cv2, "imdecode", failing)
    photos = _photos(tmp_path)
    _check_same_as_pillow(photos)
    assert len(pillow_decodes) == 2 * len(photos)


def test_a_missing_api_names_the_package_and_version_not_the_photo(tmp_path, monkeypatch):
    path = _jpeg(tmp_path / "good.jpg")

    def missing(*args):
        raise AttributeError("module 'cv2' has no attribute 'imdecode'")

    monkeypatch.setattr(cv2, "imdecode", missing)
    with pytest.raises(DependencyError) as info:
        load_image(path)
    message = str(info.value)
    assert f"opencv-python-headless {cv2.__version__}" in message
    assert "not a fault of the file" in message and "corrupt" not in message
    assert "good.jpg" in message


def test_a_codec_pillow_was_built_without_names_pillow(tmp_path, monkeypatch):
    import PIL

    path = tmp_path / "photo.png"
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(path)

    def no_codec(im, name):
        raise OSError("decoder zip not available")

    monkeypatch.setattr(image_io, "decode_pixels", no_codec)
    with pytest.raises(
        DependencyError, match=rf"installed pillow {PIL.__version__}.*decoder zip not available"
    ):
        load_image(path)


def test_corrupt_data_is_still_blamed_on_the_file(tmp_path):
    path = _jpeg(tmp_path / "cut.jpg")
    path.write_bytes(path.read_bytes()[:-300])
    with pytest.raises(CliffTerrainError) as info:
        load_image(path)
    assert not isinstance(info.value, DependencyError) and "truncated" in str(info.value)


def test_out_of_memory_is_reported_as_such(tmp_path, monkeypatch):
    path = tmp_path / "photo.png"
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(path)

    def oom(im, name):
        raise MemoryError

    monkeypatch.setattr(image_io, "decode_pixels", oom)
    with pytest.raises(CliffTerrainError, match="ran out of memory"):
        load_image(path)


def test_environment_error_classifies_only_environment_problems():
    doing = "cannot read image 'x.tif'"
    lzw = ValueError("<COMPRESSION.LZW: 5> requires the 'imagecodecs' package")
    assert "imagecodecs" in str(_deps.environment_error(lzw, doing=doing))
    broken = ImportError("numpy.core.multiarray failed to import", name="cv2")
    assert "opencv-python-headless" in str(_deps.environment_error(broken, doing=doing))
    assert _deps.environment_error(ValueError("image file is truncated"), doing=doing) is None
    assert (
        _deps.environment_error(AttributeError("'NoneType' object has no attribute 'x'"), doing=doing) is None
    )


# A stand-in OpenCV first on sys.path, in a fresh interpreter.
FAKE_CV2 = {
    "broken": "raise ImportError('numpy.core.multiarray failed to import')",
    "old": "__version__ = '4.5.1'",
}


@pytest.mark.parametrize(
    ("fake", "expected"),
    [
        ("broken", r"cannot import opencv-python-headless .*numpy.core.multiarray failed to import.*>= 4\.8"),
        (
            "old",
            r"opencv-python-headless 4\.5\.1 is too old: Cliff Terrain needs opencv-python-headless >= 4\.8",
        ),
    ],
)
def test_a_broken_or_old_library_is_named_at_first_use_and_by_the_cli(tmp_path, fake, expected):
    (tmp_path / "cv2").mkdir()
    (tmp_path / "cv2" / "__init__.py").write_text(FAKE_CV2[fake] + "\n")
    env = {"PYTHONPATH": f"{tmp_path}{':'}{ROOT}", "PATH": "/usr/bin:/bin"}
    script = textwrap.dedent(
        """
        import cliff_terrain  # cheap: nothing heavy is imported yet
        try:
            cliff_terrain.build_relief
        except cliff_terrain.DependencyError as error:
            assert isinstance(error, ImportError) and isinstance(error, ValueError)
            print(error)
        """
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr
    assert __import__("re").search(expected, run.stdout), run.stdout
    cli = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", "synthetic", str(tmp_path / "f.png")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert cli.returncode == 2 and not (tmp_path / "f.png").exists()
    lines = cli.stderr.strip().splitlines()
    assert len(lines) == 1 and __import__("re").search(expected, lines[0]), cli.stderr


def test_the_declared_ranges_match_the_checked_minimums_and_the_tested_floor():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {}
    for requirement in project["dependencies"]:
        name, _, spec = requirement.partition(">=")
        declared[name.strip()] = spec.split(",")[0].strip()
    for dist, minimum in _deps.REQUIRED.values():
        assert declared[dist] == minimum, dist
    # The floor environment (bpy 4.2) pins exactly the lowest supported versions.
    floor = {}
    for line in (ROOT / "requirements-bpy42.txt").read_text().splitlines():
        name, _, version = line.split("#")[0].strip().partition("==")
        if version:
            floor[name] = version
    for dist, minimum in _deps.REQUIRED.values():
        if dist != "numpy":
            assert _deps.version_tuple(floor[dist])[:2] == _deps.version_tuple(minimum)[:2], dist
    assert floor["numpy"].startswith("1.26")


def test_package_import_is_cheap_and_lists_its_public_names():
    code = (
        "import sys, cliff_terrain; print(sorted(m for m in ('cv2', 'scipy', 'skimage') if m in sys.modules))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert run.stdout.strip() == "[]", run.stdout + run.stderr
    for name in cliff_terrain.__all__:
        assert getattr(cliff_terrain, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        cliff_terrain.nonexistent  # noqa: B018


def test_the_io_packages_load_a_module_only_when_one_of_its_names_is_used():
    # cliff_terrain._lazy.attach, shared by the package and its io subpackages: importing
    # io.raster imports none of its modules; asking for MosaicReader imports mosaic (and what it
    # needs) but not bands; dir() lists the lazy names; an unknown name is an AttributeError.
    code = (
        "import sys, json\nimport cliff_terrain.io.raster as r, cliff_terrain.io.vector as v\n"
        "loaded = lambda: sorted(m for m in ('cliff_terrain.io.raster.mosaic', 'cliff_terrain.io.raster.bands',"
        " 'cliff_terrain.io.vector.plot_polygons') if m in sys.modules)\n"
        "before = loaded()\nreader = r.MosaicReader\nafter = loaded()\n"
        "try:\n    r.nonexistent\n    missing = ''\nexcept AttributeError as e:\n    missing = str(e)\n"
        "print(json.dumps([before, after, 'MosaicReader' in dir(r), 'MosaicReader' in vars(r),"
        " sorted(v.__all__) == v.__all__ and 'PlotSet' in v.__all__, missing]))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    before, after, listed, kept, all_names, missing = json.loads(run.stdout.strip().splitlines()[-1])
    assert before == []
    assert after == ["cliff_terrain.io.raster.mosaic"]
    assert listed and kept and all_names
    assert missing == "module 'cliff_terrain.io.raster' has no attribute 'nonexistent'"


@pytest.mark.blender
def test_the_build_operator_reports_a_broken_library_by_name(monkeypatch, tmp_path):
    # The add-on imports the core when Build Relief runs; a library that fails there is one line in
    # Blender's report naming the package and its version, and nothing is created.
    pytest.importorskip("bpy")
    import bpy
    from conftest import load_addon

    addon = load_addon()
    if not hasattr(bpy.types.Scene, "cliff_terrain"):
        addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    core = importlib.import_module(f"{addon.__name__}.cliff_terrain")
    deps = importlib.import_module(f"{addon.__name__}.cliff_terrain._deps")

    def broken(name):
        raise core.DependencyError(f"Cliff Terrain cannot import {deps.describe('cv2')}: ImportError: boom")

    monkeypatch.delattr(core, "build_relief", raising=False)  # as before the first build
    monkeypatch.setattr(deps, "_checked", [])
    monkeypatch.setattr(deps, "import_required", broken)
    photo = tmp_path / "field.png"
    Image.fromarray(np.zeros((20, 20, 3), np.uint8)).save(photo)
    objects = len(bpy.data.objects)
    with pytest.raises(
        RuntimeError, match=rf"cannot import opencv-python-headless {cv2.__version__}: ImportError: boom"
    ):
        bpy.ops.cliff_terrain.build_relief(filepath=str(photo))
    assert len(bpy.data.objects) == objects
