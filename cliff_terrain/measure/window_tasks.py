"""The windows of :mod:`cliff_terrain.measure.windowed` as self-contained tasks: what one window
needs, picklable, so that the same function runs in this process or on a Dask worker.

- :class:`OverviewTask` / :func:`overview_band`: a band of the orthophoto's overview, on which the
  plant/soil threshold is taken.
- :class:`CoarseTask` / :func:`coarse_window`: the first pass, one window of the orthophoto and
  its DSM reduced to the ground grid.
- :class:`WindowTask` / :func:`measure_window`: the second pass, one window's CHM, its error and
  support at full resolution, and the rows of the plots whose centre it holds.

A task names its files by path: a cluster's workers must see them at the same paths (a shared
disk), as a season's dates. Each worker thread keeps its readers open from one task to the next
(:func:`worker_sources`): a striped DSM is decoded whole once per worker, not once per window.
"""

from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass

import numpy as np

from ..photo_heights.vegetation import BLUR_REACH
from .field_plots import pixel_vertices, table_columns
from .ground import canopy_height, surface_data
from .ground_grid import reduce_for_ground
from .window_reading import WindowSources, upsample, windows

_LOCAL = threading.local()


def worker_sources(ortho, dsm, dtm, scale=None):
    """This thread's open :class:`~cliff_terrain.measure.window_reading.WindowSources` of the three
    files (the orthophoto's sample `scale` given), reopened when a path, size or modification time
    changes (the previous ones closed)."""

    def stamp(path):
        if path is None:
            return None
        s = os.stat(path)
        return (str(path), s.st_size, s.st_mtime_ns)

    key = (stamp(ortho), stamp(dsm), stamp(dtm), scale)
    held = getattr(_LOCAL, "sources", None)
    if held is None or held[0] != key:
        if held is not None:
            held[1].close()
        _LOCAL.sources = None
        _LOCAL.sources = (key, WindowSources(ortho, dsm, dtm, scale=scale))
    return _LOCAL.sources[1]


def close_worker_sources():
    """Close this thread's readers (:func:`worker_sources`)."""
    held = getattr(_LOCAL, "sources", None)
    if held is not None:
        held[1].close()
        _LOCAL.sources = None


@dataclass
class OverviewTask:
    """One band of rows of the orthophoto's overview (picklable: :func:`overview_band`)."""

    ortho: str
    dsm: str
    rows: tuple  # (r0, r1)
    step: int


def overview_band(task, *, sources=None):
    """:meth:`cliff_terrain.io.raster.mosaic.MosaicReader.overview_band` of `task`'s rows."""
    if sources is None:
        sources = worker_sources(task.ortho, task.dsm, None)
    return sources.ortho.overview_band(*task.rows, task.step)


@dataclass
class CoarseTask:
    """One window of the first pass (picklable: :func:`coarse_window`)."""

    ortho: str
    dsm: str
    transform: np.ndarray
    shape: tuple
    factor: int
    index: str
    threshold: float
    core: tuple  # (r0, r1, c0, c1), multiples of factor but at the grid's end
    # The whole photo's soil class's upper limit (bare_soil.soil_ceiling), for ``factor`` > 1.
    soil_ceiling: float = float("inf")
    scale: float | None = None  # the orthophoto's sample scale (io.raster.photo_samples.sample_scale)


def coarse_window(task, *, sources=None):
    """`task`'s window reduced to the ground grid: ``{"at": (row, col), "valid", "dsm"}`` and, with
    ``factor`` 1, the window's own ``rgb`` (the bare soil is then taken on the whole grid, as in
    memory), else the blocks that show bare ``soil``.

    Each ``factor`` x ``factor`` block gives the mean height of its bare-soil pixels when it shows
    any, so that the plants in a block do not lift the soil it shows, and the mean of its pixels
    with data when it shows none; a block has data when most of its pixels inside the raster have
    (:func:`~cliff_terrain.measure.ground_grid.reduce_for_ground`, as in memory). Bare soil is
    what :func:`~cliff_terrain.photo_heights.bare_soil.bare_soil` calls it on the whole photo:
    the blurred index at or below the threshold and at or below the whole photo's
    ``soil_ceiling``, so that shaded, yellowing or senescent leaves below the plant threshold
    neither lift a block's soil nor count as the ground's evidence. Any soil, not most: the full
    grid takes every bare pixel as the ground's evidence, and a share threshold aliases with the
    crop rows (a block holds more or less than half soil depending on where it falls on them):
    copies of one plot on a tiled trial measured 3.1 cm apart (the interquartile range of their
    p90) on a 1.6 m grid with "most", 1.9 cm with "any", 1.25 cm with "any" of bare_soil's soil
    (`bench/bench_coarse_grid.py`).
    """
    from ..photo_heights.vegetation import blurred_index

    if sources is None:
        sources = worker_sources(task.ortho, task.dsm, None, task.scale)
    factor, shape = task.factor, task.shape
    r0, r1, c0, c1 = task.core
    surface = sources.dsm.on_grid(task.transform, r0, r1, c0, c1)
    at = (r0 // factor, c0 // factor)
    if factor == 1:
        rgb, valid = sources.photo(r0, r1, c0, c1)
        return {"at": at, "rgb": rgb, "valid": valid, "dsm": np.where(valid, surface, np.float32(np.nan))}
    reach = BLUR_REACH + 2
    R0, R1 = max(0, r0 - reach), min(shape[0], r1 + reach)
    C0, C1 = max(0, c0 - reach), min(shape[1], c1 + reach)
    rgb, valid = sources.photo(R0, R1, C0, C1)
    vi, _ = blurred_index(rgb, index=task.index)
    del rgb
    core = (slice(r0 - R0, r1 - R0), slice(c0 - C0, c1 - C0))
    valid, vi = valid[core], vi[core]
    bare = valid & (vi <= task.threshold) & (vi <= task.soil_ceiling)
    del vi
    # The in-memory path's reduction, on its pixels with data: the photo's where the DSM has a
    # surface (a block half off the DSM has no data, as in memory, not the mean of its other half).
    heights, soil, data = reduce_for_ground(surface, bare, valid & surface_data(surface), factor)
    return {"at": at, "valid": data, "soil": soil, "dsm": heights}


def coarse_tasks(sources, shape, transform, factor, index, threshold, window, *, soil_ceiling=float("inf")):
    """The first pass's :class:`CoarseTask` s, row-major, each about `window` pixels a side."""
    side = max(factor, window // factor * factor)
    return [
        CoarseTask(
            sources.ortho.path,
            sources.dsm.path,
            transform,
            shape,
            factor,
            index,
            threshold,
            core,
            soil_ceiling,
            sources.ortho.scale,
        )
        for core in windows(shape, side)
    ]


def _plot_boxes(plots, transform):
    """Each plot's rings in global pixel coordinates and its bounding box (c0, r0, c1, r1), pixels."""
    counts = np.fromiter(map(len, plots.polygons), np.int64, len(plots.polygons))
    boxes = np.full((len(counts), 4), np.nan)
    points, sizes = pixel_vertices(plots.polygons, transform)
    if not sizes.size:
        return [[] for _ in counts], boxes
    # One min and max per plot over its vertices (a loop of numpy calls per plot took 1.7 s of
    # 130 000 plots, twice a run).
    pieces = np.split(points, np.cumsum(sizes)[:-1])
    first = np.cumsum(counts) - counts
    rings = [pieces[k : k + n] for k, n in zip(first.tolist(), counts.tolist(), strict=True)]
    vertices = np.add.reduceat(sizes, first[counts > 0])  # of each plot with a ring
    has = np.flatnonzero(counts > 0)[vertices > 0]  # plots with at least one vertex
    starts = (np.cumsum(vertices) - vertices)[vertices > 0]
    boxes[has, :2] = np.minimum.reduceat(points, starts, axis=0)
    boxes[has, 2:] = np.maximum.reduceat(points, starts, axis=0)
    return rings, boxes


def window_halo(plots, transform):
    """Pixels a window is read beyond its core: the blur's reach, and half the largest plot's extent
    (each plot belongs to the window holding its centre, so it lies whole in the window read)."""
    if plots is None or not len(plots):
        return BLUR_REACH + 2
    return _halo(_plot_boxes(plots, transform)[1])


def _halo(boxes):
    halo = BLUR_REACH + 2
    extent = np.nan_to_num(np.maximum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]))
    return halo + math.ceil(float(extent.max(initial=0.0)) / 2) + 1


@dataclass
class PackedRings:
    """Plots' rings in one (points, 2) array, as a task carries them: pickled (to a Dask worker) as
    three arrays, not one per ring (a window of 500 plots held a thousand, the most of the
    client's work in sending it).

    Examples
    --------
    >>> square = np.array([[0.0, 0], [1, 0], [1, 1], [0, 0]])
    >>> packed = PackedRings.pack([[square], [square + 5, square + 7]], offset=(5, 5))
    >>> [[ring.tolist()[1] for ring in plot] for plot in packed.unpack()]
    [[[-4.0, -5.0]], [[1.0, 0.0], [3.0, 2.0]]]
    """

    points: np.ndarray
    ring_ends: np.ndarray  # each ring's end in `points`
    plot_ends: np.ndarray  # each plot's end in the rings

    @classmethod
    def pack(cls, polygons, *, offset=(0.0, 0.0)):
        """`polygons` (a list of plots, each a list of (n, 2) rings) with `offset` subtracted."""
        rings = [ring for polygon in polygons for ring in polygon]
        points = np.concatenate(rings) if rings else np.zeros((0, 2))
        if offset != (0.0, 0.0):
            points = points - offset  # elementwise: each point as ``ring - offset`` gives it
        return cls(
            points,
            np.cumsum([len(ring) for ring in rings], dtype=np.int64),
            np.cumsum([len(polygon) for polygon in polygons], dtype=np.int64),
        )

    def unpack(self):
        """The list of plots, each a list of rings (views into :attr:`points`)."""
        rings = np.split(self.points, self.ring_ends[:-1]) if self.ring_ends.size else []
        starts = np.concatenate([[0], self.plot_ends[:-1]]).astype(np.int64)
        return [rings[a:b] for a, b in zip(starts.tolist(), self.plot_ends.tolist(), strict=True)]


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
    pixel_rings: PackedRings | None = None
    polygons: PackedRings | None = None
    attributes: list | None = None
    fields: tuple = ()
    plots_path: str = ""
    mine: np.ndarray | None = None  # the plots whose centre the core holds
    # The rasters come back encoded to this many levels (geotiff_stream.encode_block): the core is
    # whole output tiles (and its overview's whole tiles, for each level beyond the first).
    encode: int = 0
    # The plot table's columns: the rows come back with their CSV lines and GeoJSON features too.
    columns: list | None = None
    # The resolution check's box (measure.resolution_check.doubled_box): its plots' p90 come back
    # on the canopy height smoothed by it too.
    doubled_box: int = 0
    scale: float | None = None  # the orthophoto's sample scale (io.raster.photo_samples.sample_scale)


def measure_window(task, ground=None, *, sources=None):
    """The CHM, its error and support on `task`'s core, and the rows of the plots it owns.

    `ground` is ``(ground, sigma, support)`` on the coarse grid, or None with a terrain model.
    `sources` (open readers) default to this thread's readers of `task`'s files
    (:func:`worker_sources`). Returns a dict: ``core``, the rasters ``chm``, ``chm_err``,
    ``ground_support`` (the latter two without a DTM) on the core (arrays, or with ``task.encode``
    :func:`~cliff_terrain.io.raster.geotiff_stream.encode_block` dicts), ``rows`` {plot index:
    row}, with ``task.columns`` also ``csv`` and ``features`` {plot index: the row's CSV line,
    its GeoJSON Feature text}, ``valid_pixels``, ``plant_pixels`` and ``labelled`` (a plot pixel
    was burnt).
    """
    from ..io.vector.plot_polygons import PlotSet
    from ..photo_heights.vegetation import blurred_index
    from .field_plots import plot_layers, plot_table

    if sources is None:
        sources = worker_sources(task.ortho, task.dsm, task.dtm, task.scale)
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
    if task.encode:  # compressed here, on every worker at once, not by the one process writing
        from ..io.raster.geotiff_stream import encode_block

        for name in ("chm", "chm_err", "ground_support"):
            if name in out:
                out[name] = encode_block(out[name], levels=task.encode)
    if task.mine is not None and task.mine.size:
        n = len(task.plot_ids)
        local = PlotSet(task.pixel_rings.unpack(), [{}] * n, (), None, task.plots_path)
        labels = plot_layers(local, transform=np.eye(3), shape=chm.shape)
        out["labelled"] = any(layer.any() for layer in labels)
        polygons = task.polygons.unpack()
        subset = PlotSet(polygons, task.attributes, task.fields, None, task.plots_path)
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
        if task.doubled_box:
            from .resolution_check import box_mean, plot_p90s

            doubled = plot_p90s(labels, box_mean(chm, task.doubled_box), n)
            ids = task.plot_ids.tolist()
            out["p90_doubled"] = {i: float(v) for i, v in zip(ids, doubled, strict=True) if i in wanted}
        if task.columns is not None:  # the tables' text, made here on every worker at once
            from ..io.vector.geojson import feature_texts, polygon_geometry
            from .tables import csv_lines

            mine = [j for j, i in enumerate(task.plot_ids.tolist()) if i in wanted]
            ids = [int(task.plot_ids[j]) for j in mine]
            rows = [out["rows"][i] for i in ids]
            geometries = [polygon_geometry(polygons[j]) for j in mine]
            out["csv"] = dict(zip(ids, csv_lines(rows, task.columns), strict=True))
            out["features"] = dict(zip(ids, feature_texts(rows, geometries), strict=True))
    return out


def encoded_windows(window):
    """How many levels of the output rasters windows of side `window` give encoded (0: none, the
    rasters come back as arrays; :func:`~cliff_terrain.io.raster.geotiff_stream.encoded_levels`):
    their cores are then whole output tiles (:class:`~cliff_terrain.io.raster.geotiff_stream.TileSpool`)."""
    from ..io.raster.geotiff_stream import encoded_levels

    return encoded_levels(window)


def window_tasks(sources, plots, window, result):
    """The second pass's :class:`WindowTask` s, row-major."""
    transform, shape = result.transform, result.shape
    rows, cols = shape
    halo = window_halo(None, transform)
    if plots is not None:
        pixel_rings, boxes = _plot_boxes(plots, transform)
        if len(plots):
            halo = _halo(boxes)  # window_halo's, from the boxes made once
        # Each plot to the window holding its centre (clipped to the grid: a plot outside it
        # measures nothing, as on the whole grid).
        centre_r = np.clip(np.nan_to_num((boxes[:, 1] + boxes[:, 3]) / 2), 0, rows - 1)
        centre_c = np.clip(np.nan_to_num((boxes[:, 0] + boxes[:, 2]) / 2), 0, cols - 1)
        across = -(-cols // window)
        owner = (centre_r // window).astype(np.int64) * across + (centre_c // window).astype(np.int64)
    dtm = None if sources.dtm is None else sources.dtm.path
    columns = None if plots is None else table_columns(plots, support=True, sigma=True)
    box = 0
    if plots is not None:
        from .resolution_check import doubled_box, pixel_metres

        box = doubled_box(pixel_metres(transform), pixel_metres(sources.dsm.transform))
        halo += box  # the smoothing reaches this far beyond a plot: as on the whole grid
    for k, (r0, r1, c0, c1) in enumerate(windows(shape, window)):
        R0, R1 = max(0, r0 - halo), min(rows, r1 + halo)
        C0, C1 = max(0, c0 - halo), min(cols, c1 + halo)
        task = WindowTask(
            sources.ortho.path, sources.dsm.path, dtm, transform, shape, result.factor, result.index,
            result.threshold, (r0, r1, c0, c1), (R0, R1, C0, C1), encode=encoded_windows(window),
            scale=sources.ortho.scale,
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
                task.pixel_rings = PackedRings.pack([pixel_rings[i] for i in touching], offset=(C0, R0))
                task.polygons = PackedRings.pack([plots.polygons[i] for i in touching])
                task.attributes = [plots.attributes[i] for i in touching]
                task.fields, task.plots_path = plots.fields, plots.path
                task.columns = columns
                task.doubled_box = box
        yield task
