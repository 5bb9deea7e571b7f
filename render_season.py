"""Animate a season of flights in Blender: one relief per date, aligned by georeference, one date per frame.

    python render_season.py SEASON_DIR [--out DIR] [options]              (Python 3.11 with the bpy wheel)
    blender -b -P render_season.py -- SEASON_DIR [--out DIR] [options]    (Blender 4.2 or newer)

SEASON_DIR is what ``cliff-terrain season ... --out SEASON_DIR`` wrote; this script reads its
``season.json`` and cached height grids and never runs Dask. It writes into ``--out`` (default
``SEASON_DIR/animation``): ``frames/date_0001.png`` ... (one per date, the date stamped in each),
``season.mp4`` (Blender's FFmpeg output, each date held ``--hold`` frames) and ``season.blend``.
``--color-by NAME`` colours the plots on each frame by a column of ``season.csv`` (``cover``,
``height_p90``: a value per date) or of ``traits/traits.csv`` (``max_height_m``,
``senescence_date``: one per plot), viridis on one scale for the whole season, stamped on the frames;
the photo stays outside the plots.
The sidebar's Season Animation button does the same with the default options. Bad input exits
with status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
# Blender's -P does not put the script's folder on sys.path; _loader.py (which imports no bpy itself)
# holds the extension's one loader, the Blender start-up, the log and the exit.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from _loader import InputError, leave, log, start_blender  # noqa: E402

PROG = "render_season.py"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see --help)\n")


def _size(text):
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected COLSxROWS such as 1280x720, got {text!r}") from None
    if not (16 <= cols <= 8192 and 16 <= rows <= 8192):
        raise argparse.ArgumentTypeError(f"each side must be 16 to 8192, got {text!r}")
    return cols, rows


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def build_parser():
    parser = _Parser(
        prog=PROG,
        description="Render a season computed by `cliff-terrain season` as an animation, one date per frame.",
        epilog="With an installed Blender: blender -b -P render_season.py -- SEASON_DIR [options]",
    )
    parser.add_argument("season", metavar="SEASON_DIR", help="the folder `cliff-terrain season --out` wrote")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: SEASON_DIR/animation)")
    parser.add_argument("--no-plots", action="store_true", help="leave out the plot outlines")
    parser.add_argument(
        "--size", type=_size, default=(1280, 720), help="frame size COLSxROWS (default 1280x720)"
    )
    parser.add_argument("--engine", choices=("WORKBENCH", "CYCLES"), default="WORKBENCH")
    parser.add_argument("--hold", type=_positive_int, default=12, help="video frames per date (default 12)")
    parser.add_argument("--fps", type=_positive_int, default=12, help="video frame rate (default 12)")
    parser.add_argument("--no-video", action="store_true", help="the PNG frames only")
    parser.add_argument(
        "--color-by",
        metavar="NAME",
        default=None,
        help="colour the plots by a column of season.csv (cover, height_p90, ...) or "
        "traits/traits.csv (max_height_m, senescence_date, ...)",
    )
    return parser


def script_args(argv=None):
    """The script's own arguments: after ``--`` inside Blender, else the command line's."""
    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    return build_parser().parse_args(argv)


def run(args):
    season_dir = Path(args.season)
    out = Path(args.out) if args.out else season_dir / "animation"
    bpy, _, _ = start_blender(usage="blender -b -P render_season.py -- SEASON_DIR")
    from cliff_terrain_addon.cliff_terrain import errors
    from cliff_terrain_addon.cliff_terrain.io.vector import plot_polygons as plots_module
    from cliff_terrain_addon.cliff_terrain.season import reader as season_reader
    from cliff_terrain_addon.scene import season_animation as scene_season

    try:
        season = season_reader.read_season(season_dir)
        plots = None
        if season.plots and not (args.no_plots and args.color_by is None):
            plots = plots_module.read_plots(season.plots)
        colours = None
        if args.color_by is not None:
            if plots is None:
                raise errors.CliffTerrainError(f"`color_by` {args.color_by!r} needs the season's plots file")
            colours = season_reader.plot_colours(season, args.color_by, n_plots=len(plots.polygons))
    except errors.CliffTerrainError as exc:
        raise InputError(str(exc)) from None
    if colours is not None:
        log(f"colour by {colours.describe()}")
    for date, image, error in season.failed:
        log(f"left out {date} ({image}): {error}")
    built = scene_season.build_season_scene(
        bpy.context,
        season,
        plots=None if args.no_plots else plots,
        colours=colours,
        colour_plots=plots,
        size=args.size,
        engine=args.engine,
    )
    log(
        f"scene: {len(built.dates)} reliefs ({built.dates[0]} to {built.dates[-1]}), frames 1-{len(built.dates)}"
    )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {str(out)!r}: {exc}") from None
    result = scene_season.render_season(
        built, out, hold=args.hold, fps=args.fps, video=not args.no_video, log=log
    )
    blend = out / "season.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False, compress=True)
    log(f"wrote {blend}")
    return result


def main(argv=None):
    args = script_args(argv)
    try:
        run(args)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    leave(main())
