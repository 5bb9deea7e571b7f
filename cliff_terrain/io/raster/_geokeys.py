"""GeoTIFF tags parsed once for the package: the GeoKeys, map units, the georeference, GDAL_NODATA.

One parser of each, with one behaviour everywhere:

* :func:`geo_keys` reads the GeoKeyDirectoryTag's keys (inline SHORT values, and with the
  GeoDoubleParams and GeoAsciiParams tags the values stored there); a truncated or malformed
  directory gives the keys read before the damage (so a CRS it cannot tell is refused below as
  unknown, not guessed). A user-defined projected CRS in metres (no EPSG code) is read by
  :mod:`.crs`.
* Map units come from :data:`LINEAR_UNITS` (EPSG unit codes, with the international foot and the US
  survey foot told apart). A surface model or orthophoto whose map or height units are not metres is
  refused by :func:`georeference` (heights, areas and volumes are computed in metres, and a DSM's
  heights in feet cannot be told from its map units reliably); a photo's ground size
  (:func:`cliff_terrain.io.photo._camera.geotiff_pixel_size`) is a scale only, converted to metres by the
  unit's own factor.
* :func:`nodata_value` reads GDAL_NODATA: empty or "none" means no value; any other text that is not
  a number is refused (:class:`RasterReadError` naming the file and the text), by every reader
  (surface models, orthophotos, mosaics): guessing would count fill values as heights or plants.
"""

from __future__ import annotations

import numpy as np

from ...errors import CliffTerrainError, GeoreferenceError, RasterReadError
from .transform import as_affine

# TIFF tags of the georeference and GDAL's no-data value.
MODEL_PIXEL_SCALE, MODEL_TIEPOINT, MODEL_TRANSFORMATION = 33550, 33922, 34264
GEO_KEY_DIRECTORY, GEO_DOUBLE_PARAMS, GEO_ASCII_PARAMS, GDAL_NODATA = 34735, 34736, 34737, 42113
GEO_TAGS = (MODEL_PIXEL_SCALE, MODEL_TIEPOINT, MODEL_TRANSFORMATION, GEO_KEY_DIRECTORY, GEO_DOUBLE_PARAMS)
GDAL_METADATA = 42112  # GDAL's XML metadata: a band's scale and offset among them
GEO_TAGS += (GEO_ASCII_PARAMS, GDAL_NODATA, GDAL_METADATA)

# GeoKey ids (GeoTIFF 1.1, section 7) and their codes used here.
GT_MODEL_TYPE, GT_RASTER_TYPE, GEOGRAPHIC_TYPE = 1024, 1025, 2048
PROJECTED_CS_TYPE, PROJ_LINEAR_UNITS, VERTICAL_UNITS = 3072, 3076, 4099
MODEL_PROJECTED, MODEL_GEOGRAPHIC, PIXEL_IS_POINT, USER_DEFINED = 1, 2, 2, 32767
METRE = 9001

#: EPSG linear unit code -> (name, metres per unit).
LINEAR_UNITS = {
    9001: ("metres", 1.0),
    9002: ("international feet", 0.3048),
    9003: ("US survey feet", 1200.0 / 3937.0),
    9004: ("modified American feet", 0.3048122530),
    9005: ("Clarke's feet", 0.3047972654),
    9036: ("kilometres", 1000.0),
}


def geo_keys(directory, doubles=None, ascii=None):
    """GeoKey id -> value of a GeoKeyDirectoryTag value: the keys stored inline (SHORT values), and
    with `doubles` (GeoDoubleParamsTag) and `ascii` (GeoAsciiParamsTag) those stored there (a float,
    or the text without its ``|`` terminator), which a user-defined CRS needs.

    Examples
    --------
    >>> geo_keys((1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32616))
    {1024: 1, 3072: 32616}
    >>> geo_keys((1, 1, 0, 2, 3088, 34736, 1, 0, 1026, 34737, 8, 0), doubles=(-96.9,), ascii="unknown|")
    {3088: -96.9, 1026: 'unknown'}
    """
    keys = {}
    if directory is None:
        return keys
    try:
        values = [int(v) for v in directory]
    except (TypeError, ValueError):
        return keys
    if len(values) < 4:
        return keys
    if isinstance(ascii, bytes):
        ascii = ascii.decode("latin-1")
    for k in range(values[3]):
        entry = values[4 + 4 * k : 8 + 4 * k]
        if len(entry) < 4:
            break
        key, location, count, offset = entry
        if location == 0:
            keys[key] = offset
        elif location == GEO_DOUBLE_PARAMS and doubles is not None and count >= 1:
            try:
                keys[key] = float(doubles[offset]) if count == 1 else tuple(doubles[offset : offset + count])
            except (IndexError, TypeError, ValueError):
                continue
        elif location == GEO_ASCII_PARAMS and isinstance(ascii, str) and count >= 1:
            keys[key] = ascii[offset : offset + count].rstrip("|\x00")
    return keys


def tag_geo_keys(tags):
    """:func:`geo_keys` of a mapping tag code -> value, every stored key resolved."""
    return geo_keys(tags.get(GEO_KEY_DIRECTORY), tags.get(GEO_DOUBLE_PARAMS), tags.get(GEO_ASCII_PARAMS))


def unit_metres(code):
    """Metres per unit of an EPSG linear unit code, or None for an unknown (or missing) code."""
    unit = LINEAR_UNITS.get(code)
    return None if unit is None else unit[1]


def check_metric_code(code, what, *, linear=True):
    """Refuse EPSG `code` when its unit is not the metre (:mod:`.epsg_units`): a GeoTIFF may give its
    CRS by the code alone, which then implies the unit (GeoTIFF 1.1, section 7.4). A geographic code
    is always refused; one in feet only with `linear` (a unit key of the file's own overrides it).
    `what` names the file in the message.

    Examples
    --------
    >>> check_metric_code(32616, "raster 'dsm.tif'")
    >>> check_metric_code(2236, "raster 'dsm.tif'")
    Traceback (most recent call last):
    ...
    cliff_terrain.errors.GeoreferenceError: raster 'dsm.tif' has map units in US survey feet (EPSG:2236); \
Cliff Terrain needs metres: reproject it to a projected CRS in metres (e.g. its UTM zone)
    """
    from .epsg_units import GEOGRAPHIC, UNITS, code_unit

    unit = code_unit(code)
    if unit is None or (unit != GEOGRAPHIC and not linear):
        return
    if unit == GEOGRAPHIC:
        raise GeoreferenceError(
            f"{what} is in degrees (geographic CRS EPSG:{code}); "
            "reproject it to a projected CRS in metres (e.g. its UTM zone)"
        )
    name = LINEAR_UNITS[unit][0] if unit in LINEAR_UNITS else f"{UNITS[unit][0]} units"
    raise GeoreferenceError(
        f"{what} has map units in {name} (EPSG:{code}); Cliff Terrain needs metres: "
        "reproject it to a projected CRS in metres (e.g. its UTM zone)"
    )


def code_metres(code):
    """Metres per map unit that a projected EPSG `code` implies, or None when unknown here: the
    unit's factor for a code in feet or another unit (:mod:`.epsg_units`), 1 for a UTM zone of
    WGS 84, NAD83 or ETRS89 (the metric codes photos carry).

    Examples
    --------
    >>> code_metres(32616), code_metres(2236), code_metres(4326)
    (1.0, 0.30480060960121924, None)
    """
    from .epsg_units import GEOGRAPHIC, UNITS, code_unit

    if not isinstance(code, int):
        return None
    unit = code_unit(code)
    if unit is not None:
        return None if unit == GEOGRAPHIC else UNITS[unit][1]
    # WGS 84 / UTM (326xx north, 327xx south), NAD83 / UTM (269xx), ETRS89 / UTM (258xx).
    utm = 32601 <= code <= 32660 or 32701 <= code <= 32760 or 26901 <= code <= 26923 or 25828 <= code <= 25838
    return 1.0 if utm else None


def georeference(tags, name):
    """(3x3 transform, CRS) from the GeoTIFF tags (tag code -> value), refusing what is not a metric map.

    The CRS is the EPSG code of ProjectedCSTypeGeoKey, or for a user-defined projected CRS in metres
    (code 32767, or none) a :class:`cliff_terrain.io.raster.crs.UserCrs` from its keys and citation.
    """
    keys = tag_geo_keys(tags)
    if MODEL_TIEPOINT in tags and MODEL_PIXEL_SCALE in tags:
        tie = [float(v) for v in tags[MODEL_TIEPOINT]]
        sx, sy = (float(v) for v in tags[MODEL_PIXEL_SCALE][:2])
        if len(tie) < 6 or sx <= 0 or sy <= 0:
            raise RasterReadError(f"raster {name!r} has a malformed ModelPixelScale/ModelTiepoint")
        i, j, x, y = tie[0], tie[1], tie[3], tie[4]
        transform = np.array([[sx, 0.0, x - i * sx], [0.0, -sy, y + j * sy], [0.0, 0.0, 1.0]])
    elif MODEL_TRANSFORMATION in tags:
        m = np.asarray(tags[MODEL_TRANSFORMATION], dtype=np.float64)
        if m.size != 16:
            raise RasterReadError(f"raster {name!r} has a malformed ModelTransformation")
        m = m.reshape(4, 4)
        transform = np.array([[m[0, 0], m[0, 1], m[0, 3]], [m[1, 0], m[1, 1], m[1, 3]], [0.0, 0.0, 1.0]])
    else:
        raise RasterReadError(
            f"raster {name!r} has no georeference (no ModelPixelScale+ModelTiepoint or ModelTransformation tags)"
        )
    try:
        transform = as_affine(transform)
    except CliffTerrainError:
        raise RasterReadError(f"raster {name!r} has a degenerate georeference") from None
    if keys.get(GT_RASTER_TYPE) == PIXEL_IS_POINT:
        # The tie point is a pixel's centre, not its corner (GDAL shifts by half a pixel too).
        transform[:2, 2] -= 0.5 * (transform[:2, 0] + transform[:2, 1])
    if keys.get(GT_MODEL_TYPE) == MODEL_GEOGRAPHIC or (
        PROJECTED_CS_TYPE not in keys and keys.get(GEOGRAPHIC_TYPE) is not None
    ):
        code = keys.get(GEOGRAPHIC_TYPE)
        raise GeoreferenceError(
            f"raster {name!r} is in degrees (geographic CRS{f' EPSG:{code}' if code else ''}); "
            "reproject it to a projected CRS in metres (e.g. its UTM zone)"
        )
    units = keys.get(PROJ_LINEAR_UNITS)
    if units not in (None, METRE):
        what = LINEAR_UNITS[units][0] if units in LINEAR_UNITS else f"GeoTIFF unit code {units}"
        raise GeoreferenceError(f"raster {name!r} has map units in {what}; Cliff Terrain needs metres")
    vertical = keys.get(VERTICAL_UNITS)
    if vertical in LINEAR_UNITS and vertical != METRE:
        raise GeoreferenceError(
            f"raster {name!r} has heights in {LINEAR_UNITS[vertical][0]}; Cliff Terrain needs metres"
        )
    code = keys.get(PROJECTED_CS_TYPE)
    if code is not None and code != USER_DEFINED:
        # Without the unit key the code implies the unit; with it the key wins, as in GDAL.
        check_metric_code(code, f"raster {name!r}", linear=units is None)
    if code is None or code == USER_DEFINED:
        from .crs import geokeys_crs

        crs = (
            geokeys_crs(keys, name=name)
            if keys.get(GT_MODEL_TYPE, MODEL_PROJECTED) == MODEL_PROJECTED
            else None
        )
        if crs is None:
            raise RasterReadError(
                f"raster {name!r} has an unknown CRS (no EPSG code in its GeoKeys, and no projection "
                "method, parameters and ellipsoid that define one); save it with an EPSG CRS"
            )
        return transform, crs
    return transform, code


def nodata_value(text, name):
    """GDAL_NODATA's value (the tag's ASCII text) as a float, or None when there is none.

    Examples
    --------
    >>> nodata_value("-3.4028234663852886e+38\\x00", "dsm.tif")
    -3.4028234663852886e+38
    >>> nodata_value("no", "dsm.tif")
    Traceback (most recent call last):
    ...
    cliff_terrain.errors.RasterReadError: raster 'dsm.tif' has an unreadable GDAL_NODATA value 'no'
    """
    if text is None:
        return None
    if isinstance(text, bytes):
        text = text.decode("ascii", "replace")
    text = str(text).strip().strip("\x00").strip()
    if text.lower() in ("", "none"):
        return None
    try:
        return float(text)
    except ValueError:
        raise RasterReadError(f"raster {name!r} has an unreadable GDAL_NODATA value {text!r}") from None


def gdal_items(text, samples):
    """(descriptions, scales, offsets) per sample from GDAL_METADATA's XML text (None where absent;
    a value that is not a number, or XML GDAL could not have written, says nothing)."""
    import xml.etree.ElementTree as ElementTree

    descriptions, scales, offsets = [None] * samples, [None] * samples, [None] * samples
    if text is None:
        return descriptions, scales, offsets
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    try:
        root = ElementTree.fromstring(str(text).strip().strip("\x00"))
    except ElementTree.ParseError:
        return descriptions, scales, offsets
    for item in root.iter("Item"):
        sample, role = item.get("sample"), (item.get("role") or "").lower()
        if sample is None or not sample.isdigit() or int(sample) >= samples:
            continue
        value = (item.text or "").strip()
        if role == "description" or item.get("name", "").upper() == "DESCRIPTION":
            descriptions[int(sample)] = value
        elif role in ("scale", "offset"):
            try:
                (scales if role == "scale" else offsets)[int(sample)] = float(value)
            except ValueError:
                pass
    return descriptions, scales, offsets


def scale_offset(text):
    """``(scale, offset)`` of band 1 from GDAL_METADATA's XML text (:func:`gdal_items`): stored
    values times scale plus offset are the heights; ``(1.0, 0.0)`` when the file gives neither. A DSM
    in centimetres as int16 with scale 0.01 is read in metres: without it, its heights would read
    100 times too tall.

    Examples
    --------
    >>> xml = '<GDALMetadata><Item name="SCALE" sample="0" role="scale">0.01</Item>'
    >>> xml += '<Item name="OFFSET" sample="0" role="offset">270</Item></GDALMetadata>'
    >>> scale_offset(xml)
    (0.01, 270.0)
    >>> scale_offset(None)
    (1.0, 0.0)
    """
    _, scales, offsets = gdal_items(text, 1)
    return (1.0 if scales[0] is None else scales[0]), (0.0 if offsets[0] is None else offsets[0])
