"""Field plot polygons read from GeoJSON or ESRI Shapefiles, with the CRS they declare.

Plot boundaries are drawn in QGIS (or exported by FIELDimageR, EasyIDP, ...) as GeoJSON or
Shapefiles in the rasters' CRS. :func:`read_plots` reads them into a :class:`PlotSet`; the
measurement on a raster's grid is in :mod:`cliff_terrain.measure.field_plots`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import CliffTerrainError, PlotFileError
from ..raster.crs import UserCrs, wkt_crs


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
    crs : int, UserCrs or None
        The EPSG code the file declares, a user-defined projected CRS in metres its .prj declares
        (:class:`cliff_terrain.io.raster.crs.UserCrs`), None when it declares none.
    path : str
        The file read.
    """

    polygons: list
    attributes: list
    fields: tuple
    crs: int | UserCrs | None
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
    if path.stat().st_size == 0:
        raise PlotFileError(f"plot file {name!r} is empty (0 bytes)")
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
    missing = [
        path.with_suffix(s).name
        for s in (".shx", ".dbf")
        if not (path.with_suffix(s).is_file() or path.with_suffix(s.upper()).is_file())
    ]
    if missing:
        raise PlotFileError(
            f"Shapefile {name!r} lacks {' and '.join(missing)} beside it (a Shapefile is its .shp, .shx "
            "and .dbf together); copy all its files"
        )
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
    """EPSG code of a WKT1 CRS: its outermost AUTHORITY, else a WGS 84 UTM or geographic name; a
    projected CRS in metres without either is a :class:`cliff_terrain.io.raster.crs.UserCrs`.

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
    if wkt.startswith(("PROJCS[", "GEOGCS[")):
        return wkt_crs(wkt, source=source, error=PlotFileError)
    raise PlotFileError(
        f"{source!r}: its CRS is not one Cliff Terrain recognises (no EPSG code): {wkt[:60]!r}"
    )


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
