"""Write ``cliff_terrain/io/raster/epsg_units.py``: which EPSG CRS codes are not in metres.

    python tools/epsg_units.py        # needs pyproj (its proj.db holds the EPSG dataset)

A GeoTIFF may give a projected CRS by its EPSG code alone, without ProjLinearUnitsGeoKey: the code
then implies the unit (GeoTIFF 1.1, section 7.4). Cliff Terrain cannot carry pyproj into Blender
(its wheels hold PROJ's database, tens of MB each), so the one fact it needs from the database, the
unit of each code that is not the metre, is extracted here into ranges of consecutive codes and
written as a small module. Re-run this when the EPSG dataset gains codes in feet.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "cliff_terrain" / "io" / "raster" / "epsg_units.py"
GEOGRAPHIC = 0  # the ranges' "unit" of a geographic CRS (degrees)

HEADER = '''"""The EPSG CRS codes that are not in metres: projected CRSs in feet, links, yards..., and geographic ones.

Written by ``tools/epsg_units.py`` from the EPSG dataset {version} ({date}) in PROJ's database; not
edited by hand. A GeoTIFF may give its projected CRS by an EPSG code alone, without the unit key
(GeoTIFF 1.1, section 7.4: the code implies the unit), and a State Plane code in US survey feet was
then read as metres: heights 3.28 times too tall. Derived from the EPSG Geodetic Parameter Dataset
(IOGP, https://epsg.org; its terms of use: https://epsg.org/terms-of-use.html): only each code's unit.

:func:`code_unit` answers from ranges of consecutive codes; a code outside them is in metres or
unknown to the dataset (taken as metres, as before).

Examples
--------
>>> code_unit(2236)  # NAD83 / Florida East (ftUS)
9003
>>> code_unit(32616) is None  # WGS 84 / UTM zone 16N: metres
True
>>> code_unit(4326)  # WGS 84: geographic
0
"""

from bisect import bisect_right

#: The ranges' unit of a geographic CRS (degrees).
GEOGRAPHIC = 0

#: EPSG unit code -> (its name, metres per unit), for every linear unit in :data:`RANGES`.
UNITS = {names}

#: (first code, last code, EPSG unit code or :data:`GEOGRAPHIC`), sorted, not overlapping; every code
#: in a range that the dataset holds has that unit.
# fmt: off
RANGES = (
{ranges})
# fmt: on

_FIRSTS = tuple(first for first, _, _ in RANGES)


def code_unit(code):
    """The EPSG unit code of CRS `code` when it is not the metre, :data:`GEOGRAPHIC` for a geographic
    CRS, None for a code in metres (or one the dataset does not hold)."""
    index = bisect_right(_FIRSTS, int(code)) - 1
    if index >= 0 and RANGES[index][0] <= int(code) <= RANGES[index][1]:
        return RANGES[index][2]
    return None
'''


def main():
    import pyproj
    from pyproj.database import get_database_metadata

    con = sqlite3.connect(Path(pyproj.datadir.get_data_dir()) / "proj.db")
    rows = con.execute(
        "select cast(p.code as int), cast(a.uom_code as int), u.name, u.conv_factor from projected_crs p "
        "join axis a on a.coordinate_system_auth_name = p.coordinate_system_auth_name "
        "and a.coordinate_system_code = p.coordinate_system_code "
        "join unit_of_measure u on u.auth_name = a.uom_auth_name and u.code = a.uom_code "
        "where p.auth_name = 'EPSG' and a.uom_auth_name = 'EPSG' and a.coordinate_system_order = 1"
    ).fetchall()
    kind = {code: unit for code, unit, _, _ in rows}
    names = {unit: (name, factor) for _, unit, name, factor in rows if unit != 9001}
    for (code,) in con.execute(
        "select cast(code as int) from geodetic_crs where auth_name = 'EPSG' "
        "and type in ('geographic 2D', 'geographic 3D')"
    ):
        kind[code] = GEOGRAPHIC
    ranges = []
    previous = None  # the last code held, of any unit: a range never spans a code of another unit
    for code in sorted(kind):
        unit = kind[code]
        if unit != 9001:
            if ranges and ranges[-1][2] == unit and previous == ranges[-1][1]:
                ranges[-1][1] = code
            else:
                ranges.append([code, code, unit])
        previous = code
    cells = [f"({a}, {b}, {u})," for a, b, u in ranges]
    lines = "".join("    " + " ".join(cells[i : i + 5]) + "\n" for i in range(0, len(cells), 5))
    text = HEADER.format(
        version=get_database_metadata("EPSG.VERSION"),
        date=get_database_metadata("EPSG.DATE"),
        names="{" + ", ".join(f"{u}: {n!r}" for u, n in sorted(names.items())) + "}",
        ranges=lines,
    )
    OUT.write_text(text, encoding="utf-8")
    print(f"{OUT}: {len(ranges)} ranges")


if __name__ == "__main__":
    main()
