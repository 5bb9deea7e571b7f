"""Canopy height and plot tables of a whole trial in bounded memory: the orthophoto read in windows.

A breeding trial's orthophoto has 100 MP to 1 GP and 100 000 plots; :func:`measure_canopy` on the
whole grid needs about 0.4 GiB per megapixel. :func:`measure_windowed` needs the same per megapixel
of a bounded *ground grid* plus one window, whatever the orthophoto's size:

1. **The ground, on a coarse grid.** The orthophoto and the DSM (resampled bilinearly onto the
   orthophoto's pixels, as :func:`cliff_terrain.io.geotiff.resample` does) are read window by window
   and reduced by an integer `factor` to a grid of at most `ground_pixels` pixels, and no finer
   than `GROUND_PIXEL_M` (5 cm: the ground's finest detail is a Gaussian of 0.15 m): each
   `factor` x `factor` block gives the mean of its pixels with data or, when most of them are not
   plants, of those only, so that the plants in a block lift neither the soil it shows nor tint its
   colour. Plants are the blurred vegetation index above the photo's threshold
   (:func:`cliff_terrain.relief.vegetation.photo_threshold`), taken on an overview of the whole
   orthophoto (every n-th pixel, at most 4 MP: the orthophoto itself up to that size). On the
   coarse grid the bare soil (:func:`~cliff_terrain.relief.vegetation.bare_soil`, at that
   threshold) is taken as :func:`cliff_terrain.measure.canopy.measure_orthophoto` takes it, and
   :func:`cliff_terrain.measure.ground.fit_ground` fits and checks the ground (its held-out check,
   standard error and support) unchanged.
2. **The canopy, at full resolution.** Each window's DSM minus the ground bilinearly upsampled from
   the coarse grid (pixel centres aligned: full pixel ``i`` lies at coarse ``(i + 0.5) / factor -
   0.5``, held flat beyond the outer centres) is the CHM; it, the ground's standard error and its
   support are spooled window by window into tiled, Deflate GeoTIFFs with overviews
   (:mod:`cliff_terrain.io.geotiff_stream`). Plants are the blurred index above the same threshold
   (the rule of :func:`~cliff_terrain.measure.canopy.plant_mask`).
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

import math
from dataclasses import dataclass, field

import numpy as np

from .._validate import check_float, check_int
from ..errors import CliffTerrainError, GeoreferenceError, RasterReadError
from ..io.crs import crs_text
from ..io.transform import affine_inverse, apply_affine
from .ground import DEFAULT_BLOCK_M, canopy_height, fit_ground

#: The ground grid's finest pixel (metres): the ground's finest detail is a Gaussian of 0.15 m.
GROUND_PIXEL_M = 0.05
#: Default side (pixels) of a window's core; a multiple of the output's 512-pixel tiles.
WINDOW_PX = 2048
#: Default budget of the ground grid (pixels); :mod:`cliff_terrain.commands.memory_estimate` sets
#: it from ``--max-memory``.
GROUND_PIXELS = 6_000_000
# The blurred index's reach (pixels): cv2's Gaussian of sigma 1 on float32 has a 9-pixel kernel.
_BLUR_REACH = 4


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
    check : dict or None
        The ground's held-out check (:func:`cliff_terrain.measure.ground.fit_ground`).
    rows : list of dict or None
        The plot table, as :func:`cliff_terrain.measure.field_plots.plot_table` gives it.
    spools : dict
        Raster name (``"chm"``, ``"chm_err"``, ``"ground_support"``) ->
        :class:`~cliff_terrain.io.geotiff_stream.RasterSpool`.
    windows : int
        Number of windows measured.
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
    spools: dict = field(default_factory=dict)
    windows: int = 0
    plant_pixels: int = 0
    valid_pixels: int = 0

    def close(self):
        """Remove the spooled rasters."""
        for spool in self.spools.values():
            spool.close()


class SurfaceWindows:
    """A surface model GeoTIFF (DSM or DTM) read in windows: heights in metres, NaN for no data.

    The no-data rules are :func:`cliff_terrain.io.geotiff.read_surface`'s. A tiled file decodes
    only the TIFF tiles a window overlaps; a striped one is decoded whole once.
    """

    def __init__(self, path, *, what="surface model"):
        from ..io.geokeys import GDAL_NODATA, georeference, nodata_value
        from ..io.tiff_window import TiffRaster

        self.raster = TiffRaster(path)
        self.path = self.raster.path
        try:
            if self.raster.samples != 1:
                raise RasterReadError(f"{what} {self.path!r} has {self.raster.samples} bands, expected 1")
            self.transform, self.crs = georeference(self.raster.tags, self.path)
            self.nodata = nodata_value(self.raster.tags.get(GDAL_NODATA), self.path)
        except CliffTerrainError:
            self.raster.close()
            raise
        self.shape = self.raster.shape

    def close(self):
        self.raster.close()

    def read(self, r0, r1, c0, c1):
        """Heights [r0:r1, c0:c1] (float32, NaN for no data)."""
        from ..io.geotiff import _is_nodata

        raw = self.raster.read_window(r0, r1, c0, c1)[..., 0]
        data = raw.astype(np.float32, copy=True)
        invalid = ~np.isfinite(data)
        if self.nodata is not None:
            invalid |= _is_nodata(raw, self.nodata)
        data[invalid] = np.nan
        return data

    def on_grid(self, transform, r0, r1, c0, c1):
        """The surface bilinearly resampled onto pixels [r0:r1, c0:c1] of the grid `transform`."""
        m = _pixel_map(self.transform, transform, name=self.path)
        ys = m[1, 1] * np.arange(r0, r1, dtype=np.float64) + m[1, 2]
        xs = m[0, 0] * np.arange(c0, c1, dtype=np.float64) + m[0, 2]
        rows, cols = self.shape
        inside_y = (ys >= 0) & (ys <= rows - 1)
        inside_x = (xs >= 0) & (xs <= cols - 1)
        out = np.full((r1 - r0, c1 - c0), np.nan, np.float32)
        if not inside_y.any() or not inside_x.any():
            return out
        iy, ix = np.flatnonzero(inside_y), np.flatnonzero(inside_x)
        y, x = ys[iy], xs[ix]
        sr0, sr1 = int(np.floor(y.min())), min(rows, int(np.floor(y.max())) + 2)
        sc0, sc1 = int(np.floor(x.min())), min(cols, int(np.floor(x.max())) + 2)
        source = self.read(sr0, sr1, sc0, sc1)
        part = _bilinear(source, y - sr0, x - sc0)
        out[iy[0] : iy[-1] + 1, ix[0] : ix[-1] + 1] = part
        return out


def _pixel_map(source, target, *, name):
    """Target pixel index -> source pixel index (centres at integers), axis-aligned; refuses a rotation."""
    shift = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])
    unshift = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    m = unshift @ affine_inverse(source) @ np.asarray(target, np.float64) @ shift
    if abs(m[0, 1]) > 1e-12 * abs(m[0, 0]) or abs(m[1, 0]) > 1e-12 * abs(m[1, 1]):
        raise GeoreferenceError(
            f"{name!r} is rotated against the orthophoto's grid; the windowed measure needs north-up "
            "rasters: measure it without --windowed or warp it north-up"
        )
    return m


def _bilinear(source, y, x):
    """`source` at rows `y` x columns `x` (source pixel indices, inside it), separably bilinear.

    The weights come from the coordinates alone, so a pixel's value does not depend on the
    window it is computed in; NaN in any of the four neighbours gives NaN, as OpenCV's does.
    """
    rows, cols = source.shape
    y0 = np.floor(y).astype(np.int64)
    x0 = np.floor(x).astype(np.int64)
    fy = (y - y0).astype(np.float32)[:, None]
    fx = (x - x0).astype(np.float32)[None, :]
    y1, x1 = np.minimum(y0 + 1, rows - 1), np.minimum(x0 + 1, cols - 1)
    top, bottom = source[y0], source[y1]
    upper = top[:, x0] * (1 - fx) + top[:, x1] * fx
    lower = bottom[:, x0] * (1 - fx) + bottom[:, x1] * fx
    return (upper * (1 - fy) + lower * fy).astype(np.float32)


def upsample(coarse, factor, r0, r1, c0, c1):
    """Pixels [r0:r1, c0:c1] of the full grid, bilinear from `coarse` (`factor` full pixels per
    coarse pixel, centres aligned, held flat beyond the outer centres).

    Examples
    --------
    >>> upsample(np.array([[0.0, 2.0]], np.float32), 2, 0, 1, 0, 4).tolist()
    [[0.0, 0.5, 1.5, 2.0]]
    """
    if factor == 1:
        return np.asarray(coarse[r0:r1, c0:c1], np.float32).copy()
    rows, cols = coarse.shape
    y = np.clip((np.arange(r0, r1) + 0.5) / factor - 0.5, 0, rows - 1)
    x = np.clip((np.arange(c0, c1) + 0.5) / factor - 0.5, 0, cols - 1)
    return _bilinear(np.asarray(coarse, np.float32), y, x)


def ground_factor(shape, pixel_size, *, ground_pixels=GROUND_PIXELS):
    """Orthophoto pixels per ground-grid pixel: the grid within `ground_pixels`, no finer than 5 cm.

    Examples
    --------
    >>> ground_factor((20000, 20000), 0.01, ground_pixels=8_000_000)   # 400 MP at 1 cm: 8 cm
    8
    >>> ground_factor((535, 550), 0.2)                                 # a small field: its own grid
    1
    """
    rows, cols = shape
    by_detail = max(1, math.floor(GROUND_PIXEL_M / pixel_size + 1e-9))
    by_budget = max(1, math.ceil(math.sqrt(rows * cols / ground_pixels)))
    factor = max(by_detail, by_budget)
    while math.ceil(rows / factor) * math.ceil(cols / factor) > ground_pixels:
        factor += 1
    return factor


def windows(shape, size):
    """Core windows ``(r0, r1, c0, c1)`` of side `size` covering `shape`, row-major."""
    rows, cols = shape
    return [
        (r0, min(rows, r0 + size), c0, min(cols, c0 + size))
        for r0 in range(0, rows, size)
        for c0 in range(0, cols, size)
    ]


def _reduce(values, factor, weights):
    """Means of `factor` x `factor` blocks of `values` (rows, cols[, bands]) over `weights` (bool),
    and each block's count of weighted pixels (float32 sums: a block holds few pixels)."""
    rows, cols = weights.shape
    nr, nc = -(-rows // factor), -(-cols // factor)
    bands = values.shape[2:]
    w = np.zeros((nr * factor, nc * factor), np.float32)
    w[:rows, :cols] = weights
    v = np.zeros((nr * factor, nc * factor, *bands), np.float32)
    v[:rows, :cols] = values
    v[~(w > 0)] = 0  # NaN where there is no weight must not reach the sums
    v *= w.reshape(*w.shape, *([1] * len(bands)))
    counts = w.reshape(nr, factor, nc, factor).sum(axis=(1, 3))
    sums = v.reshape(nr, factor, nc, factor, *bands).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts.reshape(nr, nc, *([1] * len(bands)))
    return means, counts


class _Sources:
    """The orthophoto (in windows, :class:`cliff_terrain.io.mosaic.MosaicReader`), DSM and DTM."""

    def __init__(self, ortho, dsm, dtm):
        from ..io.mosaic import MosaicReader

        self.ortho = MosaicReader(ortho)
        self.opened = [self.ortho]
        try:
            if self.ortho.transform is None:
                raise RasterReadError(f"orthophoto {self.ortho.path!r} has no georeference")
            self.dsm = SurfaceWindows(dsm)
            self.opened.append(self.dsm)
            self.dtm = None
            if dtm is not None:
                self.dtm = SurfaceWindows(dtm, what="terrain model")
                self.opened.append(self.dtm)
            for surface in filter(None, (self.dsm, self.dtm)):
                if surface.crs != self.ortho.crs:
                    raise GeoreferenceError(
                        f"{surface.path!r} is in {crs_text(surface.crs)} but {self.ortho.path!r} is in "
                        f"{crs_text(self.ortho.crs)}; reproject one"
                    )
                _pixel_map(surface.transform, self.ortho.transform, name=surface.path)
        except BaseException:
            self.close()
            raise

    def close(self):
        for reader in self.opened:
            reader.close()

    def photo(self, r0, r1, c0, c1):
        rgb, valid = self.ortho.read(r0, r1, c0, c1)
        return rgb, (np.ones(rgb.shape[:2], bool) if valid is None else valid)


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
):
    """Measure an orthophoto of any size window by window: ground, CHM rasters and plot table.

    Parameters
    ----------
    ortho : path
        The orthophoto GeoTIFF (tiled, or striped up to
        :data:`cliff_terrain.io.mosaic.MAX_STRIPED_PIXELS`).
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
        Spread the second pass's windows over a Dask cluster (:func:`measure_window` as tasks,
        the coarse ground scattered to every worker once); the results are the same.

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
    ground_pixels = check_int("ground_pixels", ground_pixels, minimum=10_000)
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    step = progress or (lambda fraction, stage: None)
    sources = _Sources(ortho, dsm, dtm)
    try:
        return _measure(sources, plots, folder, block_m, ground_method, window, ground_pixels, step, client)
    finally:
        sources.close()


def _measure(sources, plots, folder, block_m, ground_method, window, ground_pixels, step, client):
    from ..io.geotiff_stream import RasterSpool
    from ..relief.vegetation import bare_soil, blurred_index, photo_threshold

    transform = sources.ortho.transform
    shape = sources.ortho.shape
    pixel_size = float(np.mean([np.hypot(*transform[:2, 0]), np.hypot(*transform[:2, 1])]))
    name = sources.ortho.path
    factor = ground_factor(shape, pixel_size, ground_pixels=ground_pixels)

    # 0. The plant/soil threshold, on an overview of the whole photo (every step-th pixel, <= 4 MP).
    overview, valid_o, _ = sources.ortho.overview()
    vi_o, index = blurred_index(overview)
    threshold = float(photo_threshold(vi_o, overview, index=index, valid=valid_o).threshold)
    del overview, valid_o, vi_o

    # 1. The coarse grid: photo, its valid pixels and the surface, reduced window by window. A block
    # mostly not plants gives the mean of those pixels only: the plants in it must not lift the soil
    # it shows (nor tint its colour), whatever the block's place against the rows.
    rows_c, cols_c = -(-shape[0] // factor), -(-shape[1] // factor)
    rgb_c = np.zeros((rows_c, cols_c, 3), np.uint8)
    valid_c = np.zeros((rows_c, cols_c), bool)
    dsm_c = np.full((rows_c, cols_c), np.nan, np.float32)
    side = max(factor, window // factor * factor)
    parts = windows(shape, side)
    reach = _BLUR_REACH + 2
    for k, (r0, r1, c0, c1) in enumerate(parts):
        surface = sources.dsm.on_grid(transform, r0, r1, c0, c1)
        cr, cc = r0 // factor, c0 // factor
        if factor == 1:
            rgb, valid = sources.photo(r0, r1, c0, c1)
            rgb_c[r0:r1, c0:c1], valid_c[r0:r1, c0:c1] = rgb, valid
            dsm_c[r0:r1, c0:c1] = np.where(valid, surface, np.nan)
        else:
            R0, R1, C0, C1 = (
                max(0, r0 - reach),
                min(shape[0], r1 + reach),
                max(0, c0 - reach),
                min(shape[1], c1 + reach),
            )
            rgb, valid = sources.photo(R0, R1, C0, C1)
            vi, _ = blurred_index(rgb, index=index)
            core = (slice(r0 - R0, r1 - R0), slice(c0 - C0, c1 - C0))
            rgb, valid, vi = rgb[core], valid[core], vi[core]
            bare = valid & (vi <= threshold)
            del vi
            colour, counts = _reduce(rgb, factor, valid)
            colour_bare, n_bare = _reduce(rgb, factor, bare)
            mostly_bare = n_bare * 2 > counts
            colour = np.where(mostly_bare[..., None], colour_bare, colour)
            heights, _ = _reduce(surface, factor, valid & np.isfinite(surface))
            heights_bare, _ = _reduce(surface, factor, bare & np.isfinite(surface))
            heights = np.where(mostly_bare & np.isfinite(heights_bare), heights_bare, heights)
            block = factor * factor
            n_r, n_c = counts.shape
            # A coarse pixel has data when most of its block has (the in-memory grid's nearest pixel).
            valid_c[cr : cr + n_r, cc : cc + n_c] = counts * 2 > block
            rgb_c[cr : cr + n_r, cc : cc + n_c] = np.clip(np.nan_to_num(colour) + 0.5, 0, 255).astype(
                np.uint8
            )
            dsm_c[cr : cr + n_r, cc : cc + n_c] = heights
        step(0.4 * (k + 1) / len(parts), "ground grid")
    has_data = valid_c & np.isfinite(dsm_c)
    if not has_data.any():
        raise GeoreferenceError(f"{sources.dsm.path!r} has no data where it overlaps {name!r}")
    plant_c = valid_c  # for the summary's cover, replaced by the full grid's below
    ground_c = support_c = sigma_c = None
    check = None
    if sources.dtm is None:
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
        )
        ground_c, support_c, sigma_c, check = fit.ground, fit.support, fit.sigma, fit.check
        del fit, soil_c
    del dsm_c, has_data, plant_c, valid_c

    # 2. and 3. The full grid, window by window: CHM, its error and support, and the plots.
    result = WindowedCanopy(
        transform, sources.ortho.crs, shape, pixel_size, "dtm" if sources.dtm else "estimated",
        factor, threshold, index, check,
    )  # fmt: skip
    names = ["chm"] + (["chm_err", "ground_support"] if ground_c is not None else [])
    result.spools = {n: RasterSpool(folder, n, shape) for n in names}
    try:
        ground = None if ground_c is None else (ground_c, sigma_c, support_c)
        _full_grid(sources, plots, window, result, ground, step, client)
    except BaseException:
        result.close()
        raise
    return result


def _plot_boxes(plots, transform):
    """Each plot's rings in global pixel coordinates and its bounding box (c0, r0, c1, r1), pixels."""
    inverse = affine_inverse(transform)
    rings = [[apply_affine(inverse, ring) for ring in polygon] for polygon in plots.polygons]
    boxes = np.array(
        [
            (*np.concatenate(r).min(axis=0), *np.concatenate(r).max(axis=0)) if r else (np.nan,) * 4
            for r in rings
        ],
        np.float64,
    ).reshape(-1, 4)
    return rings, boxes


def window_halo(plots, transform):
    """Pixels a window is read beyond its core: the blur's reach, and half the largest plot's extent
    (each plot belongs to the window holding its centre, so it lies whole in the window read)."""
    halo = _BLUR_REACH + 2
    if plots is None or not len(plots):
        return halo
    _, boxes = _plot_boxes(plots, transform)
    extent = np.nan_to_num(np.maximum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]))
    return halo + math.ceil(float(extent.max(initial=0.0)) / 2) + 1


@dataclass
class WindowTask:
    """One window of the second pass: everything it needs but the coarse ground (picklable, so a
    Dask worker can run it: :func:`measure_window`)."""

    ortho: str
    dsm: str
    dtm: str | None
    transform: np.ndarray
    shape: tuple
    factor: int
    index: str
    threshold: float
    core: tuple  # (r0, r1, c0, c1)
    read: tuple  # (R0, R1, C0, C1): the core and its halo, inside the grid
    # The plots touching the window (file order), in pixels of the window read, and in map units.
    plot_ids: np.ndarray | None = None
    pixel_rings: list | None = None
    polygons: list | None = None
    attributes: list | None = None
    fields: tuple = ()
    plots_path: str = ""
    mine: np.ndarray | None = None  # the plots whose centre the core holds


def measure_window(task, ground=None, *, sources=None):
    """The CHM, its error and support on `task`'s core, and the rows of the plots it owns.

    `ground` is ``(ground, sigma, support)`` on the coarse grid, or None with a terrain model.
    `sources` (open readers) default to opening `task`'s files. Returns a dict: ``core``, the
    rasters ``chm``, ``chm_err``, ``ground_support`` (the latter two without a DTM) on the core,
    ``rows`` {plot index: row}, ``valid_pixels``, ``plant_pixels`` and ``labelled`` (a plot
    pixel was burnt).
    """
    from ..io.plot_polygons import PlotSet
    from ..relief.vegetation import blurred_index
    from .field_plots import plot_table, rasterize_plots

    own = sources is None
    if own:
        sources = _Sources(task.ortho, task.dsm, task.dtm)
    try:
        r0, r1, c0, c1 = task.core
        R0, R1, C0, C1 = task.read
        transform, factor = task.transform, task.factor
        rgb, valid = sources.photo(R0, R1, C0, C1)
        vi, _ = blurred_index(rgb, index=task.index)
        del rgb
        plants = (vi > task.threshold) & valid
        del vi
        surface = sources.dsm.on_grid(transform, R0, R1, C0, C1)
        if ground is None:
            heights = sources.dtm.on_grid(transform, R0, R1, C0, C1)
            sigma = support = None
        else:
            heights = upsample(ground[0], factor, R0, R1, C0, C1)
            sigma = upsample(ground[1], factor, R0, R1, C0, C1)
            support = upsample(ground[2], factor, R0, R1, C0, C1)
    finally:
        if own:
            sources.close()
    chm = canopy_height(surface, heights)
    del surface, heights
    chm[~valid] = np.nan
    core = (slice(r0 - R0, r1 - R0), slice(c0 - C0, c1 - C0))
    core_valid = valid[core] & np.isfinite(chm[core])
    out = {
        "core": task.core,
        "chm": chm[core].copy(),
        "valid_pixels": int(np.count_nonzero(core_valid)),
        "plant_pixels": int(np.count_nonzero(plants[core] & core_valid)),
        "rows": {},
        "labelled": False,
    }
    if sigma is not None:
        out["chm_err"], out["ground_support"] = sigma[core].copy(), support[core].copy()
    if task.mine is not None and task.mine.size:
        n = len(task.plot_ids)
        local = PlotSet(task.pixel_rings, [{}] * n, (), None, task.plots_path)
        labels = rasterize_plots(local, transform=np.eye(3), shape=chm.shape)
        out["labelled"] = bool(labels.any())
        subset = PlotSet(task.polygons, task.attributes, task.fields, None, task.plots_path)
        table = plot_table(
            subset,
            labels,
            mask=plants,
            heights=chm,
            pixel_area_m2=float(abs(np.linalg.det(transform[:2, :2]))),
            support=np.ones(chm.shape, np.float32) if support is None else support,
            sigma=np.zeros(chm.shape, np.float32) if sigma is None else sigma,
        )
        wanted = set(task.mine.tolist())
        for i, row in zip(task.plot_ids.tolist(), table, strict=True):
            if i in wanted:
                row["plot"] = i
                out["rows"][i] = row
    return out


def window_tasks(sources, plots, window, result):
    """The second pass's :class:`WindowTask` s, row-major."""
    transform, shape = result.transform, result.shape
    rows, cols = shape
    halo = window_halo(plots, transform)
    if plots is not None:
        pixel_rings, boxes = _plot_boxes(plots, transform)
        # Each plot to the window holding its centre (clipped to the grid: a plot outside it
        # measures nothing, as on the whole grid).
        centre_r = np.clip(np.nan_to_num((boxes[:, 1] + boxes[:, 3]) / 2), 0, rows - 1)
        centre_c = np.clip(np.nan_to_num((boxes[:, 0] + boxes[:, 2]) / 2), 0, cols - 1)
        across = -(-cols // window)
        owner = (centre_r // window).astype(np.int64) * across + (centre_c // window).astype(np.int64)
    dtm = None if sources.dtm is None else sources.dtm.path
    for k, (r0, r1, c0, c1) in enumerate(windows(shape, window)):
        R0, R1 = max(0, r0 - halo), min(rows, r1 + halo)
        C0, C1 = max(0, c0 - halo), min(cols, c1 + halo)
        task = WindowTask(
            sources.ortho.path, sources.dsm.path, dtm, transform, shape, result.factor, result.index,
            result.threshold, (r0, r1, c0, c1), (R0, R1, C0, C1),
        )  # fmt: skip
        if plots is not None:
            mine = np.flatnonzero(owner == k)
            if mine.size:
                # Every plot touching the window, in file order: overlaps resolve as on the whole grid.
                touching = np.flatnonzero(
                    (boxes[:, 2] >= C0) & (boxes[:, 0] <= C1) & (boxes[:, 3] >= R0) & (boxes[:, 1] <= R1)
                )
                touching = np.union1d(touching, mine)
                task.plot_ids, task.mine = touching, mine
                task.pixel_rings = [[ring - (C0, R0) for ring in pixel_rings[i]] for i in touching]
                task.polygons = [plots.polygons[i] for i in touching]
                task.attributes = [plots.attributes[i] for i in touching]
                task.fields, task.plots_path = plots.fields, plots.path
        yield task


def _full_grid(sources, plots, window, result, ground, step, client=None):
    tasks = window_tasks(sources, plots, window, result)  # made as they are taken: plots stay single
    count = len(windows(result.shape, window))
    if client is None:
        outputs = (measure_window(task, ground, sources=sources) for task in tasks)
    else:
        from .._dask import in_order

        shared = None if ground is None else client.scatter(ground, broadcast=True)
        ahead = max(2, len(client.scheduler_info().get("workers", {})) + 1)
        outputs = in_order(client, measure_window, ((task, shared) for task in tasks), ahead=ahead)
    rows_out = [None] * len(plots) if plots is not None else None
    labelled = False
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
        result.windows += 1
        step(0.45 + 0.5 * (k + 1) / count, "canopy and plots")
    if plots is not None:
        if not labelled:
            raise GeoreferenceError(
                f"no plot of {plots.path!r} overlaps the orthophoto {sources.ortho.path!r}"
            )
        result.rows = rows_out
