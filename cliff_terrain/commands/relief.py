"""``cliff-terrain relief IMAGE --out DIR``: the relief's maps and figures, without Blender.

Writes ``height.tif`` (float32 heights on the processing grid, in the relief's units), ``mask.png``,
``labels.tif`` (uint32 region ids), ``regions.csv`` (one row per plant: centroid, area, diameter,
cover, and heights and volume in metres when the GSD is known) and ``relief.json`` (settings, units,
region count, timings), all or none. Existing files are never replaced without ``--overwrite``.
"""

from __future__ import annotations

import json
from pathlib import Path

from .. import settings

HELP = "build a relief from one photo and write its height map, mask, regions and a summary"
OUTPUTS = ("height.tif", "mask.png", "labels.tif", "regions.csv", "relief.json")


def configure(parser):
    parser.add_argument("image", type=Path, help="the UAV photo (JPEG, PNG, TIFF, WebP or BMP)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument(
        "--max-size",
        type=int,
        default=settings.DEFAULT_MAX_SIZE,
        help=f"longest side of the processing grid, {settings.MIN_SIZE} to {settings.MAX_SIZE} "
        f"(default {settings.DEFAULT_MAX_SIZE})",
    )
    parser.add_argument(
        "--segmentation",
        choices=settings.ids(settings.SEGMENTATIONS),
        default=settings.DEFAULT_SEGMENTATION,
    )
    parser.add_argument(
        "--profile", choices=settings.ids(settings.PROFILES), default=settings.DEFAULT_PROFILE
    )
    parser.add_argument("--exaggeration", type=float, default=settings.DEFAULT_EXAGGERATION)
    parser.add_argument(
        "--max-height",
        type=float,
        default=settings.DEFAULT_MAX_HEIGHT,
        help="canopy height of the plateau profile (a cap for the others): metres with a GSD, else "
        "processing pixels (default: the radius of a typical isolated plant)",
    )
    parser.add_argument("--gsd", type=float, default=None, help="metres per pixel of the photo")
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")


def run(args):
    import numpy as np
    import tifffile
    from PIL import Image

    from ..errors import CliffTerrainError
    from ..pipeline import build_relief
    from ..tables import REGION_COLUMNS, region_table, table_csv, write_files

    out = args.out
    if not args.overwrite:
        existing = [name for name in OUTPUTS if (out / name).exists()]
        if existing:
            raise CliffTerrainError(f"{str(out / existing[0])!r} exists; pass --overwrite to replace it")
    relief = build_relief(
        str(args.image),
        max_size=args.max_size,
        segmentation=args.segmentation,
        profile=args.profile,
        exaggeration=args.exaggeration,
        max_height=args.max_height,
        gsd=args.gsd,
        two_sided=False,
    )
    metric = relief.units == "m"
    regions = region_table(
        relief.labels,
        heights=relief.heights if metric else None,
        pixel_size=relief.pixel_size if metric else None,
    )
    summary = {
        "image": str(args.image),
        "regions": relief.n_regions,
        "cover": float(relief.mask.mean()),
        "max_height": relief.max_height,
        "units": relief.units,
        "pixel_size": float(relief.pixel_size),
        "grid": list(relief.heights.shape),
        "params": {
            k: v for k, v in relief.params.items() if isinstance(v, (str, int, float, bool, type(None)))
        },
        "timings_s": {k: round(float(v), 4) for k, v in relief.timings.items()},
    }
    heights = np.ascontiguousarray(relief.heights, dtype=np.float32)
    files = {
        out / "height.tif": lambda tmp: tifffile.imwrite(tmp, heights),
        out / "labels.tif": lambda tmp: tifffile.imwrite(tmp, relief.labels.astype(np.uint32)),
        out / "mask.png": lambda tmp: Image.fromarray(relief.mask.astype(np.uint8) * 255).save(
            tmp, format="PNG"
        ),
        # Heights in metres only with a GSD; in pixels the table keeps areas and diameters in pixels.
        out / "regions.csv": table_csv(regions, REGION_COLUMNS),
        out / "relief.json": json.dumps(summary, indent=2) + "\n",
    }
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_files(files)  # all or nothing
    except OSError as exc:
        raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
    print(
        f"{args.image}: {relief.n_regions} regions, cover {summary['cover']:.1%}, max height "
        f"{relief.max_height:.3g} {relief.units}; wrote {', '.join(OUTPUTS)} into {out}"
    )
    return 0
