"""Fields cut the way users cut them: per-plot heights of a window of a field against the whole field's.

    python bench/bench_cuts.py DATA_DIR [--json OUT.json]

Users rarely measure a whole flight: they cut a trial block, a strip along the field's edge, the
plots' bounding box. The ground must hold there too, where less of the field's soil is in view.
For every date of every field in ``DATA_DIR/fields`` (the layout of ``bench/validate_real.py``),
this cuts ten windows of the date's orthophoto (or, for a surface model without one, of the
DSM): a strip along each edge, reaching from the raster's border a quarter of the plots' extent
into the plots (so with the headland beside them); the plots' bounding box; the raster's four
quarters, split at the plots' middle (an orthomosaic tiled in four, each tile with its corner's
headland); and the plots' centre, the middle half of their box across each direction (a trial
block with no headland). A window that holds no plot whole is skipped. On each window it
runs what a user would (``cliff-terrain heights ORTHO --dsm DSM --plots PLOTS``; on a surface model
alone, its ground from the surface as ``validate_real`` does) and compares the per-plot p90 of
the plots whole in the window with the whole field's aligned two-flight difference (the
reference of ``validate_real``: made once, on the whole field). The naive baseline (the DSM's
2nd percentile in 5 m blocks) runs on the same window. Reported per cut: plots, ours and the
baseline (bias and RMSE, cm), the median stated error (``height_p90_err_m``) and its coverage
(the share of plots with |error| <= 1.645 x that error), the ground's method, evidence and
held-out error, and the occlusion check's rise.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from cliff_terrain.measure.ruler import Z90  # noqa: E402

# How far each edge strip reaches into the plots: this share of the plots' extent across it.
STRIP_SHARE = 0.25


def cut_windows(labels, shape):
    """``{name: (r0, r1, c0, c1)}``: the four edge strips with their headland, the plots' box, the
    raster's four quarters (split at the plots' middle) and the plots' centre (the middle half of
    the plots' box across each direction)."""
    rows, cols = np.nonzero(labels > 0)
    top, bottom, left, right = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    dr, dc = int(STRIP_SHARE * (bottom - top)), int(STRIP_SHARE * (right - left))
    mid_r, mid_c = (top + bottom) // 2, (left + right) // 2
    return {
        "west strip": (0, shape[0], 0, left + dc),
        "east strip": (0, shape[0], right - dc, shape[1]),
        "north strip": (0, top + dr, 0, shape[1]),
        "south strip": (bottom - dr, shape[0], 0, shape[1]),
        "plots' box": (top, bottom, left, right),
        # An orthomosaic tiled in four, each tile with its corner's headland.
        "north-west quarter": (0, mid_r, 0, mid_c),
        "north-east quarter": (0, mid_r, mid_c, shape[1]),
        "south-west quarter": (mid_r, shape[0], 0, mid_c),
        "south-east quarter": (mid_r, shape[0], mid_c, shape[1]),
        # A trial block inside the field: no headland at all.
        "plots' centre": (top + dr, bottom - dr, left + dc, right - dc),
    }


def _ours_on_photo(folder, spec, files, window, photo, tmp):
    """``heights`` on the orthophoto cut to `window`: (p90, err, ground check)."""
    from cliff_terrain.io.raster.geotiff import write_geotiff

    r0, r1, c0, c1 = window
    transform = np.array(photo.transform, float)
    transform[:2, 2] = (transform @ np.array([c0, r0, 1.0]))[:2]
    cut = Path(tmp) / "cut.tif"
    write_geotiff(cut, photo.data[r0:r1, c0:c1], transform=transform, crs=photo.crs)
    out = Path(tmp) / "out"
    args = [str(cut), "--dsm", str(folder / files["dsm"]), "--plots", str(folder / spec["plots"])]
    run = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", "heights", *args, "--out", str(out), "--no-progress"],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    if run.returncode:
        return None, None, {"refused": run.stderr.strip().splitlines()[-1] if run.stderr.strip() else "?"}
    with open(out / "plots.csv", newline="") as stream:
        table = list(csv.DictReader(stream))
    ours = np.array([float(row["height_p90_m"] or "nan") for row in table])
    err = np.array([float(row["height_p90_err_m"] or "nan") for row in table])
    return ours, err, json.loads((out / "summary.json").read_text())["ground_check"]


def _ours_on_surface(dsm, labels, n, pixel):
    """The ground from the cut surface alone (as ``validate_real`` does): (p90, err, check)."""
    from validate_real import _plot_rms, plot_p90

    from cliff_terrain.errors import GroundError
    from cliff_terrain.measure.ground import canopy_height, fit_ground

    try:
        fit = fit_ground(dsm, pixel_size=pixel)
    except GroundError as exc:
        return None, None, {"refused": str(exc)}
    ours = plot_p90(labels, n, canopy_height(dsm, fit.ground))
    return ours, _plot_rms(labels, n, fit.sigma, np.isfinite(dsm)), fit.check


def _figures(ours, err, base, truth, whole):
    """Ours and the baseline on the same plots: whole in the cut, with a reference and both heights."""
    ok = whole & np.isfinite(truth) & np.isfinite(base)
    if ours is not None:
        ok &= np.isfinite(ours) & np.isfinite(err)
    out = {"plots": int(ok.sum())}
    e = base[ok] - truth[ok]
    out["baseline_bias_cm"], out["baseline_rmse_cm"] = 100 * e.mean(), 100 * np.sqrt(np.mean(e**2))
    if ours is not None:
        e = ours[ok] - truth[ok]
        out["ours_bias_cm"], out["ours_rmse_cm"] = 100 * e.mean(), 100 * np.sqrt(np.mean(e**2))
        out["err_median_cm"] = 100 * float(np.median(err[ok]))
        out["coverage"] = float(np.mean(np.abs(e) <= Z90 * err[ok]))
    return out


def field_cuts(data_dir):
    """Every cut of every date: a list of records (see the module)."""
    from validate_real import aligned_difference, plot_p90

    from cliff_terrain.io.raster.geotiff import read_orthophoto, read_surface, resample
    from cliff_terrain.io.vector.plot_polygons import read_plots
    from cliff_terrain.measure.field_plots import rasterize_plots
    from cliff_terrain.measure.ground import canopy_height, naive_block_ground

    records = []
    for spec_path in sorted((data_dir / "fields").glob("*/field.json")):
        folder = spec_path.parent
        spec = json.loads(spec_path.read_text())
        if not spec.get("reference"):
            continue
        plots = read_plots(folder / spec["plots"])
        n = len(plots.polygons)
        for date, files in spec["dates"].items():
            photo = read_orthophoto(folder / files["ortho"]) if files.get("ortho") else None
            surface = read_surface(folder / files["dsm"])
            grid = photo if photo is not None else surface
            transform, shape = grid.transform, grid.data.shape[:2]
            pixel = float(np.hypot(*np.asarray(transform)[:2, 0]))
            dsm = resample(surface, transform=transform, shape=shape)
            early = resample(read_surface(folder / spec["reference"]), transform=transform, shape=shape)
            labels = rasterize_plots(plots, transform=transform, shape=shape)
            difference = dsm - early
            truth = plot_p90(labels, n, np.maximum(aligned_difference(difference, labels, pixel), 0))
            sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
            for name, (r0, r1, c0, c1) in cut_windows(labels, shape).items():
                part, cut_dsm = labels[r0:r1, c0:c1], dsm[r0:r1, c0:c1]
                whole = (np.bincount(part.ravel(), minlength=n + 1)[1:] == sizes) & (sizes > 0)
                if not whole.any():
                    continue  # a strip that holds no plot whole (a frame of a few large plots)
                with tempfile.TemporaryDirectory() as tmp:
                    if photo is not None:
                        ours, err, check = _ours_on_photo(folder, spec, files, (r0, r1, c0, c1), photo, tmp)
                    else:
                        ours, err, check = _ours_on_surface(cut_dsm, part, n, pixel)
                base = plot_p90(
                    part,
                    n,
                    canopy_height(cut_dsm, naive_block_ground(cut_dsm, pixel_size=pixel, percentile=2.0)),
                )
                record = {"field": folder.name, "date": date, "cut": name, "size_m": [
                    round((r1 - r0) * pixel, 1), round((c1 - c0) * pixel, 1)]}  # fmt: skip
                record.update(_figures(ours, err, base, truth, whole))
                record.update(_ground(check))
                records.append(record)
                print(cut_line(record), flush=True)
    return records


def _ground(check):
    if "refused" in check:
        return {"refused": check["refused"]}
    occlusion = check.get("occlusion") or {}
    return {
        "ground": check.get("method"),
        "evidence": (check.get("evidence") or {}).get("source"),
        "held_out_cm": 100 * check["candidates"][check["method"]]["error_m"],
        "narrow_rise_cm": 100 * occlusion["rise_m"] if occlusion.get("tested") else None,
        "occlusion_passed": occlusion.get("passed"),
    }


def cut_line(r):
    """One markdown table row of a record."""
    size = f"{r['size_m'][0]:g} x {r['size_m'][1]:g} m"
    base = f"{r['baseline_bias_cm']:+.1f} / {r['baseline_rmse_cm']:.1f}"
    if "refused" in r:
        return f"| {r['field']} | {r['date']} | {r['cut']} | {size} | {r['plots']} | refused | {base} | - | - | - |"
    rise = "-" if r["narrow_rise_cm"] is None else f"{r['narrow_rise_cm']:+.1f}"
    ours = f"{r['ours_bias_cm']:+.1f} / {r['ours_rmse_cm']:.1f}"
    ground = f"{r['ground']} ({r['held_out_cm']:.1f} cm, {r['evidence']})"
    return (
        f"| {r['field']} | {r['date']} | {r['cut']} | {size} | {r['plots']} | {ours} | {base} | "
        f"{r['err_median_cm']:.1f} cm, {100 * r['coverage']:.0f} % | {ground} | {rise} |"
    )


HEADER = (
    "| field | date | cut | size | plots | ours: bias / RMSE (cm) | baseline: bias / RMSE (cm) | "
    "stated error (median), coverage | ground (held-out error, evidence) | narrow openings' rise (cm) |\n"
    "|---|---|---|---|---|---|---|---|---|---|"
)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--json", type=Path, help="write the records here")
    args = parser.parse_args(argv)
    if not (args.data_dir / "fields").is_dir():
        parser.exit(
            2, f"bench_cuts.py: {args.data_dir / 'fields'} is not a folder (see bench/validate_real.py)\n"
        )
    print(HEADER, flush=True)
    records = field_cuts(args.data_dir)
    measured = [r for r in records if "refused" not in r]
    losses = [r for r in measured if r["ours_rmse_cm"] > r["baseline_rmse_cm"]]
    wrong = [r for r in measured if r["coverage"] < 0.5]
    print(
        f"{len(records)} cuts, {len(records) - len(measured)} refused; ours' RMSE above the baseline's in "
        f"{len(losses)}; the stated error covers under half the plots in {len(wrong)}: "
        + ", ".join(f"{r['field']} {r['date']} {r['cut']}" for r in wrong)
    )
    if args.json:
        args.json.write_text(json.dumps(records, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
