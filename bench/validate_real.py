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
        for folder in sorted((data_dir / kind).glob("*")) if (data_dir / kind).is_dir() else []:
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
                    }
                )
                print(_image_line(rows[-1]), flush=True)
    return rows


def _image_line(row):
    return (
        f"  {row['set']}/{row['image']} [{row['half']}]: IoU {row['iou']:.3f}, F1 {row['f1']:.3f}, "
        f"volume on plants {row['volume_on_plants']:.1%} (threshold {row['threshold']:.3f}, "
        f"{row['threshold_source']}; reference {row['reference']})"
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


def field_rows(data_dir, *, ground="auto"):
    """Per field and date: ours, the naive baseline and plantcv-geospatial's p90 - p25 against every
    reference the field has (the aligned and raw two-flight difference, a ruler), with the coverage
    of ours' uncertainty (|error| <= 1.645 x height_p90_err_m)."""
    import cv2

    from cliff_terrain.io.geotiff import read_surface, resample
    from cliff_terrain.io.plot_polygons import read_plots
    from cliff_terrain.measure.field_plots import rasterize_plots
    from cliff_terrain.measure.ground import canopy_height, fit_ground, naive_block_ground
    from cliff_terrain.measure.ruler import read_ruler

    rows = []
    for spec_path in (
        sorted((data_dir / "fields").glob("*/field.json")) if (data_dir / "fields").is_dir() else []
    ):
        folder = spec_path.parent
        spec = json.loads(spec_path.read_text())
        plots = read_plots(folder / spec["plots"])
        reference = read_surface(folder / spec["reference"]) if spec.get("reference") else None
        ruler_spec = spec.get("ruler") if isinstance(spec.get("ruler"), dict) else None
        if ruler_spec and ruler_spec.get("unit") not in ("m", "cm", "mm"):
            ruler_spec = None  # a field book whose unit nobody knows is no ruler
        n = len(plots.polygons)
        for date, files in spec["dates"].items():
            ruler = None
            if ruler_spec:
                ruler = read_ruler(
                    folder / ruler_spec["file"],
                    plots,
                    id_column=ruler_spec.get("id"),
                    height_column=ruler_spec.get("height"),
                    units=ruler_spec["unit"],
                )
            dsm_raster = read_surface(folder / files["dsm"])
            if files.get("ortho"):
                ours, err, check, transform, shape = _run_heights(folder, files, spec, ground)
            else:  # a surface model alone: the ground from its shape, no colour
                transform, shape = dsm_raster.transform, dsm_raster.shape
                pixel = float(np.mean(dsm_raster.pixel_size))
                dsm = resample(dsm_raster, transform=transform, shape=shape)
                fit = fit_ground(dsm, pixel_size=pixel, method=ground)
                labels = rasterize_plots(plots, transform=transform, shape=shape)
                ours = plot_p90(labels, n, canopy_height(dsm, fit.ground))
                err = _plot_rms(labels, n, fit.sigma, np.isfinite(dsm))
                check = fit.check
            dsm = resample(dsm_raster, transform=transform, shape=shape)
            labels = rasterize_plots(plots, transform=transform, shape=shape)
            pixel = float(
                np.mean([np.hypot(*np.asarray(transform)[:2, 0]), np.hypot(*np.asarray(transform)[:2, 1])])
            )
            peers = {
                "baseline": plot_p90(
                    labels, n, canopy_height(dsm, naive_block_ground(dsm, pixel_size=pixel, percentile=2.0))
                ),
                "plantcv": _plot_percentile(labels, n, dsm, 90) - _plot_percentile(labels, n, dsm, 25),
            }
            truths = {}
            if reference is not None:
                early = resample(reference, transform=transform, shape=shape)
                difference = dsm - early
                # Stable ground: at least half a metre outside every plot.
                reach = max(1, round(0.5 / pixel))
                near = cv2.dilate((labels > 0).astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)) > 0
                aligned = difference - stable_alignment(difference, ~near)
                truths["aligned"] = plot_p90(labels, n, np.maximum(aligned, 0))
                truths["raw"] = plot_p90(labels, n, np.maximum(difference, 0))
            if ruler is not None:
                truths["ruler"] = ruler.heights_m
            row = {
                "field": folder.name,
                "crop": spec.get("crop", ""),
                "stage": spec.get("stage", ""),
                "date": date,
                "half": "holdout" if date in spec.get("holdout", []) else "tune",
                "plots": n,
                "colour": bool(files.get("ortho")),
                "ground_method": check.get("method"),
                "ground_check_error_cm": 100 * check["candidates"][check["method"]]["error_m"],
                "evidence": check.get("evidence", {}).get("source"),
                "against": {},
            }
            for kind, truth in truths.items():
                row["against"][kind] = {
                    "ours": agreement(ours, truth),
                    "coverage": _coverage(ours, err, truth),
                    **{name: agreement(values, truth) for name, values in peers.items()},
                }
            rows.append(row)
            print(_field_line(row), flush=True)
    return rows


def _run_heights(folder, files, spec, ground):
    """`cliff-terrain heights` on one date: (p90, p90 err, ground check, grid transform, grid shape)."""
    from cliff_terrain.cli import main as cli
    from cliff_terrain.io.geotiff import read_surface

    with tempfile.TemporaryDirectory() as out:
        args = ["heights", str(folder / files["ortho"]), "--dsm", str(folder / files["dsm"])]
        args += ["--plots", str(folder / spec["plots"]), "--out", out, "--ground", ground]
        if cli(args) != 0:
            raise CliffTerrainError(f"cliff-terrain heights failed on {folder.name} {files['dsm']}")
        chm = read_surface(Path(out) / "chm.tif")
        summary = json.loads((Path(out) / "summary.json").read_text())
        with open(Path(out) / "plots.csv", newline="") as stream:
            table = list(csv.DictReader(stream))
    ours = np.array([float(row["height_p90_m"]) for row in table])
    err = np.array([float(row["height_p90_err_m"]) for row in table])
    return ours, err, summary["ground_check"], chm.transform, chm.shape


def _plot_rms(labels, n, values, valid):
    pick = labels.ravel() * valid.ravel()
    counts = np.bincount(pick, minlength=n + 1)[1:]
    sums = np.bincount(pick, weights=np.nan_to_num(values.ravel()) ** 2, minlength=n + 1)[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, np.sqrt(sums / np.maximum(counts, 1)), np.nan)


def _plot_percentile(labels, n, values, q):
    flat, vals = labels.ravel(), values.ravel()
    ok = (flat > 0) & np.isfinite(vals)
    order = np.lexsort((vals[ok], flat[ok]))
    lab, v = flat[ok][order], vals[ok][order]
    out = np.full(n, np.nan)
    starts = np.searchsorted(lab, np.arange(1, n + 1))
    ends = np.searchsorted(lab, np.arange(1, n + 1), side="right")
    for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
        if b > a:
            out[k] = np.percentile(v[a:b], q)
    return out


def _coverage(ours, err, truth):
    ok = np.isfinite(ours) & np.isfinite(err) & np.isfinite(truth)
    if not ok.any():
        return None
    return float(np.mean(np.abs(ours[ok] - truth[ok]) <= 1.645 * err[ok]))


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

    lines = [
        f"  {row['field']} {row['date']} [{row['half']}], {row['plots']} plots, ground {row['ground_method']} "
        f"(held-out {row['ground_check_error_cm']:.1f} cm, evidence: {row['evidence']})"
    ]
    for kind, figures in row["against"].items():
        cov = figures["coverage"]
        lines.append(
            f"    vs {kind:8s} ours {fmt(figures['ours'])} (coverage {'n/a' if cov is None else f'{cov:.0%}'})"
            f" | baseline {fmt(figures['baseline'])} | plantcv {fmt(figures['plantcv'])}"
        )
    return "\n".join(lines)


def summarise(rows, half):
    picked = [r for r in rows if half == "all" or r["half"] == half]
    if not picked:
        return None
    return {
        "images": len(picked),
        "iou_median": float(np.median([r["iou"] for r in picked])),
        "f1_median": float(np.median([r["f1"] for r in picked])),
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
    parser.add_argument("--ground", default="auto", help="the heights' --ground (default auto)")
    args = parser.parse_args(argv)
    if not args.data_dir.is_dir():
        parser.error(f"DATA_DIR {str(args.data_dir)!r} is not a folder")
    warnings.filterwarnings("ignore", message=".*GDAL_NODATA.*")
    images = [] if args.skip_images else image_rows(args.data_dir, args.max_size)
    fields = [] if args.skip_fields else field_rows(args.data_dir, ground=args.ground)
    record = {"images": images, "fields": fields, "summary": {}}
    for half in ("tune", "holdout"):
        for group in sorted({r["set"] for r in images}):
            record["summary"][f"{group}/{half}"] = summarise([r for r in images if r["set"] == group], half)
    for key, value in record["summary"].items():
        if value:
            print(
                f"{key}: {value['images']} images, IoU median {value['iou_median']:.3f}, F1 median "
                f"{value['f1_median']:.3f}, volume on plants min {value['volume_on_plants_min']:.1%} "
                f"median {value['volume_on_plants_median']:.1%}"
            )
    if args.json:
        args.json.write_text(json.dumps(record, indent=2) + "\n")
    return record


if __name__ == "__main__":
    main()
