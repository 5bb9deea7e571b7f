"""Projected CRSs in metres that carry no EPSG code, read from a GeoTIFF's GeoKeys or a WKT1 .prj.

Exports from R (FIELDimageR through terra/sf), older Pix4D projects and local survey grids carry a
*user-defined* projected CRS: an azimuthal equidistant on a sphere, a local transverse Mercator...
The GeoTIFF holds it as ``ProjectedCSTypeGeoKey = 32767`` with the projection method
(``ProjCoordTransGeoKey``), its parameters, the ellipsoid and ``ProjLinearUnitsGeoKey = 9001``
(metre), often with the WKT or the ESRI "PE string" in a citation; the Shapefile's ``.prj`` holds
ESRI WKT1. :class:`UserCrs` is such a CRS, and two of them are **the same CRS when they agree**:

* the same projection method (its WKT1 or ESRI name, or the GeoTIFF code, mapped to one name);
* the same parameters: longitude and latitude of the origin to 1e-9 degree, false easting and
  northing to 0.1 mm, scale factor and standard parallels; a parameter one definition leaves out
  takes its WKT default (0, or 1 for a scale factor);
* the same ellipsoid: semi-major axis to 1 mm and inverse flattening to 1e-9 (a sphere has none);
* the same prime meridian, and metres as the unit (feet and degrees are refused, as for EPSG CRSs).

Names (``"unknown"``, ``"D_unknown"``, ``"unnamed"``) are not compared: each writer makes up its
own for a CRS without a code. Datums are compared through their ellipsoid (a user-defined CRS on a
user-defined datum has nothing else to compare).

Why not pyproj: it is the field's library and ``pyproj.CRS.equals`` would do this, but the readers
run inside Blender too (measured heights in the sidebar), where every dependency must come as
wheels in the extension for 4 platforms x 2 Pythons, and pyproj's wheels carry PROJ and its
database (tens of MB each). What is needed is the small WKT1 subset above and the GeoKeys already
parsed by :mod:`._geokeys`; one parser (:func:`parse_wkt`) reads the bracket grammar of WKT1
(OGC 01-009 section 7), the same for ESRI's dialect.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from ...errors import CliffTerrainError

# Projection method names (WKT1 OGC, ESRI, PROJ) and GeoTIFF CT codes -> one name.
_METHODS = {
    "transverse_mercator": "Transverse_Mercator",
    "gauss_kruger": "Transverse_Mercator",
    "azimuthal_equidistant": "Azimuthal_Equidistant",
    "lambert_azimuthal_equal_area": "Lambert_Azimuthal_Equal_Area",
    "lambert_conformal_conic_1sp": "Lambert_Conformal_Conic_1SP",
    "lambert_conformal_conic_2sp": "Lambert_Conformal_Conic_2SP",
    "lambert_conformal_conic": "Lambert_Conformal_Conic_2SP",  # ESRI's name of both
    "albers_conic_equal_area": "Albers_Conic_Equal_Area",
    "albers": "Albers_Conic_Equal_Area",
    "mercator_1sp": "Mercator_1SP",
    "mercator": "Mercator_1SP",
    "mercator_2sp": "Mercator_2SP",
    "orthographic": "Orthographic",
    "stereographic": "Stereographic",
    "oblique_stereographic": "Oblique_Stereographic",
    "double_stereographic": "Oblique_Stereographic",
    "polar_stereographic": "Polar_Stereographic",
    "equirectangular": "Equirectangular",
    "equidistant_cylindrical": "Equirectangular",
    "plate_carree": "Equirectangular",
    "cassini_soldner": "Cassini_Soldner",
    "cassini": "Cassini_Soldner",
    "sinusoidal": "Sinusoidal",
    "hotine_oblique_mercator": "Hotine_Oblique_Mercator",
    "oblique_mercator": "Hotine_Oblique_Mercator",
    "gnomonic": "Gnomonic",
    "polyconic": "Polyconic",
    "new_zealand_map_grid": "New_Zealand_Map_Grid",
}

# GeoTIFF 1.1 ProjCoordTransGeoKey codes (section 7.5.5) -> the method names above.
COORD_TRANSFORMS = {
    1: "Transverse_Mercator",
    3: "Hotine_Oblique_Mercator",
    7: "Mercator_1SP",
    8: "Lambert_Conformal_Conic_2SP",
    9: "Lambert_Conformal_Conic_1SP",
    10: "Lambert_Azimuthal_Equal_Area",
    11: "Albers_Conic_Equal_Area",
    12: "Azimuthal_Equidistant",
    14: "Stereographic",
    15: "Polar_Stereographic",
    16: "Oblique_Stereographic",
    17: "Equirectangular",
    18: "Cassini_Soldner",
    19: "Gnomonic",
    21: "Orthographic",
    22: "Polyconic",
    24: "Sinusoidal",
    26: "New_Zealand_Map_Grid",
}

# Parameter names (WKT1 OGC and ESRI) -> one role each, in degrees or metres.
_PARAMETERS = {
    "central_meridian": "longitude_of_origin",
    "longitude_of_origin": "longitude_of_origin",
    "longitude_of_center": "longitude_of_origin",
    "longitude_of_centre": "longitude_of_origin",
    "longitude_of_natural_origin": "longitude_of_origin",
    "straight_vertical_longitude_from_pole": "longitude_of_origin",
    "latitude_of_origin": "latitude_of_origin",
    "latitude_of_center": "latitude_of_origin",
    "latitude_of_centre": "latitude_of_origin",
    "latitude_of_natural_origin": "latitude_of_origin",
    "standard_parallel_1": "standard_parallel_1",
    "standard_parallel_2": "standard_parallel_2",
    "scale_factor": "scale_factor",
    "scale_factor_at_natural_origin": "scale_factor",
    "false_easting": "false_easting",
    "false_northing": "false_northing",
    "azimuth": "azimuth",
    "rectified_grid_angle": "rectified_grid_angle",
}
_DEFAULTS = {"scale_factor": 1.0, "false_easting": 0.0, "false_northing": 0.0}
_METRIC = ("false_easting", "false_northing")


@dataclass(frozen=True, eq=False)
class UserCrs:
    """A projected CRS in metres without an EPSG code (see the module's docs for "agree").

    Attributes
    ----------
    method : str
        The projection method, e.g. ``"Azimuthal_Equidistant"``.
    parameters : dict
        Role -> value (degrees for angles, metres for false easting/northing), defaults filled in.
    semi_major : float
        Of the ellipsoid, metres.
    inverse_flattening : float
        0 for a sphere.
    prime_meridian : float
        Degrees east of Greenwich.
    wkt : str
        The WKT as read (or written from the GeoKeys when the file carries none): what
        ``summary.json`` records and a ``.prj`` written for these plots holds.
    """

    method: str
    parameters: dict = field(hash=False)
    semi_major: float
    inverse_flattening: float
    prime_meridian: float
    wkt: str

    def __eq__(self, other):
        if isinstance(other, int) and not isinstance(other, bool):
            # An EPSG code this module can define (WGS 84 / UTM): a .prj that spells a UTM zone out
            # without its code is that zone.
            wkt = utm_wkt(other)
            return wkt is not None and self == wkt_crs(wkt, source=f"EPSG:{other}")
        if not isinstance(other, UserCrs):
            return NotImplemented
        if self.method != other.method:
            return False
        if not math.isclose(self.semi_major, other.semi_major, rel_tol=0.0, abs_tol=1e-3):
            return False
        if not math.isclose(self.inverse_flattening, other.inverse_flattening, rel_tol=1e-9, abs_tol=1e-9):
            return False
        if not math.isclose(self.prime_meridian, other.prime_meridian, abs_tol=1e-9):
            return False
        names = set(self.parameters) | set(other.parameters)
        for name in names:
            a = self.parameters.get(name, _DEFAULTS.get(name, 0.0))
            b = other.parameters.get(name, _DEFAULTS.get(name, 0.0))
            if not math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-4 if name in _METRIC else 1e-9):
                return False
        return True

    def __hash__(self):  # not a dict key beside EPSG codes: equal to one, it hashes apart from it
        return hash(self.method)

    def __str__(self):
        where = ", ".join(
            f"{name.replace('_', ' ')} {value:g}"
            for name, value in self.parameters.items()
            if name in ("longitude_of_origin", "latitude_of_origin")
        )
        body = "a sphere" if self.inverse_flattening == 0 else "an ellipsoid"
        return (
            f"a user-defined {self.method.replace('_', ' ')} CRS ({where}{', ' if where else ''}on {body} "
            f"of {self.semi_major:.0f} m, no EPSG code)"
        )


def utm_wkt(code):
    """ESRI WKT1 of a WGS 84 / UTM EPSG code (326xx north, 327xx south), None for any other code."""
    if not (32601 <= code <= 32660 or 32701 <= code <= 32760):
        return None
    zone, north = code % 100, code < 32700
    return (
        f'PROJCS["WGS_1984_UTM_Zone_{zone}{"N" if north else "S"}",GEOGCS["GCS_WGS_1984",'
        'DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],'
        'UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
        f'PARAMETER["False_Easting",500000.0],PARAMETER["False_Northing",{0.0 if north else 10000000.0}],'
        f'PARAMETER["Central_Meridian",{-183 + 6 * zone}.0],PARAMETER["Scale_Factor",0.9996],'
        'PARAMETER["Latitude_Of_Origin",0.0],UNIT["Meter",1.0]]'
    )


def crs_text(crs):
    """How a message names a CRS: ``EPSG:32616`` or the user-defined CRS described."""
    return str(crs) if isinstance(crs, UserCrs) else f"EPSG:{crs}"


def crs_record(crs):
    """A CRS for JSON files and Blender properties: the EPSG code, or the WKT of a user-defined one."""
    if crs is None:
        return None
    return crs.wkt if isinstance(crs, UserCrs) else int(crs)


def crs_from_record(value, *, source="a record"):
    """The CRS :func:`crs_record` wrote: an EPSG code or a :class:`UserCrs` from its WKT."""
    if value is None:
        return None
    if isinstance(value, str):
        return wkt_crs(value, source=source)
    return int(value)


# ---- WKT1 ----


def parse_wkt(text):
    """The tree of a WKT1 string: ``(keyword, [values and child trees])``.

    Examples
    --------
    >>> parse_wkt('UNIT["Meter",1.0]')
    ('UNIT', ['Meter', 1.0])
    """
    tokens = re.findall(r'"(?:[^"]|"")*"|[\[\](),]|[^\[\](),"\s]+', text)
    position = 0

    def node():
        nonlocal position
        keyword = tokens[position]
        position += 1
        if position >= len(tokens) or tokens[position] not in "[(":
            return keyword  # a bare value (an enumeration like NORTH)
        position += 1
        values = []
        while tokens[position] not in "])":
            token = tokens[position]
            if token == ",":
                position += 1
                continue
            if token.startswith('"'):
                values.append(token[1:-1].replace('""', '"'))
                position += 1
                continue
            try:
                values.append(float(token))
                position += 1
            except ValueError:
                values.append(node())
        position += 1
        return keyword.upper(), values

    try:
        tree = node()
    except IndexError:
        raise ValueError("unbalanced brackets") from None
    if not isinstance(tree, tuple) or position != len(tokens):
        raise ValueError("not one bracketed WKT element")
    return tree


def _children(values, keyword):
    return [v for v in values if isinstance(v, tuple) and v[0] == keyword]


def _key(name):
    return re.sub(r"[^a-z0-9]+", "_", str(name).lower()).strip("_")


def wkt_crs(wkt, *, source, error=CliffTerrainError):
    """A :class:`UserCrs` from a WKT1 ``PROJCS`` (OGC or ESRI), refusing what is not metres.

    Raises
    ------
    CliffTerrainError
        (`error`, naming `source`) Not WKT, not a projected CRS, an unknown projection method, or
        units other than metres.

    Examples
    --------
    >>> crs = wkt_crs('PROJCS["unknown",GEOGCS["GCS_unknown",DATUM["D_unknown",SPHEROID["unknown",'
    ...     '6371007.181,0.0]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],'
    ...     'PROJECTION["Azimuthal_Equidistant"],PARAMETER["False_Easting",0.0],'
    ...     'PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-96.9],'
    ...     'PARAMETER["Latitude_Of_Origin",40.1],UNIT["Meter",1.0]]', source="plots.prj")
    >>> crs.method, crs.parameters["longitude_of_origin"], crs.semi_major
    ('Azimuthal_Equidistant', -96.9, 6371007.181)
    """
    text = wkt.strip()
    try:
        keyword, values = parse_wkt(text)
    except ValueError as exc:
        raise error(f"{source!r}: its CRS is not readable WKT ({exc}): {text[:60]!r}") from None
    if keyword in ("GEOGCS", "GEOGCRS"):
        raise error(
            f"{source!r} is in degrees (a geographic CRS); reproject it to a projected CRS in metres "
            "(e.g. its UTM zone)"
        )
    if keyword != "PROJCS":
        raise error(f"{source!r}: its CRS is a {keyword}, not a projected CRS (PROJCS) in metres")
    projection = _children(values, "PROJECTION")
    method = _METHODS.get(_key(projection[0][1][0])) if projection and projection[0][1] else None
    if method is None:
        what = repr(projection[0][1][0]) if projection and projection[0][1] else "none"
        raise error(
            f"{source!r}: its projection method ({what}) is not one Cliff Terrain knows; "
            "save it with an EPSG CRS"
        )
    units = _children(values, "UNIT")
    factor = units[-1][1][1] if units and len(units[-1][1]) > 1 else None
    if not isinstance(factor, float) or abs(factor - 1.0) > 1e-12:
        name = units[-1][1][0] if units else "no unit"
        raise error(f"{source!r} has map units in {name} ({factor} m); Cliff Terrain needs metres")
    parameters = {}
    for _, (name, value, *_) in _children(values, "PARAMETER"):
        role = _PARAMETERS.get(_key(name), _key(name))
        parameters[role] = float(value)
    for name, default in _DEFAULTS.items():
        parameters.setdefault(name, default)
    semi_major, inverse_flattening, prime_meridian = 0.0, 0.0, 0.0
    for _, geog in _children(values, "GEOGCS"):
        for _, datum in _children(geog, "DATUM"):
            for _, spheroid in _children(datum, "SPHEROID"):
                semi_major, inverse_flattening = float(spheroid[1]), float(spheroid[2])
        for _, primem in _children(geog, "PRIMEM"):
            prime_meridian = float(primem[1])
    if semi_major <= 0:
        raise error(f"{source!r}: its CRS has no ellipsoid (GEOGCS[DATUM[SPHEROID]])")
    return UserCrs(method, parameters, semi_major, inverse_flattening, prime_meridian, text)


def geokeys_crs(keys, *, name):
    """A :class:`UserCrs` from a GeoTIFF's user-defined projected CRS keys (id -> value, with the
    GeoDoubleParams and GeoAsciiParams values resolved), or None when they do not define one.

    A WKT or ESRI PE string in a citation key wins (it is what the writer meant, the same text as
    the .prj beside it); otherwise the CRS comes from the projection keys.
    """
    for key in (3073, 1026):  # PCSCitationGeoKey, GTCitationGeoKey
        citation = keys.get(key)
        if isinstance(citation, str):
            match = re.search(r"PROJCS\[.*\]", citation, flags=re.DOTALL)
            if match:
                try:
                    return wkt_crs(match.group(0), source=name)
                except CliffTerrainError:
                    break  # an unreadable citation: the keys themselves decide
    method = COORD_TRANSFORMS.get(keys.get(3075))
    if method is None:
        return None
    roles = {
        3078: "standard_parallel_1",
        3079: "standard_parallel_2",
        3080: "longitude_of_origin",
        3081: "latitude_of_origin",
        3082: "false_easting",
        3083: "false_northing",
        3084: "longitude_of_origin",
        3085: "latitude_of_origin",
        3086: "false_easting",
        3087: "false_northing",
        3088: "longitude_of_origin",
        3089: "latitude_of_origin",
        3090: "false_easting",
        3091: "false_northing",
        3092: "scale_factor",
        3093: "scale_factor",
        3094: "azimuth",
        3095: "longitude_of_origin",
    }
    parameters = dict(_DEFAULTS)
    for key, role in roles.items():
        if isinstance(keys.get(key), float | int) and key in keys:
            parameters[role] = float(keys[key])
    ellipsoid = keys.get(2056)
    if ellipsoid == 7030 or keys.get(2050) == 6326 or keys.get(2048) == 4326:  # WGS 84
        semi_major, inverse_flattening = 6378137.0, 298.257223563
    else:
        semi_major = keys.get(2057)
        if not isinstance(semi_major, float | int) or semi_major <= 0:
            return None
        semi_major = float(semi_major)
        if isinstance(keys.get(2059), float | int):
            inverse_flattening = float(keys[2059])
        elif isinstance(keys.get(2058), float | int) and keys[2058] < semi_major:
            inverse_flattening = semi_major / (semi_major - float(keys[2058]))
        else:
            inverse_flattening = 0.0  # a sphere
    prime_meridian = float(keys.get(2061, 0.0)) if isinstance(keys.get(2061, 0.0), float | int) else 0.0
    crs = UserCrs(method, parameters, semi_major, inverse_flattening, prime_meridian, "")
    return UserCrs(method, parameters, semi_major, inverse_flattening, prime_meridian, esri_wkt(crs))


def esri_wkt(crs):
    """ESRI WKT1 of a :class:`UserCrs` (what a .prj holds), for one made from GeoKeys alone."""
    if crs.wkt:
        return crs.wkt
    names = {
        "longitude_of_origin": "Central_Meridian",
        "latitude_of_origin": "Latitude_Of_Origin",
        "standard_parallel_1": "Standard_Parallel_1",
        "standard_parallel_2": "Standard_Parallel_2",
        "scale_factor": "Scale_Factor",
        "false_easting": "False_Easting",
        "false_northing": "False_Northing",
        "azimuth": "Azimuth",
    }
    parameters = ",".join(
        f'PARAMETER["{names.get(k, k)}",{float(v)!r}]' for k, v in sorted(crs.parameters.items())
    )
    return (
        f'PROJCS["unknown",GEOGCS["GCS_unknown",DATUM["D_unknown",SPHEROID["unknown",{crs.semi_major!r},'
        f'{crs.inverse_flattening!r}]],PRIMEM["Greenwich",{crs.prime_meridian!r}],'
        f'UNIT["Degree",0.0174532925199433]],PROJECTION["{crs.method}"],{parameters},UNIT["Meter",1.0]]'
    )


# GeoTIFF key of each parameter role, for writing (section 7.6: natural origin, false easting...).
_WRITE_KEYS = {
    "standard_parallel_1": 3078,
    "standard_parallel_2": 3079,
    "longitude_of_origin": 3080,
    "latitude_of_origin": 3081,
    "false_easting": 3082,
    "false_northing": 3083,
    "scale_factor": 3092,
    "azimuth": 3094,
}
# Methods whose origin GeoTIFF stores as a "center" (ProjCenterLong/LatGeoKey), as GDAL writes them.
_CENTRED = {
    "Azimuthal_Equidistant",
    "Lambert_Azimuthal_Equal_Area",
    "Orthographic",
    "Hotine_Oblique_Mercator",
}


def user_geokeys(crs):
    """(GeoKeyDirectoryTag, GeoDoubleParamsTag, GeoAsciiParamsTag) values of a :class:`UserCrs`,
    laid out as GDAL writes a user-defined projected CRS, with its WKT as the ESRI PE string."""
    code = next(c for c, m in COORD_TRANSFORMS.items() if m == crs.method)
    ascii_keys = {1026: f"ESRI PE String = {crs.wkt}"}
    doubles = {2057: crs.semi_major, 2059: crs.inverse_flattening, 2061: crs.prime_meridian}
    for role, value in crs.parameters.items():
        key = _WRITE_KEYS.get(role)
        if key is None:
            continue
        if crs.method in _CENTRED and key in (3080, 3081):
            key += 8  # ProjCenterLong/LatGeoKey
        doubles[key] = value
    shorts = {1024: 1, 1025: 1, 2048: 32767, 2050: 32767, 2054: 9102, 2056: 32767, 3072: 32767}
    shorts |= {3074: 32767, 3075: code, 3076: 9001}
    entries, double_values, text = [], [], ""
    for key in sorted({*shorts, *doubles, *ascii_keys}):
        if key in shorts:
            entries.append((key, 0, 1, shorts[key]))
        elif key in doubles:
            entries.append((key, 34736, 1, len(double_values)))
            double_values.append(float(doubles[key]))
        else:
            value = ascii_keys[key] + "|"
            entries.append((key, 34737, len(value), len(text)))
            text += value
    directory = [1, 1, 0, len(entries)] + [v for entry in entries for v in entry]
    return tuple(directory), tuple(double_values), text
