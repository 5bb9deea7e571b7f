"""Re-create DATA_DIR/fields/<field>/ for bench/validate_real.py from public GitHub repositories.

    python bench/layout_fields.py DATA_DIR

Needs the repositories as bare git directories (the session's `fetch` tool puts them under
/work/.mirror/<owner>+<name>/repo; anything else: `git clone --bare`, then set MIRROR or edit
REPOS). Every file is extracted by its pinned commit with `git show COMMIT:path`, so the layout is
byte-for-byte reproducible; sha1 (git blob ids) of everything written go to DATA_DIR/fields/MANIFEST.

Day 70 of filipematias23/FIELDimageR-QGIS-Workshop (and its byte-identical copy `4_75` in
phenome-force/FIELDimageR-workshop, and `3_70` in FIELDimageR-Workshop-10) is HELD OUT: no file
whose name carries that date is ever read here. `assert_not_held_out` guards every path.

Fields (see SOURCES in bench/validate_real.py):

potato_fieldimager           filipematias23/FIELDimageR-QGIS-Workshop @ 88091a2: DSM/1_30, 2_40,
                             4_100, MOSAIC/2_40, 4_100, Data_Total.* (140 plots); reference day 30.
potato_fieldimager_d55_d90   phenome-force/FIELDimageR-workshop @ ea5072e: DSM/3_55, 5_90,
                             MOSAIC/3_55, 5_90; the plots and day-30 DSM of the first field (the
                             day-30 DSM blob is identical in both repositories).
potato_fieldimager_ex1       filipematias23/FIELDimageR-QGIS @ 40adb59: EX_DSM0.tif (bare soil),
                             EX_DSM1.tif (vegetative), fieldMap.csv (9 x 14). No plot polygons were
                             published and EX1_RGB.tif is not in the snapshot: the 126 polygons are
                             made here (`ex1_plots`) from the field map and the DSM1 - DSM0 heights.
potato_fieldimager_ex2       filipematias23/FIELDimageR-Workshop-10 @ df52c1d: dsm.tif,
                             odm_orthophoto.tif (identical to ../shared/data/dsm/fieldimager_ex2),
                             EX2.Shape.* (588 plots, in FIELDimageR's rotated frame;
                             `ex2_unrotate` puts them back in EPSG:32616); no reference.
soybean_pliman               cran/pliman @ 49fda6a (the R package pliman 3.1.1's CRAN mirror;
                             TiagoOlivoto/pliman's snapshot is too large to fetch):
                             inst/tmp_images/soy_dsm.tif, soy_dtm.tif, soy_ortho.tif (2.2 cm) and
                             soy_shape.rds (15 plots, a terra PackedSpatVector: `pliman_plots`
                             writes it as GeoJSON, with the `rdata` package: pip install rdata).
                             The reference is the package's DTM, made from the same DSM's soil.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench import _mirror as mirror  # noqa: E402

REPOS = {
    "qgis_workshop": ("filipematias23/FIELDimageR-QGIS-Workshop", "88091a23c458fcfd8b633c3f5803bd219516c32c"),
    "phenome_force": ("phenome-force/FIELDimageR-workshop", "ea5072efd0d09aca6c22a589efe889ae3cb085cc"),
    "qgis": ("filipematias23/FIELDimageR-QGIS", "40adb5910b4f1879816e99fb67af896a60adb588"),
    "workshop10": ("filipematias23/FIELDimageR-Workshop-10", "df52c1de6038c6d0edb96809dcc05c8318296ed0"),
    "pliman": ("cran/pliman", "49fda6a611a8ea6bf1242b989ae8bd6909aeec8f"),
}
HELD_OUT = re.compile(r"(^|[^0-9])(70|75)([^0-9]|$)")
SHAPE_PARTS = ("shp", "shx", "dbf", "prj")


def assert_not_held_out(path):
    name = Path(path).name
    if HELD_OUT.search(name):
        raise SystemExit(f"refusing {path}: day 70 (or its copy 75) is held out")


def extract(key, path, target):
    """`git show COMMIT:path > target`; returns the blob's sha1."""
    assert_not_held_out(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    data = mirror.blob(*REPOS[key], path)
    target.write_bytes(data)
    return mirror.blob_id(data)


def write_json(path, spec):
    path.write_text(json.dumps(spec, indent=2) + "\n")


def potato_fieldimager(base, manifest):
    folder = base / "potato_fieldimager"
    files = [f"Data_Total.{e}" for e in (*SHAPE_PARTS, "cpg")]
    files += ["DSM/1_30_dsm.tif", "DSM/2_40_dsm.tif", "DSM/4_100_dsm.tif"]
    files += ["MOSAIC/2_40_RGB.tif", "MOSAIC/4_100_RGB.tif"]
    for f in files:
        manifest[f"{folder.name}/{f}"] = ("qgis_workshop", f, extract("qgis_workshop", f, folder / f))
    write_json(
        folder / "field.json",
        {
            "crop": "potato",
            "stage": "30-100 days after planting, canopy closing",
            "plots": "Data_Total.shp",
            "reference": "DSM/1_30_dsm.tif",
            "dates": {
                "40": {"ortho": "MOSAIC/2_40_RGB.tif", "dsm": "DSM/2_40_dsm.tif"},
                "100": {"ortho": "MOSAIC/4_100_RGB.tif", "dsm": "DSM/4_100_dsm.tif"},
            },
            "holdout": ["70"],
        },
    )


def potato_fieldimager_d55_d90(base, manifest):
    folder = base / "potato_fieldimager_d55_d90"
    for f in [f"Data_Total.{e}" for e in (*SHAPE_PARTS, "cpg")]:
        manifest[f"{folder.name}/{f}"] = ("qgis_workshop", f, extract("qgis_workshop", f, folder / f))
    for f in [
        "DSM/1_30_dsm.tif",
        "DSM/3_55_dsm.tif",
        "DSM/5_90_dsm.tif",
        "MOSAIC/3_55_RGB.tif",
        "MOSAIC/5_90_RGB.tif",
    ]:
        manifest[f"{folder.name}/{f}"] = ("phenome_force", f, extract("phenome_force", f, folder / f))
    write_json(
        folder / "field.json",
        {
            "crop": "potato",
            "stage": "day 55: rows of plants, canopy open; day 90: CLOSED canopy (rows merged, green) - "
            "complements day 100 (senescing) in potato_fieldimager",
            "plots": "Data_Total.shp",
            "reference": "DSM/1_30_dsm.tif",
            "dates": {
                "55": {"ortho": "MOSAIC/3_55_RGB.tif", "dsm": "DSM/3_55_dsm.tif"},
                "90": {"ortho": "MOSAIC/5_90_RGB.tif", "dsm": "DSM/5_90_dsm.tif"},
            },
        },
    )


def ex1_plots(dsm0_path, dsm1_path, map_path, out_path):
    """The 126 plots of EX1: single-row plots, 9 ranges x 14 rows (fieldMap.csv), inside a border
    row on each side and a border range at each end.

    From DSM1 - DSM0 (on DSM1's grid): plant pixels (> 8 cm); the field's rotation is the angle
    whose rotated column profile of plant pixels is sharpest; in the rotated frame the 16 plant
    rows are the 16 strongest column peaks (the outer two are borders) and the 11 ranges the runs
    of the row profile (the first and last are borders). A plot spans half-way to its neighbouring
    rows across and its range's run of plants along. Polygon ids from fieldMap.csv: map row i is
    the i-th range from the top (north), map column j the j-th row from the left (west)."""
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository
    from cliff_terrain.io.raster.geotiff import read_surface, resample

    dsm1 = read_surface(dsm1_path)
    dsm0 = resample(read_surface(dsm0_path), transform=dsm1.transform, shape=dsm1.shape)
    height = np.nan_to_num(dsm1.data - dsm0, nan=0.0)
    rows, cols = np.nonzero(height > 0.08)
    t = dsm1.transform
    x = t[0, 2] + (cols + 0.5) * t[0, 0]
    y = t[1, 2] + (rows + 0.5) * t[1, 1]
    cx, cy = x.mean(), y.mean()

    def frame(a):  # u across the rows (east), v along them (north)
        c, s = np.cos(a), np.sin(a)
        return c * (x - cx) + s * (y - cy), -s * (x - cx) + c * (y - cy)

    bin_m = 0.03
    best = None
    for a in np.radians(np.arange(-5.0, 5.0001, 0.05)):
        u, _ = frame(a)
        hist = np.bincount(((u - u.min()) / bin_m).astype(int))
        score = float(np.var(hist))
        if best is None or score > best[0]:
            best = (score, a)
    angle = best[1]
    u, v = frame(angle)

    def profile(w, step):
        lo = w.min()
        return lo, np.bincount(((w - lo) / step).astype(int)).astype(float)

    u0, hu = profile(u, bin_m)
    smooth = np.convolve(hu, np.ones(7) / 7, mode="same")
    peaks = [i for i in range(1, len(smooth) - 1) if smooth[i] >= smooth[i - 1] and smooth[i] > smooth[i + 1]]
    # Non-maximum suppression at 60 % of the typical spacing (about 0.9 m).
    peaks.sort(key=lambda i: -smooth[i])
    kept = []
    for i in peaks:
        if all(abs(i - k) * bin_m > 0.5 for k in kept):
            kept.append(i)
        if len(kept) == 16:
            break
    centres = np.sort(u0 + (np.array(kept) + 0.5) * bin_m)
    edges = np.concatenate(
        [
            [centres[0] - (centres[1] - centres[0]) / 2],
            (centres[:-1] + centres[1:]) / 2,
            [centres[-1] + (centres[-1] - centres[-2]) / 2],
        ]
    )
    v0, hv = profile(v, 0.05)
    on = hv > 0.25 * np.median(hv[hv > 0])
    on = np.convolve(on, np.ones(5), mode="same") > 2  # close small gaps
    change = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
    runs = [(v0 + a * 0.05, v0 + b * 0.05) for a, b in change.reshape(-1, 2) if (b - a) * 0.05 > 1.0]
    if len(centres) != 16 or len(runs) != 11:
        raise SystemExit(f"EX1 grid: {len(centres)} plant rows, {len(runs)} ranges (want 16 and 11)")
    field_map = [line.split(",") for line in Path(map_path).read_text().split()]
    c, s = np.cos(angle), np.sin(angle)
    features = []
    for i, (vlo, vhi) in enumerate(sorted(runs[1:-1], key=lambda r: -r[0])):  # north first
        for j in range(14):
            ulo, uhi = edges[j + 1], edges[j + 2]
            ring = []
            for uu, vv in ((ulo, vlo), (uhi, vlo), (uhi, vhi), (ulo, vhi), (ulo, vlo)):
                ring.append([float(cx + c * uu - s * vv), float(cy + s * uu + c * vv)])
            features.append(
                {
                    "type": "Feature",
                    "properties": {"plot": int(field_map[i][j]), "map_row": i + 1, "map_col": j + 1},
                    "geometry": {"type": "Polygon", "coordinates": [ring]},
                }
            )
    Path(out_path).write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32616"}},
                "features": features,
            }
        )
    )
    return {
        "angle_deg": float(np.degrees(angle)),
        "row_spacing_m": float(np.median(np.diff(centres))),
        "ranges_m": [round(b - a, 2) for a, b in runs],
    }


def potato_fieldimager_ex1(base, manifest):
    folder = base / "potato_fieldimager_ex1"
    for f in ["EX_DSM0.tif", "EX_DSM1.tif", "fieldMap.csv", "fieldData.csv"]:
        manifest[f"{folder.name}/{f}"] = ("qgis", f, extract("qgis", f, folder / f))
    info = ex1_plots(
        folder / "EX_DSM0.tif", folder / "EX_DSM1.tif", folder / "fieldMap.csv", folder / "plots.geojson"
    )
    print("  ex1 grid:", info)
    write_json(
        folder / "field.json",
        {
            "crop": "potato",
            "stage": "vegetative growth (canopy not closed, plants 0.1-0.3 m above the ridges)",
            "plots": "plots.geojson",
            "reference": "EX_DSM0.tif",
            "dates": {"vegetative": {"dsm": "EX_DSM1.tif"}},
            # fieldData.csv's Height: no unit stated anywhere, so no ruler (validate_real drops it).
            "ruler": {"file": "fieldData.csv", "id": "Plot", "height": "Height", "unit": "unknown"},
        },
    )


def ex2_unrotate(shp_path, out_path, *, theta_deg):
    """EX2.Shape.shp back in EPSG:32616. Script_EX2.R drew it on `fieldRotate(EX2, theta = 2.3)`,
    whose `rotate` relabels the UTM coordinates as "+proj=aeqd +ellps=sphere +lat_0=90 +lon_0=0" and
    projects them to lon_0 = -theta: on a polar azimuthal equidistant projection that is exactly a
    rotation by theta (counter-clockwise) about the origin, so x = x' cos t + y' sin t,
    y = -x' sin t + y' cos t gives the UTM coordinates back (the .prj's Central_Meridian is -2.3)."""
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository
    from cliff_terrain.io.vector.plot_polygons import read_plots

    plots = read_plots(shp_path)
    t = np.radians(theta_deg)
    c, s = np.cos(t), np.sin(t)
    features = []
    for rings, attrs in zip(plots.polygons, plots.attributes, strict=True):
        back = [[[float(c * x + s * y), float(-s * x + c * y)] for x, y in ring] for ring in rings]
        props = {
            k: (v if isinstance(v, (int, float, str)) or v is None else str(v)) for k, v in attrs.items()
        }
        features.append(
            {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": back}}
        )
    Path(out_path).write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32616"}},
                "features": features,
            }
        )
    )
    xy = np.array([p for f in features for ring in f["geometry"]["coordinates"] for p in ring])
    return {
        "plots": len(features),
        "x": [round(xy[:, 0].min(), 1), round(xy[:, 0].max(), 1)],
        "y": [round(xy[:, 1].min(), 1), round(xy[:, 1].max(), 1)],
    }


def potato_fieldimager_ex2(base, manifest):
    folder = base / "potato_fieldimager_ex2"
    for f in ["dsm.tif", "odm_orthophoto.tif", *(f"EX2.Shape.{e}" for e in SHAPE_PARTS)]:
        manifest[f"{folder.name}/{f}"] = ("workshop10", f, extract("workshop10", f, folder / f))
    info = ex2_unrotate(folder / "EX2.Shape.shp", folder / "plots_utm.geojson", theta_deg=2.3)
    print("  ex2 plots:", info)
    write_json(
        folder / "field.json",
        {
            "crop": "potato",
            "stage": "flowering (FIELDimageR README: UW-Madison potato breeding trials 'during the flowering "
            "time', Hancock ARS, 60 m flight)",
            "plots": "plots_utm.geojson",
            "dates": {"flowering": {"ortho": "odm_orthophoto.tif", "dsm": "dsm.tif"}},
        },
    )


def pliman_plots(rds_path, out_path):
    """soy_shape.rds (a terra PackedSpatVector of polygons, read with `rdata`) as GeoJSON, its CRS
    as EPSG:32414 (the file's own WKT: WGS 72BE / UTM 14N, as the rasters' GeoKeys say)."""
    try:
        import rdata
    except ImportError:
        raise SystemExit(
            "soybean_pliman needs the rdata package to read its plots: pip install rdata"
        ) from None
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Missing constructor for R class PackedSpatVector": its parts do
        packed = rdata.conversion.convert(rdata.parser.parse_file(rds_path), default_encoding="utf8")
    if 'EPSG",32414]]' not in str(packed.crs[0]).replace(" ", "").replace("\n", ""):
        raise SystemExit(f"{rds_path}: expected EPSG:32414 polygons")
    xy = [[float(x), float(y)] for x, y in packed.coordinates.values]
    index = packed.index.values.astype(int)  # geom, part, hole, start (1-based), one row per ring
    starts = list(index[:, 3] - 1) + [len(xy)]
    table = packed.attributes
    features = []
    for k, (geom, part, hole, start) in enumerate(index):
        if part != 1 or hole != 0:
            raise SystemExit(f"{rds_path}: plot {geom} is not one ring")
        ring = xy[start - 1 : starts[k + 1]]
        properties = {c: str(table[c].iloc[k]) for c in table.columns}
        features.append(
            {
                "type": "Feature",
                "properties": properties,
                "geometry": {"type": "Polygon", "coordinates": [ring]},
            }
        )
    doc = {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "EPSG:32414"}},
        "features": features,
    }
    out_path.write_text(json.dumps(doc) + "\n")
    return len(features)


def soybean_pliman(base, manifest):
    folder = base / "soybean_pliman"
    for name in ["soy_dsm.tif", "soy_dtm.tif", "soy_ortho.tif", "soy_shape.rds"]:
        f = f"inst/tmp_images/{name}"
        manifest[f"{folder.name}/{name}"] = ("pliman", f, extract("pliman", f, folder / name))
    print("  soybean plots:", pliman_plots(folder / "soy_shape.rds", folder / "plots.geojson"))
    write_json(
        folder / "field.json",
        {
            "crop": "soybean",
            "stage": "vegetative (pliman's documentation: soybean plots in the vegetative stage; 5 rows x 3 "
            "columns, data by Arthur Bernardeli)",
            "plots": "plots.geojson",
            "reference": "soy_dtm.tif",
            "reference_label": "DSM minus pliman's DTM (made from the same DSM's soil, not a second flight)",
            "dates": {"vegetative": {"ortho": "soy_ortho.tif", "dsm": "soy_dsm.tif"}},
        },
    )


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    data = Path(argv[0]) if argv else Path(__file__).resolve().parent
    base = data / "fields"
    manifest = {}
    for make in (
        potato_fieldimager,
        potato_fieldimager_d55_d90,
        potato_fieldimager_ex1,
        potato_fieldimager_ex2,
        soybean_pliman,
    ):
        print(make.__name__, flush=True)
        make(base, manifest)
    lines = [
        f"{sha}  {target}  <- {REPOS[key][0]}@{REPOS[key][1][:7]}:{path}"
        for target, (key, path, sha) in sorted(manifest.items())
    ]
    (base / "MANIFEST").write_text("\n".join(lines) + "\n")
    print(f"{len(manifest)} files under {base}")


if __name__ == "__main__":
    main()
