"""``cliff-terrain season INPUTS... --plots FILE --out DIR``: a season of flights, one table and a chart.

Writes ``DIR/season.csv`` (one row per date and plot), ``DIR/growth.png``, ``DIR/season.json`` (what
``render_season.py`` animates) and ``DIR/cache/`` (one entry per image; a rerun computes only what is
missing). By default a small season runs in this process and a larger one on a local Dask cluster
(one line says which, and why); ``--workers N`` forces a cluster of N, ``--workers 0`` this process,
``--scheduler ADDRESS`` an existing cluster. ``--indices NDVI,NDRE`` adds the indices' columns per plot
and date (``ndvi_mean``, ``ndvi_median``, ``ndvi_plant_mean``, ``ndvi_plant_median`` ...). Exit status 1 when some images failed (their rows carry the error).
"""

from __future__ import annotations

import sys
from pathlib import Path

from .._progress import add_progress_argument
from ..params import add_option
from .cluster_options import add_cluster_arguments
from .index_options import add_index_arguments

HELP = "per-plot growth over a season of dated orthophotos (cover, heights, volume), on Dask"


def configure(parser):
    parser.add_argument("inputs", nargs="+", type=Path, metavar="INPUT", help="photos or folders of photos")
    parser.add_argument("--plots", type=Path, required=True, help="plot polygons (GeoJSON or Shapefile)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument(
        "--dates",
        nargs="+",
        default=(),
        metavar="PATH=YYYY-MM-DD",
        help="a photo's date (its path, or its file name when unique), over the date its file holds "
        "(EXIF, then a date in the name, then the TIFF's write date)",
    )
    parser.add_argument(
        "--dsm",
        default=None,
        help="surface models for measured heights: a folder (matched by date or name), "
        "a pattern with {stem}, or one file for one photo",
    )
    add_cluster_arguments(
        parser,
        workers_help="local Dask worker processes (default: this process for a small season, else one "
        "per core); 0 runs serially in this process",
    )
    parser.add_argument(
        "--color-by", default=None, metavar="FIELD", help="plot attribute colouring the chart"
    )
    for name in ("max_size", "segmentation", "profile", "exaggeration", "height_source"):
        add_option(parser, name)
    parser.add_argument(
        "--no-align",
        action="store_true",
        help="take each date's georeference as it is (by default each date's shift against the season's "
        "consensus is measured and corrected: season.json's shift_px and shift_m)",
    )
    add_progress_argument(parser)
    add_index_arguments(parser, band_files=False)


def run(args):
    from .._deps import require_extra
    from ..season.dates import parse_given_dates
    from ..season.plan import plan_season
    from ..season.runner import run_season
    from .cluster_options import cluster_security
    from .out_folder import check_out_folder

    security = cluster_security(args)  # checked before any work
    check_out_folder(args.out)
    jobs, plot_set = plan_season(
        args.inputs,
        plots=args.plots,
        dates=parse_given_dates(args.dates),
        dsm=args.dsm,
        max_size=args.max_size,
        segmentation=args.segmentation,
        profile=args.profile,
        exaggeration=args.exaggeration,
        height_source=args.height_source,
        indices=args.indices,
        bands=args.bands,
    )
    # After the inputs' checks, before any work: growth.png is drawn after every date is measured
    # (a base install measured them all, then stopped with a traceback and no table).
    require_extra("matplotlib", extra="season", needed_by="the season's growth.png")
    season = run_season(
        jobs,
        plot_set,
        out=args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        security=security,
        timeout=args.timeout,
        memory_limit=args.memory_limit,
        progress=not args.no_progress,
        color_by=args.color_by,
        align=not args.no_align,
    )
    print(
        f"{len(jobs)} dates x {len(plot_set.polygons)} plots: {season.computed} images computed, "
        f"{season.cached} from the cache, in {season.seconds:.1f} s; wrote {season.table}, "
        f"{season.out / 'growth.png'}, {season.out / 'season.json'}"
    )
    if season.removed:
        print(
            f"removed {', '.join(p.name for p in season.removed)} from {season.removed[0].parent}: fitted on "
            "the season this run replaced; run `cliff-terrain traits` again"
        )
    where = "in this process" if season.runner == "in-process" else f"on {season.runner}"
    hint = "; --workers N forces a cluster" if args.workers is None and season.runner == "in-process" else ""
    print(f"ran {where}: {season.runner_reason}{hint}")
    for record in season.dates:
        if record.get("shift_flag"):
            print(f"warning: {record['date']}: {record['shift_flag']}", file=sys.stderr)
    if season.failures:
        print(f"{len(season.failures)} of {len(jobs)} images failed:", file=sys.stderr)
        for image, error in season.failures:
            print(f"  {image}: {error}", file=sys.stderr)
        return 1
    return 0
