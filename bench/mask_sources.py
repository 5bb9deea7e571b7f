"""Plant masks on annotated photos from several public sources, the colour test's bound chosen
leave-one-source-out.

    python bench/mask_sources.py DATA_DIR [--max-size 1000] [--json OUT.json]

Fetches nothing. ``DATA_DIR/masks/<source>/NAME.(png|jpg|tif)`` with ``NAME_mask.png`` (255 = plant)
are annotated photos; ``DATA_DIR/photos/<source>/`` photos without a hand mask, whose reference is an
independent ExG/Otsu index mask (said so in the table). Each source is one folder.

The threshold rule's colour test has one constant, ``COLOUR_SEPARATION`` (the least Ashman's D of
the chroma across Otsu's split that counts as two classes; 2 is Ashman's own bound). For every
source, the bound is chosen from ``CANDIDATES`` on the *other* sources only (the largest median IoU
over their images, ties to the bound nearest 2), and the source is reported at that bound: no
constant is chosen with the source it is reported on. The table gives per source the images, the
bound its fold chose, and median and worst IoU, F1 and share of the relief's volume on the
reference's plants, beside the same figures with the colour test off (last round's rule), and the
reference's median plant cover (a source of seedlings scores low IoU on few pixels).

What each source is (crop, soil, light, stage, licence, origin) is in ``DATA_DIR/masks/SOURCES.md``;
``bench/layout_masks.py DATA_DIR`` lays the public sources out from their repositories' pinned commits.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.validate_real import PHOTO_SUFFIXES, read_mask  # noqa: E402
from cliff_terrain import build_relief  # noqa: E402
from cliff_terrain.evaluate.mask_quality import mask_agreement, reference_mask, volume_fraction  # noqa: E402
from cliff_terrain.photo_heights import vegetation  # noqa: E402

# Bounds tried for the colour test; inf switches it off (last round's valley-only rule).
CANDIDATES = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, float("inf"))


def photos(data_dir):
    """[(source, kind, photo path)] for every photo under masks/ and photos/."""
    found = []
    for kind in ("masks", "photos"):
        base = data_dir / kind
        for folder in sorted(p for p in base.glob("*") if p.is_dir()) if base.is_dir() else []:
            for photo in sorted(folder.iterdir()):
                if photo.suffix.lower() in PHOTO_SUFFIXES and not photo.stem.endswith("_mask"):
                    found.append((folder.name, kind, photo))
    return found


def oracle_iou(relief, reference):
    """The best IoU any single threshold on the relief's own (blurred) index reaches against
    `reference`, and that threshold: an upper bound for every threshold rule, chosen *with* the
    annotation, so it says whether a source loses in the threshold or in the index itself."""
    vi, _ = vegetation.blurred_index(np.asarray(relief.working), index=relief.params["threshold"]["index"])
    values = vi[np.isfinite(vi)]
    best = (0.0, float("nan"))
    for t in np.unique(np.percentile(values, np.linspace(0.5, 99.5, 100))):
        mask = vi > t
        union = np.count_nonzero(mask | reference)
        iou = np.count_nonzero(mask & reference) / union if union else 0.0
        best = max(best, (float(iou), float(t)))
    return best


def figures_at(photo, kind, bound, max_size, *, oracle=False):
    """IoU, F1, volume on plants and the threshold record of `photo`'s relief, the colour test's
    bound set to `bound` for this build; with `oracle`, also :func:`oracle_iou` against the reference."""
    saved = vegetation.COLOUR_SEPARATION
    vegetation.COLOUR_SEPARATION = bound
    try:
        relief = build_relief(photo, max_size=max_size, mesh=None)
    finally:
        vegetation.COLOUR_SEPARATION = saved
    rule = relief.params["threshold"]
    shape = relief.mask.shape
    if kind == "masks":
        reference, name = read_mask(photo.with_name(f"{photo.stem}_mask.png"), shape), "annotation"
    else:
        index = "nir" if rule["index"] == "nir" else "exg"
        reference, name = reference_mask(relief.working, index=index), f"{index}/Otsu (no hand mask)"
    agreement = mask_agreement(relief.mask, reference)
    extra = {}
    if oracle:
        extra["oracle_iou"], extra["oracle_threshold"] = oracle_iou(relief, reference)
    return {
        "iou": agreement["iou"],
        "f1": agreement["f1"],
        "volume_on_plants": volume_fraction(relief.heights, reference),
        "reference_cover": float(np.count_nonzero(reference)) / reference.size,
        "threshold": rule["value"],
        "source": rule["source"],
        "valley": rule["valley"],
        "colour_separation": rule.get("colour_separation"),
        "note": rule.get("note", ""),
        "reference": name,
        **extra,
    }


def evaluate(data_dir, max_size, *, oracle=False):
    """{source: [{bound: figures} per image]} and the images' names.

    Two builds per photo: the colour test off (bound inf) and always passed (bound -inf). At any
    bound b the photo gets the second when its separation D >= b, else the first (D does not
    depend on the bound).
    """
    table, names = {}, {}
    for source, kind, photo in photos(data_dir):
        off = figures_at(photo, kind, float("inf"), max_size)
        on = figures_at(photo, kind, float("-inf"), max_size, oracle=oracle)
        if oracle:
            off.update(oracle_iou=on["oracle_iou"], oracle_threshold=on["oracle_threshold"])
        d = on["colour_separation"]
        d = float("nan") if d is None else float(d)
        row = {b: (on if np.isfinite(b) and d >= b else off) for b in CANDIDATES}
        table.setdefault(source, []).append(row)
        names.setdefault(source, []).append(photo.name)
        at2 = row[2.0]
        print(
            f"  {source}/{photo.name}: D {d:.2f}, at 2: {at2['source']} {at2['threshold']:.3f} "
            f"IoU {at2['iou']:.3f} volume {at2['volume_on_plants']:.1%} (off: {off['source']} "
            f"{off['threshold']:.3f} IoU {off['iou']:.3f} volume {off['volume_on_plants']:.1%})"
            + (f" [{at2['note'].split(':')[0]}]" if at2["note"] else ""),
            flush=True,
        )
    return table, names


def choose_bound(table, held_out):
    """The bound with the largest median IoU over the images of every source but `held_out`."""
    others = [row for source, rows in table.items() if source != held_out for row in rows]

    def score(bound):
        return float(np.median([row[bound]["iou"] for row in others])) if others else 0.0

    # Ties to the bound nearest Ashman's 2 (inf, off, is farthest).
    return max(CANDIDATES, key=lambda b: (round(score(b), 4), -abs(b - 2.0)))


def summary(rows, bound):
    """Median and worst of each figure over `rows` at `bound`."""
    out = {"images": len(rows)}
    out["reference_cover_median"] = float(np.median([row[bound]["reference_cover"] for row in rows]))
    keys = ("iou", "f1", "volume_on_plants") + (("oracle_iou",) if "oracle_iou" in rows[0][bound] else ())
    for key in keys:
        values = [row[bound][key] for row in rows]
        out[f"{key}_median"] = float(np.median(values))
        out[f"{key}_worst"] = float(np.min(values))
    return out


def loso_table(table):
    """Per source: the bound chosen without it, its figures there, and the same with the test off."""
    result = {}
    for source, rows in table.items():
        bound = choose_bound(table, source)
        result[source] = {
            "bound": bound,
            "reference": rows[0][bound]["reference"],
            "ours": summary(rows, bound),
            "colour_test_off": summary(rows, float("inf")),
            "colour_test_fired": sum(row[bound]["source"] == "photo (colour)" for row in rows),
        }
    return result


def markdown(result):
    oracle = any("oracle_iou_median" in r["ours"] for r in result.values())
    lines = [
        "| source | images | bound (chosen without it) | IoU median / worst | F1 median / worst "
        "| volume on plants median / worst | colour test fired | test off: IoU median / worst | "
        "test off: volume median / worst | reference (its plant cover, median) |"
        + (" oracle threshold IoU median / worst |" if oracle else ""),
        "|---|---|---|---|---|---|---|---|---|---|" + ("---|" if oracle else ""),
    ]
    for source, r in result.items():
        o, f = r["ours"], r["colour_test_off"]
        tail = f" {o['oracle_iou_median']:.3f} / {o['oracle_iou_worst']:.3f} |" if oracle else ""
        lines.append(
            f"| {source} | {o['images']} | {r['bound']:g} | {o['iou_median']:.3f} / {o['iou_worst']:.3f} "
            f"| {o['f1_median']:.3f} / {o['f1_worst']:.3f} | {o['volume_on_plants_median']:.1%} / "
            f"{o['volume_on_plants_worst']:.1%} | {r['colour_test_fired']} | {f['iou_median']:.3f} / "
            f"{f['iou_worst']:.3f} | {f['volume_on_plants_median']:.1%} / {f['volume_on_plants_worst']:.1%} "
            f"| {r['reference']} ({o['reference_cover_median']:.0%}) |{tail}"
        )
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--max-size", type=int, default=1000)
    parser.add_argument("--json", type=Path, default=None, help="write every figure here")
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="also report the best single threshold's IoU per photo (chosen with the reference: an upper "
        "bound for any threshold rule, never a figure of ours)",
    )
    args = parser.parse_args(argv)
    if not args.data_dir.is_dir():
        parser.error(f"DATA_DIR {str(args.data_dir)!r} is not a folder")
    warnings.filterwarnings("ignore", message=".*GDAL_NODATA.*")
    table, names = evaluate(args.data_dir, args.max_size, oracle=args.oracle)
    result = loso_table(table)
    print(markdown(result))
    if args.json:
        record = {
            "candidates": [str(b) for b in CANDIDATES],
            "sources": {
                s: {
                    **result[s],
                    "images": [
                        {"image": n, **{str(b): row[b] for b in CANDIDATES}}
                        for n, row in zip(names[s], table[s], strict=True)
                    ],
                }
                for s in result
            },
        }
        args.json.write_text(json.dumps(record, indent=2, default=str) + "\n")
    return result


if __name__ == "__main__":
    main()
