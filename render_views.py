"""Render the figures of one UAV photo's relief: lit, flat, side and perspective views, the mesh
coloured by height, the pipeline's maps, the Blender scene, and metrics.json (PSNR and SSIM of the top
views against the photo, as in the paper's Table 4).

    python render_views.py IMAGE [--out DIR] [options]              (Python 3.11 with the bpy wheel)
    blender -b -P render_views.py -- IMAGE [--out DIR] [options]    (Blender 4.2 or newer)

Both run the same code: the repository root (this file's folder) is loaded as the package
``cliff_terrain_addon`` and registered like the installed extension (``_loader.py``); the relief
object is made by the build operator's own function (``scene.relief_object.build_relief_object``),
the views by the modules of ``scene/``. Arguments are parsed before Blender is imported, so
``--help`` and bad options answer at once: their choices, defaults and limits come from
``cliff_terrain/settings.py`` and their checks from ``cliff_terrain/_validate.py``, which need
neither bpy nor the core's libraries. Bad input exits with status 2 and one line on stderr;
existing output files are never replaced without ``--overwrite``.

A script only: what other scripts, tests and benchmarks share with it (loading the extension,
starting Blender, the log, the exit) is in ``_loader.py``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
# Blender's -P does not put the script's folder on sys.path.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
import _loader  # noqa: E402
from _loader import InputError, leave, log  # noqa: E402

# The extension's bpy-free modules, importable before Blender starts.
_loader.package(execute=False)
from cliff_terrain_addon.cliff_terrain import _validate, errors, settings  # noqa: E402
from cliff_terrain_addon.cliff_terrain.params import ReliefParams  # noqa: E402

PROG = "render_views.py"


# --------------------------------------------------------------------------------------------
# Arguments (no bpy)
# --------------------------------------------------------------------------------------------


def _number(kind, option, **limits):
    """An argparse type: a finite number of `kind` within `limits`, checked as the core checks it."""
    check = _validate.check_int if kind is int else _validate.check_float

    def convert(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'}, got {text!r}"
            ) from None
        try:
            return check(option, value, **limits)
        except errors.CliffTerrainError as exc:
            # argparse names the option already: "argument --max-size: must be >= 16, got 3".
            raise argparse.ArgumentTypeError(str(exc).removeprefix(f"`{option}` ")) from None

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
    ReliefParams.add_arguments(build, number=_number)
    build.add_argument(
        "--plots", metavar="FILE", help="plot polygons (GeoJSON or Shapefile): writes plots.csv (needs --dsm)"
    )
    build.add_argument(
        "--indices",
        metavar="NAMES",
        help="vegetation indices per plant and plot (regions.csv, plots.csv), e.g. NDVI,NDRE: "
        "ExG, NGRDI, VARI, GLI, NDVI, NDRE, GNDVI, OSAVI",
    )
    render = parser.add_argument_group("rendering")
    render.add_argument(
        "--engine",
        choices=settings.ids(settings.ENGINES),
        default=settings.DEFAULT_ENGINE,
        help=f"engine of the lit views (default {settings.DEFAULT_ENGINE}; the flat top view is always Cycles)",
    )
    render.add_argument(
        "--resolution",
        type=_number(int, "--resolution", minimum=settings.MIN_VIEW_SIDE, maximum=settings.MAX_RESOLUTION),
        help=(
            "longest side of the rendered views in pixels (default: the processing grid's, enlarged "
            f"until the shorter side has {settings.MIN_VIEW_SIDE})"
        ),
    )
    render.add_argument(
        "--samples",
        type=_number(int, "--samples", minimum=1, maximum=settings.MAX_SAMPLES),
        default=settings.DEFAULT_SAMPLES,
        help=f"samples per pixel (default {settings.DEFAULT_SAMPLES})",
    )
    render.add_argument(
        "--sun-azimuth",
        type=_number(float, "--sun-azimuth", minimum=-360.0, maximum=360.0),
        default=settings.DEFAULT_SUN_AZIMUTH,
        help="where the sun comes from, degrees clockwise from the image's top "
        f"(default {settings.DEFAULT_SUN_AZIMUTH:g}: upper left)",
    )
    render.add_argument(
        "--sun-elevation",
        type=_number(float, "--sun-elevation", minimum=0.0, maximum=90.0, strict_minimum=True),
        default=settings.DEFAULT_SUN_ELEVATION,
        help=f"sun elevation in degrees (default {settings.DEFAULT_SUN_ELEVATION:g})",
    )
    render.add_argument(
        "--ambient",
        type=_number(float, "--ambient", minimum=0.0, maximum=settings.MAX_AMBIENT),
        default=settings.DEFAULT_AMBIENT,
        help="share of sky light on level ground, the sun gives the rest "
        f"(default {settings.DEFAULT_AMBIENT:g})",
    )
    render.add_argument(
        "--transect",
        metavar="STRIP",
        help="side view of one strip of the photo only (photo pixels): rows=R0:R1 (a band of rows, seen "
        "from the south) or line=R0,C0,R1,C1[,WIDTH] (a line across the field, seen from its right)",
    )
    render.add_argument(
        "--side-exaggeration",
        type=_number(float, "--side-exaggeration", minimum=0.0, strict=True),
        help="vertical exaggeration of the side view (default: a round factor that makes the relief "
        "rise to 12-30 %% of the view's width, at least 1)",
    )
    render.add_argument(
        "--color-by",
        metavar="INDEX",
        help="also render the top view coloured by a vegetation index of the image's bands (viridis, "
        "2nd to 98th percentile) into xy_<index>.png, e.g. NDVI",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return parser


def script_args(argv=None):
    """The script's own arguments: after ``--`` inside Blender, else sys.argv[1:]."""
    if argv is not None:
        return list(argv)
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1 :]
    if _loader.INSIDE_BLENDER:
        return []  # blender -b -P render_views.py without "--": Blender's own arguments are not ours
    return sys.argv[1:]


def output_folder(args):
    image = Path(args.image)
    return Path(args.out) if args.out else image.with_name(f"{image.stem}_relief")


def index_view_name(index):
    """The file of the top view coloured by `index`: ``xy_ndvi.png``."""
    return f"xy_{index.lower()}.png"


def check_inputs(args):
    """Fail before any work: a missing photo, an output folder that is a file, files to overwrite.

    Each check imports what it needs only (a Blender without the core's libraries gets as far as
    :func:`_loader.start_blender`, which says how to install them).
    """
    image = Path(args.image)
    if not image.exists():
        raise InputError(f"image not found: {image}")
    if not image.is_file():
        raise InputError(f"image is not a file: {image}")
    out = output_folder(args)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out exists and is not a folder: {out}")
    args.color_index = None
    if args.color_by:
        from cliff_terrain_addon.cliff_terrain.photo_heights import indices

        try:
            (args.color_index,) = indices.parse_indices(args.color_by)
        except ValueError:  # a CliffTerrainError (an unknown index), or more than one index
            raise InputError(f"--color-by takes one vegetation index, got {args.color_by!r}") from None
    if not args.overwrite:
        from cliff_terrain_addon.cliff_terrain.figures.writer import OUTPUTS

        names = OUTPUTS  # everything the script writes
        if args.color_index:
            names = (*names, index_view_name(args.color_index))
        if args.dsm or args.plots or args.indices:  # and the region and plot tables
            from cliff_terrain_addon.cliff_terrain.measure.tables import TABLES

            names = (*names, *TABLES)
        existing = [out / name for name in names if (out / name).exists()]
        if existing:
            more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
            raise InputError(f"{existing[0]} exists{more}; use --overwrite to replace it")
    args.plot_set = None
    if args.dtm and not args.dsm:
        raise InputError("--dtm needs --dsm (the surface model)")
    if args.plots:
        if not args.dsm:
            raise InputError("--plots needs --dsm (plot heights are measured on the surface model)")
        from cliff_terrain_addon.cliff_terrain.io.vector import plot_polygons

        try:
            args.plot_set = plot_polygons.read_plots(args.plots)
        except errors.CliffTerrainError as exc:
            raise InputError(str(exc)) from None
    args.bands_read = None
    if args.indices or args.color_index:  # an index whose band the file lacks: one line, before any work
        from cliff_terrain_addon.cliff_terrain.io.raster import bands
        from cliff_terrain_addon.cliff_terrain.photo_heights import indices

        try:
            names = indices.parse_indices(args.indices)
            args.bands_read = bands.read_bands(str(image), names=args.bands)
            wanted = (*names, *([args.color_index] if args.color_index else []))
            indices.check_indices(args.bands_read, wanted)
        except errors.CliffTerrainError as exc:
            raise InputError(str(exc)) from None
    args.transect_strip = None
    if args.transect is not None:
        # Checked against the photo's header now, not after the pipeline's seconds of work.
        from cliff_terrain_addon.cliff_terrain.io import photo
        from cliff_terrain_addon.cliff_terrain.io.vector import transect

        try:
            meta = photo.read_metadata(str(image))
            args.transect_strip = transect.parse_transect(
                args.transect, shape=(meta.height, meta.width), name="--transect"
            )
        except errors.CliffTerrainError as exc:
            raise InputError(str(exc)) from None
    return image, out


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------


def run(args):
    image, out = check_inputs(args)
    log("starting Blender")
    bpy, _, core = _loader.start_blender(usage="blender -b -P render_views.py -- IMAGE")
    from cliff_terrain_addon.cliff_terrain.evaluate import views as evaluation
    from cliff_terrain_addon.cliff_terrain.figures import writer
    from cliff_terrain_addon.scene import colour_by, render_settings, rig, views
    from cliff_terrain_addon.scene.relief_object import build_relief_object

    timings = {"blender_start": time.perf_counter() - _loader.START}
    log(f"Blender {bpy.app.version_string}, Cliff Terrain {core.__version__}")

    def stage(name, start):
        timings[name] = time.perf_counter() - start

    start = time.perf_counter()
    path = str(image.resolve())
    try:
        params = ReliefParams.from_args(args)
        relief = core.build_relief(path, params, progress=lambda fraction, name: log(f"pipeline: {name}"))
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
        resolution = evaluation.view_resolution(args.resolution, rows, cols, name="--resolution")
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

    engine = render_settings.choose_engine(args.engine, log=log)
    view_rig = rig.make_rig(
        context,
        obj,
        resolution=resolution,
        sun_azimuth=args.sun_azimuth,
        sun_elevation=args.sun_elevation,
        ambient=args.ambient,
        side_exaggeration=args.side_exaggeration,
        transect=args.transect_strip,
        photo_shape=(relief.metadata.height, relief.metadata.width),
    )
    log(f"side view: vertical exaggeration {view_rig.side['exaggeration']:g}x")
    paths, seconds = views.render_views(
        context, view_rig, str(out), engine=engine, samples=args.samples, log=log, quiet=True
    )
    for view, value in seconds.items():
        timings[f"render_{view}"] = value

    log("comparing the top views with the photo")
    start = time.perf_counter()
    metrics = views.evaluate_relief(obj, view_rig, paths["xy"], paths["xy_flat"], source=path)
    stage("metrics", start)

    if args.color_index:
        log(f"rendering the top view coloured by {args.color_index}")
        shown = colour_by.colour_relief(obj, "INDEX", index=args.color_index)
        if shown != "INDEX":
            raise InputError(
                f"{path}: its header names no bands giving {args.color_index}; name them in the file"
            )
        start = time.perf_counter()
        views.render_view(
            context, view_rig, "xy", str(out / index_view_name(args.color_index)), engine=engine,
            samples=args.samples, quiet=True,
        )  # fmt: skip
        stage(f"render_{args.color_index.lower()}", start)

    log("saving scene.blend")
    start = time.perf_counter()
    views.set_top_view(context, view_rig, engine, samples=args.samples)
    blend = out / writer.SCENE
    if blend.exists():
        blend.unlink()  # no scene.blend1 backup beside it
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    stage("save_blend", start)

    index_maps = None
    if args.bands_read is not None:
        from cliff_terrain_addon.cliff_terrain.photo_heights import indices

        index_maps = indices.index_maps(
            args.bands_read, indices.parse_indices(args.indices), shape=relief.mask.shape
        )
    try:
        record = writer.write_outputs(
            relief,
            out,
            side=view_rig.side,
            metrics=metrics,
            transect=args.transect_strip,
            plots=args.plot_set,
            render=views.render_record(obj, engine=engine, samples=args.samples, light=view_rig.light),
            timings=timings,
            started=_loader.START,
            log=log,
            index_maps=index_maps,
        )
    except core.CliffTerrainError as exc:
        raise InputError(str(exc)) from None
    log(f"{evaluation.metrics_summary(metrics)} ({evaluation.paper_summary()})")
    log(f"done: {out}")
    return record


def main(argv=None):
    args = build_parser().parse_args(script_args(argv))
    try:
        run(args)
    except InputError as exc:
        message = " ".join(str(exc).split())
        print(f"{PROG}: error: {message}", file=sys.stderr, flush=True)
        return 2
    return 0


if __name__ == "__main__":
    leave(main())
