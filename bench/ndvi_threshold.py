"""The NDVI path's plant/soil threshold on real multispectral captures: this round's rule (valley or
red-reflectance separation, else the prior band) beside last round's (Otsu's threshold always, above
the 0.1 floor).

    python bench/ndvi_threshold.py DATA_DIR [--json OUT.json]

Fetches nothing. ``DATA_DIR/multispectral/plantcv_615/615.tif`` (PlantCV-geospatial's 5-band
reflectance clip, a plot of seedling rows) and ``DATA_DIR/multispectral/micasense_rededge/
capture_0001.tif`` (a MicaSense RedEdge capture of hedgerow rows and young orchard trees on dry
soil, converted to reflectance and band-aligned by ``/work/data/multispectral_layout.py``; origin
and licence in ``DATA_DIR/SOURCES.md``). Bands B, G, R, RE, NIR.

Each window is built with ``build_relief(..., bands="B,G,R,RE,N")``. Windows of mixed plants and
soil are scored against an independent ExG/Otsu mask of the true-colour rendering (no hand mask
exists: said so in the table); the one-class windows were drawn by eye inside one class (a hedgerow
canopy, the bare dirt road), and their reference is that class: the share of the window that rises.
No constant is chosen here: the separation bound is Ashman's 2, the band the published NDVI ranges.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cliff_terrain import build_relief  # noqa: E402
from cliff_terrain.evaluate.mask_quality import mask_agreement, reference_mask, volume_fraction  # noqa: E402
from cliff_terrain.photo_heights import vegetation  # noqa: E402

MICASENSE = "multispectral/micasense_rededge/capture_0001.tif"
PLANTCV = "multispectral/plantcv_615/615.tif"
ALL = (slice(None), slice(None))
# (name, file, (rows, cols) window, reference): "exg" = ExG/Otsu of the rendering, "plant" / "soil" =
# a window drawn by eye inside that class.
WINDOWS = (
    ("plantcv_615 plot (seedling rows)", PLANTCV, ALL, "exg"),
    ("micasense whole capture", MICASENSE, ALL, "exg"),
    ("micasense orchard on dry soil", MICASENSE, (slice(0, 944), slice(700, 1253)), "exg"),
    ("micasense hedgerows", MICASENSE, (slice(0, 944), slice(0, 520)), "exg"),
    ("micasense one tree", MICASENSE, (slice(190, 250), slice(760, 820)), "exg"),
    ("micasense inside hedgerow A", MICASENSE, (slice(100, 140), slice(50, 450)), "plant"),
    ("micasense inside hedgerow B", MICASENSE, (slice(380, 410), slice(50, 450)), "plant"),
    ("micasense dirt road", MICASENSE, (slice(300, 700), slice(580, 640)), "soil"),
)
LAST_ROUND = (vegetation.NDVI_FLOOR, float("inf"))  # the band that makes the rule Otsu's, floored


def run_window(path, window, reference, band):
    saved = vegetation._NDVI_BAND
    vegetation._NDVI_BAND = band
    try:
        raw = tifffile.imread(path)
        if raw.ndim == 3 and raw.shape[0] < raw.shape[-1] and raw.shape[0] <= 8:
            raw = np.moveaxis(raw, 0, -1)
        cut = np.ascontiguousarray(raw[window])
        with tempfile.TemporaryDirectory() as tmp:
            tif = Path(tmp) / "window.tif"
            extratags = [(42113, 2, 0, "-10000", True)] if (cut == -10000).any() else []
            tifffile.imwrite(tif, cut, photometric="minisblack", planarconfig="contig", extratags=extratags)
            relief = build_relief(tif, mesh=None, bands="B,G,R,RE,N", max_size=2000)
    finally:
        vegetation._NDVI_BAND = saved
    rule = relief.params["threshold"]
    row = {
        "source": "photo (Otsu)" if band == LAST_ROUND else rule["source"],
        "threshold": rule["value"],
        "valley": rule["valley"],
        "red_d": rule["colour_separation"],
        "cover": float(relief.mask.mean()),
    }
    if reference == "exg":
        valid = None if relief.working.shape[:2] != relief.mask.shape else (relief.working.sum(axis=2) > 0)
        ref = reference_mask(relief.working, valid=valid)
        agreement = mask_agreement(relief.mask, ref)
        row.update(
            iou=agreement["iou"],
            volume_on_plants=volume_fraction(relief.heights, ref),
            reference_cover=float(ref.mean()),
        )
    else:
        row["risen"] = float(relief.mask[relief.working.sum(axis=2) > 0].mean())
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    rows = []
    for name, file, window, reference in WINDOWS:
        path = args.data / file
        if not path.exists():
            print(f"skipped {name}: {path} is absent (see /work/data/multispectral_layout.py)")
            continue
        ours = run_window(path, window, reference, vegetation._NDVI_BAND)
        last = run_window(path, window, reference, LAST_ROUND)
        rows.append({"window": name, "reference": reference, "ours": ours, "last_round": last})
    print(
        "| window | reference | rule (source, threshold) | valley | red D | ours: IoU / volume on plants "
        "or share risen | last round: rule, IoU / volume or risen |"
    )
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        o, f = row["ours"], row["last_round"]

        def figures(r):
            if "iou" in r:
                return f"{r['iou']:.3f} / {r['volume_on_plants']:.1%}"
            return f"{r['risen']:.1%} risen"

        ref = {"exg": "ExG/Otsu (no hand mask)", "plant": "all plant (by eye)", "soil": "all soil (by eye)"}
        print(
            f"| {row['window']} | {ref[row['reference']]} | {o['source']}, {o['threshold']:.3f} | "
            f"{o['valley']:.2f} | {o['red_d']:.2f} | {figures(o)} | {f['source']}, {f['threshold']:.3f}: "
            f"{figures(f)} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
