"""``cliff-terrain heights ORTHO --dsm DSM [--dtm DTM] [--plots FILE] --out DIR``: measured canopy height.

Runs the relief's own stages (:func:`cliff_terrain.build.build_relief` without a mesh, heights
measured), so its plants, cover and heights are the ones ``render_views.py --dsm`` and the sidebar
report for the same orthophoto and grid. Writes ``chm.tif`` (float32 GeoTIFF, metres, NaN as no-data,
the grid's georeference), ``ground_support.tif`` beside it when the ground is estimated (the share of
bare soil that carried the ground around each pixel, 0 where it is interpolated only),
``chm_err.tif`` (the ground's standard error at each pixel, metres, from its held-out check),
``regions.csv`` and ``regions.geojson`` (one row per plant), with ``--plots`` ``plots.csv`` and
``plots.geojson`` (one row per polygon, with ``height_p90_err_m``), with ``--indices NDVI,NDRE`` their
index columns (``ndvi_mean``, ``ndvi_median``, ``ndvi_plant_mean``, ``ndvi_plant_median`` ...), with
``--ruler`` the measured heights (``ruler_height_m``; ``height_calibrated_m`` and its standard error
``height_calibrated_err_m`` with ``--calibrate``) and ``ruler.png`` (the plots' heights against the
ruler's, with r, RMSE, bias and CCC), and ``summary.json`` (the key figures, the ground's source,
method and held-out check, the ruler's agreement, the share of its plots the uncertainty covers and
a warning when too few, and the plant/soil threshold). All files appear together or none does.
The rasters and plots may be in an EPSG CRS or in a user-defined projected CRS in metres (no EPSG
code; ``summary.json``'s ``crs_wkt``) when their definitions agree (:mod:`cliff_terrain.io.raster.crs`).
The run's memory is estimated before the work and refused past ``--max-memory`` (4 GiB) with the
``--max-size``/``--resolution`` that fit (:mod:`.memory_estimate`). ``chm.tif`` and
``ground_support.tif`` are tiled, compressed and have overviews. On a terminal a progress bar shows
the stage and its ETA (``--no-progress``); an interrupted run leaves no ``summary.json``, and the
same command then runs again (:mod:`.out_folder`).
"""

from __future__ import annotations

from pathlib import Path

from .. import settings
from .._progress import add_progress_argument
from ..params import add_option
from .cluster_options import add_cluster_arguments
from .index_options import add_index_arguments

HELP = "measure canopy height from an orthophoto and its DSM (and DTM); write the CHM and tables"
# Windows measured at once in this process without a cluster (one per core, up to this many).
MAX_THREADS = 4


def configure(parser):
    parser.add_argument("ortho", type=Path, help="the orthophoto GeoTIFF")
    add_option(parser, "dsm", type=Path, required=True)
    add_option(parser, "dtm", type=Path)
    parser.add_argument("--plots", type=Path, default=None, help="plot polygons: GeoJSON or ESRI Shapefile")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument(
        "--resolution",
        type=float,
        default=None,
        help="metres per pixel of the grid, no finer than the orthophoto's: a finer value measures on "
        f"the orthophoto's own, and the summary line says so (default: the orthophoto's, up to "
        f"{settings.MAX_SIZE} pixels on its longest side; summary.json's grid says what was used)",
    )
    parser.add_argument(
        "--max-size",
        type=int,
        default=None,
        help="longest side of the grid in pixels, as render_views.py --max-size (default: the orthophoto's)",
    )
    add_option(parser, "ground_block", default=settings.DEFAULT_GROUND_BLOCK_M)
    add_option(parser, "ground_method", default="auto")
    parser.add_argument(
        "--ruler",
        type=Path,
        default=None,
        help="CSV of measured plot heights (needs --plots): a plot id column and a height column",
    )
    parser.add_argument("--ruler-id", default=None, help="the ruler file's plot id column (default: found)")
    parser.add_argument(
        "--ruler-height", default=None, help="the ruler file's height column (default: found)"
    )
    parser.add_argument(
        "--ruler-units",
        choices=("m", "cm", "mm", "in"),  # measure.ruler.UNITS (not imported to parse arguments)
        default=None,
        help="unit of the ruler's heights (default: from a 'unit' column or the column's name)",
    )
    parser.add_argument(
        "--calibrate",
        action="store_true",
        help="fit height = a + b x height_p90 on the ruler's plots, apply it to every plot "
        "(height_calibrated_m, with its standard error height_calibrated_err_m) and report its "
        "leave-one-out error",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    parser.add_argument(
        "--max-memory",
        type=float,
        default=4.0,
        metavar="GIB",
        help="refuse, before the work, a run estimated to need more memory than this (GiB; default 4)",
    )
    parser.add_argument(
        "--windowed",
        action="store_true",
        help="measure at full resolution window by window, in bounded memory (chm.tif and the plot "
        "tables; no regions.csv); chosen by itself when the in-memory run would pass --max-memory",
    )
    parser.add_argument(
        "--window",
        type=int,
        default=None,
        metavar="PX",
        help="side of a window's core in pixels with --windowed (default 2048; the tables do not depend on it)",
    )
    add_cluster_arguments(
        parser,
        workers_help="with --windowed, spread the windows over a local Dask cluster of N worker "
        "processes (default: this process; the tables do not depend on it)",
    )
    add_progress_argument(parser)
    add_index_arguments(parser)


def grid_size(ortho, *, resolution=None, max_size=None):
    """Longest side (pixels) of the measuring grid: the orthophoto's own, or coarser on request."""
    import numpy as np

    from .._validate import check_float, check_int
    from ..errors import CliffTerrainError
    from ..io.raster.geotiff import raster_size, read_georeference

    if resolution is not None and max_size is not None:
        raise CliffTerrainError(
            f"give `--resolution` or `--max-size`, not both (got {resolution} and {max_size})"
        )
    transform, _ = read_georeference(ortho)
    longest = max(raster_size(ortho))
    if max_size is not None:
        max_size = check_int("--max-size", max_size, minimum=settings.MIN_SIZE)
        return min(longest, max_size, settings.MAX_SIZE)
    if resolution is not None:
        resolution = check_float("--resolution", resolution, minimum=0.0, strict_minimum=True)
        pixel = float(np.mean([np.hypot(*transform[:2, 0]), np.hypot(*transform[:2, 1])]))
        longest = max(settings.MIN_SIZE, min(longest, round(longest * pixel / resolution)))
    return min(longest, settings.MAX_SIZE)


def run(args):
    import json

    from .._progress import stage_bar
    from ..build import build_relief
    from ..errors import CliffTerrainError
    from ..evaluate.views import json_safe
    from ..figures.ruler_chart import plot_rows_ruler_figure
    from ..io.raster.geotiff import read_georeference, write_geotiff
    from ..io.vector.plot_polygons import read_plots
    from ..measure.canopy import relief_tables
    from ..measure.key_figures import figures_line, key_figures, undecided_cover
    from ..measure.tables import PLOTS_CSV, PLOTS_GEOJSON, REGIONS_CSV, REGIONS_GEOJSON, write_files
    from ..params import ReliefParams
    from .index_options import relief_index_maps, requested_bands
    from .memory_estimate import check_heights_memory
    from .out_folder import check_inputs_not_outputs, check_out_folder, finished_outputs

    out = args.out
    check_out_folder(out)
    outputs = ["chm.tif", "ground_support.tif", "chm_err.tif", REGIONS_CSV, REGIONS_GEOJSON]
    outputs += [PLOTS_CSV, PLOTS_GEOJSON] if args.plots else []
    outputs += ["summary.json"]
    if args.dtm is not None:
        outputs.remove("ground_support.tif")
        outputs.remove("chm_err.tif")
    if args.ruler is not None:
        outputs.insert(-1, "ruler.png")
    if args.ruler is not None and args.plots is None:
        raise CliffTerrainError(f"--ruler {str(args.ruler)!r} needs --plots: its heights belong to plots")
    if args.calibrate and args.ruler is None:
        raise CliffTerrainError("--calibrate needs --ruler: the measured heights it is fitted on")
    inputs = {
        "the orthophoto": args.ortho,
        "--dsm": args.dsm,
        "--dtm": args.dtm,
        "--plots": args.plots,
        "--ruler": args.ruler,
    }
    check_inputs_not_outputs(out, outputs, inputs)
    if not args.overwrite:  # summary.json is written last: without it, outputs are an interrupted run's
        existing = finished_outputs(out, outputs, marker="summary.json")
        if existing:
            raise CliffTerrainError(f"{str(out / existing[0])!r} exists; pass --overwrite to replace it")
    plots = read_plots(args.plots) if args.plots else None  # a bad plot file fails before the work
    ruler = None
    if args.ruler is not None:  # and so does a bad ruler
        from ..measure.ruler import read_ruler

        ruler = read_ruler(
            args.ruler,
            plots,
            id_column=args.ruler_id,
            height_column=args.ruler_height,
            units=args.ruler_units,
        )
    if _windowed(args):
        return _run_windowed(args, outputs, plots, ruler)
    bands = requested_bands(args, args.ortho)  # and so does an index whose band the file lacks
    size = grid_size(args.ortho, resolution=args.resolution, max_size=args.max_size)
    check_heights_memory(args.ortho, (args.dsm, args.dtm), longest=size, cap_gib=args.max_memory)
    params = ReliefParams(
        max_size=size,
        dsm=args.dsm,
        dtm=args.dtm,
        height_source="measured",
        bands=None if args.band_files else args.bands,  # --bands names the orthophoto's own bands
        mesh=None,
        ground_block=args.ground_block,
        ground_method=args.ground_method,
    )
    with stage_bar(f"heights {args.ortho.name}", enabled=not args.no_progress) as progress:
        relief = build_relief(args.ortho, params, progress=progress)
    canopy = relief.canopy
    maps = relief_index_maps(args, bands, relief.mask.shape)
    ruler_record, ruler_rows = {}, []

    def with_ruler(rows):
        from ..measure.ruler import ruler_columns

        columns, record = ruler_columns(rows, ruler, calibrate_heights=args.calibrate)
        ruler_record.update(record)
        ruler_rows.extend(rows)
        return columns

    plot_rows = []

    def extra(rows):  # the plot rows, for the resolution check, and the ruler's columns
        plot_rows.extend(rows)
        return with_ruler(rows) if ruler is not None else []

    tables = relief_tables(relief, plots=plots, source=str(args.ortho), index_maps=maps, extra=extra)
    resolution = None
    if plots is not None:
        from ..measure.resolution_check import plots_resolution_check

        resolution = plots_resolution_check(
            plots, plot_rows, canopy.chm, canopy.transform, surface_transform=read_georeference(args.dsm)[0]
        )
    files = {out / name: text for name, text in tables.items()}
    files[out / "chm.tif"] = lambda tmp: write_geotiff(
        tmp, canopy.chm, transform=canopy.transform, crs=canopy.crs, nodata=float("nan"), overviews=True
    )
    if canopy.support is not None:
        # NaN declared as no data: a support or error of exactly 0 is a value (a reader that takes
        # an undeclared corner of 0 for gdalwarp's fill would drop it).
        files[out / "ground_support.tif"] = lambda tmp: write_geotiff(
            tmp,
            canopy.support,
            transform=canopy.transform,
            crs=canopy.crs,
            nodata=float("nan"),
            overviews=True,
        )
        files[out / "chm_err.tif"] = lambda tmp: write_geotiff(
            tmp, canopy.sigma, transform=canopy.transform, crs=canopy.crs, nodata=float("nan"), overviews=True
        )
    if ruler_rows:
        files[out / "ruler.png"] = lambda tmp: plot_rows_ruler_figure(ruler_rows, ruler_record).save(
            tmp, format="PNG"
        )
    figures = key_figures(relief)
    check = canopy.check or {}
    summary = {
        **figures,
        "ground": canopy.ground_source,
        "ground_method": check.get("method"),
        # Where the ground is guessed: the pixels that are not its bare-soil evidence.
        "ground_support": check.get("support_where_guessed"),
        "ground_check": check or None,
        "ruler": ruler_record or None,
        "resolution_check": resolution,
        "threshold": relief.params["threshold"],
        "grid": {
            "rows": int(relief.mask.shape[0]),
            "cols": int(relief.mask.shape[1]),
            "pixel_size_m": canopy.pixel_size,
        },
        # The CRS: its EPSG code, or the WKT of a user-defined one (no EPSG code) as the files carry it.
        "crs": canopy.crs if isinstance(canopy.crs, int) else None,
        "crs_wkt": getattr(canopy.crs, "wkt", None),
        "ortho": str(args.ortho),
        "dsm": str(args.dsm),
        "dtm": None if args.dtm is None else str(args.dtm),
        "outputs": outputs,  # what this run wrote: a later --overwrite removes only these
    }
    files[out / "summary.json"] = json.dumps(json_safe(summary), indent=2) + "\n"
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_files(files, remove=stale_outputs(out, outputs))
    except OSError as exc:
        raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
    ground = canopy.ground_source
    if check:
        from ..measure.ground_evidence import evidence_note

        ground += f" ({check['method']}, held-out bare soil within {check['candidates'][check['method']]['error_m'] * 100:.1f} cm{evidence_note(check)})"
    from ..measure.resolution_check import resolution_line
    from ..measure.ruler import ruler_line

    against = ruler_line(ruler_record) + resolution_line(resolution) + _finer_note(args, canopy)
    print(
        f"{args.ortho}: ground {ground}, {figures_line(figures, cover_note=undecided_cover(summary['threshold']))}"
        f"{against}; wrote {', '.join(outputs)} into {out}"
    )
    return 0


def _finer_note(args, canopy):
    """The summary line's note when ``--resolution`` asked for a grid finer than the orthophoto's
    pixel (which holds no finer detail): the grid measured instead."""
    import numpy as np

    from ..io.raster.geotiff import read_georeference

    if args.resolution is None:
        return ""
    transform, _ = read_georeference(args.ortho)
    own = float(np.mean([np.hypot(*transform[:2, 0]), np.hypot(*transform[:2, 1])]))
    if args.resolution >= 0.99 * own:
        return ""
    return (
        f"; --resolution {args.resolution:g} m is finer than the orthophoto's {own:.3g} m: measured on a "
        f"{canopy.pixel_size:.3g} m grid"
    )


# Every file `heights` may write but its tables (measure.tables.TABLES, which pulls numpy in: not
# at the command line's start); summary.json, written last, marks a finished run.
RASTERS_AND_SUMMARY = ("chm.tif", "ground_support.tif", "chm_err.tif", "ruler.png", "summary.json")


def stale_outputs(out, outputs):
    """An earlier run's outputs in `out` that this run, writing `outputs`, does not write (its plots
    without --plots, its regions when windowed, its ruler.png without --ruler), as its summary.json
    lists them: removed as this run's are written (:func:`~cliff_terrain.measure.tables.previous_outputs`)."""
    from ..measure.tables import TABLES, previous_outputs

    every = (*RASTERS_AND_SUMMARY, *TABLES)
    return previous_outputs(out, [n for n in every if n not in outputs], record="summary.json")


def _windowed(args):
    """Whether to measure window by window: asked for, or the in-memory run would pass the cap at the
    orthophoto's own resolution (a coarser grid asked for with --max-size or --resolution is measured
    in memory, or refused there with what fits)."""
    from ..errors import CliffTerrainError
    from .memory_estimate import check_heights_memory

    if args.window is not None and not args.windowed:
        raise CliffTerrainError(f"--window {args.window} needs --windowed")
    if (args.workers or args.scheduler) and not args.windowed:
        given = f"--workers {args.workers}" if args.workers else f"--scheduler {args.scheduler}"
        raise CliffTerrainError(f"{given} spreads the windows of --windowed over a cluster: add --windowed")
    if args.workers is not None and args.workers < 0:
        raise CliffTerrainError(f"--workers must be 0 or more, got {args.workers}")
    if args.windowed:
        if args.max_size is not None or args.resolution is not None:
            raise CliffTerrainError(
                "--windowed measures at the orthophoto's own resolution; drop --max-size/--resolution"
            )
        return True
    if args.max_size is not None or args.resolution is not None or args.indices or args.band_files:
        return False
    size = grid_size(args.ortho)
    try:
        check_heights_memory(args.ortho, (args.dsm, args.dtm), longest=size, cap_gib=args.max_memory)
    except CliffTerrainError as refused:
        from ..measure.windowed import WINDOW_PX
        from .memory_estimate import windowed_plan

        try:  # without plots yet: their halo is added when the plan is made for the run
            windowed_plan(args.ortho, (args.dsm, args.dtm), window_px=WINDOW_PX, cap_gib=args.max_memory)
        except CliffTerrainError:
            raise refused from None  # neither fits: the in-memory refusal says which grid would
        return True
    return False


def _run_windowed(args, outputs, plots, ruler):
    import functools

    from .._threads import usable_cores
    from .._validate import check_int
    from ..errors import CliffTerrainError
    from ..io.raster.geotiff import read_georeference
    from ..measure.window_tasks import window_halo
    from ..measure.windowed import WINDOW_PX
    from .heights_windowed import run_windowed
    from .memory_estimate import windowed_plan

    window = check_int("--window", args.window if args.window is not None else WINDOW_PX, minimum=64)
    args.window = window
    transform, _ = read_georeference(args.ortho)
    halo = window_halo(plots, transform)
    plan = functools.partial(
        windowed_plan,
        args.ortho,
        (args.dsm, args.dtm),
        window_px=window + 2 * halo,
        cap_gib=args.max_memory,
        plots=0 if plots is None else len(plots),
        workers=0 if args.scheduler else (args.workers or 0),
    )
    # Without a cluster, one window per core at once, as many as the cap allows (one at the least).
    threads = 1 if (args.scheduler or args.workers) else min(MAX_THREADS, usable_cores())
    while True:
        try:
            budget, estimate = plan(threads=threads)
            break
        except CliffTerrainError:
            if threads == 1:
                raise
            threads -= 1
    outputs = [n for n in outputs if not n.startswith("regions.")]
    return run_windowed(
        args,
        outputs=outputs,
        plots=plots,
        ruler=ruler,
        ground_pixels=budget,
        estimate_gib=estimate,
        threads=threads,
        stale=stale_outputs(args.out, outputs),
    )
