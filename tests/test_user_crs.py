"""Projected CRSs in metres without an EPSG code (issue 40): read from GeoKeys and .prj, agreed on.

The fixtures are written the way the exports are, independently of the package's writer: GeoTIFFs
with GDAL's layout of a user-defined azimuthal equidistant on a sphere (ProjectedCSTypeGeoKey
32767, the projection's keys in GeoDoubleParams, the ESRI PE string in GTCitationGeoKey), and a
Shapefile whose .prj is the ESRI WKT1 that R's sf/terra write for FIELDimageR's plots.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import shapefile
import tifffile
from conftest import REPO

from cliff_terrain.data.synthetic_surface import synthetic_surface
from cliff_terrain.errors import GeoreferenceError, PlotFileError, RasterReadError
from cliff_terrain.io.raster.crs import UserCrs, parse_wkt, wkt_crs
from cliff_terrain.io.raster.geotiff import read_orthophoto, read_surface, write_geotiff
from cliff_terrain.io.vector.plot_polygons import read_plots

# The CRS of an R export centred on its field: AEQD on the authalic sphere GDAL/PROJ use for it.
SPHERE = 6371007.181
AEQD_PRJ = (
    'PROJCS["unknown",GEOGCS["GCS_unknown",DATUM["D_unknown",SPHEROID["unknown",6371007.181,0.0]],'
    'PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Azimuthal_Equidistant"],'
    'PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-96.6],'
    'PARAMETER["Latitude_Of_Origin",39.2],UNIT["Meter",1.0]]'
)
# The same CRS in OGC WKT1 (GDAL's exportToWkt) with other names and the parameters in another order.
AEQD_OGC = (
    'PROJCS["unnamed",GEOGCS["unnamed ellipse",DATUM["unknown",SPHEROID["unnamed",6371007.181,0]],'
    'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]]],'
    'PROJECTION["Azimuthal_Equidistant"],PARAMETER["latitude_of_center",39.2],'
    'PARAMETER["longitude_of_center",-96.6],PARAMETER["false_easting",0],PARAMETER["false_northing",0],'
    'UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
)
GSD = 0.02
ORIGIN = (-4.5, 3.0)  # map x, y of the top-left corner: metres from the AEQD's centre


def aeqd_keys(*, lon=-96.6, lat=39.2, units=9001, citation=AEQD_PRJ):
    """(GeoKeyDirectory, GeoDoubleParams, GeoAsciiParams) as GDAL writes a user-defined AEQD."""
    text = f"ESRI PE String = {citation}|" if citation else ""
    doubles = [SPHERE, SPHERE, 0.0, lon, lat, 0.0, 0.0]
    keys = [1024, 0, 1, 1, 1025, 0, 1, 1]
    keys += [1026, 34737, len(text), 0] if citation else []
    keys += [2048, 0, 1, 32767, 2050, 0, 1, 32767, 2054, 0, 1, 9102, 2056, 0, 1, 32767]
    keys += [2057, 34736, 1, 0, 2058, 34736, 1, 1, 2061, 34736, 1, 2]
    keys += [3072, 0, 1, 32767, 3074, 0, 1, 32767, 3075, 0, 1, 12, 3076, 0, 1, units]
    keys += [3082, 34736, 1, 5, 3083, 34736, 1, 6, 3088, 34736, 1, 3, 3089, 34736, 1, 4]
    return (1, 1, 0, len(keys) // 4, *keys), tuple(doubles), text


def write_user_tiff(path, data, *, keys, **options):
    directory, doubles, text = keys
    tags = [
        (33550, 12, 3, (GSD, GSD, 0.0), True),
        (33922, 12, 6, (0, 0, 0, *ORIGIN, 0), True),
        (34735, 3, len(directory), directory, True),
        (34736, 12, len(doubles), doubles, True),
    ]
    if text:
        tags.append((34737, 2, 0, text, True))
    tifffile.imwrite(path, data, extratags=tags, **options)
    return path


def write_plots_shp(path, rings, *, prj=AEQD_PRJ):
    with shapefile.Writer(str(path.with_suffix("")), shapeType=shapefile.POLYGON) as writer:
        writer.field("plot", "N", size=8)
        for i, ring in enumerate(rings):
            writer.poly([ring])
            writer.record(i + 1)
    if prj is not None:
        path.with_suffix(".prj").write_text(prj)
    return path


PLOT = [[-4.0, 2.5], [-4.0, -0.5], [-1.0, -0.5], [-1.0, 2.5], [-4.0, 2.5]]  # clockwise, inside


@pytest.fixture
def trial(tmp_path):
    """A synthetic field exported as the R tools do: orthophoto, DSM and plots in one user AEQD."""
    img, dsm, truth = synthetic_surface(shape=(300, 450), gsd=GSD, seed=6)
    keys = aeqd_keys()
    write_user_tiff(tmp_path / "ortho.tif", img, keys=keys)
    write_user_tiff(tmp_path / "dsm.tif", np.nan_to_num(dsm, nan=-3.4e38).astype(np.float32), keys=keys)
    write_plots_shp(tmp_path / "plots.shp", [PLOT])
    return tmp_path, truth


def run_cli(*args):
    command = [sys.executable, "-m", "cliff_terrain", *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, cwd=REPO)


def test_wkt_parser_reads_the_bracket_grammar():
    tree = parse_wkt('PROJCS["a ""quoted"" name",UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["E",EAST]]')
    assert tree == (
        "PROJCS",
        [
            'a "quoted" name',
            ("UNIT", ["metre", 1.0, ("AUTHORITY", ["EPSG", "9001"])]),
            ("AXIS", ["E", "EAST"]),
        ],
    )
    with pytest.raises(ValueError, match="unbalanced"):
        parse_wkt('PROJCS["x",UNIT["m",1]')


def test_esri_and_ogc_wkt_of_one_crs_agree_and_a_moved_centre_does_not():
    esri, ogc = wkt_crs(AEQD_PRJ, source="a.prj"), wkt_crs(AEQD_OGC, source="b.prj")
    assert esri == ogc and esri.method == "Azimuthal_Equidistant" and esri.inverse_flattening == 0.0
    assert esri.parameters["latitude_of_origin"] == 39.2 and esri.semi_major == SPHERE
    moved = wkt_crs(AEQD_PRJ.replace("-96.6", "-96.7"), source="c.prj")
    assert moved != esri
    wgs84 = wkt_crs(AEQD_PRJ.replace("6371007.181,0.0", "6378137.0,298.257223563"), source="d.prj")
    assert wgs84 != esri
    shifted = wkt_crs(AEQD_PRJ.replace('"False_Easting",0.0', '"False_Easting",1000.0'), source="e.prj")
    assert shifted != esri


def test_rasters_in_a_user_defined_crs_are_read_with_it(trial):
    folder, _ = trial
    dsm, ortho = read_surface(folder / "dsm.tif"), read_orthophoto(folder / "ortho.tif")
    assert isinstance(dsm.crs, UserCrs) and dsm.crs == ortho.crs == wkt_crs(AEQD_OGC, source="x")
    assert dsm.crs.wkt == AEQD_PRJ  # the ESRI PE string as the file carries it
    assert dsm.bounds == pytest.approx((-4.5, 3.0 - 300 * GSD, -4.5 + 450 * GSD, 3.0))


def test_the_keys_alone_define_the_crs_when_the_citation_is_missing(trial):
    folder, _ = trial
    keys_only = write_user_tiff(
        folder / "keys.tif", np.ones((8, 8), np.float32), keys=aeqd_keys(citation=None)
    )
    plain = read_surface(keys_only)
    assert plain.crs == read_surface(folder / "dsm.tif").crs
    assert plain.crs.wkt.startswith('PROJCS["unknown"') and "Azimuthal_Equidistant" in plain.crs.wkt
    # Our own writer keeps the CRS: written and read back, it is the same CRS with the same WKT.
    write_geotiff(folder / "again.tif", plain.data, transform=plain.transform, crs=plain.crs)
    again = read_surface(folder / "again.tif")
    assert again.crs == plain.crs and again.crs.wkt == plain.crs.wkt


def test_the_prj_of_an_r_export_is_read_as_the_rasters_crs(trial):
    folder, _ = trial
    plots = read_plots(folder / "plots.shp")
    assert plots.crs == read_surface(folder / "dsm.tif").crs and plots.crs.wkt == AEQD_PRJ


def test_heights_accepts_the_trial_and_records_its_wkt(trial):
    folder, truth = trial
    out = folder / "out"
    done = run_cli(
        "heights", folder / "ortho.tif", "--dsm", folder / "dsm.tif", "--plots", folder / "plots.shp",
        "--out", out,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["crs"] is None and summary["crs_wkt"] == AEQD_PRJ
    chm = read_surface(out / "chm.tif")
    assert chm.crs == read_surface(folder / "dsm.tif").crs and chm.crs.wkt == AEQD_PRJ
    # The plot is measured: 3 x 3 m, and its p90 canopy height near the truth's under it.
    header, row = (out / "plots.csv").read_text().splitlines()[:2]
    values = dict(zip(header.split(","), row.split(","), strict=True))
    assert float(values["area_m2"]) == pytest.approx(9.0) and values["error"] == ""
    geo = json.loads((out / "plots.geojson").read_text())
    assert "crs" not in geo  # GeoJSON names CRSs by EPSG URN only; GDAL leaves a user CRS out too


def test_plots_in_another_user_crs_are_refused_in_one_line_naming_both(trial):
    folder, _ = trial
    write_plots_shp(folder / "moved.shp", [PLOT], prj=AEQD_PRJ.replace("-96.6", "-95.0"))
    done = run_cli(
        "heights", folder / "ortho.tif", "--dsm", folder / "dsm.tif", "--plots", folder / "moved.shp",
        "--out", folder / "bad",
    )  # fmt: skip
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "moved.shp" in lines[0] and "ortho.tif" in lines[0] and "longitude of origin -95" in lines[0]
    assert "reproject" in lines[0]
    assert not (folder / "bad").exists()


def test_a_dsm_in_another_user_crs_is_refused_naming_both(trial):
    folder, _ = trial
    other = write_user_tiff(
        folder / "other.tif", read_surface(folder / "dsm.tif").data, keys=aeqd_keys(lon=-90.0, citation=None)
    )
    done = run_cli(
        "heights",
        folder / "ortho.tif",
        "--dsm",
        other,
        "--out",
        folder / "bad",
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert (
        "other.tif" in lines[0]
        and "ortho.tif" in lines[0]
        and "user-defined Azimuthal Equidistant" in lines[0]
    )


def test_feet_and_degrees_are_still_refused(tmp_path):
    feet = write_user_tiff(tmp_path / "feet.tif", np.ones((4, 4), np.float32), keys=aeqd_keys(units=9003))
    with pytest.raises(GeoreferenceError, match="'.*feet.tif' has map units in US survey feet"):
        read_surface(feet)
    prj_feet = AEQD_PRJ.replace('UNIT["Meter",1.0]]', 'UNIT["Foot_US",0.3048006096012192]]')
    write_plots_shp(tmp_path / "feet.shp", [PLOT], prj=prj_feet)
    with pytest.raises(PlotFileError, match=r"feet.prj' has map units in Foot_US .*needs metres"):
        read_plots(tmp_path / "feet.shp")
    degrees = (
        'GEOGCS["GCS_unknown",DATUM["D_unknown",SPHEROID["unknown",6371007.181,0.0]],PRIMEM["Greenwich",0.0]]'
    )
    write_plots_shp(tmp_path / "degrees.shp", [PLOT], prj=degrees)
    with pytest.raises(PlotFileError, match="degrees.prj' is in degrees"):
        read_plots(tmp_path / "degrees.shp")
    # A user-defined CRS whose keys name no projection method is still unknown.
    directory, doubles, _ = aeqd_keys(citation=None)
    directory = tuple(v if v != 12 else 32767 for v in directory)  # ProjCoordTransGeoKey: user-defined
    unknown = write_user_tiff(
        tmp_path / "unknown.tif", np.ones((4, 4), np.float32), keys=(directory, doubles, "")
    )
    with pytest.raises(
        RasterReadError, match="'.*unknown.tif' has an unknown CRS .*save it with an EPSG CRS"
    ):
        read_surface(unknown)


def test_geojson_plots_without_a_crs_near_the_centre_of_a_user_crs_are_not_taken_for_degrees(trial):
    # GeoJSON names CRSs by EPSG URN only, so plots in a user-defined CRS come without one; centred
    # on the field, their coordinates (a few metres) would pass for longitude/latitude.
    folder, _ = trial
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"plot": 1}, "geometry": {"type": "Polygon", "coordinates": [PLOT]}}]}  # fmt: skip
    (folder / "plots.geojson").write_text(json.dumps(doc))
    done = run_cli(
        "heights", folder / "ortho.tif", "--dsm", folder / "dsm.tif", "--plots", folder / "plots.geojson",
        "--out", folder / "out", "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    header, row = (folder / "out" / "plots.csv").read_text().splitlines()[:2]
    assert dict(zip(header.split(","), row.split(","), strict=True))["area_m2"].startswith("9.0")


def test_a_utm_zone_spelt_out_without_its_code_agrees_with_the_epsg_code_and_no_other():
    # OGC WKT of WGS 84 / UTM 16N with no AUTHORITY (as some exporters write .prj files).
    wkt = (
        'PROJCS["UTM Zone 16, Northern Hemisphere",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",'
        '6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
        'PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",-87],'
        'PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],'
        'UNIT["Meter",1]]'
    )
    crs = wkt_crs(wkt, source="plots.prj")
    assert crs == 32616 and 32616 == crs and crs != 32615 and crs != 32716 and crs != 3857
    assert wkt_crs(wkt.replace("-87", "-86.9"), source="x.prj") != 32616
