"""Field plots burnt into a raster, and their height table.

:func:`rasterize_plots` turns plot polygons (:func:`cliff_terrain.io.vector.plot_polygons.read_plots`)
into a label image on a raster's grid (pixel centres inside a polygon, even-odd rule, so holes and
multi-part plots work), and :func:`plot_table` gives one row per plot. Transforms map pixel
(col, row) to map (x, y), GDAL's convention (see :mod:`cliff_terrain.io.raster.transform`).
"""

from __future__ import annotations

import math

import numpy as np

from .._validate import check_choice, check_float
from ..errors import CliffTerrainError, GeoreferenceError
from ..io.raster.crs import crs_text
from ..io.raster.transform import affine_inverse, apply_affine, as_affine
from ..io.vector.plot_polygons import polygon_area
from .index_figures import index_columns, index_figures

# Metric statistics of a plot, in the order of the table's columns.
HEIGHT_COLUMNS = ("height_mean_m", "height_p50_m", "height_p90_m", "height_p99_m", "height_max_m")
PLOT_COLUMNS = ("plot", "area_m2", "cover", *HEIGHT_COLUMNS, "volume_m3", "error")
HEIGHT_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def check_plot_crs(plots, crs, *, raster):
    """Refuse plots that do not use the raster's CRS (`crs`, read from file `raster`): another EPSG
    code, or a user-defined CRS that does not agree (:class:`cliff_terrain.io.raster.crs.UserCrs`).

    Plots that declare no CRS are taken to be in the raster's, unless their coordinates all look
    like longitude/latitude while the raster's are projected (GeoJSON without a ``crs`` is WGS 84).
    """
    if plots.crs is not None and crs is not None and plots.crs != crs:
        raise GeoreferenceError(
            f"plot file {plots.path!r} is in {crs_text(plots.crs)} but raster {raster!r} is in {crs_text(crs)}; "
            "reproject the plots to the raster's CRS"
        )
    # Only against an EPSG CRS: a user-defined one centred on its field (an R export's AEQD) has map
    # coordinates of a few metres, which look like degrees, and its plots' GeoJSON carries no CRS.
    if plots.crs is None and isinstance(crs, int) and crs != 4326:
        points = np.concatenate([ring for rings in plots.polygons for ring in rings])
        if np.all(np.abs(points[:, 0]) <= 180) and np.all(np.abs(points[:, 1]) <= 90):
            raise GeoreferenceError(
                f"plot file {plots.path!r} declares no CRS and looks like longitude/latitude, but raster "
                f"{raster!r} is in {crs_text(crs)}; save the plots in the raster's CRS"
            )


def rasterize_plots(plots, *, transform, shape):
    """Burn plots into a label image on a raster's grid.

    A pixel belongs to a plot when its centre lies inside the plot (even-odd rule over all its
    rings, so holes stay out). Where plots overlap, the later one in the file wins.

    Parameters
    ----------
    plots : PlotSet
    transform : (2, 3) or (3, 3) array
        Pixel (col, row) -> map (x, y) affine of the raster; (0, 0) is the top-left pixel's
        top-left corner (GDAL's convention, see the module's docs).
    shape : (int, int)
        (rows, cols) of the raster.

    Returns
    -------
    (rows, cols) int32 array
        0 outside every plot, ``i + 1`` inside plot ``i``.

    Examples
    --------
    >>> square = [np.array([[1.0, -1.0], [3.0, -1.0], [3.0, -3.0], [1.0, -3.0]])]
    >>> from cliff_terrain.io.vector.plot_polygons import PlotSet
    >>> plots = PlotSet([square], [{}], (), None, "")
    >>> rasterize_plots(plots, transform=[[1, 0, 0], [0, -1, 0]], shape=(4, 4))
    array([[0, 0, 0, 0],
           [0, 1, 1, 0],
           [0, 1, 1, 0],
           [0, 0, 0, 0]], dtype=int32)
    """
    t = as_affine(transform)
    rows, cols = (int(n) for n in shape)
    if rows < 1 or cols < 1:
        raise CliffTerrainError(f"`shape` must be (rows, cols) >= 1, got {tuple(shape)}")
    return _burn(plots.polygons, np.arange(1, len(plots.polygons) + 1), t, (rows, cols))[0]


def plot_layers(plots, *, transform, shape):
    """The plots burnt into as few label images as hold each of them whole: overlapping plots (a
    buffer reaching into the neighbour, a layer exported twice) in different ones.

    :func:`rasterize_plots` gives an overlap's pixels to the later plot: the earlier lost them, and a
    plot a later copy covers lost all of them. Here the first image is :func:`rasterize_plots`'s,
    without the plots that lost pixels in it. Those are coloured greedily so that no two whose
    boxes overlap share a colour, and each colour is burnt into an image of its own: a grid whose
    every plot reaches into its neighbours takes a handful (its boxes' overlaps), not one image
    per plot. Without overlaps, that is the one image. :func:`plot_table` takes the list.

    Returns
    -------
    list of (rows, cols) int32 arrays
        ``i + 1`` where plot ``i`` is, in exactly one of them (0 elsewhere); the one image where no
        plot overlaps another.

    Examples
    --------
    >>> from cliff_terrain.io.vector.plot_polygons import PlotSet
    >>> square = [np.array([[0.0, 0.0], [2.0, 0.0], [2.0, -2.0], [0.0, -2.0]])]
    >>> layers = plot_layers(PlotSet([square, square], [{}, {}], (), None, ""), transform=[[1, 0, 0], [0, -1, 0]], shape=(2, 3))
    >>> [layer.tolist() for layer in layers]
    [[[2, 2, 0], [2, 2, 0]], [[1, 1, 0], [1, 1, 0]]]
    """
    t = as_affine(transform)
    rows, cols = (int(n) for n in shape)
    if rows < 1 or cols < 1:
        raise CliffTerrainError(f"`shape` must be (rows, cols) >= 1, got {tuple(shape)}")
    polygons = plots.polygons
    numbers = np.arange(1, len(polygons) + 1)
    labels, whole = _burn(polygons, numbers, t, (rows, cols))
    kept = np.bincount(labels.ravel(), minlength=len(polygons) + 1)[1:]
    lost = numbers[kept < whole]
    if not lost.size:
        return [labels]
    labels[np.isin(labels, lost)] = 0
    colour = _box_colours([polygons[k - 1] for k in lost], t)
    layers = [labels]
    for c in range(int(colour.max()) + 1):
        group = lost[colour == c]
        layers.append(_burn([polygons[k - 1] for k in group], group, t, (rows, cols))[0])
    return layers


def _box_colours(polygons, t):
    """A colour (0, 1, ...) for each polygon, greedy in their order, that no polygon whose pixel box
    overlaps its own has: polygons of one colour share no pixel."""
    points, sizes = pixel_vertices(polygons, t)
    rings = np.array([len(polygon) for polygon in polygons])
    first = (np.cumsum(sizes) - sizes)[np.cumsum(rings) - rings]  # each polygon's first vertex
    x0, x1 = np.minimum.reduceat(points[:, 0], first), np.maximum.reduceat(points[:, 0], first)
    y0, y1 = np.minimum.reduceat(points[:, 1], first), np.maximum.reduceat(points[:, 1], first)
    cell = max(1.0, float(np.median(np.maximum(x1 - x0, y1 - y0))))
    grid = {}  # (cell column, cell row) -> polygons already coloured whose box reaches it
    colour = np.zeros(len(polygons), np.int64)
    for i in range(len(polygons)):
        cells = [
            (a, b)
            for a in range(int(x0[i] // cell), int(x1[i] // cell) + 1)
            for b in range(int(y0[i] // cell), int(y1[i] // cell) + 1)
        ]
        near = {j for key in cells for j in grid.get(key, ())}
        used = {
            int(colour[j])
            for j in near
            if x0[i] < x1[j] and x0[j] < x1[i] and y0[i] < y1[j] and y0[j] < y1[i]
        }
        colour[i] = next(c for c in range(len(used) + 1) if c not in used)
        for key in cells:
            grid.setdefault(key, []).append(i)
    return colour


def _burn(polygons, numbers, t, shape):
    """(labels, pixels): `polygons` burnt with their `numbers` (ascending; a higher one wins an
    overlap) on a grid of `shape` whose pixel -> map affine is `t`, and each one's own pixel count
    (what it would cover alone)."""
    rows, cols = shape
    owners = np.repeat(np.asarray(numbers, np.int64), [len(polygon) for polygon in polygons])
    labels = np.zeros((rows, cols), dtype=np.int32)
    whole = np.zeros(len(polygons), np.int64)
    points, sizes = pixel_vertices(polygons, t)
    if not sizes.size:
        return labels, whole
    starts = np.cumsum(sizes) - sizes
    # Plots in batches of about _BURN_PIXELS pixels of bounding box (a plot's rings together), so
    # that the runs' pixel indices stay a few tens of MB however much of a large grid the plots cover.
    span_y = np.maximum.reduceat(points[:, 1], starts) - np.minimum.reduceat(points[:, 1], starts)
    span_x = np.maximum.reduceat(points[:, 0], starts) - np.minimum.reduceat(points[:, 0], starts)
    area = np.minimum(span_y + 1, rows) * np.minimum(span_x + 1, cols)
    batch = (np.cumsum(area) // _BURN_PIXELS).astype(np.int64)
    batch = batch[np.searchsorted(owners, owners)]  # each ring in its plot's first ring's batch
    position = {int(k): i for i, k in enumerate(numbers)}
    for r0, r1 in zip(*_runs(batch), strict=True):
        v0, v1 = starts[r0], starts[r1 - 1] + sizes[r1 - 1]
        for owner, count in _burn_even_odd(labels, points[v0:v1], sizes[r0:r1], owners[r0:r1]).items():
            whole[position[owner]] += count
    return labels, whole


_BURN_PIXELS = 1 << 22


def pixel_vertices(polygons, transform):
    """(points, sizes): every ring of `polygons` (lists of (n, 2) map rings) in the pixel coordinates
    of `transform` (pixel -> map), one after another, and each ring's vertex count.

    One affine over every vertex: row by row the numbers each ring alone gives, without a loop of
    numpy calls per ring. :func:`rasterize_plots` and the windows' plot boxes both start here.
    """
    rings = [ring for polygon in polygons for ring in polygon]
    if not rings:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    points = apply_affine(affine_inverse(transform), np.concatenate(rings))
    return points, np.fromiter(map(len, rings), np.int64, len(rings))


def _runs(values):
    """(starts, ends) of the runs of equal neighbours in `values` (non-empty)."""
    cut = np.flatnonzero(values[1:] != values[:-1]) + 1
    return np.r_[0, cut], np.r_[cut, len(values)]


def _burn_even_odd(labels, points, sizes, owners):
    """Burn into `labels` the pixels whose centre is inside each owner's rings (even-odd rule over
    all its rings; a higher owner wins where they overlap), every plot of the batch at once, and
    return {owner: its pixel count alone}.

    `points` (pixel coordinates) holds the rings one after another, `sizes` their vertex counts,
    `owners` the label (>= 1, non-decreasing) of each ring. A scanline fill: each edge crosses the
    centre lines y = r + 0.5 with min(y0, y1) <= y < max(y0, y1) (half-open, so a vertex on a
    centre line counts once); a crossing at x starts or ends a run at column floor(x - 0.5) + 1;
    each owner's crossings on a row, sorted, pair into runs. Per plot (a Python loop of numpy
    calls) this took 45 ms for a window's 460 plots, a fifth of the window's measuring.
    """
    rows, cols = labels.shape
    x, y = points[:, 0], points[:, 1]
    starts = np.cumsum(sizes) - sizes
    # Each owner's vertices are contiguous: its first ring's first vertex starts its group.
    first_ring, after_last = _runs(owners)
    at = starts[first_ring]
    # Rows and columns whose centres (index + 0.5) can lie inside each owner's bounding box.
    r0 = np.maximum(0, np.ceil(np.minimum.reduceat(y, at) - 0.5))
    r1 = np.minimum(rows - 1, np.floor(np.maximum.reduceat(y, at) - 0.5))
    c0 = np.maximum(0, np.ceil(np.minimum.reduceat(x, at) - 0.5)).astype(np.int64)
    c1 = np.minimum(cols - 1, np.floor(np.maximum.reduceat(x, at) - 0.5)).astype(np.int64)
    group = np.repeat(np.repeat(np.arange(len(at)), after_last - first_ring), sizes)
    following = np.arange(len(x)) + 1
    wraps = following == np.repeat(starts + sizes, sizes)
    following[wraps] = np.repeat(starts, sizes)[wraps]
    x1, y1 = x[following], y[following]
    first = np.maximum(np.ceil(np.minimum(y, y1) - 0.5), r0[group]).astype(np.int64)
    last = np.minimum(np.ceil(np.maximum(y, y1) - 0.5) - 1, r1[group]).astype(np.int64)
    counts = np.maximum(last - first + 1, 0)
    counts[((r1 < r0) | (c1 < c0))[group]] = 0  # an owner wholly off the grid
    edge = np.repeat(np.arange(len(x)), counts)
    if edge.size == 0:
        return {}
    row = first[edge] + (np.arange(edge.size) - np.repeat(np.cumsum(counts) - counts, counts))
    cross = x[edge] + (row + 0.5 - y[edge]) * (x1[edge] - x[edge]) / (y1[edge] - y[edge])
    owner = group[edge]
    col = np.clip(np.floor(cross - 0.5).astype(np.int64) + 1, c0[owner], c1[owner] + 1)
    order = np.lexsort((col, row, owner))  # an even number of crossings per owner and row
    owner, row, col = owner[order][0::2], row[order][0::2], col[order]
    begin, length = col[0::2], col[1::2] - col[0::2]
    pixels = np.repeat(row * cols + begin - (np.cumsum(length) - length), length) + np.arange(
        int(length.sum())
    )
    numbers = owners[first_ring][owner]
    np.maximum.at(labels.reshape(-1), pixels, np.repeat(numbers.astype(np.int32), length))
    # Each owner's pixels as if alone (runs of one owner never overlap: even-odd pairs).
    alone = np.bincount(owner, weights=length, minlength=len(at))
    return {int(k): int(c) for k, c in zip(owners[first_ring], alone, strict=True)}


def plot_table(
    plots,
    plot_labels,
    *,
    mask,
    heights,
    pixel_area_m2,
    height_units="m",
    support=None,
    sigma=None,
    index_maps=None,
):
    """One row per plot: its attributes, area, plant cover and canopy heights.

    Heights are taken over every pixel of the plot with a height (soil counts as its own, about
    zero, height), which is what the difference of two flights measures; pixels without data
    (NaN) count for neither heights nor cover.

    Parameters
    ----------
    plots : PlotSet
    plot_labels : (rows, cols) int array, or a list of them
        :func:`rasterize_plots` on the grid of `mask` and `heights`, or :func:`plot_layers` (each
        plot measured whole where plots overlap).
    mask : (rows, cols) bool array
        Plant pixels (the segmentation).
    heights : (rows, cols) float array or None
        Canopy height (CHM) in `height_units`, NaN where there is no data. None gives the areas
        and cover only (height columns NaN).
    pixel_area_m2 : float
        Ground area of one pixel in square metres (> 0).
    height_units : {"m", "cm", "mm"}, optional
        Units of `heights`; the table is in metres.
    support : (rows, cols) float array, optional
        The ground's support (:func:`cliff_terrain.measure.ground_check.ground_support`); adds the column
        ``ground_support``, its mean over the plot's pixels (0: the ground under the plot was
        interpolated from soil elsewhere; 1 with a terrain model).
    sigma : (rows, cols) float array, optional
        The ground's standard error in metres (:attr:`cliff_terrain.measure.canopy.Canopy.sigma`);
        adds the column ``height_p90_err_m``, the root mean square of `sigma` over the plot's
        pixels with data: the standard error of ``height_p90_m`` that the ground carries (an
        error of the ground under a plot moves all its heights together; 0 with a terrain model).
    index_maps : dict, optional
        Vegetation index name -> (rows, cols) map on the grid (NaN = no value): adds, per index,
        ``ndvi_mean`` and ``ndvi_median`` over the plot's pixels and ``ndvi_plant_mean`` and
        ``ndvi_plant_median`` over its plant pixels (:mod:`cliff_terrain.measure.index_figures`).

    Returns
    -------
    list of dict
        Keys: ``plot`` (0-based index in the file), the plot's attributes, then ``area_m2``
        (of the pixels inside the raster), ``cover`` (plant fraction of the plot's pixels with
        data), ``height_mean_m``, ``height_p50_m``, ``height_p90_m``, ``height_p99_m``,
        ``height_max_m``, ``volume_m3`` (sum of heights times the pixel area) and ``error``
        (empty, or why the plot has no or partial figures). Missing figures are NaN.

    Examples
    --------
    >>> square = [np.array([[0.0, 0.0], [2.0, 0.0], [2.0, -2.0], [0.0, -2.0]])]
    >>> from cliff_terrain.io.vector.plot_polygons import PlotSet
    >>> plots = PlotSet([square], [{"name": "A"}], ("name",), None, "")
    >>> labels = rasterize_plots(plots, transform=[[1, 0, 0], [0, -1, 0]], shape=(2, 2))
    >>> h = np.array([[0.0, 0.5], [1.0, 0.0]])
    >>> row = plot_table(plots, labels, mask=h > 0, heights=h, pixel_area_m2=1.0)[0]
    >>> row["name"], row["area_m2"], row["cover"], row["height_max_m"], row["volume_m3"]
    ('A', 4.0, 0.5, 1.0, 1.5)
    """
    if isinstance(plot_labels, list | tuple):
        # Layers (plot_layers): each plot is whole in one of them, and measured there.
        tables = [
            _plot_rows(plots, layer, mask, heights, pixel_area_m2, height_units, support, sigma, index_maps)
            for layer in plot_labels
        ]
        rows = [max(candidates, key=lambda row: row["pixels"]) for candidates in zip(*tables, strict=True)]
    else:
        rows = _plot_rows(
            plots, plot_labels, mask, heights, pixel_area_m2, height_units, support, sigma, index_maps
        )
    full_areas = [polygon_area(rings) for rings in plots.polygons]
    for index, row in enumerate(rows):
        # The share of its area the figures stand on: its pixels in the raster, with heights those
        # that have one (a DSM over half a plot gave the other half's p90, silently).
        inside = row["area_m2"] / full_areas[index] if full_areas[index] > 0 else 1.0
        inside *= row["valid_pixels"] / row["pixels"] if heights is not None and row["pixels"] else 1.0
        if row["pixels"] == 0:
            row["error"] = "outside the raster (or smaller than a pixel)"
        elif heights is not None and row["valid_pixels"] == 0:
            row["error"] = "no height data in the plot"
        elif inside < 0.9:
            row["error"] = f"partly measured ({inside:.0%} of its area; no data on the rest)"
        else:
            row["error"] = ""
        del row["pixels"], row["valid_pixels"]
    return rows


def _plot_rows(plots, plot_labels, mask, heights, pixel_area_m2, height_units, support, sigma, index_maps):
    """:func:`plot_table`'s rows on one label image, with each plot's ``pixels`` and ``valid_pixels``
    and without ``error``."""
    plot_labels = np.asarray(plot_labels)
    mask = np.asarray(mask, dtype=bool)
    if plot_labels.ndim != 2 or mask.shape != plot_labels.shape:
        raise CliffTerrainError(
            f"`mask` must have the shape of `plot_labels` {plot_labels.shape}, got {mask.shape}"
        )
    if heights is not None:
        heights = np.asarray(heights)
        if heights.shape != plot_labels.shape:
            raise CliffTerrainError(
                f"`heights` must have the shape of `plot_labels` {plot_labels.shape}, got {heights.shape}"
            )
    pixel_area_m2 = check_float("pixel_area_m2", pixel_area_m2, minimum=0.0, strict_minimum=True)
    check_choice("height_units", height_units, tuple(HEIGHT_UNITS))
    to_m = HEIGHT_UNITS[height_units]
    n = len(plots.polygons)
    figures = region_figures(
        plot_labels, n, mask=mask, heights=heights, pixel_area_m2=pixel_area_m2, to_m=to_m
    )
    if support is not None:
        support = np.asarray(support, dtype=np.float64)
        if support.shape != plot_labels.shape:
            raise CliffTerrainError(
                f"`support` must have the shape of `plot_labels` {plot_labels.shape}, got {support.shape}"
            )
        counts = np.bincount(plot_labels.ravel(), minlength=n + 1)[1 : n + 1]
        sums = np.bincount(plot_labels.ravel(), weights=support.ravel(), minlength=n + 1)[1 : n + 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            plot_support = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    if sigma is not None:
        sigma = np.asarray(sigma, dtype=np.float64)
        if sigma.shape != plot_labels.shape:
            raise CliffTerrainError(
                f"`sigma` must have the shape of `plot_labels` {plot_labels.shape}, got {sigma.shape}"
            )
        # Over the pixels with a height: where the heights come from.
        with_data = plot_labels.ravel() * (np.isfinite(heights).ravel() if heights is not None else 1)
        counts = np.bincount(with_data, minlength=n + 1)[1 : n + 1]
        sums = np.bincount(with_data, weights=np.nan_to_num(sigma.ravel()) ** 2, minlength=n + 1)[1 : n + 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            plot_sigma = np.where(counts > 0, np.sqrt(sums / np.maximum(counts, 1)), np.nan)
    indices = index_figures(plot_labels, n, maps=index_maps, mask=mask) if index_maps else None
    rows = []
    for index in range(n):
        attributes = plots.attributes[index]
        row = {"plot": index, **{_attribute_name(k): v for k, v in attributes.items()}, **figures[index]}
        row["error"] = ""  # its place among the columns; plot_table words it
        if support is not None:
            row["ground_support"] = float(plot_support[index])
        if sigma is not None:
            row["height_p90_err_m"] = float(plot_sigma[index])
        if indices:
            row.update(indices[index])
        rows.append(row)
    return rows


def _attribute_name(name):
    """An attribute's column: its own name, unless it is one of ours (then with ``_attr``)."""
    ours = (*PLOT_COLUMNS, "ground_support", "height_p90_err_m", "pixels", "valid_pixels")
    return f"{name}_attr" if name in ours else name


def table_columns(plots, *, support=False, sigma=False, indices=()):
    """Columns of :func:`plot_table`'s rows: ``plot``, the attributes, then the figures.

    An attribute named like one of the figures (a plot file's own ``plot`` field, say) keeps its
    value under its name with ``_attr`` appended. With `support`, ``ground_support`` comes before
    ``error``, with `sigma` ``height_p90_err_m``, and so do the columns of `indices` (index names,
    :func:`index_columns`).
    """
    figures = [
        *PLOT_COLUMNS[1:-1],
        *(["ground_support"] if support else []),
        *(["height_p90_err_m"] if sigma else []),
        *index_columns(indices),
    ]
    figures.append(PLOT_COLUMNS[-1])
    return ["plot", *(_attribute_name(name) for name in plots.fields), *figures]


def region_figures(labels, n, *, mask, heights, pixel_area_m2, to_m=1.0):
    """Area, cover and height statistics of regions 1..n of `labels` (a list of n dicts).

    Height statistics are over the region's pixels with a finite height; percentiles are
    numpy's linear ones. Used for plots and for the per-region table. Each region is read in its
    bounding box only (``scipy.ndimage.find_objects``), so the work follows the regions' extent.
    """
    from scipy import ndimage

    labels = np.asarray(labels)
    mask = np.asarray(mask, dtype=bool)
    if heights is not None:
        heights = np.asarray(heights)
    boxes = ndimage.find_objects(labels, max_label=n) if n else []
    result = []
    for region, box in enumerate(boxes, start=1):
        figure = {"pixels": 0, "valid_pixels": 0, "area_m2": 0.0, "cover": math.nan}
        figure.update(dict.fromkeys(HEIGHT_COLUMNS, math.nan))
        figure["volume_m3"] = math.nan
        if box is not None:
            inside = labels[box] == region
            pixels = int(np.count_nonzero(inside))
            valid = None
            if heights is not None:
                values = heights[box][inside].astype(np.float64) * to_m
                valid = np.isfinite(values)
                values = values[valid]
            plants = mask[box][inside]
            n_valid = pixels if valid is None else int(np.count_nonzero(valid))
            n_plants = int(np.count_nonzero(plants if valid is None else plants[valid]))
            figure.update(pixels=pixels, valid_pixels=n_valid, area_m2=float(pixels * pixel_area_m2))
            if n_valid:
                figure["cover"] = n_plants / n_valid
            if heights is not None and values.size:
                total = float(values.sum())
                p50, p90, p99, top = _percentiles(values, (50.0, 90.0, 99.0, 100.0))
                figure.update(
                    height_mean_m=total / values.size,
                    height_p50_m=float(p50),
                    height_p90_m=float(p90),
                    height_p99_m=float(p99),
                    height_max_m=float(top),
                    volume_m3=total * pixel_area_m2,
                )
        result.append(figure)
    return result


def _percentiles(values, percents):
    """numpy's linear percentiles of `values`, by one partial sort (``np.partition``) for all of them."""
    positions = np.asarray(percents) / 100.0 * (len(values) - 1)
    low = np.floor(positions).astype(np.int64)
    high = np.minimum(low + 1, len(values) - 1)
    part = np.partition(values, np.unique(np.concatenate([low, high])))
    return part[low] + (part[high] - part[low]) * (positions - low)
