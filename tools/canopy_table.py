"""Where a relief's volume stands, and how its plant mask agrees with an independent reference.

    python tools/canopy_table.py IMAGE_OR_FOLDER... [--profile P] [--segmentation S] [--max-size N]
                                 [--json FILE]

For each photo (folders are searched for JPEG, PNG and TIFF files; ``synthetic-open`` and
``synthetic-closed`` stand for ``synthetic_field(seed=0)`` in each canopy mode) it builds the relief
and prints a Markdown row: plant cover of the relief's mask; against two reference masks, ExG
(or (NIR - B) / (NIR + B) for a false-colour NIR frame) and CIELAB a*, each with Otsu's threshold
(:mod:`cliff_terrain.evaluate.mask_quality`), their IoU and the share of the relief's volume standing on
reference plant pixels; for the synthetic fields the share on the drawn plants and on the enclosed
soil strips. ``--json`` also writes every figure (F1, precision, recall too) to FILE.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cliff_terrain import build_relief  # noqa: E402
from cliff_terrain.data.synthetic import synthetic_field  # noqa: E402
from cliff_terrain.evaluate.mask_quality import mask_agreement, reference_mask, volume_fraction  # noqa: E402
from cliff_terrain.photo_heights.vegetation import vegetation_index  # noqa: E402

SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
SYNTHETIC = ("synthetic-open", "synthetic-closed")


def find_images(paths):
    for path in paths:
        if path in SYNTHETIC:
            yield path
        elif Path(path).is_dir():
            yield from sorted(str(p) for p in Path(path).rglob("*") if p.suffix.lower() in SUFFIXES)
        else:
            yield path


def measure(image, **options):
    """The figures of one photo (a path or a synthetic name) for `build_relief(**options)`."""
    truth = None
    if image in SYNTHETIC:
        source, truth = synthetic_field(seed=0, canopy=image.split("-")[1])
    else:
        source = image
    relief = build_relief(source, two_sided=False, **options)
    working = relief.working
    valid = None
    if relief.metadata.valid_mask is not None:
        size = working.shape[1::-1]
        valid = (
            cv2.resize(relief.metadata.valid_mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
        )
    area = float(valid.sum()) if valid is not None else float(relief.mask.size)
    figures = {
        "image": image,
        "cover": float(relief.mask.sum()) / area,
        "regions": relief.n_regions,
        "max_height": relief.max_height,
        "units": relief.units,
    }
    nir = vegetation_index(working)[1] == "nir"
    for name, index in (("exg", "nir" if nir else "exg"), ("lab_a", "lab_a")):
        reference = reference_mask(working, index=index, valid=valid)
        figures[name] = {
            "cover": float(reference.sum()) / area,
            **mask_agreement(relief.mask, reference),
            "volume": volume_fraction(relief.heights, reference),
        }
    if truth is not None and truth.mask.shape == relief.heights.shape:
        figures["volume_on_plants"] = volume_fraction(relief.heights, truth.mask)
        figures["volume_on_strips"] = 1.0 - volume_fraction(relief.heights, ~truth.strips)
        figures["truth_iou"] = mask_agreement(relief.mask, truth.mask)["iou"]
    return figures


def main(argv=None):
    parser = argparse.ArgumentParser(prog="canopy_table.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("images", nargs="+", metavar="IMAGE_OR_FOLDER")
    parser.add_argument("--profile", default=None)
    parser.add_argument("--segmentation", default=None)
    parser.add_argument("--max-size", type=int, default=1000)
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    args = parser.parse_args(argv)
    options = {"max_size": args.max_size}
    if args.profile:
        options["profile"] = args.profile
    if args.segmentation:
        options["segmentation"] = args.segmentation
    rows = []
    print("| image | cover | ExG cover | ExG IoU | volume on ExG | a* cover | a* IoU | volume on a* | top |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for image in find_images(args.images):
        try:
            m = measure(image, **options)
        except ValueError as exc:  # a DSM or an unreadable file: say so and go on
            print(f"| {image} | failed: {exc} | | | | | | | |")
            continue
        rows.append(m)
        e, a = m["exg"], m["lab_a"]
        print(
            f"| {image} | {m['cover']:.1%} | {e['cover']:.1%} | {e['iou']:.3f} | {e['volume']:.1%} "
            f"| {a['cover']:.1%} | {a['iou']:.3f} | {a['volume']:.1%} | {m['max_height']:.3g} {m['units']} |",
            flush=True,
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
