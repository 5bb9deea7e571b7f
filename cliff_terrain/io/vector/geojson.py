"""GeoJSON text of table rows with their geometries (points of regions, polygons of plots)."""

from __future__ import annotations

import json
import math

import numpy as np

from .plot_polygons import enclosing_rings


def _json_value(value):
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if value is None or isinstance(value, bool | int | str):
        return value
    return str(value)  # dates and other attribute types of Shapefiles


def table_geojson(rows, geometries, *, crs):
    """GeoJSON text: one Feature per row, with its geometry (a GeoJSON geometry dict) and EPSG `crs`.

    A CRS without an EPSG code (a :class:`cliff_terrain.io.raster.crs.UserCrs`, or its WKT as a record
    holds it) is left out, as GDAL does: GeoJSON's ``crs`` member names CRSs by URN only.
    """
    features = [
        {"type": "Feature", "properties": {k: _json_value(v) for k, v in row.items()}, "geometry": geometry}
        for row, geometry in zip(rows, geometries, strict=True)
    ]
    doc = {"type": "FeatureCollection"}
    if isinstance(crs, int | np.integer):
        doc["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{crs}"}}
    doc["features"] = features
    return json.dumps(doc, allow_nan=False) + "\n"


def point_geometries(rows):
    return [{"type": "Point", "coordinates": [row["x"], row["y"]]} for row in rows]


def polygon_geometries(plots):
    """GeoJSON geometries of the plots: each ring inside an odd number of others is a hole of the
    innermost ring around it (the even-odd rule the plots are read and rasterised with)."""
    geometries = []
    for rings in plots.polygons:
        parts = [[ring.tolist()] for ring in _outer_rings(rings, holes=False)]
        for hole, outer in _outer_rings(rings, holes=True):
            parts[outer].append(hole.tolist())
        if len(parts) == 1:
            geometries.append({"type": "Polygon", "coordinates": parts[0]})
        else:
            geometries.append({"type": "MultiPolygon", "coordinates": parts})
    return geometries


def _outer_rings(rings, *, holes):
    """The outer rings (even depth), or (hole, index of its outer ring among them) for the holes."""
    inside = enclosing_rings(rings)
    outer = [i for i in range(len(rings)) if len(inside[i]) % 2 == 0]
    if not holes:
        return [rings[i] for i in outer]
    found = []
    for i in range(len(rings)):
        if len(inside[i]) % 2:
            # The innermost enclosing outer ring: the one inside the most others.
            parent = max((j for j in inside[i] if j in outer), key=lambda j: len(inside[j]))
            found.append((rings[i], outer.index(parent)))
    return found
