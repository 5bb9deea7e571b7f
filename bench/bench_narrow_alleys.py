"""Benchmark: a mature cereal trial whose gaps and alleys the surface model fills (issue 38), ours
against the naive baseline and a ruler.

No public field here has a mature cereal canopy with a surface model and a ruler, so this one is
synthetic, laid out like a breeding trial: 220 plots 1.5 m wide in 11 ranges of 20, a golden
canopy 0.55-0.95 m tall (uniform at random; the ruler reads each plot's top) whose edges lean to
60 % of it over 0.2 m and whose heads stand up to a few cm below the top, on a tilted, undulating
field with 2 m of open soil around the trial. The surface model is that surface smoothed by a
Gaussian of ``sfm_sigma`` and lifted halfway to its 15 cm dilation (a stand-in for dense matching,
which fills openings narrower than what surrounds them is tall; not a photogrammetric simulation),
with 1 cm noise. Two layouts:

* ``open``: 0.3 m gaps, 1 m alleys, 5 m plots, ``sfm_sigma`` 0.1 m: the alleys are seen.
* ``narrow``: 0.2 m gaps, 0.5 m alleys, 8 m plots, ``sfm_sigma`` 0.2 m, straw-coloured soil: the
  gaps and alleys are filled 13-43 cm up.

For each: ``cliff-terrain heights --ruler`` (r, RMSE, bias of ``height_p90_m`` against the ruler,
the uncertainty's coverage, the occlusion check), and the naive baseline's p90 (the DSM's 2nd
percentile in 5 m blocks, as in ``bench_scale.py``) in the same run.

    python bench/bench_narrow_alleys.py [--folder DIR] [--gsd 0.03] [--layouts open narrow]
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

LAYOUTS = {
    "open": {"gap": 0.3, "alley": 1.0, "plot_l": 5.0, "sfm_sigma": 0.10, "soil": (135, 115, 92)},
    "narrow": {"gap": 0.2, "alley": 0.5, "plot_l": 8.0, "sfm_sigma": 0.20, "soil": (150, 130, 105)},
}
GSD = 0.03
TIE = (500000.0, 4000000.0)
CRS = 32616


def make_trial(
    folder, *, gap, alley, plot_l, sfm_sigma, soil, seed=0, plot_w=1.5, n_cols=20, n_ranges=11, gsd=GSD
):
    """Write ortho.tif, dsm.tif, plots.geojson and ruler.csv into `folder`; return the plot count."""
    import cv2

    from cliff_terrain.io.raster.geotiff import write_geotiff

    rng = np.random.default_rng(seed)
    margin = 2.0
    width = 2 * margin + n_cols * plot_w + (n_cols - 1) * gap
    length = 2 * margin + n_ranges * plot_l + (n_ranges - 1) * alley
    rows, cols = int(length / gsd), int(width / gsd)
    y, x = np.mgrid[:rows, :cols].astype(np.float32) * gsd
    ground = 100 + 0.01 * x + 0.02 * y + 0.05 * np.sin(2 * np.pi * x / 23) * np.cos(2 * np.pi * y / 31)
    surface = ground.copy()
    canopy = np.zeros((rows, cols), bool)
    heights = rng.uniform(0.55, 0.95, (n_ranges, n_cols))
    features, ruler = [], []
    for i in range(n_ranges):
        for j in range(n_cols):
            x0, y0 = margin + j * (plot_w + gap), margin + i * (plot_l + alley)
            r0, r1, c0, c1 = int(y0 / gsd), int((y0 + plot_l) / gsd), int(x0 / gsd), int((x0 + plot_w) / gsd)
            yy, xx = y[r0:r1, c0:c1] - y0, x[r0:r1, c0:c1] - x0
            edge = np.minimum.reduce([xx, plot_w - xx, yy, plot_l - yy])
            lean = np.clip(0.6 + 0.4 * edge / 0.2, 0.6, 1.0)
            top = heights[i, j] * lean - np.abs(rng.normal(0, 0.03, lean.shape))
            surface[r0:r1, c0:c1] = ground[r0:r1, c0:c1] + top
            canopy[r0:r1, c0:c1] = True
            k = len(features) + 1
            x_0, x_1, y_0, y_1 = TIE[0] + x0, TIE[0] + x0 + plot_w, TIE[1] - y0, TIE[1] - y0 - plot_l
            ring = [[x_0, y_0], [x_1, y_0], [x_1, y_1], [x_0, y_1], [x_0, y_0]]
            features.append(
                {
                    "type": "Feature",
                    "properties": {"plot": k},
                    "geometry": {"type": "Polygon", "coordinates": [ring]},
                }
            )
            ruler.append((k, float(heights[i, j])))
    sigma = sfm_sigma / gsd
    dsm = cv2.GaussianBlur(surface.astype(np.float32), (0, 0), sigma)
    lifted = cv2.GaussianBlur(
        cv2.dilate(surface.astype(np.float32), np.ones((int(0.15 / gsd) | 1,) * 2, np.uint8)), (0, 0), sigma
    )
    dsm = np.maximum(dsm, 0.5 * (dsm + lifted)) + rng.normal(0, 0.01, dsm.shape).astype(np.float32)
    texture = 1 + 0.08 * rng.standard_normal((rows, cols, 1))
    rgb = np.where(canopy[..., None], np.array([205.0, 178.0, 110.0]), np.array(soil, float)) * texture
    shade = cv2.dilate(canopy.astype(np.uint8), np.ones((int(0.4 / gsd), 1), np.uint8), anchor=(0, 0)).astype(
        bool
    )
    rgb[shade & ~canopy] *= 0.55  # each plot's shadow on the soil north of it
    transform = [[gsd, 0, TIE[0]], [0, -gsd, TIE[1]]]
    write_geotiff(folder / "ortho.tif", np.clip(rgb, 0, 255).astype(np.uint8), transform=transform, crs=CRS)
    write_geotiff(folder / "dsm.tif", dsm.astype(np.float32), transform=transform, crs=CRS)
    doc = {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": f"EPSG:{CRS}"}},
        "features": features,
    }
    (folder / "plots.geojson").write_text(json.dumps(doc))
    (folder / "ruler.csv").write_text("plot,height_m\n" + "".join(f"{k},{h:.3f}\n" for k, h in ruler))
    return len(features)


def agreement(values, truth):
    """r, RMSE and bias (cm) of `values` against the ruler: the ruler's own (`measure.ruler.agreement`)."""
    from cliff_terrain.measure.ruler import agreement as in_metres

    a = in_metres(values, truth)
    return {
        "r": round(a["r"], 3),
        "rmse_cm": round(100 * a["rmse_m"], 1),
        "bias_cm": round(100 * a["bias_m"], 1),
    }


def run_layout(folder, spec, gsd=GSD):
    from bench_scale import naive_heights

    from cliff_terrain.cli import main as cli

    make_trial(folder, **spec, gsd=gsd)
    files = [str(folder / f) for f in ("ortho.tif", "dsm.tif", "plots.geojson")]
    code = cli(["heights", files[0], "--dsm", files[1], "--plots", files[2], "--ruler", str(folder / "ruler.csv"),
                "--out", str(folder / "out"), "--no-progress"])  # fmt: skip
    if code != 0:
        raise SystemExit(f"heights failed on {folder}")
    with open(folder / "ruler.csv") as f:
        truth = np.array([float(r["height_m"]) for r in csv.DictReader(f)])
    with open(folder / "out" / "plots.csv") as f:
        ours = np.array([float(r["height_p90_m"]) for r in csv.DictReader(f)])
    summary = json.loads((folder / "out" / "summary.json").read_text())
    occlusion = summary["ground_check"]["occlusion"]
    return {
        "ours": agreement(ours, truth),
        "baseline": agreement(np.asarray(naive_heights(*files), float), truth),
        "coverage": summary["ruler"]["height_p90_m"]["coverage"],
        "held_out_cm": round(
            100 * summary["ground_check"]["candidates"][summary["ground_method"]]["error_m"], 1
        ),
        "occlusion_rise_cm": None if occlusion["rise_m"] is None else round(100 * occlusion["rise_m"], 1),
        "canopy_from_narrow": None if not occlusion["tested"] else round(occlusion["canopy_from_narrow"], 2),
        "occlusion_passed": occlusion["passed"],
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--folder", type=Path, default=None, help="where the trials are written (a temporary folder)"
    )
    parser.add_argument(
        "--gsd",
        type=float,
        default=GSD,
        help=f"metres per pixel (default {GSD}; finer ones fit the ground on ~5 cm)",
    )
    parser.add_argument("--layouts", nargs="+", default=list(LAYOUTS), choices=list(LAYOUTS))
    args = parser.parse_args(argv)
    base = Path(tempfile.mkdtemp(prefix="bench_narrow_alleys-", dir=args.folder))
    rows = {}
    try:
        for name in args.layouts:
            folder = base / name
            folder.mkdir()
            rows[name] = run_layout(folder, LAYOUTS[name], gsd=args.gsd)
            print(name, json.dumps(rows[name]), flush=True)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    return rows


if __name__ == "__main__":
    main()
