"""Canopy height and plot tables of a whole trial in bounded memory: the orthophoto read in windows.

A breeding trial's orthophoto has 100 MP to 1 GP and 100 000 plots; :func:`measure_canopy` on the
whole grid needs about 0.4 GiB per megapixel. :func:`measure_windowed` needs the same per megapixel
of a bounded *ground grid* plus one window, whatever the orthophoto's size:

1. **The ground, on a coarse grid.** The orthophoto and the DSM (resampled bilinearly onto the
   orthophoto's pixels, as :func:`cliff_terrain.io.raster.geotiff.resample` does) are read window by window
   and reduced by an integer `factor` to a grid of at most `ground_pixels` pixels, each as many
   orthophoto pixels as fit in 5 cm or more (:mod:`cliff_terrain.measure.ground_grid`; the
   ground's finest detail is a Gaussian of 0.15 m): each `factor` x `factor` block gives the mean
   height of its bare-soil pixels when it shows any, and is then the ground's evidence (the full
   grid's evidence is every bare pixel; a share threshold would alias with the crop rows), or of
   all its pixels with data, so that the plants in a block do not lift the soil it shows. Plants
   are the blurred vegetation index above the photo's threshold
   (:func:`cliff_terrain.photo_heights.vegetation.photo_threshold`), taken on an overview of the whole
   orthophoto (every n-th pixel, at most 4 MP: the orthophoto itself up to that size); where the
   colour leaves it undecided, the DSM sampled at the overview's pixels decides it, as the
   in-memory segmentation's :func:`~cliff_terrain.photo_heights.segmentation.decide_by_surface` does.
   Bare soil is what :func:`~cliff_terrain.photo_heights.bare_soil.bare_soil` calls it in memory:
   below that threshold and below the soil class's ceiling
   (:func:`~cliff_terrain.photo_heights.bare_soil.soil_ceiling`, on the same overview), so that
   shaded, yellowing or senescent leaves neither lift a block nor count as soil (on the photo's own
   grid, ``factor`` 1, it is taken on the whole grid, exactly as in memory). On a recoloured
   soybean field whose plants were made golden, a 2 x 2 grid that took every pixel below the
   threshold as soil measured its plots 4.2 cm too low, the in-memory path 0.9 cm too high.
   :func:`cliff_terrain.measure.ground.fit_ground` fits and checks the ground (its held-out check,
   standard error and support) unchanged.
2. **The canopy, at full resolution.** Each window's DSM minus the ground bilinearly upsampled from
   the coarse grid (pixel centres aligned: full pixel ``i`` lies at coarse ``(i + 0.5) / factor -
   0.5``, held flat beyond the outer centres) is the CHM; it, the ground's standard error and its
   support are spooled window by window into tiled, Deflate GeoTIFFs with overviews
   (:mod:`cliff_terrain.io.raster.geotiff_stream`); windows of whole 512-pixel tiles (the default)
   come back compressed from where they were measured, so no one process compresses them all.
   Plants are the blurred index above the same threshold (the rule of
   :func:`~cliff_terrain.measure.canopy.plant_mask`).
3. **Plots, exactly.** Each plot belongs to the window holding its centre; windows are read with a
   halo of half the largest plot's extent (plus the blur's reach), so every plot lies whole in its
   window and :func:`cliff_terrain.measure.field_plots.plot_table` takes all its pixels: the
   percentiles are not approximated. Every plot that touches a window is burnt into it in file
   order, so overlapping plots resolve as on the whole grid.

Every pixel's value is computed from global pixel coordinates (bilinear weights, the index's blur
inside the halo), so the tables and rasters do not depend on the window size: small windows give
exactly what one window over the whole orthophoto gives (tested). They differ from the in-memory
path's where the grids differ: the ground's grid (coarser on a big field), and the plants (the
photo's threshold here, the segmentation's watershed there).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np

from .._dask import as_done, in_order
from .._progress import StageClock
from .._validate import check_float, check_int
from ..errors import GeoreferenceError
from .ground import DEFAULT_BLOCK_M, fit_ground, surface_data
from .ground_grid import ground_factor
from .window_reading import WindowSources, windows
from .window_tasks import (
    OverviewTask,
    coarse_tasks,
    coarse_window,
    encoded_windows,
    measure_window,
    overview_band,
    window_tasks,
)

#: Default side (pixels) of a window's core; a multiple of the output's 512-pixel tiles.
WINDOW_PX = 2048
#: Default budget of the ground grid (pixels); :mod:`cliff_terrain.commands.memory_estimate` sets
#: it from ``--max-memory``.
GROUND_PIXELS = 6_000_000


@dataclass
class WindowedCanopy:
    """What :func:`measure_windowed` measured (the rasters are in ``spools``, on disk).

    Attributes
    ----------
    transform : (3, 3) float64
        The orthophoto's grid (pixel -> map).
    crs : int or UserCrs
    shape : (int, int)
        (rows, cols) of the grid.
    pixel_size : float
        Metres per pixel (mean of x and y).
    ground_source : {"dtm", "estimated"}
    factor : int
        Orthophoto pixels per ground-grid pixel (along each axis).
    threshold : float
        The plant/soil threshold of the vegetation index (``index``).
    index : str
    threshold_rule : dict
        How the threshold was chosen: ``source`` (:class:`~cliff_terrain.photo_heights.vegetation.ThresholdRule`'s,
        or ``"photo (dsm)"`` when the surface model decided an undecided photo) and ``note``.
    check : dict or None
        The ground's held-out check (:func:`cliff_terrain.measure.ground.fit_ground`).
    rows : list of dict or None
        The plot table, as :func:`cliff_terrain.measure.field_plots.plot_table` gives it.
    spools : dict
        Raster name (``"chm"``, ``"chm_err"``, ``"ground_support"``) ->
        :class:`~cliff_terrain.io.raster.geotiff_stream.TileSpool` (windows of whole tiles) or
        :class:`~cliff_terrain.io.raster.geotiff_stream.RasterSpool`.
    windows : int
        Number of windows measured.
    table_text : dict or None
        The plot table's text as the windows made it: ``{"csv": [line], "features": [GeoJSON
        Feature text]}`` in plot order (:func:`~cliff_terrain.measure.tables.table_csv`'s `lines`,
        :func:`~cliff_terrain.io.vector.geojson.table_geojson`'s `features`), for the columns of
        :func:`~cliff_terrain.measure.field_plots.table_columns` with support and sigma.
    seconds : dict
        Wall time of each stage: ``overview`` (the threshold's), ``ground_grid`` (the first pass),
        ``ground_fit`` (the fit here, its held-out check's five folds on a remote scheduler's
        workers) and ``windows`` (the second pass).
    """

    transform: np.ndarray
    crs: object
    shape: tuple
    pixel_size: float
    ground_source: str
    factor: int
    threshold: float
    index: str
    check: dict | None = None
    rows: list | None = None
    p90_doubled: list | None = None  # each plot's p90 for the resolution check (its module)
    spools: dict = field(default_factory=dict)
    windows: int = 0
    plant_pixels: int = 0
    valid_pixels: int = 0
    seconds: dict = field(default_factory=dict)
    table_text: dict | None = None
    threshold_rule: dict = field(default_factory=dict)

    def close(self):
        """Remove the spooled rasters."""
        for spool in self.spools.values():
            spool.close()


def measure_windowed(
    ortho,
    dsm,
    *,
    dtm=None,
    plots=None,
    folder,
    block_m=DEFAULT_BLOCK_M,
    ground_method="auto",
    window=WINDOW_PX,
    ground_pixels=GROUND_PIXELS,
    progress=None,
    client=None,
    threads=1,
):
    """Measure an orthophoto of any size window by window: ground, CHM rasters and plot table.

    Parameters
    ----------
    ortho : path
        The orthophoto GeoTIFF (tiled, or striped up to
        :data:`cliff_terrain.io.raster.mosaic.MAX_STRIPED_PIXELS`).
    dsm : path
        Its surface model GeoTIFF (same CRS, north-up; any grid).
    dtm : path, optional
        A terrain model: the ground, instead of estimating it.
    plots : PlotSet, optional
        Plot polygons in the orthophoto's CRS: adds :attr:`WindowedCanopy.rows`.
    folder : path
        Where the rasters are spooled (about 4 bytes per pixel each) until written.
    block_m : float, optional
        The ground's block (:func:`cliff_terrain.measure.ground.fit_ground`).
    ground_method : {"auto", "baseline", "smooth", "detailed"}, optional
    window : int, optional
        Side of a window's core in pixels (the tables do not depend on it).
    ground_pixels : int, optional
        Budget of the ground grid (:func:`ground_factor`).
    progress : callable, optional
        ``progress(fraction, stage)``.
    client : distributed.Client, optional
        Spread both passes' windows over a Dask cluster (:func:`~.window_tasks.coarse_window`
        and :func:`~.window_tasks.measure_window` as tasks, the coarse ground scattered to every
        worker once); the results are the same. A client joined to a scheduler by its address
        (not one made on a local cluster object here) also gets the ground check's folds.
    threads : int, optional
        Without `client`, windows measured at once in this process, each thread with its own
        readers (numpy, OpenCV and the TIFF codecs release the GIL); the results are the same.

    Returns
    -------
    WindowedCanopy
        Its rasters stay spooled in `folder` until :meth:`WindowedCanopy.close`.

    Raises
    ------
    GeoreferenceError
        CRSs differ, a raster is rotated, or no plot overlaps the orthophoto.
    GroundError
        The ground cannot be estimated (:func:`~cliff_terrain.measure.ground.fit_ground`).
    """
    window = check_int("window", window, minimum=16)
    threads = check_int("threads", threads, minimum=1)
    ground_pixels = check_int("ground_pixels", ground_pixels, minimum=10_000)
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    step = progress or (lambda fraction, stage: None)
    sources = WindowSources(ortho, dsm, dtm)
    readers = [sources]
    try:
        if client is None:
            readers += [WindowSources(ortho, dsm, dtm) for _ in range(threads - 1)]
        run = _runner(client, readers)
        # The ground's check sends its five folds to a scheduler elsewhere, whose memory is its own;
        # here, and on a local cluster, they run one after another in this process: the memory plan
        # (commands.memory_estimate.windowed_plan) counts one fold at a time beside idle workers,
        # and each fold at once would add about 0.15 GiB per megapixel of the ground grid.
        fit_run = run if client is not None and getattr(client, "cluster", None) is None else None
        return _measure(
            sources, plots, folder, block_m, ground_method, window, ground_pixels, step, run, fit_run, readers
        )
    finally:
        for reader in readers:
            reader.close()


def _runner(client, readers):
    """``run(function, argument tuples, shared, ordered=True)``: the calls' results on `client`'s
    workers (`shared` scattered to them once), on one thread per reader, or here; in order, or with
    ``ordered=False`` on a cluster as they finish (the passes place each result by its window)."""
    if client is not None:

        def on_cluster(function, arguments, shared=None, *, ordered=True):
            if shared is not None:
                shared = client.scatter(shared, broadcast=True)
            calls = ((*args, *_extra(shared)) for args in arguments)
            return (in_order if ordered else as_done)(client, function, calls, ahead=_ahead(client))

        return on_cluster
    if len(readers) == 1:
        return lambda function, arguments, shared=None, *, ordered=True: (
            function(*args, *_extra(shared), sources=readers[0]) for args in arguments
        )
    return lambda function, arguments, shared=None, *, ordered=True: _on_threads(
        function, arguments, shared, readers
    )


def _extra(shared):
    """The trailing argument every call gets: `shared`, when there is one."""
    return () if shared is None else (shared,)


def _on_threads(function, arguments, shared, readers):
    """The calls on one thread per reader, each call with a free reader; results in order, with
    at most two calls per thread submitted ahead of the one being returned (so memory stays a
    few windows while every thread has its next window ready)."""
    import queue
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    free = queue.SimpleQueue()
    for reader in readers:
        free.put(reader)

    def call(args):
        reader = free.get()
        try:
            return function(*args, *_extra(shared), sources=reader)
        finally:
            free.put(reader)

    pool = ThreadPoolExecutor(len(readers), thread_name_prefix="cliff-window")
    pending = deque()
    try:
        for args in arguments:
            pending.append(pool.submit(call, args))
            if len(pending) > 2 * len(readers):
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _measure(
    sources, plots, folder, block_m, ground_method, window, ground_pixels, step, run, fit_run=None, readers=()
):
    from ..io.raster.geotiff_stream import RasterSpool, TileSpool
    from ..photo_heights.bare_soil import bare_soil, soil_ceiling
    from ..photo_heights.vegetation import blurred_index, photo_threshold

    transform = sources.ortho.transform
    shape = sources.ortho.shape
    pixel_size = float(np.mean([np.hypot(*transform[:2, 0]), np.hypot(*transform[:2, 1])]))
    name = sources.ortho.path
    factor = ground_factor(shape, pixel_size, ground_pixels=ground_pixels)

    seconds = {}
    clock = StageClock(None, seconds, digits=3)  # `step` draws the bar, in its own stages
    clock.start("overview")
    # 0. The plant/soil threshold, on an overview of the whole photo (every step-th pixel, <= 4 MP),
    # read band by band where the windows are (decoding the photo is most of it).
    overview, valid_o = _overview(sources, run, readers)
    vi_o, index = blurred_index(overview)
    rule = photo_threshold(vi_o, overview, index=index, valid=valid_o)
    threshold, decision = float(rule.threshold), {"source": rule.source, "note": rule.note}
    if rule.note.startswith("undecided"):
        # As the in-memory segmentation does (decide_by_surface): a class the colour cannot place
        # (a senescent canopy, straw) is plant when it stands above the rest on the DSM.
        threshold, decision = _decide_by_surface(sources, vi_o, valid_o, rule)
    # The soil class's upper limit, as bare_soil takes it on the whole photo (on a coarser ground
    # grid the windows need it before any of them is read; on the photo's own, the grid gives it).
    ceiling = float("inf")
    if factor > 1:
        below = vi_o <= threshold if valid_o is None else valid_o & (vi_o <= threshold)
        ceiling = soil_ceiling(vi_o[below])
    del overview, valid_o, vi_o
    clock.start("ground_grid")

    # 1. The coarse grid: the photo (factor 1) or the blocks showing bare soil, the valid pixels and
    # the surface, reduced window by window (:func:`~.window_tasks.coarse_window`, here or on the
    # cluster's workers).
    rows_c, cols_c = -(-shape[0] // factor), -(-shape[1] // factor)
    rgb_c = np.zeros((rows_c, cols_c, 3), np.uint8) if factor == 1 else None
    soil_c = np.zeros((rows_c, cols_c), bool) if factor > 1 else None
    valid_c = np.zeros((rows_c, cols_c), bool)
    dsm_c = np.full((rows_c, cols_c), np.nan, np.float32)
    parts = coarse_tasks(sources, shape, transform, factor, index, threshold, window, soil_ceiling=ceiling)
    # Each block lands where it says (``at``): taken as the workers finish them. Closed on a failure
    # here, so that the windows still on the workers are cancelled at once.
    blocks = run(coarse_window, ((task,) for task in parts), ordered=False)
    with contextlib.closing(blocks):
        for k, block in enumerate(blocks):
            cr, cc = block["at"]
            n_r, n_c = block["valid"].shape
            where = (slice(cr, cr + n_r), slice(cc, cc + n_c))
            valid_c[where], dsm_c[where] = block["valid"], block["dsm"]
            if factor == 1:
                rgb_c[where] = block["rgb"]
            else:
                soil_c[where] = block["soil"]
            step(0.4 * (k + 1) / len(parts), "ground grid")
    clock.start("ground_fit")
    has_data = valid_c & np.isfinite(dsm_c)
    if not has_data.any():
        raise GeoreferenceError(f"{sources.dsm.path!r} has no data where it overlaps {name!r}")
    plant_c = valid_c  # for the summary's cover, replaced by the full grid's below
    ground_c = support_c = sigma_c = None
    check = None
    if sources.dtm is None:
        if factor == 1:  # the photo's own grid: its bare soil as in memory, to the pixel
            soil_c = bare_soil(rgb_c, valid=valid_c, index=index, threshold=threshold)
        del rgb_c
        step(0.45, "ground")
        fit = fit_ground(
            np.where(has_data, dsm_c, np.float32(np.nan)),
            soil=soil_c & has_data,
            pixel_size=pixel_size * factor,
            block_m=block_m,
            method=ground_method,
            source=f"{sources.dsm.path!r} over {name!r}",
            run=fit_run,  # the check's five folds on a remote scheduler's workers, or here
        )
        ground_c, support_c, sigma_c, check = fit.ground, fit.support, fit.sigma, fit.check
        check["ground_pixel_m"] = pixel_size * factor  # as in memory (:mod:`.ground_grid`)
        del fit, soil_c
    del dsm_c, has_data, plant_c, valid_c
    clock.start("windows")

    # 2. and 3. The full grid, window by window: CHM, its error and support, and the plots.
    result = WindowedCanopy(
        transform, sources.ortho.crs, shape, pixel_size, "dtm" if sources.dtm else "estimated",
        factor, threshold, index, check, seconds=seconds, threshold_rule=decision,
    )  # fmt: skip
    names = ["chm"] + (["chm_err", "ground_support"] if ground_c is not None else [])
    levels = encoded_windows(window)
    if levels:
        result.spools = {n: TileSpool(folder, n, shape, levels=levels) for n in names}
    else:
        result.spools = {n: RasterSpool(folder, n, shape) for n in names}
    try:
        ground = None if ground_c is None else (ground_c, sigma_c, support_c)
        _full_grid(sources, plots, window, result, ground, step, run)
        clock.start(None)
    except BaseException:
        result.close()
        raise
    return result


def _decide_by_surface(sources, vi, valid, rule, *, band_rows=256):
    """The overview's undecided threshold decided by the DSM: ``(threshold, {"source", "note"})``.

    The DSM is sampled at the overview's pixels (every step-th pixel's centre), a band of rows at
    a time so that only a band of it is read; the photo's own split is taken when the class above
    it stands above the rest by Ashman's D >= ``COLOUR_SEPARATION``
    (:func:`~cliff_terrain.photo_heights.separation.surface_split`).
    """
    from ..photo_heights.separation import surface_split
    from ..photo_heights.vegetation import COLOUR_SEPARATION

    step = sources.ortho.overview_bands()[0]
    offset = 0.5 - 0.5 * step  # overview pixel j's centre is full pixel j * step's centre
    grid = sources.ortho.transform @ np.array([[step, 0.0, offset], [0.0, step, offset], [0.0, 0.0, 1.0]])
    rows, cols = vi.shape
    surface = np.concatenate(
        [
            sources.dsm.on_grid(grid, r0, min(rows, r0 + band_rows), 0, cols)
            for r0 in range(0, rows, band_rows)
        ]
    )
    surface[~surface_data(surface)] = np.nan  # an undeclared -3.4e38 would tilt the ground's plane
    upper = rule.threshold if rule.source == "photo (upper valley)" else None
    split, d = surface_split(vi, surface, valid=valid, upper=upper)
    if d >= COLOUR_SEPARATION:
        note = f"decided by the DSM: the class above the photo's own split stands above the rest (D {d:.2f})"
        return float(split), {"source": "photo (dsm)", "note": note}
    note = f"{rule.note}; the DSM does not show it standing above the rest either (D {d:.2f})"
    return float(rule.threshold), {"source": rule.source, "note": note}


def _overview(sources, run, readers=()):
    """:meth:`~cliff_terrain.io.raster.mosaic.MosaicReader.overview`'s photo and valid mask, its bands
    read by `run`; the file's sample scale, taken from it, is given to every reader of `readers`."""
    from ..io.raster.mosaic import overview_from_bands

    step, bands = sources.ortho.overview_bands()
    tasks = ((OverviewTask(sources.ortho.path, sources.dsm.path, band, step),) for band in bands)
    photo = sources.ortho.from_overview(
        overview_from_bands(sources.ortho.shape, step, run(overview_band, tasks))
    )
    for reader in readers:
        reader.ortho.scale = sources.ortho.scale
    return photo


def _ahead(client):
    """Tasks queued beyond the one being taken: one per worker and one more, so none waits."""
    return max(2, len(client.scheduler_info().get("workers", {})) + 1)


def _full_grid(sources, plots, window, result, ground, step, run):
    tasks = window_tasks(sources, plots, window, result)  # made as they are taken: plots stay single
    count = len(windows(result.shape, window))
    # Each window's rasters land at its core and its rows at their plots' places: taken as the
    # workers finish them (the spools write the files in row-major order whatever the order here).
    if ground is None:
        outputs = run(measure_window, ((task, None) for task in tasks), ordered=False)
    else:
        outputs = run(measure_window, ((task,) for task in tasks), ground, ordered=False)
    rows_out = [None] * len(plots) if plots is not None else None
    lines = [None] * len(plots) if plots is not None else None
    features = [None] * len(plots) if plots is not None else None
    doubled = [float("nan")] * len(plots) if plots is not None else None
    labelled = False
    with contextlib.closing(outputs):  # as above: a failure here cancels the windows in flight
        for k, out in enumerate(outputs):
            r0, _, c0, _ = out["core"]
            for name, spool in result.spools.items():
                spool.put(r0, c0, out[name])
            result.valid_pixels += out["valid_pixels"]
            result.plant_pixels += out["plant_pixels"]
            labelled = labelled or out["labelled"]
            if rows_out is not None:
                for i, row in out["rows"].items():
                    rows_out[i] = row
                for i, value in out.get("p90_doubled", {}).items():
                    doubled[i] = value
                for i, line in out.get("csv", {}).items():
                    lines[i] = line
                for i, text in out.get("features", {}).items():
                    features[i] = text
            result.windows += 1
            step(0.45 + 0.5 * (k + 1) / count, "canopy and plots")
    if plots is not None:
        if not labelled:
            raise GeoreferenceError(
                f"no plot of {plots.path!r} overlaps the orthophoto {sources.ortho.path!r}"
            )
        result.rows, result.p90_doubled = rows_out, doubled
        if all(line is not None for line in lines) and all(text is not None for text in features):
            result.table_text = {"csv": lines, "features": features}
