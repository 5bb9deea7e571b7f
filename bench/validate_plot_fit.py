"""Plot-grid fit against breeders' own plot polygons: ``python bench/validate_plot_fit.py [DATA_DIR]``.

For every trial and date it starts from the breeders' grid's four outer corners, each moved by a
random distance of up to 0.25 m in a random direction (seeds 0-4), and compares three grids with
the breeders' polygons: the corners alone (unfitted), the fit as it was (``fit_grid`` with the
corners as a rough placement, no tolerance) and the fit with the corners as constraints (the
``plots --corners --fit`` default: tolerance half the plot's smaller side). Per grid:

- matched: breeders' plots matched one-to-one (Hungarian assignment on the centres) within half the
  smaller pitch, worst seed;
- IoU: mean over the breeders' plots of the IoU with the matched plot (0 when unmatched), mean of
  the seeds and worst seed;
- plants in: the share of the plant pixels inside the plots, mean of the seeds, against the
  breeders' own polygons (``breeder``);
- confidence and accepted: the fit's grid confidence (mean) and how many seeds it accepted.

Trials: the shared Lamberton soybean trial (7 dates, 5 x 8 plots standing apart, its
``plots.geojson``), the shared OpenDroneMap orthophoto with the hand-drawn reference in
``tests/data`` (4 x 9 blocks), and, when DATA_DIR holds it, the FIELDimageR potato trial
(``potato_fieldimager``: 14 x 10 touching single-row plots, the breeder's ``Data_Total.shp``, days 30,
40 and 100; day 70 is held out and never read).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from cliff_terrain.io.raster.geotiff import read_orthophoto  # noqa: E402
from cliff_terrain.io.vector.plot_polygons import read_plots  # noqa: E402
from cliff_terrain.measure.canopy import plant_mask  # noqa: E402
from cliff_terrain.measure.field_plots import rasterize_plots  # noqa: E402
from cliff_terrain.measure.fit_flags import fitted_plots  # noqa: E402
from cliff_terrain.measure.plot_fit import fit_grid  # noqa: E402
from cliff_terrain.measure.plot_grid import place_grid, plots_from  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
SEEDS = range(5)
OFF = 0.25  # metres: how far each corner is moved


def trials(data_dir):
    """(name, date, orthophoto path, reference PlotSet path, (columns, rows), plot size (w, l))."""
    lamberton = SHARED / "uav" / "lamberton_soybean"
    for tif in sorted(lamberton.glob("*_Lamberton_clipped.tif")):
        yield "lamberton soybean", tif.name[:8], tif, lamberton / "plots.geojson", (5, 8), (1.592, 5.2725)
    odm = SHARED / "dsm" / "fieldimager_ex2" / "odm_orthophoto.tif"
    if odm.is_file():
        yield (
            "ODM blocks (hand-drawn)",
            "-",
            odm,
            REPO / "tests" / "data" / "odm_plots_by_hand.geojson",
            (4, 9),
            (14.2, 4.8),
        )
    potato = Path(data_dir) / "potato_fieldimager" if data_dir else None
    if potato is not None and (potato / "Data_Total.shp").is_file():
        for day in ("1_30", "2_40", "4_100"):  # never 3_70: held out
            tif = potato / "MOSAIC" / f"{day}_RGB.tif"
            if tif.is_file():
                yield (
                    "potato single rows",
                    "day " + day.split("_")[1],
                    tif,
                    potato / "Data_Total.shp",
                    (14, 10),
                    (0.83, 6.0),
                )


def centres(plots):
    return np.array([rings[0][:4].mean(axis=0) for rings in plots.polygons])


def outer_corners(plots, width):
    """The rectangle around all the plots along their own axes, u along the side nearest `width`."""
    quads = np.array([rings[0][:4] for rings in plots.polygons])
    a, b = quads[0][1] - quads[0][0], quads[0][2] - quads[0][1]
    u = a if abs(np.hypot(*a) - width) < abs(np.hypot(*b) - width) else b
    u = u / np.hypot(*u)
    v = np.array([-u[1], u[0]])
    pu, pv = quads.reshape(-1, 2) @ u, quads.reshape(-1, 2) @ v
    return np.array(
        [
            p * u + q * v
            for p, q in (
                (pu.min(), pv.min()),
                (pu.max(), pv.min()),
                (pu.max(), pv.max()),
                (pu.min(), pv.max()),
            )
        ]
    )


def small_pitch(plots):
    xy = centres(plots)
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def compare(plots, reference, ref_labels, ortho, plants, pitch):
    """(matched within half a pitch, mean IoU, share of plant pixels inside the plots)."""
    d = np.hypot(*(centres(reference)[:, None] - centres(plots)[None]).transpose(2, 0, 1))
    rows, cols = linear_sum_assignment(d)
    good = d[rows, cols] < 0.5 * pitch
    labels = rasterize_plots(plots, transform=ortho.transform, shape=ortho.shape)
    n_ref, n_our = len(reference) + 1, len(plots) + 1
    joint = np.bincount(
        (ref_labels.astype(np.int64) * n_our + labels).ravel(), minlength=n_ref * n_our
    ).reshape(n_ref, n_our)
    area_ref, area_our = joint.sum(axis=1), joint.sum(axis=0)
    ious = np.zeros(len(reference))
    for r, c, ok in zip(rows, cols, good, strict=True):
        if ok:
            inter = joint[r + 1, c + 1]
            ious[r] = inter / (area_ref[r + 1] + area_our[c + 1] - inter)
    share = (plants & (labels > 0)).sum() / plants.sum()
    return int(good.sum()), float(ious.mean()), float(share)


def run(data_dir, only=None):
    header = (
        "| trial | date | plots | grid | matched (worst seed) | mean IoU (mean / worst) | plants in: ours / breeder | confidence | accepted |\n"
        "|---|---|---|---|---|---|---|---|---|"
    )
    print(header)
    for name, date, tif, ref_path, (columns, rows), size in trials(data_dir):
        if only and only not in name:
            continue
        ortho = read_orthophoto(tif)
        plants = plant_mask(ortho.data, valid=ortho.valid)
        if plants.sum() < 100:
            print(
                f"| {name} | {date} | - | the plant mask finds {plants.sum()} plant pixels: no fit | | | | | |"
            )
            continue
        reference = read_plots(ref_path)
        ref_labels = rasterize_plots(reference, transform=ortho.transform, shape=ortho.shape)
        ref_share = (plants & (ref_labels > 0)).sum() / plants.sum()
        pitch = small_pitch(reference)
        truth = outer_corners(reference, size[0])
        results = {"corners only": [], "fit (rough placement)": [], "fit (corners as constraints)": []}
        for seed in SEEDS:
            rng = np.random.default_rng(seed)
            angle, radius = rng.uniform(0, 2 * np.pi, 4), OFF * np.sqrt(rng.uniform(0, 1, 4))
            corners = truth + radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
            layout, placement = place_grid(columns, rows, plot_size=size, corners=corners)
            results["corners only"].append(
                (
                    *compare(plots_from(layout, placement), reference, ref_labels, ortho, plants, pitch),
                    None,
                    None,
                )
            )
            old = fit_grid(plants, ortho.transform, layout, placement=placement, valid=ortho.valid)
            results["fit (rough placement)"].append(
                (
                    *compare(
                        plots_from(old.layout, old.placement), reference, ref_labels, ortho, plants, pitch
                    ),
                    old.report["confidence"],
                    None,
                )
            )
            new = fit_grid(
                plants,
                ortho.transform,
                layout,
                placement=placement,
                valid=ortho.valid,
                tolerance=0.5 * min(size),
            )
            results["fit (corners as constraints)"].append(
                (
                    *compare(
                        fitted_plots(layout, placement, new), reference, ref_labels, ortho, plants, pitch
                    ),
                    new.report["confidence"],
                    new.report["accepted"],
                )
            )
        for grid, rows_ in results.items():
            matched = min(r[0] for r in rows_)
            ious = [r[1] for r in rows_]
            share = np.mean([r[2] for r in rows_])
            conf = "-" if rows_[0][3] is None else f"{np.mean([r[3] for r in rows_]):.2f}"
            acc = "-" if rows_[0][4] is None else f"{sum(r[4] for r in rows_)}/{len(rows_)}"
            print(
                f"| {name} | {date} | {len(reference)} | {grid} | {matched}/{len(reference)} | {np.mean(ious):.3f} / {min(ious):.3f} "
                f"| {share:.3f} / {ref_share:.3f} | {conf} | {acc} |",
                flush=True,
            )


if __name__ == "__main__":
    run(sys.argv[1] if len(sys.argv) > 1 else None, sys.argv[2] if len(sys.argv) > 2 else None)
