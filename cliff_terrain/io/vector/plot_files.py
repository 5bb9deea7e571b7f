"""Plot grid files: the field book joined to the plots, checks against the orthophoto, GeoJSON and
Shapefile output (with a .prj for the CRS)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ...errors import CliffTerrainError, PlotFileError
from ..raster.transform import affine_inverse, apply_affine, as_affine
from .geojson import polygon_geometries, table_geojson


def read_field_book(path):
    """The rows of a field book CSV (dicts of strings); its header must name ``plot`` or ``column`` and ``row``.

    Names are matched without regard to case (``Plot``, ``COLUMN``).
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as stream:
            rows = list(csv.DictReader(stream))
    except UnicodeDecodeError as exc:
        raise PlotFileError(
            f"the field book {str(path)!r} is not a text CSV (byte {exc.object[exc.start]:#04x} at "
            f"{exc.start} is not UTF-8); save it as CSV UTF-8"
        ) from None
    except (OSError, csv.Error) as exc:
        raise PlotFileError(f"cannot read the field book {str(path)!r}: {exc}") from None
    if not rows:
        raise PlotFileError(f"the field book {str(path)!r} has no rows")
    for i, row in enumerate(rows):
        if None in row:  # csv.DictReader's key for the values beyond the header's columns
            header = [k for k in row if k is not None]
            hint = (
                f"; its header is one column, {header[0]!r}: save it comma-separated"
                if len(header) == 1 and any(c in header[0] for c in ";\t|")
                else " (a trailing comma, or a value with a comma that is not quoted?)"
            )
            raise PlotFileError(
                f"the field book {str(path)!r} row {i + 2} has {len(header) + len(row[None])} values "
                f"for the header's {len(header)} columns{hint}"
            )
    return [{(k or "").strip(): (v or "").strip() for k, v in row.items()} for row in rows], str(path)


def join_field_book(attributes, field_book):
    """The field book's values for each plot in `attributes`, and the columns added.

    `field_book` is ``(rows, name)`` as :func:`read_field_book` returns, or a list of dicts.
    Joined by ``plot`` when the book has it, else by ``column`` and ``row``. Every plot needs
    exactly one row, and every row a plot.
    """
    rows, name = field_book if isinstance(field_book, tuple) else (field_book, "the field book")
    lower = {k.lower(): k for k in rows[0]}
    if "plot" in lower:
        keys = [lower["plot"]]

        def plot_key(a):
            return (a["plot"],)
    elif "column" in lower and "row" in lower:
        keys = [lower["column"], lower["row"]]

        def plot_key(a):
            return (a["column"], a["row"])
    else:
        raise PlotFileError(
            f"{name!r} needs a `plot` column, or `column` and `row` columns; it has {list(rows[0])}"
        )
    book = {}
    for i, row in enumerate(rows):
        try:
            key = tuple(int(float(row[k])) for k in keys)
        except (TypeError, ValueError):
            raise PlotFileError(
                f"{name!r} row {i + 2}: {keys} must be whole numbers, got {[row[k] for k in keys]}"
            ) from None
        if key in book:
            raise PlotFileError(
                f"{name!r}: plot {_key_text(keys, key)} appears twice (rows {book[key][0] + 2} and {i + 2})"
            )
        book[key] = (i, row)
    wanted = {plot_key(a) for a in attributes}
    unknown = sorted(set(book) - wanted)
    missing = sorted(wanted - set(book))
    if unknown:
        raise PlotFileError(f"{name!r} names plots the grid does not have: {_key_list(keys, unknown)}")
    if missing:
        raise PlotFileError(f"{name!r} has no row for plots {_key_list(keys, missing)}")
    ours = {"plot", "column", "row"}
    columns = [k for k in rows[0] if k and k.lower() not in ours]
    renamed = {k: (f"{k}_book" if k in ours else k) for k in columns}
    extra = [{renamed[k]: book[plot_key(a)][1][k] for k in columns} for a in attributes]
    return extra, [renamed[k] for k in columns]


def _key_text(keys, key):
    return " ".join(f"{k}={v}" for k, v in zip(keys, key, strict=True))


def _key_list(keys, items, limit=6):
    text = ", ".join(_key_text(keys, k) for k in items[:limit])
    return text + (f" and {len(items) - limit} more" if len(items) > limit else "")


def check_plots_fit(plots, *, transform, shape, source):
    """Refuse plots outside the raster or overlapping each other (one line naming `source`)."""
    inverse = affine_inverse(as_affine(transform))
    rows, cols = shape
    outside = []
    for attributes, rings in zip(plots.attributes, plots.polygons, strict=True):
        points = rings[0][:, :2]
        pix = apply_affine(inverse, points)
        if (
            (pix[:, 0] < -0.5).any()
            or (pix[:, 1] < -0.5).any()
            or (pix[:, 0] > cols + 0.5).any()
            or (pix[:, 1] > rows + 0.5).any()
        ):
            outside.append(attributes["plot"])
    if outside:
        raise CliffTerrainError(
            f"plots {outside[:8]}{' ...' if len(outside) > 8 else ''} lie outside {source!r} "
            f"({len(outside)} of {len(plots)}); check the placement and the grid's size"
        )
    overlaps = _overlaps(plots)
    if overlaps:
        a, b = overlaps[0]
        raise CliffTerrainError(
            f"plots {a} and {b} overlap ({len(overlaps)} pairs): the pitch is smaller than the plot size, "
            "or the corners are too close together"
        )


def _overlaps(plots):
    """Pairs of plot numbers whose convex quadrilaterals overlap (separating-axis test)."""
    quads = [rings[0][:4] for rings in plots.polygons]
    numbers = [a["plot"] for a in plots.attributes]
    lows = np.array([q.min(axis=0) for q in quads])
    highs = np.array([q.max(axis=0) for q in quads])
    pairs = []
    for i in range(len(quads)):
        candidates = np.nonzero(
            (lows[i + 1 :] < highs[i]).all(axis=1) & (highs[i + 1 :] > lows[i]).all(axis=1)
        )[0]
        for j in candidates + i + 1:
            if _convex_overlap(quads[i], quads[j]):
                pairs.append((numbers[i], numbers[j]))
    return pairs


def _convex_overlap(a, b, tolerance=1e-6):
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        for edge in edges:
            normal = np.array([-edge[1], edge[0]])
            norm = np.hypot(*normal)
            if norm == 0:
                continue
            pa, pb = a @ normal / norm, b @ normal / norm
            if pa.max() <= pb.min() + tolerance or pb.max() <= pa.min() + tolerance:
                return False
    return True


def write_plots(plots, path, *, crs):
    """Write `plots` as GeoJSON, or as an ESRI Shapefile (with its .prj) when `path` ends in ``.shp``."""
    path = Path(path)
    rows = [dict(a) for a in plots.attributes]
    if path.suffix.lower() != ".shp":
        path.write_text(table_geojson(rows, polygon_geometries(plots), crs=crs))
        return [path]
    import shapefile

    with shapefile.Writer(str(path.with_suffix("")), shapeType=shapefile.POLYGON) as writer:
        for name in plots.fields:
            numeric = all(isinstance(a.get(name), int) for a in plots.attributes)
            writer.field(name[:10], "N" if numeric else "C", size=18 if numeric else 254)
        for attributes, rings in zip(plots.attributes, plots.polygons, strict=True):
            # Shapefile outer rings run clockwise.
            writer.poly([ring[::-1].tolist() if _ccw(ring) else ring.tolist() for ring in rings])
            writer.record(*[attributes.get(name) for name in plots.fields])
    # pyshp names the files in lower case whatever the name's case ("plots.SHP" -> plots.shp).
    base = path.with_suffix("")
    prj = base.with_suffix(".prj")
    prj.write_text(epsg_wkt(crs))
    return [base.with_suffix(".shp"), base.with_suffix(".shx"), base.with_suffix(".dbf"), prj]


def _ccw(ring):
    x, y = ring[:, 0], ring[:, 1]
    return float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1])) > 0


def epsg_wkt(crs):
    """ESRI WKT of a CRS for a .prj: WGS 84 / UTM zones in full, other codes by authority only, a
    user-defined CRS (:class:`cliff_terrain.io.raster.crs.UserCrs`) as it was read."""
    from ..raster.crs import UserCrs, utm_wkt

    if isinstance(crs, UserCrs):
        return crs.wkt
    crs = int(crs)
    return utm_wkt(crs) or f'PROJCS["EPSG:{crs}",AUTHORITY["EPSG","{crs}"]]'
