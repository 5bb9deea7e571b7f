"""Render the figures of one UAV photo's relief: lit, flat, side and perspective views, the mesh
coloured by height, the pipeline's maps, the Blender scene, and metrics.json (PSNR and SSIM of the top
views against the photo, as in the paper's Table 4).

    python render_views.py IMAGE [--out DIR] [options]              (Python 3.11 with the bpy wheel)
    blender -b -P render_views.py -- IMAGE [--out DIR] [options]    (Blender 4.2 or newer)

Both run the same code: the repository root (this file's folder) is loaded as the package
``cliff_terrain_addon`` and registered like the installed extension; the relief object is made by the
build operator's own function (``operators.build.build_relief_object``), the views by
``operators.views``. Arguments are parsed before Blender is imported, so ``--help`` and bad options
answer at once. Bad input exits with status 2 and one line on stderr; existing output files are
never replaced without ``--overwrite``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
PACKAGE = "cliff_terrain_addon"
PROG = "render_views.py"

# Everything the script writes into the output folder.
RENDERS = ("xy.png", "xy_flat.png", "xz.png", "view3d.png", "mesh.png")
MAPS = ("filtered.png", "mask.png", "distance.png", "height.tif")
OUTPUTS = (*RENDERS, *MAPS, "scene.blend", "metrics.json")

# The paper's Table 4 (its lit top view against the photo).
PAPER_TABLE4 = {"psnr": 17.73, "ssim": 0.8713}

# operators.views.MAX_RESOLUTION and MIN_VIEW_SIDE, repeated here because the arguments are checked
# before bpy (and with it operators.views) is imported: the longest side of a rendered view, and
# the shorter side that default views are enlarged to.
MAX_RESOLUTION = 16384
MIN_VIEW_SIDE = 16

_START = time.perf_counter()
# Inside Blender (blender -b -P) bpy is loaded before this script runs; with the bpy wheel it is not.
INSIDE_BLENDER = "bpy" in sys.modules


class InputError(Exception):
    """Bad input the user can fix: reported as one line on stderr, exit status 2."""


# --------------------------------------------------------------------------------------------
# Arguments (no bpy)
# --------------------------------------------------------------------------------------------


def _number(kind, *, minimum=None, maximum=None, strict=False):
    """An argparse type: a finite number of `kind` within bounds (the error names the value)."""

    def convert(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'}, got {text!r}"
            ) from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if minimum is not None and (value <= minimum if strict else value < minimum):
            raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {minimum}, got {text}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum}, got {text}")
        return value

    convert.__name__ = kind.__name__
    return convert


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block): ``render_views.py: error: ...``, status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see --help)\n")


def build_parser():
    parser = _Parser(
        prog=PROG,
        description="Build the 3D relief of a UAV photo in Blender and render its figures and metrics.",
        epilog="With an installed Blender: blender -b -P render_views.py -- IMAGE [options]",
    )
    parser.add_argument("image", metavar="IMAGE", help="the UAV photo (JPEG, PNG, TIFF, WebP, BMP)")
    parser.add_argument(
        "--out", metavar="DIR", help="output folder (default: <image stem>_relief/ beside the image)"
    )
    build = parser.add_argument_group("relief (as cliff_terrain.build_relief)")
    build.add_argument(
        "--max-size",
        type=_number(int, minimum=16, maximum=16384),
        default=1000,
        help="longest side of the processing grid in pixels (default 1000)",
    )
    build.add_argument("--segmentation", choices=("vegetation", "paper"), default="vegetation")
    build.add_argument("--profile", choices=("circular", "poisson"), default="circular")
    build.add_argument(
        "--exaggeration", type=_number(float, minimum=0.0, strict=True), default=1.0, help="height factor"
    )
    build.add_argument(
        "--gsd",
        type=_number(float, minimum=0.0, strict=True),
        help="ground sampling distance of the photo in m/px (default: from its metadata, if any)",
    )
    build.add_argument("--one-sided", action="store_true", help="the relief surface only (no walls and base)")
    render = parser.add_argument_group("rendering")
    render.add_argument(
        "--engine",
        choices=("CYCLES", "WORKBENCH", "EEVEE"),
        default="CYCLES",
        help="engine of the lit views (default CYCLES; the flat top view is always Cycles)",
    )
    render.add_argument(
        "--resolution",
        type=_number(int, minimum=16, maximum=MAX_RESOLUTION),
        help=(
            "longest side of the rendered views in pixels (default: the processing grid's, enlarged "
            f"until the shorter side has {MIN_VIEW_SIDE})"
        ),
    )
    render.add_argument(
        "--samples",
        type=_number(int, minimum=1, maximum=4096),
        default=16,
        help="samples per pixel (default 16)",
    )
    render.add_argument(
        "--sun-azimuth",
        type=_number(float, minimum=-360.0, maximum=360.0),
        default=315.0,
        help="where the sun comes from, degrees clockwise from the image's top (default 315: upper left)",
    )
    render.add_argument(
        "--sun-elevation",
        type=_number(float, minimum=0.0, maximum=90.0, strict=True),
        default=70.0,
        help="sun elevation in degrees (default 70)",
    )
    render.add_argument(
        "--ambient",
        type=_number(float, minimum=0.0, maximum=0.99),
        default=0.4,
        help="share of sky light on level ground, the sun gives the rest (default 0.4)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return parser


def script_args(argv=None):
    """The script's own arguments: after ``--`` inside Blender, else sys.argv[1:]."""
    if argv is not None:
        return list(argv)
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1 :]
    if INSIDE_BLENDER:
        return []  # blender -b -P render_views.py without "--": Blender's own arguments are not ours
    return sys.argv[1:]


def output_folder(args):
    image = Path(args.image)
    return Path(args.out) if args.out else image.with_name(f"{image.stem}_relief")


def check_inputs(args):
    """Fail before any work: a missing photo, an output folder that is a file, files to overwrite."""
    image = Path(args.image)
    if not image.exists():
        raise InputError(f"image not found: {image}")
    if not image.is_file():
        raise InputError(f"image is not a file: {image}")
    out = output_folder(args)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out exists and is not a folder: {out}")
    if not args.overwrite:
        existing = [out / name for name in OUTPUTS if (out / name).exists()]
        if existing:
            more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
            raise InputError(f"{existing[0]} exists{more}; use --overwrite to replace it")
    return image, out


# --------------------------------------------------------------------------------------------
# Blender and the extension
# --------------------------------------------------------------------------------------------


def log(message):
    print(f"[{time.perf_counter() - _START:6.1f} s] {message}", flush=True)


def start_blender():
    """Import bpy, start from an empty scene and register the extension from this folder."""
    try:
        import bpy
    except ImportError:
        raise InputError(
            "Blender's Python module is missing: run `blender -b -P render_views.py -- IMAGE` "
            "or install the bpy wheel (pip install -r requirements-dev.txt)"
        ) from None
    # An empty scene with factory settings; the preferences (and installed add-ons) stay untouched.
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    addon = sys.modules.get(PACKAGE)
    if addon is None:
        spec = importlib.util.spec_from_file_location(
            PACKAGE, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)]
        )
        addon = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = addon
        spec.loader.exec_module(addon)
    # An installed Cliff Terrain extension may already have registered the same classes.
    if not hasattr(bpy.types.Scene, "cliff_terrain"):
        addon.register()
    try:
        core = importlib.import_module(f"{PACKAGE}.cliff_terrain")
    except ImportError as exc:
        raise InputError(
            f"Cliff Terrain's libraries are missing in this Python ({exc}): install the extension zip "
            "in Blender (Edit > Preferences > Get Extensions > Install from Disk), or pip-install "
            "requirements.txt into Blender's Python"
        ) from None
    return bpy, addon, core


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------


def write_maps(relief, out):
    """filtered.png, mask.png, distance.png (8-bit) and height.tif (float32 heights, in relief.units)."""
    import numpy as np
    import tifffile
    from PIL import Image

    filtered = np.round(np.clip(relief.filtered, 0.0, 1.0) * 255.0).astype(np.uint8)
    Image.fromarray(filtered).save(out / "filtered.png")
    Image.fromarray(relief.mask.astype(np.uint8) * 255).save(out / "mask.png")
    top = float(relief.distance.max(initial=0.0))
    distance = relief.distance / top if top > 0 else relief.distance
    Image.fromarray(np.round(distance * 255.0).astype(np.uint8)).save(out / "distance.png")
    tifffile.imwrite(
        out / "height.tif",
        np.ascontiguousarray(relief.heights, dtype=np.float32),
        photometric="minisblack",
        metadata={"units": relief.units, "pixel_size": float(relief.pixel_size)},
    )


def run(args):
    image, out = check_inputs(args)
    log("starting Blender")
    bpy, addon, core = start_blender()
    views = importlib.import_module(f"{PACKAGE}.operators.views")
    build_relief_object = importlib.import_module(f"{PACKAGE}.operators.build").build_relief_object

    timings = {"blender_start": time.perf_counter() - _START}
    log(f"Blender {bpy.app.version_string}, Cliff Terrain {core.__version__}")

    def stage(name, start):
        timings[name] = time.perf_counter() - start

    start = time.perf_counter()
    path = str(image.resolve())
    try:
        relief = core.build_relief(
            path,
            max_size=args.max_size,
            segmentation=args.segmentation,
            profile=args.profile,
            exaggeration=args.exaggeration,
            gsd=args.gsd,
            two_sided=not args.one_sided,
            progress=lambda fraction, name: log(f"pipeline: {name}"),
        )
    except core.CliffTerrainError as exc:
        raise InputError(str(exc)) from None
    stage("pipeline", start)
    for name, seconds in relief.timings.items():
        timings[f"pipeline_{name}"] = seconds
    rows, cols = relief.mesh.grid_shape
    log(
        f"processing grid {cols} x {rows}, {relief.n_regions} regions, max height {relief.max_height:.4g} {relief.units}"
    )

    try:
        resolution = views.view_resolution(args.resolution, rows, cols, name="--resolution")
    except core.CliffTerrainError as exc:
        raise InputError(str(exc)) from None

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder {out}: {exc.strerror}") from None

    start = time.perf_counter()
    context = bpy.context
    obj = build_relief_object(context, relief, path, relief.params, created=[])
    stage("blender_object", start)
    log(f"relief object {obj.name}: {len(obj.data.vertices)} vertices, {len(obj.data.polygons)} faces")

    engine = views.choose_engine(args.engine, log=log)
    rig = views.make_rig(
        context,
        obj,
        resolution=resolution,
        sun_azimuth=args.sun_azimuth,
        sun_elevation=args.sun_elevation,
        ambient=args.ambient,
    )
    paths, seconds = views.render_views(
        context, rig, str(out), engine=engine, samples=args.samples, log=log, quiet=True
    )
    for view, value in seconds.items():
        timings[f"render_{view}"] = value

    log("comparing the top views with the photo")
    start = time.perf_counter()
    metrics = views.evaluate_relief(obj, rig, paths["xy"], paths["xy_flat"], source=path)
    stage("metrics", start)

    log("writing the maps")
    start = time.perf_counter()
    write_maps(relief, out)
    stage("maps", start)

    log("saving scene.blend")
    start = time.perf_counter()
    views.set_top_view(context, rig, engine, samples=args.samples)
    blend = out / "scene.blend"
    if blend.exists():
        blend.unlink()  # no scene.blend1 backup beside it
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    stage("save_blend", start)
    timings["total"] = time.perf_counter() - _START

    meta = relief.metadata
    record = {
        **{key: _plain(value) for key, value in metrics.items()},
        "regions": relief.n_regions,
        "max_height": relief.max_height,
        "units": relief.units,
        "gsd_m_per_px": meta.gsd_m_per_px,
        "gsd_source": meta.gsd_source,
        "vertices": len(obj.data.vertices),
        "faces": len(obj.data.polygons),
        "image": {"path": path, "width": meta.width, "height": meta.height},
        "processing_size": [cols, rows],
        "params": relief.params,
        "engine": engine,
        "samples": args.samples,
        "flat_view": f"Cycles, texture as emission, {views.FLAT_SAMPLES} samples, 1-pixel box filter",
        "light": rig.light,
        "paper_table4": PAPER_TABLE4,
        "timings_s": {key: round(value, 3) for key, value in timings.items()},
        "versions": {"cliff_terrain": core.__version__, "blender": bpy.app.version_string},
    }
    (out / "metrics.json").write_text(json.dumps(record, indent=2) + "\n")
    log(
        f"lit top view PSNR {metrics['psnr_xy']:.2f} dB, SSIM {metrics['ssim_xy']:.4f}; "
        f"flat PSNR {metrics['psnr_xy_flat']:.2f} dB, SSIM {metrics['ssim_xy_flat']:.4f} "
        f"(paper: {PAPER_TABLE4['psnr']} dB, {PAPER_TABLE4['ssim']})"
    )
    log(f"done: {out}")
    return record


def _plain(value):
    """JSON-friendly numbers (inf PSNR of identical images becomes null)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def main(argv=None):
    args = build_parser().parse_args(script_args(argv))
    try:
        run(args)
    except InputError as exc:
        message = " ".join(str(exc).split())
        print(f"{PROG}: error: {message}", file=sys.stderr, flush=True)
        return 2
    return 0


def leave(code):
    """Exit with `code`.

    bpy 4.2-4.5 as a Python module segfaults while the interpreter shuts down once a PropertyGroup
    has been registered (even after unregistering it): there, flush, remove Blender's session
    folder and leave without the teardown, so the exit code is ours.
    """
    bpy = sys.modules.get("bpy")
    if INSIDE_BLENDER or bpy is None or bpy.app.version >= (5, 0, 0):
        sys.exit(code)
    import shutil

    sys.stdout.flush()
    sys.stderr.flush()
    if bpy.app.tempdir:
        shutil.rmtree(bpy.app.tempdir, ignore_errors=True)
    os._exit(code)


if __name__ == "__main__":
    leave(main())
