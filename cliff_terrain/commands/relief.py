"""``cliff-terrain relief IMAGE --out DIR``: the relief's maps and figures, without Blender.

Writes ``height.tif`` (float32 heights on the processing grid, in the relief's units), ``mask.png``,
``labels.tif`` (uint32 region ids), ``regions.csv`` (one row per plant: centroid, area, diameter,
cover, and heights and volume in metres when the GSD is known) and ``relief.json`` (settings, units,
region count, timings), all or none. Existing files are never replaced without ``--overwrite``.
"""

from __future__ import annotations

import json
from pathlib import Path

from .._progress import add_progress_argument
from ..figures.writer import HEIGHT_MAP, MASK
from ..params import ReliefParams

LABELS, SUMMARY = "labels.tif", "relief.json"
HELP = "build a relief from one photo and write its height map, mask, regions and a summary"


def configure(parser):
    parser.add_argument("image", type=Path, help="the UAV photo (JPEG, PNG, TIFF, WebP or BMP)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    ReliefParams.add_arguments(parser)
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_progress_argument(parser)


def run(args):
    import numpy as np
    import tifffile
    from PIL import Image

    from .._progress import stage_bar
    from ..build import build_relief
    from ..errors import CliffTerrainError
    from ..figures.writer import write_height_map
    from ..measure.key_figures import plant_cover
    from ..measure.tables import REGION_COLUMNS, REGIONS_CSV, region_table, table_csv, write_files
    from .out_folder import check_inputs_not_outputs, check_out_folder, finished_outputs

    outputs = (HEIGHT_MAP, MASK, LABELS, REGIONS_CSV, SUMMARY)

    out = args.out
    check_out_folder(out)
    check_inputs_not_outputs(out, outputs, {"the image": args.image})
    if not args.overwrite:  # relief.json is written last: without it, outputs are an interrupted run's
        existing = finished_outputs(out, outputs, marker=SUMMARY)
        if existing:
            raise CliffTerrainError(f"{str(out / existing[0])!r} exists; pass --overwrite to replace it")
    with stage_bar(f"relief {args.image.name}", enabled=not args.no_progress) as progress:
        relief = build_relief(str(args.image), ReliefParams.from_args(args), progress=progress)
    metric = relief.units == "m"
    regions = region_table(
        relief.labels,
        heights=relief.heights if metric else None,
        pixel_size=relief.pixel_size if metric else None,
    )
    summary = {
        "image": str(args.image),
        "regions": relief.n_regions,
        "cover": plant_cover(relief),  # as metrics.json and summary.json define it
        "max_height": relief.max_height,
        "units": relief.units,
        "pixel_size": float(relief.pixel_size),
        "grid": list(relief.heights.shape),
        "params": {
            k: v for k, v in relief.params.items() if isinstance(v, (str, int, float, bool, type(None)))
        },
        # Which plant/soil threshold the photo got and why (its note says when it could not decide).
        "threshold": relief.params.get("threshold"),
        "timings_s": {k: round(float(v), 4) for k, v in relief.timings.items()},
    }
    files = {
        out / HEIGHT_MAP: lambda tmp: write_height_map(relief, tmp),
        out / LABELS: lambda tmp: tifffile.imwrite(tmp, relief.labels.astype(np.uint32)),
        out / MASK: lambda tmp: Image.fromarray(relief.mask.astype(np.uint8) * 255).save(tmp, format="PNG"),
        # Heights in metres only with a GSD; in pixels the table keeps areas and diameters in pixels.
        out / REGIONS_CSV: table_csv(regions, REGION_COLUMNS),
        out / SUMMARY: json.dumps(summary, indent=2) + "\n",
    }
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_files(files)  # all or nothing
    except OSError as exc:
        raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
    print(
        f"{args.image}: {relief.n_regions} regions, cover {summary['cover']:.1%}, max height "
        f"{relief.max_height:.3g} {relief.units}; wrote {', '.join(outputs)} into {out}"
    )
    note = (relief.params.get("threshold") or {}).get("note")
    if note:
        print(f"{args.image}: {note}")
    return 0
