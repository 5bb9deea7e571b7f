"""``cliff-terrain heights --windowed``: the heights of an orthophoto of any size, window by window.

:func:`run_windowed` is what :mod:`.heights` runs with ``--windowed``, or by itself when the
in-memory run would pass ``--max-memory`` and neither ``--max-size`` nor ``--resolution`` asks for
a coarser grid (:mod:`cliff_terrain.measure.windowed`): full resolution, the ground on a grid that
fits the cap, the plot table exact. It writes ``chm.tif``, ``chm_err.tif`` and
``ground_support.tif`` (tiled, Deflate, overviews, written window by window), with ``--plots``
``plots.csv`` and ``plots.geojson`` (the in-memory run's columns), with ``--ruler`` its columns and
``ruler.png``, and ``summary.json`` (``"windowed"``: the window, the ground grid's pixel and
factor, each stage's wall time). It writes no ``regions.csv``: the plants' regions come from the
in-memory segmentation's watershed. ``--indices`` and ``--band-files`` are refused (they read the bands whole). `stale`: an earlier
run's outputs that this one does not write, removed as its own are written.
"""

from __future__ import annotations


def run_windowed(args, *, outputs, plots, ruler, ground_pixels, estimate_gib, threads=1, stale=()):
    import contextlib
    import json
    import shutil
    import tempfile

    from .._progress import stage_bar
    from .._threads import usable_cores
    from ..errors import CliffTerrainError
    from ..evaluate.views import json_safe
    from ..io.vector.geojson import polygon_geometries, table_geojson
    from ..measure.field_plots import check_plot_crs, table_columns
    from ..measure.tables import PLOTS_CSV, PLOTS_GEOJSON, table_csv, text_writer, write_files
    from ..measure.windowed import WINDOW_PX, measure_windowed
    from .cluster_options import cluster_security

    if getattr(args, "indices", None) or getattr(args, "band_files", None):
        raise CliffTerrainError(
            f"--indices and --band-files read the bands of {str(args.ortho)!r} whole; measure them without "
            "--windowed (with --max-size or --resolution)"
        )
    security = cluster_security(args)  # checked before any work
    out = args.out
    window = getattr(args, "window", None) or WINDOW_PX
    if plots is not None:
        from ..io.raster.geotiff import read_georeference

        check_plot_crs(plots, read_georeference(args.ortho)[1], raster=str(args.ortho))
    created = not out.exists()  # a folder made here and left empty by a failure is removed
    try:
        out.mkdir(parents=True, exist_ok=True)
        spool = tempfile.mkdtemp(prefix=".windows-", dir=out)
    except OSError as exc:
        raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
    cluster = None
    if args.scheduler or args.workers:
        from ..season.cluster import dask_client

        cluster = dask_client(
            workers=args.workers,
            scheduler=args.scheduler,
            timeout=args.timeout,
            memory_limit=args.memory_limit,
            security=security,
        )
    try:
        with contextlib.ExitStack() as stack:
            client = None if cluster is None else stack.enter_context(cluster)
            progress = stack.enter_context(
                stage_bar(f"heights {args.ortho.name} (windowed)", enabled=not args.no_progress)
            )
            result = measure_windowed(
                args.ortho,
                args.dsm,
                dtm=args.dtm,
                plots=plots,
                folder=spool,
                block_m=args.ground_block,
                ground_method=args.ground_method,
                window=window,
                ground_pixels=ground_pixels,
                progress=progress,
                client=client,
                threads=threads,
            )
        try:
            files, summary, ruler_columns, ruler_record = _files(
                args, result, ruler, window, estimate_gib, args_outputs=outputs
            )
            rows = result.rows
            if plots is not None:
                columns = table_columns(plots, support=True, sigma=True)
                columns[-1:-1] = ruler_columns
                # The rows' text as the windows made it (on every worker at once), unless a ruler
                # added columns; joined while the rasters are written.
                text = (result.table_text or {}) if not ruler_columns else {}
                files[out / PLOTS_CSV] = text_writer(lambda: table_csv(rows, columns, lines=text.get("csv")))
                files[out / PLOTS_GEOJSON] = text_writer(
                    lambda: table_geojson(
                        rows,
                        None if text else polygon_geometries(plots),
                        crs=result.crs,
                        features=text.get("features"),
                    )
                )
            files[out / "summary.json"] = json.dumps(json_safe(summary), indent=2) + "\n"
            order = {out / name: i for i, name in enumerate(outputs)}
            files = dict(sorted(files.items(), key=lambda item: order.get(item[0], -1)))
            # All at once: the rasters' reading, copying and Deflate of their overviews release the
            # GIL, so the tables' Python runs beside them.
            write_files(
                files,
                threads=max(usable_cores(), sum(map(callable, files.values()))),
                remove=stale,
            )
        except OSError as exc:
            raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
        finally:
            result.close()
    finally:
        shutil.rmtree(spool, ignore_errors=True)
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()  # only if empty: an unreachable scheduler leaves no empty --out behind
    check = result.check or {}
    ground = result.ground_source
    if check:
        from ..measure.ground_evidence import evidence_note

        error = check["candidates"][check["method"]]["error_m"] * 100
        ground += f" ({check['method']} on a {result.pixel_size * result.factor:.3g} m grid, held-out bare soil within {error:.1f} cm{evidence_note(check)})"
    measured = ""
    if rows is not None:
        import numpy as np

        p90 = np.array([r["height_p90_m"] for r in rows], float)
        ok = np.isfinite(p90)
        if ok.any():
            measured = f", {int(ok.sum())} of {len(rows)} plots with a height, median p90 {np.median(p90[ok]) * 100:.1f} cm"
    from ..measure.key_figures import undecided_cover
    from ..measure.resolution_check import resolution_line
    from ..measure.ruler import ruler_line

    against = ruler_line(ruler_record) + resolution_line(summary.get("resolution_check"))
    print(
        f"{args.ortho}: windowed ({result.windows} windows), ground {ground}, cover "
        f"{result.plant_pixels / max(1, result.valid_pixels):.1%}{undecided_cover(summary['threshold'])}"
        f"{measured}{against}; wrote {', '.join(outputs)} into {out}"
    )
    return 0


def _files(args, result, ruler, window, estimate_gib, args_outputs=()):
    """({path: writer} of the rasters and ruler.png, the summary, the ruler's columns and record)."""
    out = args.out
    nan = float("nan")
    files = {}
    for name, spool in result.spools.items():

        def write(tmp, spool=spool):  # NaN declared as no data, as in memory
            spool.write_geotiff(tmp, transform=result.transform, crs=result.crs, nodata=nan)

        files[out / f"{name}.tif"] = write
    ruler_columns, ruler_record = [], {}
    if ruler is not None and result.rows is not None:
        from ..figures.ruler_chart import plot_rows_ruler_figure
        from ..measure.ruler import ruler_columns as ruler_table

        ruler_columns, ruler_record = ruler_table(result.rows, ruler, calibrate_heights=args.calibrate)
        files[out / "ruler.png"] = lambda tmp: plot_rows_ruler_figure(result.rows, ruler_record).save(
            tmp, format="PNG"
        )
    check = result.check or {}
    rows, cols = result.shape
    resolution = None
    if result.rows is not None:
        from ..io.raster.geotiff import read_georeference
        from ..measure.resolution_check import pixel_metres, resolution_check

        resolution = resolution_check(
            [row["height_p90_m"] for row in result.rows],
            result.p90_doubled,
            [row.get("height_p90_err_m", nan) for row in result.rows],
            grid_pixel_m=pixel_metres(result.transform),
            surface_pixel_m=pixel_metres(read_georeference(args.dsm)[0]),
        )
    summary = {
        "cover": result.plant_pixels / max(1, result.valid_pixels),
        "plots": None if result.rows is None else len(result.rows),
        "ground": result.ground_source,
        "ground_method": check.get("method"),
        "ground_support": check.get("support_where_guessed"),
        "ground_check": check or None,
        "ruler": ruler_record or None,
        "resolution_check": resolution,
        "threshold": {
            "index": result.index,
            "threshold": result.threshold,
            "source": result.threshold_rule.get("source", "photo"),
            "note": result.threshold_rule.get("note", ""),
            "taken_on": "an overview of the orthophoto",
        },
        "grid": {"rows": rows, "cols": cols, "pixel_size_m": result.pixel_size},
        "windowed": {
            "window_px": window,
            "windows": result.windows,
            "ground_grid_factor": result.factor,
            "ground_grid_pixel_m": result.pixel_size * result.factor,
            "memory_estimate_gib": estimate_gib,
            "seconds": result.seconds,
        },
        "crs": result.crs if isinstance(result.crs, int) else None,
        "crs_wkt": getattr(result.crs, "wkt", None),
        "ortho": str(args.ortho),
        "dsm": str(args.dsm),
        "dtm": None if args.dtm is None else str(args.dtm),
        "outputs": list(args_outputs),  # what this run wrote: a later --overwrite removes only these
    }
    return files, summary, ruler_columns, ruler_record
