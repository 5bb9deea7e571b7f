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


def table_geojson(rows, geometries, *, crs, features=None):
    """GeoJSON text: one Feature per row, with its geometry (a GeoJSON geometry dict) and EPSG `crs`.

    A CRS without an EPSG code (a :class:`cliff_terrain.io.raster.crs.UserCrs`, or its WKT as a record
    holds it) is left out, as GDAL does: GeoJSON's ``crs`` member names CRSs by URN only.
    `features`, when given, are the rows' own texts (:func:`feature_texts`, made where the rows
    were: on a cluster's workers; `geometries` is then not read); the text is the same.
    """
    if features is None:
        features = feature_texts(rows, geometries)
    doc = {"type": "FeatureCollection"}
    if isinstance(crs, int | np.integer):
        doc["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{crs}"}}
    doc["features"] = []
    # json.dumps of the whole document, its features joined as json.dumps joins a list's items.
    head = json.dumps(doc, allow_nan=False)[: -len("]}")]
    return head + ", ".join(features) + "]}\n"


def feature_texts(rows, geometries):
    """Each row's Feature as JSON text, with its geometry (a GeoJSON geometry dict)."""
    return [
        json.dumps(
            {
                "type": "Feature",
                "properties": {k: _json_value(v) for k, v in row.items()},
                "geometry": geometry,
            },
            allow_nan=False,
        )
        for row, geometry in zip(rows, geometries, strict=True)
    ]


def point_geometries(rows):
    return [{"type": "Point", "coordinates": [row["x"], row["y"]]} for row in rows]


def polygon_geometries(plots):
    """GeoJSON geometries of the plots: each ring inside an odd number of others is a hole of the
    innermost ring around it (the even-odd rule the plots are read and rasterised with)."""
    return [polygon_geometry(rings) for rings in plots.polygons]


def polygon_geometry(rings):
    """The GeoJSON geometry of one plot's rings (:func:`polygon_geometries`)."""
    parts = [[ring.tolist()] for ring in _outer_rings(rings, holes=False)]
    for hole, outer in _outer_rings(rings, holes=True):
        parts[outer].append(hole.tolist())
    if len(parts) == 1:
        return {"type": "Polygon", "coordinates": parts[0]}
    return {"type": "MultiPolygon", "coordinates": parts}


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
