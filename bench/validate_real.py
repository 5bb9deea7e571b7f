"""Validation on real fields: masks against references, single-flight heights against two flights.

    python bench/validate_real.py DATA_DIR [--json OUT.json] [--half tune|holdout|all]

Fetches nothing: DATA_DIR holds the data (outside the repository; see the README's "Validation on
real fields" for the sources, their licences and how they were laid out):

``DATA_DIR/masks/<set>/NAME.(png|jpg|tif)`` with ``NAME_mask.png``
    A photo and its annotated plant mask (255 = plant). Reported: the relief mask's IoU and F1
    against it, and the share of the relief's volume that stands on its plant pixels.
``DATA_DIR/photos/<set>/NAME.(png|jpg|tif)``
    A photo without annotation: the reference is an independent ExG/Otsu mask
    (:func:`cliff_terrain.evaluate.mask_quality.reference_mask`).
``DATA_DIR/fields/<field>/field.json``
    A field flown on several dates::

        {"plots": "Data_Total.shp", "reference": "DSM/1_30_dsm.tif",
         "dates": {"40": {"ortho": "MOSAIC/2_40_RGB.tif", "dsm": "DSM/2_40_dsm.tif"}, ...},
         "holdout": ["70"]}

    For each date, ``cliff-terrain heights`` runs on the orthophoto and its DSM alone (one flight)
    and its per-plot p90 canopy height (``plots.csv``) is compared with the p90 of the difference of
    the date's DSM and the early-season reference DSM, resampled onto the same grid. Reported: r,
    RMSE and bias against that raw difference, and against the difference *aligned* on stable
    ground: photogrammetry without ground control tilts one flight against another (on the potato
    trial by up to 26 cm along the field), so a robust quadratic surface fitted to the difference
    outside the plots (plants rejected as outliers) is removed first. The naive peer (2nd
    percentile of the DSM in 5 m blocks, bilinear) runs on the same grid in the same run.

Images are split into two halves by their sorted order within each set (even: ``tune``, odd:
``holdout``); a field's dates are ``holdout`` when listed so in field.json. Thresholds were chosen
on the tune half only; the README reports the holdout half.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cliff_terrain import CliffTerrainError, build_relief  # noqa: E402
from cliff_terrain.evaluate.mask_quality import mask_agreement, reference_mask, volume_fraction  # noqa: E402

PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def halves(names):
    """{name: "tune" | "holdout"}: alternate in sorted order, so each half spans the set."""
    return {name: ("tune" if i % 2 == 0 else "holdout") for i, name in enumerate(sorted(names))}


def read_mask(path, shape):
    import cv2
    from PIL import Image

    with Image.open(path) as image:
        mask = np.asarray(image.convert("L")) > 127
    if mask.shape != shape:
        mask = cv2.resize(mask.astype(np.uint8), shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    return mask


def image_rows(data_dir, max_size):
    rows = []
    for kind in ("masks", "photos"):
        # Folders only: a SOURCES.md beside them describes them.
        base = data_dir / kind
        for folder in sorted(p for p in base.glob("*") if p.is_dir()) if base.is_dir() else []:
            photos = [
                p
                for p in folder.iterdir()
                if p.suffix.lower() in PHOTO_SUFFIXES and not p.stem.endswith("_mask")
            ]
            split = halves([p.name for p in photos])
            for photo in sorted(photos):
                relief = build_relief(photo, max_size=max_size, mesh=None)
                shape = relief.mask.shape
                if kind == "masks":
                    reference, source = (
                        read_mask(photo.with_name(f"{photo.stem}_mask.png"), shape),
                        "annotation",
                    )
                else:
                    index = "nir" if relief.params["threshold"]["index"] == "nir" else "exg"
                    reference, source = reference_mask(relief.working, index=index), f"{index}/Otsu"
                agreement = mask_agreement(relief.mask, reference)
                rows.append(
                    {
                        "set": folder.name,
                        "image": photo.name,
                        "half": split[photo.name],
                        "reference": source,
                        "iou": agreement["iou"],
                        "f1": agreement["f1"],
                        "volume_on_plants": volume_fraction(relief.heights, reference),
                        "threshold": relief.params["threshold"]["value"],
                        "threshold_source": relief.params["threshold"]["source"],
                        "valley": relief.params["threshold"]["valley"],
                        "colour_separation": relief.params["threshold"].get("colour_separation"),
                        "note": relief.params["threshold"].get("note", ""),
                    }
                )
                print(_image_line(rows[-1]), flush=True)
    return rows


def _image_line(row):
    return (
        f"  {row['set']}/{row['image']} [{row['half']}]: IoU {row['iou']:.3f}, F1 {row['f1']:.3f}, "
        f"volume on plants {row['volume_on_plants']:.1%} (threshold {row['threshold']:.3f}, "
        f"{row['threshold_source']}, colour D {row.get('colour_separation')}; reference {row['reference']})"
    )


def robust_quadratic(values, rows, cols, *, iterations=10, k=3.0):
    """Coefficients of z = quadratic(rows, cols) fitted with points beyond k robust sigmas dropped."""
    design = np.column_stack([np.ones_like(rows), rows, cols, rows * rows, rows * cols, cols * cols])
    keep = np.ones(values.size, dtype=bool)
    coef = np.zeros(6)
    for _ in range(iterations):
        coef, *_ = np.linalg.lstsq(design[keep], values[keep], rcond=None)
        residual = values - design @ coef
        spread = max(1.4826 * float(np.median(np.abs(residual[keep]))), 1e-4)
        new_keep = np.abs(residual) <= k * spread
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return coef


def stable_alignment(difference, outside):
    """The smooth surface by which one flight stands above the other on ground that did not change."""
    rr, cc = np.nonzero(outside & np.isfinite(difference))
    if rr.size < 100:
        return np.zeros_like(difference)
    step = max(1, rr.size // 200_000)
    rr, cc = rr[::step], cc[::step]
    rows, cols = difference.shape
    coef = robust_quadratic(difference[rr, cc].astype(np.float64), rr / rows, cc / cols)
    gr, gc = np.mgrid[:rows, :cols]
    gr, gc = gr / rows, gc / cols
    terms = (np.ones_like(gr), gr, gc, gr * gr, gr * gc, gc * gc)
    return sum(c * t for c, t in zip(coef, terms, strict=True)).astype(np.float32)


def agreement(estimate, truth):
    ok = np.isfinite(estimate) & np.isfinite(truth)
    a, b = estimate[ok], truth[ok]
    if a.size < 3:
        return {"n": int(a.size), "r": None, "rmse_cm": None, "bias_cm": None}
    return {
        "n": int(a.size),
        "r": float(np.corrcoef(a, b)[0, 1]),
        "rmse_cm": float(np.sqrt(np.mean((a - b) ** 2)) * 100),
        "bias_cm": float(np.mean(a - b) * 100),
    }


def field_rows(data_dir):
    import cv2

    from cliff_terrain.cli import main as cli
    from cliff_terrain.io.geotiff import read_surface, resample
    from cliff_terrain.io.plot_polygons import read_plots
    from cliff_terrain.measure.field_plots import rasterize_plots
    from cliff_terrain.measure.ground import canopy_height, naive_block_ground

    rows = []
    for spec_path in (
        sorted((data_dir / "fields").glob("*/field.json")) if (data_dir / "fields").is_dir() else []
    ):
        folder = spec_path.parent
        spec = json.loads(spec_path.read_text())
        plots = read_plots(folder / spec["plots"])
        reference = read_surface(folder / spec["reference"])
        n = len(plots.polygons)
        for date, files in spec["dates"].items():
            with tempfile.TemporaryDirectory() as out:
                args = ["heights", str(folder / files["ortho"]), "--dsm", str(folder / files["dsm"])]
                args += ["--plots", str(folder / spec["plots"]), "--out", out]
                if cli(args) != 0:
                    raise CliffTerrainError(f"cliff-terrain heights failed on {folder.name} {date}")
                chm = read_surface(Path(out) / "chm.tif")
                summary = json.loads((Path(out) / "summary.json").read_text())
                with open(Path(out) / "plots.csv", newline="") as stream:
                    table = list(csv.DictReader(stream))
            ours = np.array([float(row["height_p90_m"]) for row in table])
            support = np.array([float(row["ground_support"]) for row in table])
            dsm = resample(read_surface(folder / files["dsm"]), transform=chm.transform, shape=chm.shape)
            early = resample(reference, transform=chm.transform, shape=chm.shape)
            labels = rasterize_plots(plots, transform=chm.transform, shape=chm.shape)
            difference = dsm - early
            # Stable ground: at least half a metre outside every plot.
            pixel = float(np.mean(chm.pixel_size))
            reach = max(1, round(0.5 / pixel))
            near = cv2.dilate((labels > 0).astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)) > 0
            aligned = difference - stable_alignment(difference, ~near)

            truth_raw = plot_p90(labels, n, np.maximum(difference, 0))
            truth = plot_p90(labels, n, np.maximum(aligned, 0))
            naive_chm = canopy_height(dsm, naive_block_ground(dsm, pixel_size=pixel, percentile=2.0))
            naive = plot_p90(labels, n, naive_chm)
            role = "holdout" if date in spec.get("holdout", []) else "tune"
            row = {
                "field": folder.name,
                "date": date,
                "half": role,
                "plots": n,
                "ours_raw": agreement(ours, truth_raw),
                "ours_aligned": agreement(ours, truth),
                "peer_raw": agreement(naive, truth_raw),
                "peer_aligned": agreement(naive, truth),
                "ground_support_median": float(np.nanmedian(support)),
                "threshold": summary["threshold"],
            }
            rows.append(row)
            print(_field_line(row), flush=True)
    return rows


def plot_p90(labels, n, heights):
    """Each plot's 90th percentile of `heights` over all its pixels with data (soil counts)."""
    from cliff_terrain.measure.field_plots import region_figures

    figures = region_figures(labels, n, mask=np.ones(labels.shape, bool), heights=heights, pixel_area_m2=1.0)
    return np.array([f["height_p90_m"] for f in figures])


def _field_line(row):
    def fmt(a):
        if a["r"] is None:
            return "n/a"
        return f"r {a['r']:.3f}, RMSE {a['rmse_cm']:.1f} cm, bias {a['bias_cm']:+.1f} cm"

    return (
        f"  {row['field']} day {row['date']} [{row['half']}], {row['plots']} plots:\n"
        f"    ours  vs aligned: {fmt(row['ours_aligned'])} | vs raw: {fmt(row['ours_raw'])}\n"
        f"    peer  vs aligned: {fmt(row['peer_aligned'])} | vs raw: {fmt(row['peer_raw'])}\n"
        f"    ground support (plot median) {row['ground_support_median']:.2f}"
    )


def summarise(rows, half):
    picked = [r for r in rows if half == "all" or r["half"] == half]
    if not picked:
        return None
    return {
        "images": len(picked),
        "iou_median": float(np.median([r["iou"] for r in picked])),
        "iou_worst": float(min(r["iou"] for r in picked)),
        "f1_median": float(np.median([r["f1"] for r in picked])),
        "f1_worst": float(min(r["f1"] for r in picked)),
        "volume_on_plants_min": float(min(r["volume_on_plants"] for r in picked)),
        "volume_on_plants_median": float(np.median([r["volume_on_plants"] for r in picked])),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--max-size", type=int, default=1000)
    parser.add_argument("--json", type=Path, default=None, help="write every figure here")
    parser.add_argument("--skip-images", action="store_true")
    parser.add_argument("--skip-fields", action="store_true")
    args = parser.parse_args(argv)
    if not args.data_dir.is_dir():
        parser.error(f"DATA_DIR {str(args.data_dir)!r} is not a folder")
    warnings.filterwarnings("ignore", message=".*GDAL_NODATA.*")
    images = [] if args.skip_images else image_rows(args.data_dir, args.max_size)
    fields = [] if args.skip_fields else field_rows(args.data_dir)
    record = {"images": images, "fields": fields, "summary": {}}
    for half in ("tune", "holdout"):
        for group in sorted({r["set"] for r in images}):
            record["summary"][f"{group}/{half}"] = summarise([r for r in images if r["set"] == group], half)
    for key, value in record["summary"].items():
        if value:
            print(
                f"{key}: {value['images']} images, IoU median {value['iou_median']:.3f} worst "
                f"{value['iou_worst']:.3f}, F1 median {value['f1_median']:.3f} worst "
                f"{value['f1_worst']:.3f}, volume on plants min {value['volume_on_plants_min']:.1%} "
                f"median {value['volume_on_plants_median']:.1%}"
            )
    if args.json:
        args.json.write_text(json.dumps(record, indent=2) + "\n")
    return record


if __name__ == "__main__":
    main()
