"""Shared fixtures: where the real UAV images live, small helpers to reach them, and the extension
loaded into Blender (bpy wheel) for the Blender tests.

Nothing here imports bpy at module level: the core tests run without it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# Every file render_views.py writes (its own OUTPUTS, spelled out here as the specification).
RENDER_VIEWS_OUTPUTS = (
    "xy.png",
    "xy_flat.png",
    "xz.png",
    "view3d.png",
    "mesh.png",
    "filtered.png",
    "mask.png",
    "distance.png",
    "height.tif",
    "xy_annotated.png",
    "xz_annotated.png",
    "mesh_annotated.png",
    "summary.png",
    "scene.blend",
    "metrics.json",
)
# CI clones the repo beside ../shared; the images are never copied into the project.
SHARED_UAV = REPO.parent / "shared" / "data" / "uav"


def load_script(path, name=None):
    """A script outside the packages (``bench/``, ``tools/``) loaded as a module from its `path`."""
    import importlib.util

    path = Path(path)
    spec = importlib.util.spec_from_file_location(name or path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def grey_copy(source, target):
    """Orthophoto GeoTIFF `source` written to `target` in grey (its luma in all three bands), its
    georeference and no-data kept (as alpha): a photo whose colour tells nothing. Returns `target`."""
    import numpy as np
    import tifffile

    from cliff_terrain.io.raster.geotiff import geotiff_tags, read_orthophoto

    photo = read_orthophoto(source)
    grey = np.round(photo.data.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32))
    alpha = np.full(photo.shape, 255, np.uint8) if photo.valid is None else np.where(photo.valid, 255, 0)
    tifffile.imwrite(
        target,
        np.dstack([np.repeat(grey.astype(np.uint8)[..., None], 3, axis=2), alpha.astype(np.uint8)]),
        photometric="rgb",
        extrasamples=[2],
        extratags=geotiff_tags(photo.transform, photo.crs),
    )
    return target


def uav_image(relative: str) -> Path:
    """Path of a shared UAV image, or skip the test with the reason when ../shared is absent."""
    path = SHARED_UAV / relative
    if not path.is_file():
        pytest.skip(f"shared UAV image {relative} not found under {SHARED_UAV} (../shared is absent)")
    return path


@pytest.fixture
def shared_uav() -> Path:
    """The folder of real UAV images (skips when ../shared is absent)."""
    if not SHARED_UAV.is_dir():
        pytest.skip(f"shared UAV images not found at {SHARED_UAV} (../shared is absent)")
    return SHARED_UAV


# ---- the extension inside Blender (bpy wheel, in this process) ----

# The repository root is imported under this name by _loader.py: bpy keeps its state for the whole
# process, so every test module shares this one registered copy through sys.modules (and imports its
# modules plainly: ``from cliff_terrain_addon.scene import views``).
ADDON = "cliff_terrain_addon"


def load_addon():
    """Import the repository root as a package, the way Blender imports an extension."""
    import _loader  # the one loader (it imports no bpy itself)

    assert _loader.PACKAGE == ADDON
    return _loader.package()


@pytest.fixture(scope="module")
def addon():
    """The extension, registered for the module's tests (unregistered after, if registered here)."""
    bpy = pytest.importorskip("bpy")
    import _loader

    module, registered_here = _loader.register()
    yield module
    if registered_here and hasattr(bpy.types.Scene, "cliff_terrain"):
        module.unregister()


@pytest.fixture
def scene(addon):
    """An empty scene with factory settings (registered classes survive the reset)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def _datablock_counts():
    import bpy

    return {
        kind: len(getattr(bpy.data, kind))
        for kind in ("objects", "meshes", "materials", "images", "textures")
    }


@pytest.fixture
def datablock_counts(addon):
    """``datablock_counts()``: how many objects, meshes, materials, images and textures exist."""
    return _datablock_counts


@pytest.fixture
def no_bpy(tmp_path):
    """An environment whose `bpy` raises on import: proof that a command or script never imports
    Blender (render_views.py's checks must come before it starts)."""
    shim = tmp_path / "shim" / "bpy"
    shim.mkdir(parents=True)
    (shim / "__init__.py").write_text("raise RuntimeError('bpy was imported')\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = str(shim.parent)
    return env


def blender_only_site(tmp_path: Path) -> Path:
    """A folder that holds only what a Blender without the extension has: bpy, numpy and bpy's own
    dependencies (bpy 5.2 needs cattrs, for example), linked from this interpreter's site-packages.
    Put it on PYTHONPATH of a ``python -S`` subprocess."""
    import importlib.metadata
    import re

    site = tmp_path / "site"
    site.mkdir()
    wanted, seen = ["bpy", "numpy"], set()
    while wanted:
        name = re.split(r"[<>=!~;\[ ]", wanted.pop(), maxsplit=1)[0].lower()
        if name in seen:
            continue
        seen.add(name)
        try:
            dist = importlib.metadata.distribution(name)
        except importlib.metadata.PackageNotFoundError:
            continue
        wanted += [r for r in dist.requires or () if "extra ==" not in r]
        tops = {
            f.parts[0] for f in dist.files or () if not f.parts[0].endswith((".dist-info", ".data", ".."))
        }
        for top in tops:
            source = Path(dist.locate_file(top))
            if source.exists() and not (site / top).exists() and top != "__pycache__":
                (site / top).symlink_to(source)
    return site


def pytest_sessionfinish(session, exitstatus):
    session.config.cliff_terrain_exitstatus = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    # bpy 4.2 as a Python module segfaults while the interpreter shuts down, after every test has
    # passed and the summary is printed; leave before that teardown, with pytest's own exit code.
    status = getattr(config, "cliff_terrain_exitstatus", None)
    # Not in a pytest-xdist worker: its "finished" message to the controller, sent at the session's
    # end, may still be queued when this hook runs, and an exit without teardown would drop it
    # (`make test` runs its workers on bpy 5.0.1, which shuts down cleanly).
    worker = "PYTEST_XDIST_WORKER" in os.environ
    if "bpy" in sys.modules and status is not None and not worker:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)


def empty_raster(path, rows, cols, pixel, *, bands=3, dtype="uint8"):
    """A tiled GeoTIFF (EPSG:32616, `pixel` metres) of `rows` x `cols` pixels whose tiles are zeros:
    they compress to nothing, so a header of any size is written in a moment and read by the
    commands' size checks and memory plans without decoding."""
    import numpy as np
    import tifffile

    from cliff_terrain.io.raster.geotiff import geotiff_tags

    transform = np.array([[pixel, 0, 500_000.0], [0, -pixel, 5_000_000.0], [0, 0, 1]])
    shape = (rows, cols, bands) if bands > 1 else (rows, cols)
    tile = np.zeros((1024, 1024, bands) if bands > 1 else (1024, 1024), dtype)
    with tifffile.TiffWriter(path, bigtiff=True) as tif:
        tif.write(
            shape=shape, dtype=dtype, tile=(1024, 1024), compression="zlib",
            extratags=geotiff_tags(transform, 32616),
            data=iter([tile] * (-(-rows // 1024) * -(-cols // 1024))),
        )  # fmt: skip
    return path
