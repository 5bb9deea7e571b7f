"""Field plots: polygons from GeoJSON or ESRI Shapefiles, burnt into a raster, and their height table.

Plot boundaries are drawn in QGIS (or exported by FIELDimageR, EasyIDP, ...) as GeoJSON or
Shapefiles in the rasters' CRS. :func:`read_plots` reads them, :func:`rasterize_plots` turns them
into a label image on a raster's grid (pixel centres inside a polygon, even-odd rule, so holes and
multi-part plots work), and :func:`plot_table` gives one row per plot.

Affine transforms here map pixel (col, row) to map (x, y), GDAL's convention: ``(col, row) = (0, 0)``
is the top-left *corner* of the top-left pixel, pixel centres are at ``(col + 0.5, row + 0.5)``::

    x = t[0, 0] * col + t[0, 1] * row + t[0, 2]
    y = t[1, 0] * col + t[1, 1] * row + t[1, 2]

given as a 2x3 array or a 3x3 one whose last row is (0, 0, 1).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._validate import check_choice, check_float
from .errors import CliffTerrainError, GeoreferenceError, PlotFileError

# Metric statistics of a plot, in the order of the table's columns.
HEIGHT_COLUMNS = ("height_mean_m", "height_p50_m", "height_p90_m", "height_p99_m", "height_max_m")
PLOT_COLUMNS = ("plot", "area_m2", "cover", *HEIGHT_COLUMNS, "volume_m3", "error")
HEIGHT_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass
class PlotSet:
    """Plot polygons and their attributes, as read from one file.

    Attributes
    ----------
    polygons : list of list of (n, 2) float64 arrays
        One entry per plot (feature, in file order): its rings in map x/y. A multi-part plot has
        several outer rings; holes are rings too (filled with the even-odd rule).
    attributes : list of dict
        One dict per plot: its own attributes (GeoJSON properties, Shapefile records).
    fields : tuple of str
        The attribute names, in file order (the union over all features for GeoJSON).
    crs : int or None
        The EPSG code the file declares, None when it declares none.
    path : str
        The file read.
    """

    polygons: list
    attributes: list
    fields: tuple
    crs: int | None
    path: str

    def __len__(self):
        return len(self.polygons)


def read_plots(path):
    """Read plot polygons from a GeoJSON file or an ESRI Shapefile.

    Parameters
    ----------
    path : str or os.PathLike
        ``.geojson``/``.json`` (a FeatureCollection, a Feature or a bare geometry; Polygon and
        MultiPolygon) or ``.shp`` (Polygon, PolygonZ or PolygonM shapes; the ``.shx`` and ``.dbf``
        beside it; the ``.prj`` gives the CRS).

    Returns
    -------
    PlotSet

    Raises
    ------
    PlotFileError
        The file is missing, broken, empty, or holds geometries other than polygons.

    Examples
    --------
    >>> import json, tempfile, os
    >>> square = [[[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]]
    >>> doc = {"type": "FeatureCollection", "features": [
    ...     {"type": "Feature", "properties": {"name": "A"}, "geometry": {"type": "Polygon", "coordinates": square}}]}
    >>> path = os.path.join(tempfile.mkdtemp(), "plots.geojson")
    >>> _ = open(path, "w").write(json.dumps(doc))
    >>> plots = read_plots(path)
    >>> len(plots), plots.fields, plots.attributes[0]["name"], plots.polygons[0][0].shape
    (1, ('name',), 'A', (5, 2))
    """
    path = Path(path)
    name = str(path)
    if not path.is_file():
        raise PlotFileError(f"plot file {name!r} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".shp":
        plots = _read_shapefile(path, name)
    elif suffix in (".geojson", ".json"):
        plots = _read_geojson(path, name)
    else:
        raise PlotFileError(
            f"plot file {name!r} must be GeoJSON (.geojson, .json) or an ESRI Shapefile (.shp)"
        )
    if not plots.polygons:
        raise PlotFileError(f"plot file {name!r} holds no polygon")
    return plots


def _read_geojson(path, name):
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise PlotFileError(f"cannot read plot file {name!r}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise PlotFileError(f"plot file {name!r} is not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(doc, dict):
        raise PlotFileError(f"plot file {name!r} is not a GeoJSON object")
    kind = doc.get("type")
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise PlotFileError(f"plot file {name!r}: its FeatureCollection has no 'features' list")
    elif kind == "Feature":
        features = [doc]
    elif kind in ("Polygon", "MultiPolygon"):
        features = [{"type": "Feature", "geometry": doc, "properties": {}}]
    else:
        raise PlotFileError(f"plot file {name!r} is not GeoJSON polygons (its type is {kind!r})")
    polygons, attributes, fields = [], [], {}
    for index, feature in enumerate(features):
        geometry = feature.get("geometry") if isinstance(feature, dict) else None
        if not isinstance(geometry, dict):
            raise PlotFileError(f"plot file {name!r}: feature {index} has no geometry")
        polygons.append(_geojson_rings(geometry, name, index))
        properties = feature.get("properties") or {}
        if not isinstance(properties, dict):
            raise PlotFileError(f"plot file {name!r}: feature {index} has properties that are not an object")
        attributes.append(dict(properties))
        fields.update(dict.fromkeys(properties))
    return PlotSet(polygons, attributes, tuple(fields), _geojson_crs(doc.get("crs"), name), name)


def _geojson_rings(geometry, name, index):
    kind, coordinates = geometry.get("type"), geometry.get("coordinates")
    if kind == "Polygon":
        parts = [coordinates]
    elif kind == "MultiPolygon":
        parts = coordinates
    else:
        raise PlotFileError(f"plot file {name!r}: feature {index} is a {kind}, not a Polygon or MultiPolygon")
    rings = []
    try:
        for part in parts:
            for ring in part:
                array = np.asarray(ring, dtype=np.float64)
                rings.append(_checked_ring(array, name, index))
    except (TypeError, ValueError) as exc:
        if isinstance(exc, CliffTerrainError):
            raise
        raise PlotFileError(f"plot file {name!r}: feature {index} has malformed coordinates") from None
    if not rings:
        raise PlotFileError(f"plot file {name!r}: feature {index} is an empty polygon")
    return rings


def _checked_ring(array, name, index):
    if array.ndim != 2 or array.shape[1] < 2 or len(array) < 3:
        raise PlotFileError(
            f"plot file {name!r}: feature {index} has a ring that is not 3 or more x/y points"
        )
    array = np.ascontiguousarray(array[:, :2])
    if not np.all(np.isfinite(array)):
        raise PlotFileError(f"plot file {name!r}: feature {index} has non-finite coordinates")
    return array


def _geojson_crs(crs, name):
    """EPSG code of a (pre-RFC 7946) GeoJSON ``crs`` member, as QGIS and GDAL write it."""
    if crs is None:
        return None
    text = crs.get("properties", {}).get("name", "") if isinstance(crs, dict) else ""
    if isinstance(text, str) and re.search(r"CRS84$", text):
        return 4326
    match = re.search(r"EPSG:+(\d+)$", text) if isinstance(text, str) else None
    if match is None:
        raise PlotFileError(f"plot file {name!r}: its CRS {text or crs!r} is not an EPSG code")
    return int(match.group(1))


def _read_shapefile(path, name):
    try:
        import shapefile
    except ImportError:
        raise PlotFileError(f"cannot read {name!r}: reading Shapefiles needs the pyshp package") from None
    try:
        with shapefile.Reader(str(path)) as reader:
            fields = tuple(field[0] for field in reader.fields[1:])
            shape_records = list(reader.iterShapeRecords())
    except (shapefile.ShapefileException, OSError, ValueError, IndexError, UnicodeDecodeError) as exc:
        raise PlotFileError(
            f"cannot read Shapefile {name!r}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        ) from None
    except Exception as exc:  # pyshp raises struct.error and others on truncated files
        raise PlotFileError(f"Shapefile {name!r} is broken ({type(exc).__name__})") from None
    polygons, attributes = [], []
    polygon_types = {shapefile.POLYGON, shapefile.POLYGONZ, shapefile.POLYGONM}
    for index, shape_record in enumerate(shape_records):
        shape = shape_record.shape
        if shape.shapeType == shapefile.NULL:
            raise PlotFileError(f"Shapefile {name!r}: shape {index} is empty (a null shape)")
        if shape.shapeType not in polygon_types:
            raise PlotFileError(f"Shapefile {name!r} holds {shape.shapeTypeName} shapes, not polygons")
        points = np.asarray(shape.points, dtype=np.float64).reshape(-1, 2)
        bounds = [*shape.parts, len(points)]
        rings = [
            _checked_ring(points[a:b], name, index) for a, b in zip(bounds[:-1], bounds[1:], strict=False)
        ]
        polygons.append(rings)
        attributes.append(dict(zip(fields, shape_record.record, strict=False)))
    return PlotSet(polygons, attributes, fields, _prj_crs(path.with_suffix(".prj"), name), name)


# ESRI WKT (QGIS writes it into .prj files without an AUTHORITY) names UTM zones like this.
_UTM_NAME = re.compile(r'PROJCS\["(?:WGS_1984_UTM_Zone_|WGS 84 / UTM zone )(\d{1,2})([NS])"', re.IGNORECASE)


def _prj_crs(prj, name):
    """EPSG code of a Shapefile's .prj (WKT1), None when there is no .prj file."""
    if not prj.is_file():
        prj = prj.with_suffix(".PRJ")
        if not prj.is_file():
            return None
    try:
        wkt = prj.read_text(encoding="utf-8", errors="replace").strip()
    except OSError as exc:
        raise PlotFileError(f"cannot read {str(prj)!r}: {exc}") from None
    return wkt_epsg(wkt, source=str(prj))


def wkt_epsg(wkt, *, source):
    """EPSG code of a WKT1 CRS: its outermost AUTHORITY, else a WGS 84 UTM or geographic name.

    Examples
    --------
    >>> wkt_epsg('PROJCS["WGS_1984_UTM_Zone_16N",GEOGCS["GCS_WGS_1984"]]', source="x.prj")
    32616
    """
    authorities = re.findall(r'AUTHORITY\["EPSG",\s*"?(\d+)"?\]\]\s*$', wkt)
    if authorities:
        return int(authorities[-1])
    utm = _UTM_NAME.match(wkt)
    if utm is not None and 1 <= int(utm.group(1)) <= 60:
        return (32600 if utm.group(2).upper() == "N" else 32700) + int(utm.group(1))
    if wkt.startswith("GEOGCS[") and re.search(r"WGS_?\s?(19)?84", wkt):
        return 4326
    raise PlotFileError(
        f"{source!r}: its CRS is not one Cliff Terrain recognises (no EPSG code): {wkt[:60]!r}"
    )


def as_affine(transform):
    """A pixel (col, row) -> map (x, y) transform as a 3x3 float64 array (see the module's docs)."""
    t = np.asarray(transform, dtype=np.float64)
    if t.shape == (2, 3):
        t = np.vstack([t, [0.0, 0.0, 1.0]])
    if t.shape != (3, 3) or not np.all(np.isfinite(t)) or not np.allclose(t[2], [0.0, 0.0, 1.0]):
        raise CliffTerrainError(f"`transform` must be a finite 2x3 or 3x3 affine matrix, got shape {t.shape}")
    if abs(np.linalg.det(t[:2, :2])) < 1e-300:
        raise CliffTerrainError("`transform` must be invertible, got a singular matrix")
    return t


def affine_inverse(transform):
    """The inverse of a 3x3 affine transform (see :func:`as_affine`), in closed form.

    Not ``np.linalg.inv``: LAPACK's inverse wakes OpenBLAS's thread pool, whose threads then spin
    for about 0.1 CPU-s on the other cores, taking them from a parallel season's other workers.

    Examples
    --------
    >>> t = as_affine([[0.5, 0.0, 100.0], [0.0, -0.5, 200.0]])
    >>> (affine_inverse(t) @ t).round(12).tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    t = as_affine(transform)
    (a, b, c), (d, e, f) = t[0], t[1]
    det = a * e - b * d
    linear = np.array([[e, -b], [-d, a]]) / det
    inverse = np.eye(3)
    inverse[:2, :2] = linear
    inverse[:2, 2] = -(linear @ [c, f])
    return inverse


def check_plot_crs(plots, crs, *, raster):
    """Refuse plots that do not use the raster's CRS (EPSG code `crs`, read from file `raster`).

    Plots that declare no CRS are taken to be in the raster's, unless their coordinates all look
    like longitude/latitude while the raster's are projected (GeoJSON without a ``crs`` is WGS 84).
    """
    if plots.crs is not None and crs is not None and plots.crs != crs:
        raise GeoreferenceError(
            f"plot file {plots.path!r} is in EPSG:{plots.crs} but raster {raster!r} is in EPSG:{crs}; "
            "reproject the plots to the raster's CRS"
        )
    if plots.crs is None and crs is not None and crs != 4326:
        points = np.concatenate([ring for rings in plots.polygons for ring in rings])
        if np.all(np.abs(points[:, 0]) <= 180) and np.all(np.abs(points[:, 1]) <= 90):
            raise GeoreferenceError(
                f"plot file {plots.path!r} declares no CRS and looks like longitude/latitude, but raster "
                f"{raster!r} is in EPSG:{crs}; save the plots in EPSG:{crs}"
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
    inverse = affine_inverse(t)
    labels = np.zeros((rows, cols), dtype=np.int32)
    for index, rings in enumerate(plots.polygons):
        pixel_rings = [ring @ inverse[:2, :2].T + inverse[:2, 2] for ring in rings]
        inside = _fill_even_odd(pixel_rings, rows, cols)
        if inside is not None:
            r0, c0, block = inside
            labels[r0 : r0 + block.shape[0], c0 : c0 + block.shape[1]][block] = index + 1
    return labels


def _fill_even_odd(rings, rows, cols):
    """Pixels whose centre is inside `rings` (pixel coordinates): (row0, col0, bool block) or None."""
    points = np.concatenate(rings)
    # Rows and columns whose centres (index + 0.5) can lie inside the bounding box.
    r0 = max(0, math.ceil(points[:, 1].min() - 0.5))
    r1 = min(rows - 1, math.floor(points[:, 1].max() - 0.5))
    c0 = max(0, math.ceil(points[:, 0].min() - 0.5))
    c1 = min(cols - 1, math.floor(points[:, 0].max() - 0.5))
    if r1 < r0 or c1 < c0:
        return None
    starts = points
    ends = np.concatenate([np.roll(ring, -1, axis=0) for ring in rings])
    x0, y0, x1, y1 = starts[:, 0], starts[:, 1], ends[:, 0], ends[:, 1]
    # Each edge crosses the centre lines y = r + 0.5 with min(y0, y1) <= y < max(y0, y1) (half-open,
    # so a vertex on a centre line counts once).
    low, high = np.minimum(y0, y1), np.maximum(y0, y1)
    first = np.maximum(np.ceil(low - 0.5), r0).astype(np.int64)
    last = np.minimum(np.ceil(high - 0.5) - 1, r1).astype(np.int64)
    counts = np.maximum(last - first + 1, 0)
    edge = np.repeat(np.arange(len(x0)), counts)
    if edge.size == 0:
        return None
    offsets = np.arange(edge.size) - np.repeat(np.cumsum(counts) - counts, counts)
    row = first[edge] + offsets
    yc = row + 0.5
    x = x0[edge] + (yc - y0[edge]) * (x1[edge] - x0[edge]) / (y1[edge] - y0[edge])
    # A crossing at x toggles every centre to its right: the first such column is floor(x - 0.5) + 1.
    col = np.clip(np.floor(x - 0.5).astype(np.int64) + 1, c0, c1 + 1)
    height, width = r1 - r0 + 1, c1 - c0 + 2
    toggles = np.bincount((row - r0) * width + (col - c0), minlength=height * width).reshape(height, width)
    block = (np.cumsum(toggles[:, :-1], axis=1) & 1).astype(bool)
    return r0, c0, block


def plot_table(plots, plot_labels, *, mask, heights, pixel_area_m2, height_units="m", support=None):
    """One row per plot: its attributes, area, plant cover and canopy heights.

    Heights are taken over every pixel of the plot with a height (soil counts as its own, about
    zero, height), which is what the difference of two flights measures; pixels without data
    (NaN) count for neither heights nor cover.

    Parameters
    ----------
    plots : PlotSet
    plot_labels : (rows, cols) int array
        :func:`rasterize_plots` on the grid of `mask` and `heights`.
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
        The ground's support (:func:`cliff_terrain.ground.ground_support`); adds the column
        ``ground_support``, its mean over the plot's pixels (0: the ground under the plot was
        interpolated from soil elsewhere; 1 with a terrain model).

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
    >>> plots = PlotSet([square], [{"name": "A"}], ("name",), None, "")
    >>> labels = rasterize_plots(plots, transform=[[1, 0, 0], [0, -1, 0]], shape=(2, 2))
    >>> h = np.array([[0.0, 0.5], [1.0, 0.0]])
    >>> row = plot_table(plots, labels, mask=h > 0, heights=h, pixel_area_m2=1.0)[0]
    >>> row["name"], row["area_m2"], row["cover"], row["height_max_m"], row["volume_m3"]
    ('A', 4.0, 0.5, 1.0, 1.5)
    """
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
    full_areas = [polygon_area(rings) for rings in plots.polygons]
    rows = []
    for index in range(n):
        attributes = plots.attributes[index]
        row = {"plot": index, **{_attribute_name(k): v for k, v in attributes.items()}, **figures[index]}
        if figures[index]["pixels"] == 0:
            row["error"] = "outside the raster (or smaller than a pixel)"
        elif heights is not None and figures[index]["valid_pixels"] == 0:
            row["error"] = "no height data in the plot"
        elif row["area_m2"] < 0.9 * full_areas[index]:
            inside = row["area_m2"] / full_areas[index]
            row["error"] = f"partly outside the raster or its data ({inside:.0%} measured)"
        else:
            row["error"] = ""
        del row["pixels"], row["valid_pixels"]
        if support is not None:
            row["ground_support"] = float(plot_support[index])
        rows.append(row)
    return rows


def _attribute_name(name):
    """An attribute's column: its own name, unless it is one of ours (then with ``_attr``)."""
    ours = (*PLOT_COLUMNS, "ground_support", "pixels", "valid_pixels")
    return f"{name}_attr" if name in ours else name


def table_columns(plots, *, support=False):
    """Columns of :func:`plot_table`'s rows: ``plot``, the attributes, then the figures.

    An attribute named like one of the figures (a plot file's own ``plot`` field, say) keeps its
    value under its name with ``_attr`` appended. With `support`, ``ground_support`` comes before
    ``error``.
    """
    figures = [*PLOT_COLUMNS[1:-1], *(["ground_support"] if support else []), PLOT_COLUMNS[-1]]
    return ["plot", *(_attribute_name(name) for name in plots.fields), *figures]


def polygon_area(rings):
    """Area of a plot (map units squared): its rings' areas, holes (rings inside an odd number of
    others, as the even-odd fill treats them) subtracted."""
    areas = []
    for ring in rings:
        x, y = ring[:, 0], ring[:, 1]
        areas.append(0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))))
    if len(areas) == 1:
        return areas[0]
    # Nesting parity: a ring inside an odd number of other rings is a hole.
    total = 0.0
    for area, around in zip(areas, enclosing_rings(rings), strict=True):
        total += -area if len(around) % 2 else area
    return total


def enclosing_rings(rings):
    """For each ring, the indices of the other rings it lies inside (tested at its first vertex).

    A ring inside an odd number of others is a hole (the even-odd rule plots are filled with).
    """
    return [
        [j for j, other in enumerate(rings) if j != i and _point_in_ring(ring[0], other)]
        for i, ring in enumerate(rings)
    ]


def _point_in_ring(point, ring):
    x, y = point
    x0, y0 = ring[:, 0], ring[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return bool(np.count_nonzero(crosses & (x < xs)) % 2)


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
