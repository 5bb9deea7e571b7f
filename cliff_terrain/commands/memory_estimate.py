"""How much memory ``cliff-terrain heights`` will take, worked out before the work, so the OS
never kills it: a run that would pass the cap is refused in one line naming the file and the
``--max-size`` / ``--resolution`` that would fit.

The estimate is linear in the pixels, with coefficients measured (``bench/bench_heights_memory.py``,
the shared OpenDroneMap pair tiled 4 x 4 and 7 x 7, peak RSS by ``/usr/bin/time -v``) and rounded up:

=============================  =========  ===========  ==========  ==========
orthophoto (MP) / grid (MP)    4.7 / 4.7  14.4 / 14.4  14.4 / 3.9  14.4 / 1.0
measured peak (GiB), 12-03     2.08       5.98         1.79        0.76
measured peak (GiB), 12-05     1.31       3.58         1.18        0.76
estimate (GiB)                 2.45       6.97         2.55        1.33
=============================  =========  ===========  ==========  ==========

(issue 40 measured 25.7 MP: 9.66 GB; the estimate says 10.8 GiB). Reading costs about 0.03 GiB per
megapixel of each file (the orthophoto, DSM and DTM are decoded whole); the measuring grid about
0.37 GiB per megapixel (the relief's stages, the ground and its held-out check, the CHM and the
tables), taken as 0.42 for a margin (measured 2026-12-03 after the checked ground, which raised the
14.4 MP peak from 5.25 to 5.98 GiB). Re-measured 2026-12-05: 0.18 GiB per megapixel of grid (why it
fell since 12-03 at this 20 cm pixel, where the ground's grid is the orthophoto's own, was not
traced); the coefficient is kept at 0.42, an estimate 1.75-2.2 times the peak, until it is measured with plots and on finer
orthophotos, whose ground now has its own, coarser grid. These are the
current code's figures: re-measure them with the bench when the ground estimator or the readers
change.
"""

from __future__ import annotations

import math

from ..errors import CliffTerrainError

#: The default cap (GiB): what a 8 GB laptop can give one command. ``--max-memory`` changes it.
DEFAULT_CAP_GIB = 4.0
BASE_GIB = 0.25  # the interpreter, NumPy, OpenCV and the readers' libraries
READ_GIB_PER_MP = 0.03  # decoding a file, per megapixel of the file
GRID_GIB_PER_MP = 0.42  # measuring, per megapixel of the grid (0.37 measured)


def heights_estimate(files_mp, grid_mp):
    """Peak memory (GiB) of a heights run reading files of `files_mp` megapixels on a grid of `grid_mp`."""
    return BASE_GIB + READ_GIB_PER_MP * sum(files_mp) + GRID_GIB_PER_MP * grid_mp


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
    scale = min(1.0, longest / max(rows, cols))
    grid_mp = rows * cols * scale**2 / 1e6
    estimate = heights_estimate(files_mp, grid_mp)
    if estimate <= cap_gib:
        return estimate
    room = cap_gib - heights_estimate(files_mp, 0.0)
    what = (
        f"measuring {str(ortho)!r} ({cols} x {rows} pixels) on a {round(cols * scale)} x {round(rows * scale)} grid "
        f"needs about {estimate:.1f} GiB, more than the {cap_gib:g} GiB cap"
    )
    if room <= GRID_GIB_PER_MP * 0.01:
        raise CliffTerrainError(
            f"{what}, and reading the files alone needs {heights_estimate(files_mp, 0.0):.1f} GiB; crop or "
            "split the orthophoto and its DSM, or raise --max-memory"
        )
    fit = math.floor(max(rows, cols) * math.sqrt(room / GRID_GIB_PER_MP / (rows * cols / 1e6)))
    transform, _ = read_georeference(ortho)
    pixel = math.hypot(*transform[:2, 0])
    metres = pixel * max(rows, cols) / fit
    raise CliffTerrainError(
        f"{what}; use --max-size {fit} or --resolution {math.ceil(metres * 1000) / 1000:g} (metres per pixel), "
        "or raise --max-memory"
    )


# The windowed path (:mod:`cliff_terrain.measure.windowed`), measured with bench/bench_scale.py. Its
# two passes peak one after the other: the ground grid's (its photo, surface, soil and fit_ground;
# fit_ground alone measured 0.35 GiB/MP), then one window's with its halo (photo, index, surface,
# ground, CHM, plot labels) beside the coarse ground. The plots and their rows stay throughout.
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
    budget = max(10_000, min(MAX_GROUND_PIXELS, int((cap_gib - resident) / GROUND_GIB_PER_MP * 1e6)))
    factor = ground_factor((rows, cols), pixel, ground_pixels=budget)
    grid = math.ceil(rows / factor) * math.ceil(cols / factor)
    ground_gib = 12 * grid / 2**30  # the coarse ground, its error and support (12 bytes a pixel)
    # Pass 1 fits the ground here while each worker idles with its interpreter and striped files;
    # pass 2 holds the coarse ground here and in each worker, and one window per thread or worker.
    fit_pass = resident + GROUND_GIB_PER_MP * grid / 1e6 + workers * (BASE_GIB + striped)
    window_pass = resident + ground_gib + workers * (BASE_GIB + striped + ground_gib + window_gib)
    window_pass += (window_gib if workers == 0 else 0) + (max(1, threads) - 1) * (striped + window_gib)
    # Pass 3 writes the three rasters at once, each a band of 512-pixel tiles, its overview's and
    # tifffile's buffer of tiles waiting for compression (never more than the raster's own tiles).
    tiles_bytes = math.ceil(rows / COG_TILE) * math.ceil(cols / COG_TILE) * COG_TILE**2 * 4
    write_pass = resident + 3 * (2 * COG_TILE * cols * 4 + min(write_buffer_bytes(), tiles_bytes)) / 2**30
    estimate = max(fit_pass, window_pass, write_pass)
    if budget < min(MIN_GROUND_PIXELS, needed) or estimate > cap_gib:
        smallest = GROUND_GIB_PER_MP * min(MIN_GROUND_PIXELS, needed) / 1e6
        least = max(estimate, resident + window_gib + smallest)
        raise CliffTerrainError(
            f"measuring {str(ortho)!r} in windows needs about {least:.1f} GiB (one {window_px}-pixel window"
            f"{f' here and in each of {workers} workers' if workers else ''}, the files that are striped "
            f"decoded whole, and the ground's grid), more than the {cap_gib:g} GiB cap; raise --max-memory, "
            f"lower --window{', use fewer --workers' if workers else ''}, or tile the striped files "
            "(gdal_translate -co TILED=YES)"
        )
    return budget, estimate
