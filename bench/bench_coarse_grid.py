"""Benchmark: how the windowed ground's coarse grid moves the plots' heights (issue 40).

A big field's ground is fitted on a grid `factor` times coarser than the orthophoto
(:func:`cliff_terrain.measure.ground_grid.ground_factor`). This measures what that costs, on the
shared OpenDroneMap pair tiled n x n with its plots copied onto every tile
(:func:`bench_scale.build_field`): for each factor, how far the copies of each plot agree (the
median over the plots of the interquartile range of their copies' p90, as ``bench_scale.py``
reports; the field repeats, so should they) and how far each plot's p90 lies from the one
measured with the ground on the orthophoto's own grid (factor 1): the median and the median
absolute deviation of that difference. The peer in the same run: the naive baseline's copies
(:func:`bench_scale.naive_heights`).

    python bench/bench_coarse_grid.py [--tiles 10] [--factors 1 3 5 6 7 8] [--folder DIR]

`main(argv=None)` returns the rows as a list of dicts.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_scale import build_field, copies_agreement, naive_heights  # noqa: E402
from machine_info import describe, machine  # noqa: E402


def budget(shape, factor):
    """The ground-grid budget (pixels) that makes :func:`ground_factor` choose `factor` for `shape`."""
    return math.ceil(shape[0] / factor) * math.ceil(shape[1] / factor)


def measure(folder, plots, factor, shape):
    """{p90, uids, seconds, method, pixel_m} of the windowed heights with the ground on a `factor` grid."""
    from cliff_terrain.measure.windowed import measure_windowed

    start = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=folder) as spool:
        result = measure_windowed(
            folder / "ortho.tif", folder / "dsm.tif", plots=plots, folder=spool, window=1024,
            ground_pixels=max(10_000, budget(shape, factor)), threads=2,
        )  # fmt: skip
        try:
            if result.factor != factor:
                raise SystemExit(f"asked for a ground grid {factor} times coarser, got {result.factor}")
            p90 = np.array([r["height_p90_m"] for r in result.rows], float)
            uids = [r["plot_uid"] for r in result.rows]
            method = result.check.get("method")
            pixel_m = result.pixel_size * result.factor
        finally:
            result.close()
    return {
        "p90": p90,
        "uids": uids,
        "seconds": time.perf_counter() - start,
        "method": method,
        "pixel_m": pixel_m,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiles", type=int, default=10, help="copies along each side (default 10)")
    parser.add_argument(
        "--factors", type=int, nargs="+", default=[1, 3, 5, 6, 7, 8], help="ground grid factors (1 first)"
    )
    parser.add_argument(
        "--folder", type=Path, default=None, help="where the field is built (default: a tmp dir)"
    )
    args = parser.parse_args(argv)
    if args.factors[0] != 1:
        parser.error("--factors must start with 1: the orthophoto's own grid, the others' reference")
    print(describe(machine()), flush=True)
    base = Path(tempfile.mkdtemp(prefix="bench_coarse-", dir=args.folder))
    rows = []
    try:
        # Every copy carries the 144 plots (the 36 hand-drawn ones cut in 4), as bench_scale's field.
        field = build_field(args.tiles, base, target_plots=144 * args.tiles**2, split=4)
        shape = (field["rows"], field["cols"])
        print(f"field {args.tiles}x{args.tiles}: {field}", flush=True)
        peer = naive_heights(str(base / "ortho.tif"), str(base / "dsm.tif"), str(base / "plots.geojson"))
        from cliff_terrain.io.vector.plot_polygons import read_plots

        plots = read_plots(base / "plots.geojson")
        reference = None
        for factor in args.factors:
            run = measure(base, plots, factor, shape)
            reference = run["p90"] if reference is None else reference
            gap = run["p90"] - reference
            row = {
                "field_mp": round(field["mp"], 1),
                "plots": field["plots"],
                "factor": factor,
                "ground_pixel_m": round(run["pixel_m"], 3),
                "ground_method": run["method"],
                "copies_p90_iqr_cm": round(copies_agreement(run["p90"], run["uids"]) * 100, 2),
                "peer_copies_p90_iqr_cm": round(copies_agreement(peer, run["uids"]) * 100, 2),
                "vs_own_grid_median_cm": round(float(np.nanmedian(gap)) * 100, 2),
                "vs_own_grid_mad_cm": round(float(np.nanmedian(np.abs(gap - np.nanmedian(gap)))) * 100, 2),
                "seconds": round(run["seconds"], 1),
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    return rows


if __name__ == "__main__":
    main()
