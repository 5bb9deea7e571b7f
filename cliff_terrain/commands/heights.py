"""``cliff-terrain heights ORTHO --dsm DSM [--dtm DTM] [--plots FILE] --out DIR``: measured canopy height.

Writes ``chm.tif`` (float32 GeoTIFF, metres, NaN as no-data, the orthophoto's georeference),
``regions.csv`` and ``regions.geojson`` (one row per plant), and with ``--plots`` ``plots.csv``
and ``plots.geojson`` (one row per polygon). All files appear together or none does.
"""

from __future__ import annotations

from pathlib import Path

from .. import settings

HELP = "measure canopy height from an orthophoto and its DSM (and DTM); write the CHM and tables"


def configure(parser):
    parser.add_argument("ortho", type=Path, help="the orthophoto GeoTIFF")
    parser.add_argument("--dsm", type=Path, required=True, help="digital surface model GeoTIFF (metres)")
    parser.add_argument(
        "--dtm", type=Path, default=None, help="digital terrain model GeoTIFF (else estimated)"
    )
    parser.add_argument("--plots", type=Path, default=None, help="plot polygons: GeoJSON or ESRI Shapefile")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument(
        "--resolution",
        type=float,
        default=None,
        help="metres per pixel of the grid (default: the orthophoto's)",
    )
    parser.add_argument(
        "--block",
        type=float,
        default=settings.DEFAULT_GROUND_BLOCK_M,
        help=f"block size of the ground estimate in metres (default {settings.DEFAULT_GROUND_BLOCK_M})",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")


def run(args):
    import numpy as np

    from ..canopy import measure_orthophoto, plot_table_files
    from ..errors import CliffTerrainError
    from ..georaster import write_geotiff
    from ..plots import read_plots
    from ..tables import REGION_COLUMNS, point_geometries, region_table, table_csv, table_geojson, write_files

    out = args.out
    outputs = ["chm.tif", "regions.csv", "regions.geojson"] + (
        ["plots.csv", "plots.geojson"] if args.plots else []
    )
    if not args.overwrite:
        existing = [name for name in outputs if (out / name).exists()]
        if existing:
            raise CliffTerrainError(f"{str(out / existing[0])!r} exists; pass --overwrite to replace it")
    plots = read_plots(args.plots) if args.plots else None  # a bad plot file fails before the work
    rgb, has_data, plants, canopy = measure_orthophoto(
        args.ortho, args.dsm, dtm=args.dtm, resolution=args.resolution, block_m=args.block
    )
    from scipy import ndimage

    labels, _ = ndimage.label(plants & has_data)
    chm = np.where(has_data, canopy.chm, np.nan).astype(np.float32)
    regions = region_table(
        labels, heights=chm, pixel_size=canopy.pixel_size, transform=canopy.transform, valid=has_data
    )
    files = {
        out / "chm.tif": lambda tmp: write_geotiff(
            tmp, chm, transform=canopy.transform, crs=canopy.crs, nodata=float("nan")
        ),
        out / "regions.csv": table_csv(regions, REGION_COLUMNS),
        out / "regions.geojson": table_geojson(regions, point_geometries(regions), crs=canopy.crs),
    }
    if plots is not None:
        tables = plot_table_files(plots, canopy, heights=chm, mask=plants, source=str(args.ortho))
        files.update({out / name: text for name, text in tables.items()})
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_files(files)
    except OSError as exc:
        raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
    heights = chm[plants & has_data]
    p50, p90 = (np.percentile(heights, (50, 90)) * 100) if heights.size else (float("nan"),) * 2
    print(
        f"{args.ortho}: ground {canopy.ground_source}, {len(regions)} plants, cover {plants[has_data].mean():.1%}, "
        f"canopy height p50 {p50:.1f} cm, p90 {p90:.1f} cm; wrote {', '.join(outputs)} into {out}"
    )
    return 0
