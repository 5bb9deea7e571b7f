"""How much memory ``cliff-terrain heights`` will take, worked out before the work, so the OS
never kills it: a run that would pass the cap is refused in one line naming the file and the
``--max-size`` / ``--resolution`` that would fit.

The estimate is linear in the pixels, with coefficients measured (``bench/bench_heights_memory.py``:
the shared OpenDroneMap pair at 20 cm tiled 4 x 4 and 7 x 7, whose ground grid is the measuring
grid, and the synthetic 1 cm field with 80 plots, whose ground is fitted on 5 cm; peak RSS, VmHWM)
and rounded up. Peaks measured 2026-12-06 (Intel Xeon, 2 cores), and the estimate:

=====================================  =========  ==========  =========  ===========  ==========  ==========  ==========  ==========
orthophoto / grid / ground grid (MP)   4.7/4.7/   4.7/3.9/    4.7/1.0/   14.4/14.4/   14.4/3.9/   14.4/1.0/   12/12/      27/27/
                                       4.7        3.9         1.0        14.4         3.9         1.0         0.48        1.08
measured peak (GiB)                    1.30       1.12        0.41       3.58         1.18        0.76        1.22        2.50
estimate (GiB)                         1.65       1.44        0.71       4.52         1.89        1.16        1.58        3.23
=====================================  =========  ==========  =========  ===========  ==========  ==========  ==========  ==========

Reading costs about 0.03 GiB per megapixel of each file (the orthophoto, DSM and DTM are decoded
whole). The measuring grid costs about 0.05 GiB per megapixel (the relief's stages, the CHM and the
tables; the fine field's two sizes) and the ground's grid about 0.12 (fitting the ground and its
held-out check; the pair's peaks less the grid's share), taken as 0.07 and 0.18: the estimate is
1.26-1.75 times the peak. Until 2026-12-05 one coefficient, 0.42 per megapixel of the grid, counted
the ground at the measuring grid's size: it estimated 5.7 GiB for the 12 MP field (measured 1.22),
so the command measured it in windows (without regions.csv) or refused it with --indices. The 20 cm
pair's peaks fell from 2.08 and 5.98 GiB (measured the morning of 2026-12-03) to 1.31 and 3.58 after
the ground detail's local quadratics were solved a band of rows at a time (that evening) instead of
holding their normal equations for every pixel: 42 float32 planes, 2.3 GiB at 14.4 MP, about what
the peak fell by. Re-measure with the bench when the ground
estimator, the segmentation or the readers change.
"""

from __future__ import annotations

import math

from ..errors import CliffTerrainError

#: The default cap (GiB): what a 8 GB laptop can give one command. ``--max-memory`` changes it.
DEFAULT_CAP_GIB = 4.0
BASE_GIB = 0.25  # the interpreter, NumPy, OpenCV and the readers' libraries
READ_GIB_PER_MP = 0.03  # decoding a file, per megapixel of the file
GRID_GIB_PER_MP = 0.07  # measuring, per megapixel of the grid (0.05 measured)
GROUND_FIT_GIB_PER_MP = 0.18  # fitting the ground, per megapixel of its grid (0.12 measured)


def heights_estimate(files_mp, grid_mp, ground_mp=None):
    """Peak memory (GiB) of a heights run reading files of `files_mp` megapixels on a grid of
    `grid_mp`, its ground fitted on a grid of `ground_mp` (default `grid_mp`: pixels of 5 cm or more
    are their own ground grid, :func:`cliff_terrain.measure.ground_grid.ground_factor`).

    Examples
    --------
    >>> round(heights_estimate([12.0, 1.3], 12.0, 0.48), 2)    # 12 MP at 1 cm, its DSM at 3 cm
    1.58
    """
    ground_mp = grid_mp if ground_mp is None else ground_mp
    return (
        BASE_GIB
        + READ_GIB_PER_MP * sum(files_mp)
        + GRID_GIB_PER_MP * grid_mp
        + GROUND_FIT_GIB_PER_MP * ground_mp
    )


def grid_estimate(ortho, files_mp, longest):
    """(estimate GiB, grid columns, grid rows) of measuring `ortho` on a grid `longest` pixels across."""
    from ..io.raster.geotiff import raster_size, read_georeference

    transform, _ = read_georeference(ortho)
    return _grid_estimate(raster_size(ortho), math.hypot(*transform[:2, 0]), files_mp, longest)


def _grid_estimate(shape, pixel, files_mp, longest):
    from ..measure.ground_grid import ground_factor

    rows, cols = shape
    scale = min(1.0, longest / max(rows, cols))
    g_rows, g_cols = max(1, round(rows * scale)), max(1, round(cols * scale))
    factor = ground_factor((g_rows, g_cols), pixel / scale)
    ground_mp = math.ceil(g_rows / factor) * math.ceil(g_cols / factor) / 1e6
    return heights_estimate(files_mp, g_rows * g_cols / 1e6, ground_mp), g_cols, g_rows


def check_heights_memory(ortho, others, *, longest, cap_gib=DEFAULT_CAP_GIB):
    """Refuse a heights run whose estimate passes `cap_gib`, naming the orthophoto and what fits.

    `longest` is the measuring grid's longest side (pixels), as
    :func:`cliff_terrain.commands.heights.grid_size` chose it; `others` are the DSM (and DTM).
    Returns the estimate in GiB.
    """
    from .._validate import check_float
    from ..io.photo import MAX_PIXELS
    from ..io.raster.geotiff import raster_size, read_georeference

    cap_gib = check_float("--max-memory", cap_gib, minimum=0.0, strict_minimum=True)
    rows, cols = raster_size(ortho)
    if rows * cols > MAX_PIXELS:  # the photo reader's own guard, whatever the grid
        raise CliffTerrainError(
            f"orthophoto {str(ortho)!r} is {cols} x {rows} pixels ({rows * cols / 1e6:.0f} MP), more than the "
            f"{MAX_PIXELS / 1e6:.0f} MP an orthophoto is read whole up to, even with --max-size or --resolution; "
            "crop or split it and its DSM into parts"
        )
    files_mp = [rows * cols / 1e6] + [math.prod(raster_size(p)) / 1e6 for p in others if p is not None]
    transform, _ = read_georeference(ortho)
    pixel = math.hypot(*transform[:2, 0])
    estimate, g_cols, g_rows = _grid_estimate((rows, cols), pixel, files_mp, longest)
    if estimate <= cap_gib:
        return estimate
    what = (
        f"measuring {str(ortho)!r} ({cols} x {rows} pixels) on a {g_cols} x {g_rows} grid "
        f"needs about {estimate:.2f} GiB, more than the {cap_gib:g} GiB cap"
    )
    if cap_gib - heights_estimate(files_mp, 0.0) <= (GRID_GIB_PER_MP + GROUND_FIT_GIB_PER_MP) * 0.01:
        raise CliffTerrainError(
            f"{what}, and reading the files alone needs {heights_estimate(files_mp, 0.0):.2f} GiB; crop or "
            "split the orthophoto and its DSM, or raise --max-memory"
        )
    longest_o = max(rows, cols)

    def fits(side):
        return _grid_estimate((rows, cols), pixel, files_mp, side)[0] <= cap_gib

    # The longest side that fits, by bisection. The estimate is not monotonic in the side: the
    # ground's grid gathers whole pixels up to 5 cm, so a 2.6 cm grid is its own ground grid while
    # a 2.4 cm one gathers 2 x 2. Both suggestions must fit, so the side steps down until the
    # coarser grid that --resolution gives (its metres rounded up to the millimetre) fits too.
    low, high = 1, min(longest, longest_o)
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (middle, high) if fits(middle) else (low, middle)
    fit = low
    while True:
        metres = math.ceil(pixel * longest_o / fit * 1000) / 1000
        if fit <= 1 or (fits(fit) and fits(min(longest_o, round(longest_o * pixel / metres)))):
            break
        fit -= 1
    raise CliffTerrainError(
        f"{what}; use --max-size {fit} or --resolution {metres:g} (metres per pixel), or raise --max-memory"
    )


# The windowed path (:mod:`cliff_terrain.measure.windowed`), measured with bench/bench_scale.py. Its
# two passes peak one after the other: the ground grid's (its photo, surface, soil and fit_ground),
# then one window's with its halo (photo, index, surface, ground, CHM, plot labels) beside the coarse
# ground. The plots and their rows stay throughout.
#
# The ground grid is sized as if fitting it took GROUND_GIB_PER_MP: fit_ground's cost when the
# budget was set (0.35 GiB/MP measured). Every windowed run's ground, and so its numbers, follow
# from that size, which is kept. Since 2026-12-06 its quadratics' moments are filtered in chunks of
# rows (0.11 GiB/MP above the process on the bench field's 7.4 MP grid, 0.19 before), so the fit
# pass is estimated with what it takes now, GROUND_FIT_GIB_PER_MP + GRID_GIB_PER_MP (its coarse
# photo, surface and soil), as in memory: the room left is the local workers', which idle beside
# it. With the old coefficient in the estimate as well, a 66 MP field (its grid 7.4 MP, 1.11 GiB
# at its peak in one process) was refused with two local workers (4.19 GiB) while a 265 MP one
# (its grid 5.4 MP) was not.
GROUND_GIB_PER_MP = 0.45
WINDOW_GIB_PER_MP = 0.25
PLOT_GIB = 4e-6  # per plot: its polygon, its pixel rings and its row (about 4 kB)
#: The ground grid's largest budget (pixels), whatever the cap.
MAX_GROUND_PIXELS = 16_000_000
MIN_GROUND_PIXELS = 250_000


def striped_gib(path):
    """GiB a file decodes whole because it is striped (0 when tiled: it is read in windows)."""
    from ..io.raster._tiff_window import TiffRaster

    with TiffRaster(path) as tiff:
        if tiff.tiled:
            return 0.0
        return tiff.shape[0] * tiff.shape[1] * tiff.samples * tiff.page.dtype.itemsize / 2**30


def windowed_plan(ortho, others, *, window_px, cap_gib=DEFAULT_CAP_GIB, plots=0, workers=0, threads=1):
    """(ground grid budget in pixels, estimated peak GiB) of a windowed heights run under `cap_gib`.

    `window_px` is the side of a window read with its halo; `others` are the DSM (and DTM);
    `plots` the number of plots; `workers` the local Dask worker processes, each holding the
    interpreter, the striped files, one window and its copy of the coarse ground (a remote
    cluster's memory is its own: 0); `threads` the windows measured at once in this process, each
    thread beyond the first holding its own readers and window.

    The ground grid's budget is what one process fits under the cap beside the interpreter, the
    plots and the striped files decoded whole (up to :data:`MAX_GROUND_PIXELS`): it depends on the
    files and the cap only, never on the window, the threads or the workers, so that every way of
    running gives the same ground and the same tables. The parallelism must then fit beside it:
    when it does not (or the budget is below :data:`MIN_GROUND_PIXELS`), the run is refused,
    naming the orthophoto and what to change (the command takes fewer threads first).
    """
    from .._validate import check_float
    from ..io.raster.geotiff import COG_TILE, raster_size, read_georeference, write_buffer_bytes
    from ..measure.ground_grid import ground_factor

    cap_gib = check_float("--max-memory", cap_gib, minimum=0.0, strict_minimum=True)
    rows, cols = raster_size(ortho)
    striped = sum(striped_gib(p) for p in (ortho, *(p for p in others if p is not None)))
    window_mp = min(window_px, rows) * min(window_px, cols) / 1e6
    window_gib = WINDOW_GIB_PER_MP * window_mp
    resident = BASE_GIB + PLOT_GIB * plots + striped  # this process, throughout
    transform, _ = read_georeference(ortho)
    pixel = math.hypot(*transform[:2, 0])
    finest = ground_factor((rows, cols), pixel, ground_pixels=rows * cols)  # the 5 cm floor alone
    needed = math.ceil(rows / finest) * math.ceil(cols / finest)
    # Pass 3 writes the three rasters at once, each a band of 512-pixel tiles, its overview's and
    # tifffile's buffer of tiles waiting for compression (never more than the raster's own tiles).
    tiles_bytes = math.ceil(rows / COG_TILE) * math.ceil(cols / COG_TILE) * COG_TILE**2 * 4
    write_pass = resident + 3 * (2 * COG_TILE * cols * 4 + min(write_buffer_bytes(), tiles_bytes)) / 2**30

    def plan(cap):
        """(budget, estimate, whether it fits) under `cap` GiB."""
        budget = max(10_000, min(MAX_GROUND_PIXELS, int((cap - resident) / GROUND_GIB_PER_MP * 1e6)))
        factor = ground_factor((rows, cols), pixel, ground_pixels=budget)
        grid = math.ceil(rows / factor) * math.ceil(cols / factor)
        ground_gib = 12 * grid / 2**30  # the coarse ground, its error and support (12 bytes a pixel)
        # Pass 1 fits the ground here while each worker idles with its interpreter and striped files;
        # pass 2 holds the coarse ground here and in each worker, and one window per thread or worker.
        fit_pass = resident + (GROUND_FIT_GIB_PER_MP + GRID_GIB_PER_MP) * grid / 1e6
        fit_pass += workers * (BASE_GIB + striped)
        window_pass = resident + ground_gib + workers * (BASE_GIB + striped + ground_gib + window_gib)
        window_pass += (window_gib if workers == 0 else 0) + (max(1, threads) - 1) * (striped + window_gib)
        estimate = max(fit_pass, window_pass, write_pass)
        return budget, estimate, budget >= min(MIN_GROUND_PIXELS, needed) and estimate <= cap

    budget, estimate, fits = plan(cap_gib)
    if not fits:
        # A larger cap also enlarges the ground's grid, so the estimate above is not a cap that
        # fits: name the least one that does (in tenths of a GiB; the room beside the grid grows with
        # the cap, so the search ends), with what else would make room.
        tenths = math.floor(cap_gib * 10) + 1
        while not plan(tenths / 10)[2]:
            tenths += 1
        # Refused for a ground grid below its least size, the estimate may lie under the cap: what
        # the least grid takes beside one window is then what it needs.
        smallest = GROUND_GIB_PER_MP * min(MIN_GROUND_PIXELS, needed) / 1e6
        least = max(estimate, resident + window_gib + smallest)
        raise CliffTerrainError(
            f"measuring {str(ortho)!r} in windows needs about {least:.2f} GiB under the "
            f"{cap_gib:g} GiB cap (one {window_px}-pixel window"
            f"{f' here and in each of {workers} workers' if workers else ''}, the files that are striped "
            f"decoded whole, and the ground's grid): give --max-memory {tenths / 10:.1f} or more, "
            f"lower --window{', use fewer --workers' if workers else ''}, or tile the striped files "
            "(gdal_translate -co TILED=YES)"
        )
    return budget, estimate
