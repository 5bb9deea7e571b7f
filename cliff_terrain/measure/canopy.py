"""Measured canopy height on an orthophoto's grid: align the DSM (and DTM), find the ground, CHM.

:func:`measure_canopy` is what the ``heights`` command, ``build_relief(dsm=...)`` and
``render_views.py --dsm`` share: rasters in, everything on one georeferenced grid out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import check_float
from ..errors import GeoreferenceError
from ..io.raster.crs import crs_record, crs_text
from ..io.raster.geotiff import (
    GeoRaster,
    check_same_crs,
    overlap_fraction,
    read_orthophoto,
    read_surface,
    resample,
)
from .ground import DEFAULT_BLOCK_M, canopy_height
from .ground_grid import fit_on_ground_grid, ground_factor


@dataclass
class Canopy:
    """Surface, ground and canopy height on one grid (metres; NaN where the DSM has no data).

    Attributes
    ----------
    transform : (3, 3) float64
        Pixel (col, row) -> map (x, y) of the grid.
    crs : int or UserCrs
        EPSG code, or a user-defined CRS (:mod:`cliff_terrain.io.raster.crs`).
    dsm, ground, chm : (rows, cols) float32
    ground_source : {"dtm", "estimated"}
    pixel_size : float
        Metres per pixel (mean of x and y).
    support : (rows, cols) float32 or None
        With an estimated ground, the share of bare soil around each pixel that carried it
        (:func:`cliff_terrain.measure.ground_check.ground_support`; 0: interpolated only), counted
        on the ground's grid (:mod:`cliff_terrain.measure.ground_grid`: a block that shows bare
        soil counts whole); None with a DTM.
    sigma : (rows, cols) float32 or None
        With an estimated ground, its standard error in metres at each pixel, from the held-out
        check (:func:`cliff_terrain.measure.ground_check.ground_sigma`); None with a DTM.
    check : dict or None
        With an estimated ground, the held-out check and the candidate chosen
        (:func:`cliff_terrain.measure.ground_check.check_ground`); None with a DTM.
    """

    transform: np.ndarray
    crs: object
    dsm: np.ndarray
    ground: np.ndarray
    chm: np.ndarray
    ground_source: str
    pixel_size: float
    support: np.ndarray | None = None
    sigma: np.ndarray | None = None
    check: dict | None = None

    @property
    def pixel_area_m2(self):
        return float(abs(np.linalg.det(self.transform[:2, :2])))

    @property
    def origin(self):
        """Map (x, y) of the grid's top-left corner."""
        return float(self.transform[0, 2]), float(self.transform[1, 2])


def grid_for(raster, shape):
    """The transform of `raster`'s extent divided into `shape` (rows, cols) pixels."""
    rows0, cols0 = raster.shape
    rows, cols = shape
    return raster.transform @ np.diag([cols0 / cols, rows0 / rows, 1.0])


def photo_grid(path, metadata, shape):
    """(transform, EPSG code) of the processing grid `shape` (rows, cols) of georeferenced photo `path`."""
    from ..io.raster.geotiff import read_georeference

    transform, crs = read_georeference(path)
    return transform @ np.diag([*metadata.grid_scale(shape), 1.0]), crs


def surface_on_grid(path, metadata, shape, dsm):
    """The DSM `dsm` (a path or :class:`GeoRaster`) resampled onto the processing grid `shape` of
    georeferenced photo `path` (NaN where it has no height)."""
    from ..io.raster.geotiff import resample

    transform, crs = photo_grid(path, metadata, shape)
    surface = load_surfaces(dsm)[0]
    return resample(surface, transform=transform, shape=shape, crs=crs, target=str(path))


def cover_pixels(relief):
    """The plant pixels canopy cover counts: ``relief.cover_mask`` (the vegetation index above the
    segmentation's threshold, ``Segmentation.index_pixels``), or the
    relief's mask where there is none (paper mode, an NDVI map). Not the holes the relief fills
    inside its plants, which the windowed measure cannot fill across its windows (on a potato
    trial's day 100, 66 % of the photo with them, 54 % without).
    """
    return relief.mask if getattr(relief, "cover_mask", None) is None else relief.cover_mask


def photo_valid(metadata, shape):
    """The photo's pixels with data (an orthophoto's alpha) on the processing grid `shape`; None: all."""
    if getattr(metadata, "valid_mask", None) is None:
        return None
    import cv2

    rows, cols = shape
    return cv2.resize(metadata.valid_mask.astype(np.uint8), (cols, rows), interpolation=cv2.INTER_NEAREST) > 0


def load_surfaces(dsm, dtm=None):
    """Read a DSM (and DTM) path into :class:`GeoRaster` (rasters pass through), checking their CRSs."""
    dsm = dsm if isinstance(dsm, GeoRaster) else read_surface(dsm)
    if dtm is not None:
        dtm = dtm if isinstance(dtm, GeoRaster) else read_surface(dtm)
        check_same_crs(dsm, dtm)
    return dsm, dtm


def measure_canopy(
    dsm,
    *,
    plants,
    transform,
    crs,
    dtm=None,
    grid_name="the orthophoto",
    block_m=DEFAULT_BLOCK_M,
    valid=None,
    soil=None,
    ground_method="auto",
):
    """DSM (and DTM) resampled onto a grid, the ground, and the canopy height there.

    Parameters
    ----------
    dsm : GeoRaster or path
        The digital surface model.
    plants : (rows, cols) bool array
        Plant pixels of the grid (the segmentation); the rest is soil where the DSM has data.
    transform : (3, 3) array
        The grid's pixel -> map transform.
    crs : int
        The grid's EPSG code.
    dtm : GeoRaster or path, optional
        A terrain model: the ground, instead of estimating it.
    grid_name : str, optional
        Name of the grid (its file) for error messages.
    block_m : float, optional
        Block size of the ground's trend (see :func:`cliff_terrain.measure.ground.estimate_ground`).
    valid : (rows, cols) bool array, optional
        Pixels where the photo has data: only there can soil be told from plants.
    soil : (rows, cols) bool array, optional
        What the photo calls bare soil (see :func:`cliff_terrain.photo_heights.bare_soil.bare_soil`):
        evidence for the ground, which the surface can overrule; default: every pixel that is not
        a plant.
    ground_method : {"auto", "baseline", "smooth", "detailed"}, optional
        The ground estimate (:func:`cliff_terrain.measure.ground.fit_ground`).

    Returns
    -------
    Canopy

    Raises
    ------
    GeoreferenceError
        CRSs differ or the rasters do not overlap the grid (the message names both).
    GroundError
        Without a DTM, too little bare soil with surface data to estimate the ground, or a
        ground that fails its held-out check (the message names the DSM and suggests a DTM).
    """
    dsm, dtm = load_surfaces(dsm, dtm)
    plants = np.asarray(plants, dtype=bool)
    shape = plants.shape
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    transform = np.asarray(transform, dtype=np.float64)
    if crs != dsm.crs:
        raise GeoreferenceError(
            f"{dsm.path!r} is in {crs_text(dsm.crs)} but {grid_name} is in {crs_text(crs)}; reproject one"
        )
    surface = resample(dsm, transform=transform, shape=shape, crs=crs, target=repr(grid_name))
    if not np.isfinite(surface).any():
        raise GeoreferenceError(f"{dsm.path!r} has no data where it overlaps {grid_name}")
    pixel_size = float(np.mean([np.hypot(*transform[:2, 0]), np.hypot(*transform[:2, 1])]))
    if dtm is not None:
        if overlap_fraction(transform, shape, dtm.transform, dtm.shape) <= 0:
            raise GeoreferenceError(f"{dtm.path!r} does not overlap {grid_name}")
        ground = resample(dtm, transform=transform, shape=shape, crs=crs, target=repr(grid_name))
        source = "dtm"
        support = sigma = check = None
    else:
        has_data = np.isfinite(surface) if valid is None else np.isfinite(surface) & np.asarray(valid, bool)
        soil = ~plants if soil is None else np.asarray(soil, dtype=bool)
        # On a grid of about 5 cm (.ground_grid), as the windowed path's: the ground has no finer detail.
        ground, sigma, support, check = fit_on_ground_grid(
            surface,
            soil=soil,
            has_data=has_data,
            pixel_size=pixel_size,
            factor=ground_factor(shape, pixel_size),
            block_m=block_m,
            method=ground_method,
            source=f"{dsm.path!r} over {grid_name}",
        )
        source = "estimated"
    chm = canopy_height(surface, ground)
    if valid is not None:  # where the photo has no data, nothing tells plant from soil
        chm[~np.asarray(valid, dtype=bool)] = np.nan
    return Canopy(transform, crs, surface, ground, chm, source, pixel_size, support, sigma, check)


def plant_mask(rgb, *, valid=None):
    """Plant pixels of a photo by its vegetation index (the segmentation's threshold, no watershed).

    Cheaper than :func:`cliff_terrain.photo_heights.segmentation.segment` on large orthophotos, where only
    plant/soil matters (the ground, plot cover).
    """
    from ..photo_heights.vegetation import blurred_index, photo_threshold

    vi, name = blurred_index(rgb)
    # The same rule as the segmentation's, colour test included.
    mask = vi > photo_threshold(vi, rgb, index=name, valid=valid).threshold
    if valid is not None:
        mask &= valid
    return mask


def measure_orthophoto(ortho, dsm, *, dtm=None, resolution=None, block_m=DEFAULT_BLOCK_M):
    """Read an orthophoto GeoTIFF and measure its canopy on its grid (or a coarser one).

    Parameters
    ----------
    ortho : path or GeoRaster
    dsm, dtm : path or GeoRaster
    resolution : float, optional
        Metres per pixel of the grid (>= the orthophoto's); default the orthophoto's own.

    Returns
    -------
    rgb : (rows, cols, 3) uint8 on the grid
    valid : (rows, cols) bool (photo and DSM have data)
    plants : (rows, cols) bool (vegetation pixels)
    canopy : Canopy
    """
    import cv2

    ortho = ortho if isinstance(ortho, GeoRaster) else read_orthophoto(ortho)
    dsm, dtm = load_surfaces(dsm, dtm)
    check_same_crs(ortho, dsm)
    rgb, valid = ortho.data, ortho.valid
    transform = ortho.transform
    if resolution is not None:
        resolution = check_float("resolution", resolution, minimum=0.0, strict_minimum=True)
        rows0, cols0 = ortho.shape
        factor = resolution / np.mean(ortho.pixel_size)
        if factor > 1.0:
            shape = (max(1, round(rows0 / factor)), max(1, round(cols0 / factor)))
            transform = grid_for(ortho, shape)
            rgb = cv2.resize(rgb, shape[::-1], interpolation=cv2.INTER_AREA)
            if valid is not None:
                valid = cv2.resize(valid.astype(np.uint8), shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    from ..photo_heights.bare_soil import bare_soil

    plants = plant_mask(rgb, valid=valid)
    canopy = measure_canopy(
        dsm,
        plants=plants,
        transform=transform,
        crs=ortho.crs,
        dtm=dtm,
        grid_name=ortho.path,
        block_m=block_m,
        valid=valid,
        soil=None if dtm is not None else bare_soil(rgb, valid=valid),
    )
    has_data = np.isfinite(canopy.chm) if valid is None else (valid & np.isfinite(canopy.chm))
    return rgb, has_data, plants, canopy


def relief_heights(
    path, stages, *, dsm, dtm, height_source, exaggeration, block_m=DEFAULT_BLOCK_M, ground_method="auto"
):
    """The relief's heights (metres) on the processing grid of orthophoto `path` (used by build_relief).

    Returns ``(canopy, heights, pixel_size, georeference)``. By `height_source`: ``"measured"``
    heights are the CHM, ``"calibrated"`` ones the photo's domes scaled so each region's top is its
    measured p99 height, ``"inflated"`` ones the domes as they are (the canopy is then only
    measured, for the figures); all times `exaggeration`.
    """
    from ..photo_heights.labels import label_max

    name = str(path)
    transform, crs = photo_grid(path, stages.metadata, stages.working.shape[:2])
    plants = stages.segmentation.mask
    valid = photo_valid(stages.metadata, plants.shape)  # an orthophoto's no-data is neither soil nor plant
    from ..photo_heights.bare_soil import bare_soil

    seg = stages.segmentation
    # The ground's soil by the threshold the plants got (the DSM's, when it decided a senescent class).
    given = seg.threshold if seg.threshold_source == "photo (dsm)" else None
    soil = None if dtm is not None else bare_soil(stages.working, valid=valid, threshold=given)
    canopy = measure_canopy(
        dsm,
        plants=plants,
        transform=transform,
        crs=crs,
        dtm=dtm,
        grid_name=name,
        valid=valid,
        soil=soil,
        block_m=block_m,
        ground_method=ground_method,
    )
    chm = np.nan_to_num(canopy.chm, nan=0.0)
    pixel_size = canopy.pixel_size
    if height_source == "measured":
        heights = chm * np.float32(exaggeration)
    elif height_source == "calibrated":
        labels = stages.segmentation.labels
        n = int(labels.max(initial=0))
        dome = stages.heights_px.astype(np.float32)
        tops = np.zeros(n + 1, dtype=np.float32)
        if n:
            from .field_plots import region_figures

            figures = region_figures(labels, n, mask=plants, heights=canopy.chm, pixel_area_m2=1.0)
            tops[1:] = np.nan_to_num([f["height_p99_m"] for f in figures], nan=0.0)
        peaks = label_max(dome, labels)  # out[k] for region k, out[0] = 0
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(peaks > 0, tops / np.maximum(peaks, 1e-12), 0.0).astype(np.float32)
        heights = dome * scale[labels] * np.float32(exaggeration)
    else:
        heights = stages.heights_px.astype(np.float32) * np.float32(pixel_size)
    x0, y0 = canopy.origin
    georeference = {
        "crs": crs_record(crs),
        "origin": [x0, y0],
        "transform": [float(v) for v in transform[:2].ravel()],
        "pixel_size_m": pixel_size,
        "ground": canopy.ground_source,
    }
    return canopy, np.ascontiguousarray(heights, dtype=np.float32), pixel_size, georeference


def dsm_noise(canopy, *, plants):
    """The DSM's noise in metres: the robust spread of the soil's residual around the ground.

    1.4826 times the median absolute deviation of DSM - ground over the soil pixels (not
    `plants`, with data in the photo and in both surfaces): the standard deviation for Gaussian
    noise, unmoved by leaves the segmentation missed. NaN without soil pixels.

    Examples
    --------
    >>> import numpy as np
    >>> grid = np.eye(3)
    >>> dsm = np.array([[0.01, 0.02, 5.0], [-0.02, -0.01, 0.03], [0.0, np.nan, -0.03]], np.float32)
    >>> canopy = Canopy(grid, 32633, dsm, np.zeros_like(dsm), dsm, "estimated", 1.0)
    >>> round(dsm_noise(canopy, plants=dsm > 1), 4)
    0.0297
    """
    residual = np.asarray(canopy.dsm, np.float64) - np.asarray(canopy.ground, np.float64)
    soil = ~np.asarray(plants, bool) & np.isfinite(residual) & np.isfinite(canopy.chm)
    if not soil.any():
        return float("nan")
    values = residual[soil][:: max(1, int(soil.sum() // 1_000_000))]  # a sample gives the spread
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def relief_tables(relief, *, plots=None, source="", index_maps=None, extra=None):
    """The tables of a :class:`~cliff_terrain.build.Relief`: {file name: text}.

    ``regions.csv`` always (heights NaN without a surface model; areas in m² with a GSD),
    ``regions.geojson`` when georeferenced, ``plots.csv`` and ``plots.geojson`` with `plots`
    (a :class:`~cliff_terrain.io.vector.plot_polygons.PlotSet` in the orthophoto's CRS; needs a surface model).
    `source` names the orthophoto in errors. `index_maps` ({index name: map on the relief's grid},
    :func:`cliff_terrain.measure.index_figures.relief_index_maps`) adds the index columns.
    `extra` (``rows -> extra columns``) may add columns to the plot rows (a ruler's, say).
    """
    from ..errors import CliffTerrainError
    from ..io.vector.geojson import point_geometries, table_geojson
    from .tables import REGIONS_CSV, REGIONS_GEOJSON, region_columns, region_table, table_csv

    columns = region_columns(tuple(index_maps or ()))
    canopy = relief.canopy
    if canopy is None:
        if plots is not None:
            raise CliffTerrainError("plot tables need a surface model (`dsm`), got none")
        size = relief.pixel_size if relief.units == "m" else None
        regions = region_table(relief.labels, pixel_size=size, index_maps=index_maps)
        return {REGIONS_CSV: table_csv(regions, columns)}
    regions = region_table(
        relief.labels,
        heights=canopy.chm,
        pixel_size=canopy.pixel_size,
        transform=canopy.transform,
        index_maps=index_maps,
    )
    files = {
        REGIONS_CSV: table_csv(regions, columns),
        REGIONS_GEOJSON: table_geojson(regions, point_geometries(regions), crs=canopy.crs),
    }
    if plots is not None:
        files.update(
            plot_table_files(
                plots,
                canopy,
                heights=canopy.chm,
                mask=cover_pixels(relief),
                source=source,
                index_maps=index_maps,
                extra=extra,
            )
        )
    return files


def plot_support(canopy):
    """The ground's support for plot tables: the estimate's, or 1 everywhere with a terrain model."""
    return np.ones(canopy.chm.shape, np.float32) if canopy.support is None else canopy.support


def plot_sigma(canopy):
    """The ground's standard error for plot tables: the estimate's, or 0 with a terrain model."""
    return np.zeros(canopy.chm.shape, np.float32) if canopy.sigma is None else canopy.sigma


def relief_plot_rows(relief, plots, *, source, index_maps=None):
    """One row per plot of a relief built from a georeferenced orthophoto: cover, and with a surface
    model the canopy heights and ground support (:func:`cliff_terrain.measure.field_plots.plot_table`'s rows).

    Without a surface model the height columns are NaN. `source` is the orthophoto's path (its
    georeference places the relief's grid). `index_maps` adds the index columns (see
    :func:`cliff_terrain.measure.field_plots.plot_table`).
    """
    from .field_plots import check_plot_crs, plot_layers, plot_table

    if relief.canopy is not None:
        canopy = relief.canopy
        transform, crs, heights = canopy.transform, canopy.crs, canopy.chm
        support, sigma = plot_support(canopy), plot_sigma(canopy)
    else:
        transform, crs = photo_grid(source, relief.metadata, relief.mask.shape)
        heights, support, sigma = None, None, None
    check_plot_crs(plots, crs, raster=str(source))
    labels = plot_layers(plots, transform=transform, shape=relief.mask.shape)
    area = float(abs(np.linalg.det(np.asarray(transform)[:2, :2])))
    return plot_table(
        plots,
        labels,
        mask=cover_pixels(relief),
        heights=heights,
        pixel_area_m2=area,
        support=support,
        sigma=sigma,
        index_maps=index_maps,
    )


def plot_table_files(plots, canopy, *, heights, mask, source, index_maps=None, extra=None):
    """``plots.csv`` and ``plots.geojson`` ({file name: text}) of `plots` on `canopy`'s grid.

    `heights` and `mask` are on that grid; `source` names the orthophoto in errors. `extra`, a
    callable ``rows -> column names``, may add columns to the rows (before ``error``).
    """
    from ..io.vector.geojson import polygon_geometries, table_geojson
    from .field_plots import check_plot_crs, plot_layers, plot_table, table_columns
    from .tables import PLOTS_CSV, PLOTS_GEOJSON, table_csv

    check_plot_crs(plots, canopy.crs, raster=source)
    labels = plot_layers(plots, transform=canopy.transform, shape=heights.shape)
    if not any(layer.any() for layer in labels):
        raise GeoreferenceError(f"no plot of {plots.path!r} overlaps the orthophoto {source!r}")
    rows = plot_table(
        plots,
        labels,
        mask=mask,
        heights=heights,
        pixel_area_m2=canopy.pixel_area_m2,
        support=plot_support(canopy),
        sigma=plot_sigma(canopy),
        index_maps=index_maps,
    )
    columns = table_columns(plots, support=True, sigma=True, indices=tuple(index_maps or ()))
    if extra is not None:
        columns[-1:-1] = extra(rows)
    return {
        PLOTS_CSV: table_csv(rows, columns),
        PLOTS_GEOJSON: table_geojson(rows, polygon_geometries(plots), crs=canopy.crs),
    }
