"""Validation on real fields: masks against references, single-flight heights against two flights.

    python bench/validate_real.py DATA_DIR [--json OUT.json] [--docs docs/validation.md]
    python bench/validate_real.py --record OUT.json --docs docs/validation.md   # the page from a record

Fetches nothing: DATA_DIR holds the data (outside the repository; see the docs' validation page,
docs/validation.md, for the sources, their licences and how they were laid out):

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
on the tune half only; the validation page reports both.
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
from cliff_terrain.measure.ruler import Z90  # noqa: E402

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


def aligned_difference(difference, labels, pixel):
    """`difference` less its :func:`stable_alignment` on the ground at least 0.5 m outside every plot."""
    import cv2

    reach = max(1, round(0.5 / pixel))
    near = cv2.dilate((labels > 0).astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)) > 0
    return difference - stable_alignment(difference, ~near)


def agreement(estimate, truth):
    """:func:`cliff_terrain.measure.ruler.agreement` (n, r, RMSE, bias) with the lengths in cm."""
    from cliff_terrain.measure.ruler import agreement as in_metres

    a = in_metres(estimate, truth)
    cm = {key: None if a[f"{key}_m"] is None else 100 * a[f"{key}_m"] for key in ("rmse", "bias")}
    return {"n": a["n"], "r": a["r"], "rmse_cm": cm["rmse"], "bias_cm": cm["bias"]}


# Plot resamples of the paired bootstrap that tells a loss from a tie (fixed seed: the same verdicts
# on every run of one record).
BOOTSTRAP_RESAMPLES = 2000


def paired_bootstrap(ours, theirs, truth, *, resamples=BOOTSTRAP_RESAMPLES, seed=0):
    """95 % intervals of ours minus theirs in r and in RMSE (cm), resampling the plots (paired).

    Both estimates are scored on the same resampled plots, so what the plots share (the
    reference's own errors, the field) cancels and the interval is the difference's alone (Efron
    and Tibshirani 1993, ch. 16). An interval that holds 0 is a tie: the plots cannot tell the two
    apart. Returns ``{"r": [lo, hi], "rmse_cm": [lo, hi]}``, or None with fewer than 10 plots.

    Examples
    --------
    >>> truth = np.linspace(0.1, 0.6, 50)
    >>> noise = np.random.default_rng(1).normal(0, 0.02, 50)
    >>> better, worse = truth + noise, truth + 3 * noise
    >>> ci = paired_bootstrap(better, worse, truth)
    >>> ci["rmse_cm"][1] < 0 < ci["r"][0]
    True
    """
    ours, theirs, truth = (np.asarray(a, dtype=np.float64) for a in (ours, theirs, truth))
    ok = np.isfinite(ours) & np.isfinite(theirs) & np.isfinite(truth)
    ours, theirs, truth = ours[ok], theirs[ok], truth[ok]
    n = truth.size
    if n < 10:
        return None
    pick = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    t, a, b = truth[pick], ours[pick], theirs[pick]

    def r(x):
        xc, tc = x - x.mean(axis=1, keepdims=True), t - t.mean(axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return (xc * tc).sum(axis=1) / np.sqrt((xc * xc).sum(axis=1) * (tc * tc).sum(axis=1))

    def rmse(x):
        return 100 * np.sqrt(np.mean((x - t) ** 2, axis=1))

    return {
        key: [float(v) for v in np.nanpercentile(f(a) - f(b), [2.5, 97.5])]
        for key, f in (("r", r), ("rmse_cm", rmse))
    }


def field_rows(data_dir, *, ground="auto", colour="photo", windowed=False):
    """Per field and date: ours, the naive baseline and plantcv-geospatial's p90 - p25 against every
    reference the field has (the aligned and raw two-flight difference, a ruler), with the coverage
    of ours' uncertainty (|error| <= 1.645 x height_p90_err_m).

    ``colour="straw"`` or ``"golden"`` runs ours on each orthophoto recoloured (:func:`straw_photo`,
    :func:`golden_photo`), and skips the dates without one: the ground when the colour does not
    follow the crop. With `windowed`, ours is ``cliff-terrain heights --windowed`` (the path of
    orthophotos too big for memory)."""
    from cliff_terrain.io.raster.geotiff import read_surface, resample
    from cliff_terrain.io.vector.plot_polygons import read_plots
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
            if colour != "photo" and not files.get("ortho"):
                continue
            dsm_raster = read_surface(folder / files["dsm"])
            if files.get("ortho"):
                ours, err, check, transform, shape = _run_heights(
                    folder, files, spec, ground, colour, windowed
                )
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
                aligned = aligned_difference(difference, labels, pixel)  # on stable ground
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
                "colour_contradicted": check.get("evidence", {}).get("colour_contradicted"),
                "occlusion_rise_cm": _occlusion_cm(check),
                "reference_label": spec.get("reference_label"),
                "against": {},
            }
            for kind, truth in truths.items():
                row["against"][kind] = {
                    "ours": agreement(ours, truth),
                    "coverage": _coverage(ours, err, truth),
                    "stated_error_cm": _stated_error(ours, err, truth),
                    **{name: agreement(values, truth) for name, values in peers.items()},
                    "difference": {
                        name: paired_bootstrap(ours, values, truth) for name, values in peers.items()
                    },
                }
            rows.append(row)
            print(_field_line(row), flush=True)
    return rows


def straw_photo(path, out):
    """Write `path`'s orthophoto to `out` with every pixel's chroma made straw (R : G : B = 1 : 0.85 :
    0.55 at the brightness of its brighter red or green band): plants and soil alike, as a senescent
    canopy over dry soil; the colour then tells nothing, the brightness (shade) still does."""
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    photo = read_orthophoto(path)
    level = np.maximum(photo.data[..., 0], photo.data[..., 1]).astype(np.float32)
    return _write_photo(out, np.stack([level, 0.85 * level, 0.55 * level], axis=-1), photo)


def golden_photo(path, out):
    """Write `path`'s orthophoto to `out` with its plants (the independent ExG/Otsu mask of the
    photo) turned golden (R : G : B = 1 : 0.8 : 0.4 at the brightness of their brightest band) and
    its soil as it is: a senescent canopy over its soil, which the photo's own threshold calls soil
    for the most part while a few pixels keep some green."""
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    photo = read_orthophoto(path)
    plants = reference_mask(photo.data)
    level = photo.data.max(axis=-1).astype(np.float32)
    gold = np.stack([level, 0.8 * level, 0.4 * level], axis=-1)
    return _write_photo(out, np.where(plants[..., None], gold, photo.data), photo)


def _write_photo(out, rgb, photo):
    """`rgb` (clipped to 8 bits) as an RGBA GeoTIFF at `out` with `photo`'s georeference, its
    no-data as alpha."""
    import tifffile

    from cliff_terrain.io.raster.geotiff import geotiff_tags

    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    alpha = np.full(photo.shape, 255, np.uint8) if photo.valid is None else np.where(photo.valid, 255, 0)
    tifffile.imwrite(
        out,
        np.dstack([rgb, alpha.astype(np.uint8)]),
        photometric="rgb",
        extrasamples=[2],
        extratags=geotiff_tags(photo.transform, photo.crs),
    )
    return out


# The photos recoloured so that their colour does not follow the crop (field_rows' `colour`).
RECOLOURED = {"straw": straw_photo, "golden": golden_photo}


def _run_heights(folder, files, spec, ground, colour="photo", windowed=False):
    """`cliff-terrain heights` on one date: (p90, p90 err, ground check, grid transform, grid shape)."""
    from cliff_terrain.cli import main as cli
    from cliff_terrain.io.raster.geotiff import read_surface

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "heights"
        ortho = folder / files["ortho"]
        if colour in RECOLOURED:
            ortho = RECOLOURED[colour](ortho, Path(tmp) / f"{colour}.tif")
        args = ["heights", str(ortho), "--dsm", str(folder / files["dsm"])]
        args += ["--plots", str(folder / spec["plots"]), "--out", str(out), "--ground", ground]
        args += ["--windowed"] if windowed else []
        if cli(args) != 0:
            raise CliffTerrainError(f"cliff-terrain heights failed on {folder.name} {files['dsm']}")
        chm = read_surface(out / "chm.tif")
        summary = json.loads((out / "summary.json").read_text())
        with open(out / "plots.csv", newline="") as stream:
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


def _occlusion_cm(check):
    """The occlusion check's rise of the narrow openings' soil (cm), None when it was not made."""
    occlusion = check.get("occlusion") or {}
    return 100 * occlusion["rise_m"] if occlusion.get("tested") else None


def _ground_cell(row):
    """The table's ground cell: method (held-out error, evidence; the occlusion check's rise)."""
    rise = row.get("occlusion_rise_cm")
    narrow = "" if rise is None else f"; narrow openings {rise:+.1f} cm"
    return f"{row.get('ground_method')} ({_num(row.get('ground_check_error_cm'), 1)} cm, {row.get('evidence')}{narrow})"


def _coverage(ours, err, truth):
    ok = np.isfinite(ours) & np.isfinite(err) & np.isfinite(truth)
    if not ok.any():
        return None
    return float(np.mean(np.abs(ours[ok] - truth[ok]) <= Z90 * err[ok]))


def _stated_error(ours, err, truth):
    """The median stated error (cm) over the plots the coverage counts."""
    ok = np.isfinite(ours) & np.isfinite(err) & np.isfinite(truth)
    return float(100 * np.median(err[ok])) if ok.any() else None


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

    rise = row["occlusion_rise_cm"]
    narrow = "not tested" if rise is None else f"{rise:+.1f} cm"
    lines = [
        f"  {row['field']} {row['date']} [{row['half']}], {row['plots']} plots, ground {row['ground_method']} "
        f"(held-out {row['ground_check_error_cm']:.1f} cm, evidence: {row['evidence']}, narrow openings' "
        f"soil {narrow})"
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
        "iou_worst": float(min(r["iou"] for r in picked)),
        "f1_median": float(np.median([r["f1"] for r in picked])),
        "f1_worst": float(min(r["f1"] for r in picked)),
        "volume_on_plants_min": float(min(r["volume_on_plants"] for r in picked)),
        "volume_on_plants_median": float(np.median([r["volume_on_plants"] for r in picked])),
    }


# --- The validation page (docs/validation.md), written from a run's record -------------------------

# The sets this script reads, where they come from and under which licence (none is in the repository).
SOURCES = (
    (
        "`cwfid` (20 photos)",
        "carrot seedlings and weeds on dark, moist soil, nadir from a field robot (not a UAV); the colours "
        "look like a NIR-sensitive camera",
        "`cwfid/dataset`, `images/`, `masks/`",
        '"non-commercial research only", cite the paper (README; no licence file)',
        "the dataset's vegetation masks (crop and weeds are plant)",
    ),
    (
        "`segveg_literal_wheat` (24)",
        "wheat plots from a handheld nadir camera: green, yellow and ripe canopy, hard shadows, some soil",
        "`mserouar/SegVeg`, `docs/DATA/Literal_wheat_dataset/` (older commit)",
        "none stated",
        "the repository's binary masks (possibly a model's output, not verified as hand-drawn)",
    ),
    (
        "`peanut` (20 of 400)",
        "field photos of peanut with weeds on brown, dry to moist soil with residue; sun and shadows",
        "`ptdkhoa/Peanut-dataset`, `images/`, `labels/`",
        "CC BY-SA 4.0 (README); cite Tran and Phan, IEEE Access 11 (2023)",
        "the dataset's hand-labelled colour maps (crop and weeds are plant)",
    ),
    (
        "`carrotweed` (39)",
        "handheld nadir-ish photos of carrot seedlings and weeds on brown soil with clods; low sun, hard "
        "shadows, overcast",
        "`lameski/rgbweeddetection`, `Images/`, `Vegetation_Masks/`",
        '"free for non-commercial applications", cite Lameski et al., ICT Innovations 2017 (README)',
        "the dataset's hand-drawn vegetation masks (crop and weeds are plant)",
    ),
    (
        "`ews_wheat` (48 of 166)",
        "Eschikon Wheat Segmentation: 350 px patches of nadir photos of winter-wheat plots, emergence to "
        "tillering, on pale dry to dark moist soil, hard shadows",
        "`supervisely-ecosystem/EWS-Dataset-training-data`, `project/{train,validation}/`",
        "CC BY-SA 4.0, cite Zenkl et al., Front. Plant Sci. 12:774068 (2022)",
        "the dataset's hand annotations (class `Wheat`)",
    ),
    (
        "`maize_sugarbeet` (30 of 154)",
        "handheld nadir phone photos of maize rows and sugar beet seedlings with weeds, on dark moist "
        "loam with straw bits, pale dry crusted soil and light clods; overcast, and low sun with hard "
        "shadows (Austria, 2022)",
        "`Schine73/Plant-and-Weed-detection-using-UNet-CNN`, `training_images/`",
        '"hand segmented by me and my class colleagues. Feel free to use them for your own purposes." '
        "(README; no licence file)",
        "the dataset's hand-segmented class maps (maize, sugar beet and weeds are plant)",
    ),
    (
        "`weedsgalore` (26)",
        "WeedsGalore's test frames: UAV nadir RGB (of a multispectral camera) of maize with four weed "
        "species on pale, dry soil, sun and hard shadows, four dates from emergence (most frames under 2 % "
        "cover) to rows closing (Germany, 2023)",
        "`koesan/weedseg`, `WeedsGalore/yolo_dataset/{images,labels}/test/` (a copy of `GFZ/weedsgalore`'s)",
        "CC BY 4.0 (WeedsGalore's README); cite Celikkan et al., WACV 2025",
        "the dataset's dense crop and weed annotations, traced to polygons by the copy's author and filled "
        "here (small plants and holes may be lost; not verified as hand-drawn)",
    ),
    (
        "`stover_residue` (30)",
        "handheld nadir photos (0.6-0.9 m, 512 px) of corn, sorghum, soybean, sunflower and wheat among "
        "straw and stalk residue, from a few stalks to full cover; sun with hard shadows, and diffuse "
        "(Stover, Kansas State University)",
        "`soilwater/stover`, `dataset_v2/{image_data,label_data}/` (30 of the 468 frames with more than 1 % "
        "plant and 10 % residue)",
        "the repository MIT; its dataset release CC BY 4.0; cite Patrignani, Bisheh and Nahitiya, "
        "Agronomy Journal (in press)",
        "the dataset's label maps (soil, green canopy, residue; green canopy is plant), threshold-made "
        "and edited by hand by their look; senescent plants are labelled residue",
    ),
    (
        "`maize_rows_straw` (22)",
        "oblique tractor-camera frames of young maize rows (about V3-V6) on straw-covered no-till soil; "
        "overcast",
        "`WoodratTradeCo/crop-rows-detection`, `mydata/images/`",
        "GPL-3.0 (the repository's; no separate data licence)",
        "none (its labels are row boxes): independent ExG/Otsu mask",
    ),
    (
        "`uavbroccoli` (6)",
        "UAV orthomosaic tiles: pale, bluish broccoli on very dark soil",
        "`UTokyo-FieldPhenomics-Lab/UAVbroccoli`, `data/broccoli_data/images/train/` (older commit)",
        "MIT for the code; the data's is unclear",
        "none: independent ExG/Otsu mask",
    ),
    (
        "`potato_fieldimager`",
        "a potato trial flown 30, 40, 70 and 100 days after planting: orthomosaics, DSMs (6.8 cm/px), "
        "140 plot polygons; day 70 is held out and used for nothing here",
        "`filipematias23/FIELDimageR-QGIS-Workshop`",
        "none stated",
        "the date's DSM minus day 30's",
    ),
    (
        "`potato_fieldimager_d55_d90`",
        "the same potato trial flown 55 days (open rows) and 90 days (closed canopy) after planting, its "
        "140 plots and day-30 reference",
        "`phenome-force/FIELDimageR-workshop` (`DSM/3_55`, `DSM/5_90`, `MOSAIC/3_55`, `MOSAIC/5_90` only)",
        "none stated",
        "the date's DSM minus day 30's",
    ),
    (
        "`potato_fieldimager_ex1`",
        "a second potato trial (Wisconsin), vegetative, plants 0.1-0.3 m above the hills: two DSMs, no "
        "orthophoto; 126 plots made from its field map and the two-flight heights",
        "`filipematias23/FIELDimageR-QGIS` (`EX_DSM0.tif`, `EX_DSM1.tif`, `fieldMap.csv`)",
        "none stated (the R package is GPL-3)",
        "DSM1 minus the bare-soil DSM0",
    ),
    (
        "`potato_fieldimager_ex2`",
        "potato breeding plots at flowering: the OpenDroneMap DSM and orthophoto in `../shared`, 588 plots",
        "`filipematias23/FIELDimageR-Workshop-10` (EX2 files only)",
        "GPL-2.0 (DSM, orthophoto); none stated (plots)",
        "none: the ground check only",
    ),
    (
        "`soybean_pliman`",
        "soybean plots in the vegetative stage (rows open, about 40 % cover), 2.2 cm DSM, DTM and "
        "orthophoto, 15 plots of 3.7 m x 0.8 m: the R package pliman's example (data by Arthur Bernardeli)",
        "`cran/pliman` (`inst/tmp_images/soy_*`; the CRAN mirror of `TiagoOlivoto/pliman`, whose snapshot "
        "is too large to fetch)",
        "GPL (>= 3), the package's; the data credited as personal data of its provider",
        "the DSM minus the package's DTM, which was made from the same DSM's soil (not a second flight; it "
        "lies 4.5 cm below the soil our ground rests on, median over the pixels it calls soil)",
    ),
)
DOCS_BEGIN = "<!-- written by bench/validate_real.py --docs from its record; not edited by hand -->"
WEAK_IOU = 0.5  # an image whose mask agrees less than this with its reference is listed as a loss
# The references of a field, by their record key.
KINDS = {"aligned": "aligned two-flight difference", "raw": "raw two-flight difference", "ruler": "ruler"}


def _kind(row, kind):
    """What a row's reference `kind` is called: a field whose reference is not a second flight (a
    terrain model) names it in its field.json's ``reference_label``."""
    label = row.get("reference_label")
    if label and kind in ("aligned", "raw"):
        return f"{label}, aligned" if kind == "aligned" else label
    return KINDS.get(kind, kind)


# The share of plots |error| <= 1.645 x height_p90_err_m should cover (issue 38).
COVERAGE_GOAL = (0.85, 0.95)


def _cells(row):
    return "| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |"


def _table(header, rows):
    return "\n".join([_cells(header), "|" + "---|" * len(header), *(_cells(r) for r in rows)])


def _pct(value):
    return "-" if value is None else f"{100 * value:.1f} %"


def _coverage_cell(figures):
    """Coverage, and the median stated error when the record holds it."""
    stated = figures.get("stated_error_cm")
    return _pct(figures.get("coverage")) + ("" if stated is None else f" (±{stated:.1f} cm)")


def _num(value, digits=3):
    return "-" if value is None else f"{value:.{digits}f}"


def _fit(a):
    if not a or a.get("r") is None:
        return "-"
    return f"{a['r']:.3f} / {a['rmse_cm']:.1f} cm / {a['bias_cm']:+.1f} cm".replace("-", "−")


def _difference(ci):
    if not ci:
        return "-"
    (r_lo, r_hi), (m_lo, m_hi) = ci["r"], ci["rmse_cm"]
    return f"[{r_lo:+.3f}, {r_hi:+.3f}], [{m_lo:+.1f}, {m_hi:+.1f}] cm".replace("-", "−")


def _verdict(ci, key):
    """', a loss: ours minus theirs in [lo, hi]' or ', a tie ...' from :func:`paired_bootstrap`."""
    if not ci:
        return ""
    lo, hi = ci[key]
    unit = " cm" if key == "rmse_cm" else ""
    digits = 1 if key == "rmse_cm" else 3
    tie = lo <= 0 <= hi
    what = "a tie" if tie else "a loss"
    return f", {what}: ours minus theirs in [{lo:+.{digits}f}, {hi:+.{digits}f}]{unit} (95 % paired bootstrap)".replace(
        "-", "−"
    )


def _losses(fields, images, summary):
    """Where we lose, found in the record: a peer's better r or RMSE, weak images and sets."""
    lines = []
    names = {"baseline": "the naive baseline", "plantcv": "plantcv-geospatial's p90 - p25"}
    for row in fields:
        for kind, figures in row.get("against", {}).items():
            ours = figures.get("ours") or {}
            if ours.get("r") is None:
                continue
            where = f"{row['field']} {row['date']} against the {_kind(row, kind)}"
            for peer, name in names.items():
                theirs = figures.get(peer) or {}
                if theirs.get("r") is None:
                    continue
                ci = (figures.get("difference") or {}).get(peer)
                if theirs["r"] > ours["r"]:
                    lines.append(
                        f"{where}: {name}'s r is higher ({theirs['r']:.3f} against {ours['r']:.3f}){_verdict(ci, 'r')}."
                    )
                if theirs["rmse_cm"] < ours["rmse_cm"]:
                    lines.append(
                        f"{where}: {name}'s RMSE is lower ({theirs['rmse_cm']:.1f} cm against "
                        f"{ours['rmse_cm']:.1f} cm){_verdict(ci, 'rmse_cm')}."
                    )
            cover = figures.get("coverage")
            if cover is not None and not COVERAGE_GOAL[0] <= cover <= COVERAGE_GOAL[1]:
                lines.append(
                    f"{where}: the uncertainty covers {_pct(cover)} of the plots (goal "
                    f"{_pct(COVERAGE_GOAL[0])}-{_pct(COVERAGE_GOAL[1])})."
                )
    for row in images:
        if row["iou"] < WEAK_IOU:
            lines.append(
                f"{row['set']}/{row['image']} ({row['half']}): IoU {row['iou']:.3f} against {row['reference']}."
            )
    for key, value in summary.items():
        if value and value["volume_on_plants_min"] < 0.6:
            lines.append(
                f"{key}: the worst image's relief stands only {_pct(value['volume_on_plants_min'])} on the "
                "reference's plants."
            )
    return lines


def docs_page(record):
    """The validation page (Markdown) for a record of :func:`main`: sources, every set, field and date."""
    images, fields, summary = record.get("images", []), record.get("fields", []), record.get("summary", {})
    parts = [
        "# Validation on real fields",
        DOCS_BEGIN,
        "The figures users trust must hold on fields the code was not tuned on. `bench/validate_real.py "
        "DATA_DIR` fetches nothing: it reads photos with annotated masks, photos without (against an "
        "independent ExG/Otsu mask) and fields flown on several dates, and reports, per image, the relief "
        "mask's IoU and F1 against the reference and the share of the relief's volume standing on the "
        "reference's plants; per field and date, r, RMSE and bias of `cliff-terrain heights`' per-plot p90 "
        "against the two-flight difference, with the naive peer (2nd percentile of the DSM in 5 m blocks) "
        "in the same run. Its docstring gives the folder layout; `bench/layout_masks.py DATA_DIR` and "
        "`bench/layout_fields.py DATA_DIR` lay the photos and the fields out from the public "
        "repositories' pinned commits (fetched as bare git directories). "
        "None of this data is in the repository: "
        "the licences below do not allow it, or are unclear. This page is written from the run's record "
        "(`python bench/validate_real.py DATA_DIR --json record.json --docs docs/validation.md`).",
    ]
    if record.get("provenance"):
        history = (
            " What each re-run changed: [Record history](#record-history)." if record.get("history") else ""
        )
        parts.append(f"*This record:* {record['provenance']}{history}")
    parts += [
        "## Sources and licences",
        _table(("set", "what", "source (public GitHub repository)", "licence", "reference"), SOURCES),
        "## Plants and soil: masks against references",
        "Each image set is split by sorted order (even: tune, odd: holdout); thresholds were chosen on "
        "the tune halves only.",
    ]
    rows = [
        (
            key.split("/")[0],
            key.split("/")[1],
            value["images"],
            _num(value["iou_median"]),
            _num(value["f1_median"]),
            f"{_pct(value['volume_on_plants_min'])} / {_pct(value['volume_on_plants_median'])}",
        )
        for key, value in sorted(summary.items())
        if value
    ]
    header = (
        "set",
        "half",
        "images",
        "IoU (median)",
        "F1 (median)",
        "volume on the reference's plants (min / median)",
    )
    parts.append(_table(header, rows) if rows else "No image set in this record.")
    if images:
        parts.append("Every image:")
        header = ("set", "image", "half", "reference", "IoU", "F1", "volume on plants", "threshold (source)")
        parts.append(
            _table(
                header,
                [
                    (
                        r["set"],
                        r["image"],
                        r["half"],
                        r["reference"],
                        _num(r["iou"]),
                        _num(r["f1"]),
                        _pct(r["volume_on_plants"]),
                        f"{r['threshold']:.3f} ({r['threshold_source']})",
                    )
                    for r in images
                ],
            )
        )
    parts += [
        "## Ground and canopy height: one flight against two, and against a ruler",
        "Per-plot p90 canopy height from one flight (`cliff-terrain heights` on the date's orthophoto and "
        "DSM; on a surface model alone, its ground from the surface) against each reference the field "
        "has: the p90 of the date's DSM minus the early-season DSM, *aligned* on stable ground first "
        "(photogrammetry without ground control tilts one flight against another; a robust quadratic "
        "surface fitted to the difference at least 0.5 m outside every plot, plants rejected as "
        "outliers, is removed) and raw, and a breeder's ruler. The naive baseline (the DSM's 2nd "
        "percentile in 5 m blocks, bilinear) and plantcv-geospatial's `height_percentile` (each plot's "
        "DSM p90 minus its p25) run on the same grid in the same run. Each cell is r / RMSE / bias; "
        "coverage is the share of plots with |error| <= 1.645 x `height_p90_err_m` (in brackets that error's "
        "median over the plots); the last column is "
        "ours minus the baseline in r and in RMSE with their 95 % intervals from a paired bootstrap over "
        "the plots (both scored on the same resampled plots): an interval that holds 0 is a tie.",
    ]
    header = (
        "field",
        "crop, stage",
        "date",
        "plots",
        "ground (held-out error)",
        "against",
        "ours",
        "naive baseline",
        "plantcv p90 - p25",
        "coverage",
        "ours − baseline: r, RMSE (95 %)",
    )
    rows = [
        (
            r["field"],
            f"{r.get('crop', '')}, {r.get('stage', '')}".strip(", "),
            r["date"],
            r["plots"],
            _ground_cell(r),
            _kind(r, kind),
            _fit(figures.get("ours")),
            _fit(figures.get("baseline")),
            _fit(figures.get("plantcv")),
            _coverage_cell(figures),
            _difference((figures.get("difference") or {}).get("baseline")),
        )
        for r in fields
        for kind, figures in r.get("against", {}).items()
    ]
    parts.append(_table(header, rows) if rows else "No field in this record.")
    recoloured = {colour: record.get(f"fields_{colour}") or [] for colour in RECOLOURED}
    if any(recoloured.values()):
        parts += [
            "### When the colour does not follow the crop",
            "The same dates, each orthophoto recoloured first: *straw* (every pixel's chroma made R : G : B "
            "= 1 : 0.85 : 0.55, its brightness kept: plants and soil alike; `straw_photo`) and *golden* (the "
            "plants of the photo's independent ExG/Otsu mask made R : G : B = 1 : 0.8 : 0.4, the soil as it "
            "is: a senescent canopy over its soil; `golden_photo`, both in `bench/validate_real.py`). The "
            "colour then does not tell the crop: the ground must come from the surface, and the heights "
            "still hold against the same references. The hidden wheat trial at maturity failed this way "
            "(its photo called the canopy soil). Against the aligned two-flight difference:",
        ]
        header = ("field", "date", "photo", "ground (held-out error)", "why the surface decided", "ours",
                  "naive baseline", "ours − baseline: r, RMSE (95 %)")  # fmt: skip
        rows = [
            (
                r["field"],
                r["date"],
                colour,
                _ground_cell(r),
                r.get("colour_contradicted") or "- (the colour was taken)",
                _fit(figures.get("ours")),
                _fit(figures.get("baseline")),
                _difference((figures.get("difference") or {}).get("baseline")),
            )
            for colour, dated in recoloured.items()
            for r in dated
            for kind, figures in r.get("against", {}).items()
            if kind == "aligned"
        ]
        parts.append(_table(header, rows))
    losses = _losses(fields, images, summary)
    for colour, dated in recoloured.items():
        losses += _losses([{**r, "date": f"{r['date']} ({colour} photo)"} for r in dated], [], {})
    parts.append("## Where we lose")
    parts.append("\n".join(f"- {line}" for line in losses) if losses else "Nowhere in this record.")
    if record.get("notes"):
        parts.append("## Notes on this run")
        parts.append("\n".join(f"- {note}" for note in record["notes"]))
    if record.get("history"):
        # The record's re-runs, oldest first: what each changed, so that the page's top stays short.
        parts.append("## Record history")
        parts.append("\n".join(f"- {entry}" for entry in record["history"]))
    return "\n\n".join(parts) + "\n"


def write_docs(record, path):
    """Write :func:`docs_page` of `record` to `path` (the docs' validation page)."""
    Path(path).write_text(docs_page(record))
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data_dir", type=Path, nargs="?", help="the data (not needed with --record)")
    parser.add_argument("--max-size", type=int, default=1000)
    parser.add_argument("--json", type=Path, default=None, help="write every figure here")
    parser.add_argument("--skip-images", action="store_true")
    parser.add_argument("--skip-fields", action="store_true")
    parser.add_argument("--ground", default="auto", help="the heights' --ground (default auto)")
    parser.add_argument(
        "--windowed", action="store_true", help="the fields' heights by the windowed path (--windowed)"
    )
    parser.add_argument("--docs", type=Path, default=None, help="write the validation page here")
    parser.add_argument(
        "--record", type=Path, default=None, help="a --json record to write --docs from, instead of a run"
    )
    args = parser.parse_args(argv)
    if args.record is not None:
        record = json.loads(args.record.read_text())
        if args.docs:
            write_docs(record, args.docs)
        return record
    if args.data_dir is None:
        parser.error("DATA_DIR is needed (or --record)")
    if not args.data_dir.is_dir():
        parser.error(f"DATA_DIR {str(args.data_dir)!r} is not a folder")
    warnings.filterwarnings("ignore", message=".*GDAL_NODATA.*")
    images = [] if args.skip_images else image_rows(args.data_dir, args.max_size)
    fields = [] if args.skip_fields else field_rows(args.data_dir, ground=args.ground, windowed=args.windowed)
    record = {"images": images, "fields": fields, "summary": {}}
    for colour in RECOLOURED:
        rows = (
            []
            if args.skip_fields
            else field_rows(args.data_dir, ground=args.ground, colour=colour, windowed=args.windowed)
        )
        record[f"fields_{colour}"] = rows
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
    if args.docs:
        write_docs(record, args.docs)
    return record


if __name__ == "__main__":
    main()
