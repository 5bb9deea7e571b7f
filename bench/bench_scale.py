"""Benchmark: ``cliff-terrain heights`` on a whole trial (issue 40), against the naive baseline in the same run.

The field is the shared OpenDroneMap pair (``../shared/data/dsm/fieldimager_ex2``: a 535 x 550
orthophoto at 0.2 m and its DSM) tiled n x n times: the orthophoto as tiled RGBA uint8, the DSM
resampled once onto the orthophoto's grid and tiled the same way (tiled float32, NaN no-data), and
the 36 hand-drawn plots of ``tests/data/odm_plots_by_hand.geojson``, each cut into ``--split`` plots
along its long side (default 4: 144 a copy, 3.7 m x 4.8 m), copied onto every `stride`-th copy so
the field carries about ``--plots`` plots. Everything is written tile by tile into a temporary
folder (``--folder``, never the repository).

Ours: ``cliff-terrain heights --plots`` (by itself windowed: the in-memory run would pass the 4 GiB
cap), in a fresh process whose peak resident set (VmHWM) it reports. The peer, in the same run: the
naive baseline, itself windowed (the DSM's 2nd percentile in 5 m blocks, bilinear between the block
centres, then each plot's p90 of DSM minus that ground over the window holding the plot). Reported:
peak RSS, wall time, MP/s, ours/peer, and how far the copies of each plot agree (the median over
the plots of the interquartile range of their copies' p90: the field repeats, so should they).

    python bench/bench_scale.py [--tiles 30] [--plots 130000] [--split 4] [--workers 1 2 [--rounds 3]] [--folder DIR]

With ``--workers``, each count runs ``--rounds`` times, the counts in turns (1, 2, 1, 2, ...): a
machine's speed drifts (on the 2-core VMs measured here, by 10-25 % from one run to the next, more
from one hour to the next), so a ratio of one pair of runs is its noise as much as the code's. The
walls and stages reported are the medians of the rounds (stage by stage); the speedup is the median
of each round's own ratio, the rounds' ratios beside it.
Each count's peaks are this process's own and, where psutil is installed (Dask brings it), the
resident sets of this process and its workers summed, sampled at 10 Hz (``workers_N_tree_peak_gib``:
what the 4 GiB cap is about on one machine).

`main(argv=None)` returns the rows as a list of dicts.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine_info import describe, machine  # noqa: E402

PAIR = ROOT.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"
PLOTS = ROOT / "tests" / "data" / "odm_plots_by_hand.geojson"  # 36 plots drawn by hand on the pair
TILE = 512
# Ours in a fresh process: its own peak (VmHWM), and the peak of the resident sets summed over it and
# its children (a local cluster's workers), from `sample_tree` (None without psutil, which Dask brings).
OURS = (
    f"import sys, json, time\nsys.path.insert(0, {str(Path(__file__).resolve().parent)!r})\n"
    "from bench_scale import sample_tree\nfrom cliff_terrain.cli import main\n"
    "from cliff_terrain._memory import peak_rss\ntree = sample_tree()\n"
    "t = time.perf_counter()\ncode = main(sys.argv[1:])\n"
    "print(json.dumps({'code': code, 'peak': peak_rss(), 'tree_peak': tree[0], 'wall': time.perf_counter() - t}))\n"
)
PEER = (
    "import sys, json, time\nsys.path.insert(0, sys.argv[1])\nfrom bench_scale import naive_heights\n"
    "from cliff_terrain._memory import peak_rss\nt = time.perf_counter()\n"
    "p90 = naive_heights(*sys.argv[2:5])\nimport numpy as np\nnp.save(sys.argv[5], p90)\n"
    "print(json.dumps({'code': 0, 'peak': peak_rss(), 'wall': time.perf_counter() - t}))\n"
)


def sample_tree(interval=0.1):
    """A one-item list that a daemon thread keeps at the peak of the resident sets summed over this
    process and its children (a local cluster's workers), sampled every `interval` seconds: a lower
    bound, since a spike between two samples passes unseen. ``[None]`` without psutil."""
    import threading

    try:
        import psutil
    except ImportError:
        return [None]
    me, peak = psutil.Process(), [0]

    def sample():
        while True:
            total = 0
            for process in [me, *me.children(recursive=True)]:
                try:
                    total += process.memory_info().rss
                except psutil.Error:  # a worker that ended between the listing and the reading
                    pass
            peak[0] = max(peak[0], total)
            time.sleep(interval)

    threading.Thread(target=sample, daemon=True).start()
    return peak


def split_plots(plots, parts):
    """([ring], [uid]): each hand-drawn plot (a quadrilateral) cut across its long side into `parts`
    plots of equal length (uid ``"<plot>-<part>"``), as a trial's single-row plots lie in a range."""
    rings, uids = [], []
    for polygon, attrs in zip(plots.polygons, plots.attributes, strict=True):
        p0, p1, p2, p3 = polygon[0][:4]
        if np.hypot(*(p1 - p0)) > np.hypot(*(p3 - p0)):  # walk along the long side
            p1, p3 = p3, p1
        for k in range(parts):
            a, b = k / parts, (k + 1) / parts
            corners = [p0 + a * (p3 - p0), p1 + a * (p2 - p1), p1 + b * (p2 - p1), p0 + b * (p3 - p0)]
            rings.append(np.array([*corners, corners[0]]))
            uids.append(f"{attrs['plot']}-{k}")
    return rings, uids


def build_field(n, folder, *, target_plots, split=1):
    """The pair tiled n x n into `folder` (ortho.tif, dsm.tif, plots.geojson); returns its figures."""
    import tifffile

    from cliff_terrain.io.raster.geotiff import geotiff_tags, read_orthophoto, read_surface, resample
    from cliff_terrain.io.vector.plot_files import write_plots
    from cliff_terrain.io.vector.plot_polygons import PlotSet, read_plots

    ortho = read_orthophoto(PAIR / "odm_orthophoto.tif")
    valid = np.ones(ortho.shape, bool) if ortho.valid is None else ortho.valid
    rgba = np.dstack([ortho.data, np.where(valid, 255, 0).astype(np.uint8)])
    dsm = resample(
        read_surface(PAIR / "dsm.tif"), transform=ortho.transform, shape=ortho.shape, crs=ortho.crs
    )
    h, w = ortho.shape
    rows, cols = n * h, n * w

    def tiles(base):
        for r0 in range(0, rows, TILE):
            ri = np.arange(r0, min(rows, r0 + TILE)) % h
            for c0 in range(0, cols, TILE):
                yield base[np.ix_(ri, np.arange(c0, min(cols, c0 + TILE)) % w)]

    for name, base, nodata in (("ortho.tif", rgba, None), ("dsm.tif", dsm, float("nan"))):
        extra = {"extrasamples": [2]} if base.ndim == 3 else {}
        with tifffile.TiffWriter(folder / name, bigtiff=rows * cols * 4 > 2**31) as tif:
            tif.write(
                tiles(base), shape=(rows, cols, *base.shape[2:]), dtype=base.dtype, tile=(TILE, TILE),
                compression="zlib", photometric="rgb" if base.ndim == 3 else "minisblack",
                extratags=geotiff_tags(ortho.transform, ortho.crs, nodata=nodata), **extra,
            )  # fmt: skip
    plots = split_plots(read_plots(PLOTS), split)
    copies = n * n
    stride = max(1, round(copies * len(plots[0]) / target_plots))
    polygons, attributes = [], []
    for k in range(0, copies, stride):
        i, j = divmod(k, n)
        shift = ortho.transform[:2, :2] @ np.array([j * w, i * h], float)
        for ring, uid in zip(*plots, strict=True):
            polygons.append([ring + shift])
            attributes.append({"plot_uid": uid, "copy": k})
    field = PlotSet(polygons, attributes, ("plot_uid", "copy"), ortho.crs, "")
    write_plots(field, folder / "plots.geojson", crs=ortho.crs)
    return {
        "mp": rows * cols / 1e6,
        "rows": rows,
        "cols": cols,
        "plots": len(polygons),
        "copies_with_plots": len(range(0, copies, stride)),
    }


def naive_heights(ortho, dsm, plots, *, window=2048, block_m=5.0, percentile=2.0):
    """The naive peer, windowed: each plot's p90 of the DSM minus its 2nd percentile in 5 m blocks.

    The block levels are taken window by window (windows aligned to the blocks), then each window
    (with a halo of the largest plot) gives the plots whose centre it holds their p90.
    """
    from scipy import ndimage

    from cliff_terrain.io.raster.geotiff import read_georeference
    from cliff_terrain.io.vector.plot_polygons import PlotSet, read_plots
    from cliff_terrain.measure.field_plots import rasterize_plots
    from cliff_terrain.measure.window_reading import SurfaceWindows, upsample, windows
    from cliff_terrain.measure.window_tasks import _plot_boxes, window_halo

    transform, _ = read_georeference(ortho)
    plots = read_plots(plots)
    surface = SurfaceWindows(dsm)
    shape = surface.shape
    pixel = float(np.hypot(*transform[:2, 0]))
    block = max(2, round(block_m / pixel))
    side = max(block, window // block * block)
    nr, nc = -(-shape[0] // block), -(-shape[1] // block)
    levels = np.full((nr, nc), np.nan, np.float32)
    for r0, r1, c0, c1 in windows(shape, side):
        data = surface.on_grid(transform, r0, r1, c0, c1)
        br, bc = -(-(r1 - r0) // block), -(-(c1 - c0) // block)
        pad = np.full((br * block, bc * block), np.nan, np.float32)
        pad[: r1 - r0, : c1 - c0] = data
        blocks = pad.reshape(br, block, bc, block).transpose(0, 2, 1, 3).reshape(br, bc, -1)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                levels[r0 // block : r0 // block + br, c0 // block : c0 // block + bc] = np.nanpercentile(
                    blocks, percentile, axis=2
                )
    levels = np.where(np.isnan(levels), np.nanmedian(levels), levels).astype(np.float32)
    rings, boxes = _plot_boxes(plots, transform)
    halo = window_halo(plots, transform)
    rows, cols = shape
    centre_r = np.clip(np.nan_to_num((boxes[:, 1] + boxes[:, 3]) / 2), 0, rows - 1)
    centre_c = np.clip(np.nan_to_num((boxes[:, 0] + boxes[:, 2]) / 2), 0, cols - 1)
    owner = (centre_r // window).astype(np.int64) * -(-cols // window) + (centre_c // window).astype(np.int64)
    p90 = np.full(len(plots), np.nan)
    for k, (r0, r1, c0, c1) in enumerate(windows(shape, window)):
        mine = np.flatnonzero(owner == k)
        if not mine.size:
            continue
        R0, R1, C0, C1 = max(0, r0 - halo), min(rows, r1 + halo), max(0, c0 - halo), min(cols, c1 + halo)
        chm = surface.on_grid(transform, R0, R1, C0, C1) - upsample(levels, block, R0, R1, C0, C1)
        local = PlotSet(
            [[ring - (C0, R0) for ring in rings[i]] for i in mine], [{}] * mine.size, (), None, ""
        )
        labels = rasterize_plots(local, transform=np.eye(3), shape=chm.shape)
        for n, (i, box) in enumerate(
            zip(mine, ndimage.find_objects(labels, max_label=mine.size), strict=True), 1
        ):
            if box is None:
                continue
            values = chm[box][labels[box] == n]
            values = values[np.isfinite(values)]
            if values.size:
                p90[i] = np.percentile(np.maximum(values, 0), 90)
    surface.close()
    return p90


def copies_agreement(p90, uids):
    """Median over the plots of the interquartile range (m) of their copies' p90."""
    groups = {}
    for value, uid in zip(p90, uids, strict=True):
        if np.isfinite(value):
            groups.setdefault(uid, []).append(value)
    iqr = [np.subtract(*np.percentile(v, [75, 25])) for v in groups.values() if len(v) > 1]
    return float(np.median(iqr)) if iqr else math.nan


def _run(code, args, cwd):
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=cwd)
    if done.returncode != 0:
        raise SystemExit(f"run failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if result["code"] != 0:  # the command's own exit status (its one-line error on stderr)
        raise SystemExit(f"run failed ({result['code']}): {done.stderr.strip()[-2000:]}")
    return result, done.stdout


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiles", type=int, nargs="+", default=[30], help="copies along each side")
    parser.add_argument("--plots", type=int, default=130_000, help="about this many plots on the field")
    parser.add_argument(
        "--folder", type=Path, default=None, help="where the field is built (default: a tmp dir)"
    )
    parser.add_argument(
        "--split", type=int, default=4, help="plots cut from each hand-drawn plot (default 4)"
    )
    parser.add_argument("--keep", action="store_true", help="keep the field and outputs")
    parser.add_argument(
        "--window",
        type=int,
        default=1024,
        help="heights --window (default 1024: two local workers and this process fit the 4 GiB cap)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        nargs="*",
        default=[],
        help="also ours on a local Dask cluster of N workers (its wall time against this process's)",
    )
    parser.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="with --workers, run the worker counts in turns this many times (medians reported)",
    )
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    if args.rounds > 1 and not args.workers:
        parser.error("--rounds runs the --workers counts in turns: give --workers (e.g. --workers 1 2)")
    if len(set(args.workers)) != len(args.workers):
        parser.error(f"--workers must not repeat a count, got {args.workers}")
    print(describe(machine()), flush=True)
    base = Path(tempfile.mkdtemp(prefix="bench_scale-", dir=args.folder))
    rows = []
    try:
        for n in args.tiles:
            folder = base / f"t{n}"
            folder.mkdir()
            t = time.perf_counter()
            field = build_field(n, folder, target_plots=args.plots, split=args.split)
            print(f"field {n}x{n}: {field} built in {time.perf_counter() - t:.0f} s", flush=True)
            ortho, dsm, plots = (str(folder / f) for f in ("ortho.tif", "dsm.tif", "plots.geojson"))
            command = [
                "heights",
                ortho,
                "--dsm",
                dsm,
                "--plots",
                plots,
                "--out",
                str(folder / "out"),
                "--no-progress",
                "--windowed",
                "--window",
                str(args.window),
            ]
            ours, out = _run(OURS, command, ROOT)
            peer, _ = _run(
                PEER, [str(Path(__file__).parent), ortho, dsm, plots, str(folder / "peer.npy")], ROOT
            )
            import csv

            with open(folder / "out" / "plots.csv") as f:
                table = list(csv.DictReader(f))
            ours_p90 = np.array([float(r["height_p90_m"] or "nan") for r in table])
            peer_p90 = np.load(folder / "peer.npy")
            uids = [r["plot_uid"] for r in table]
            summary = json.loads((folder / "out" / "summary.json").read_text())
            row = {
                "field_mp": round(field["mp"], 1),
                "plots": field["plots"],
                "ours_peak_gib": round(ours["peak"] / 2**30, 2),
                "peer_peak_gib": round(peer["peak"] / 2**30, 2),
                "ours_wall_s": round(ours["wall"], 1),
                "peer_wall_s": round(peer["wall"], 1),
                "ours_mp_per_s": round(field["mp"] / ours["wall"], 2),
                "peer_mp_per_s": round(field["mp"] / peer["wall"], 2),
                "wall_ours/peer": round(ours["wall"] / peer["wall"], 2),
                "ours_plots_with_height": int(np.isfinite(ours_p90).sum()),
                "peer_plots_with_height": int(np.isfinite(peer_p90).sum()),
                "ours_copies_p90_iqr_cm": round(copies_agreement(ours_p90, uids) * 100, 2),
                "peer_copies_p90_iqr_cm": round(copies_agreement(peer_p90, uids) * 100, 2),
                "ours_minus_peer_p90_median_cm": round(float(np.nanmedian(ours_p90 - peer_p90)) * 100, 2),
                "ground_grid_pixel_m": summary["windowed"]["ground_grid_pixel_m"],
                "ground_method": summary["ground_method"],
                "memory_estimate_gib": round(summary["windowed"]["memory_estimate_gib"], 2),
            }
            walls, stages, peaks, same, tree_peaks = ({w: [] for w in args.workers} for _ in range(5))
            for _ in range(args.rounds):  # in turns: the machine's drift falls on every count alike
                for w in args.workers:  # the same command on a local cluster: same table, its wall time
                    cluster_out = folder / f"out_w{w}"
                    shutil.rmtree(cluster_out, ignore_errors=True)  # the round before's
                    on_cluster, _ = _run(
                        OURS, [*command[:7], str(cluster_out), *command[8:], "--workers", str(w)], ROOT
                    )
                    table_bytes = (cluster_out / "plots.csv").read_bytes()
                    same[w].append(table_bytes == (folder / "out" / "plots.csv").read_bytes())
                    walls[w].append(round(on_cluster["wall"], 1))
                    peaks[w].append(round(on_cluster["peak"] / 2**30, 2))
                    if on_cluster.get("tree_peak") is not None:
                        tree_peaks[w].append(round(on_cluster["tree_peak"] / 2**30, 2))
                    stages[w].append(
                        json.loads((cluster_out / "summary.json").read_text())["windowed"]["seconds"]
                    )
            for w in args.workers:
                row[f"workers_{w}_wall_s"] = round(float(np.median(walls[w])), 1)
                if args.rounds > 1:
                    row[f"workers_{w}_walls_s"] = walls[w]
                row[f"workers_{w}_main_peak_gib"] = max(peaks[w])
                if tree_peaks[w]:  # this process and its workers together, sampled (see OURS)
                    row[f"workers_{w}_tree_peak_gib"] = max(tree_peaks[w])
                row[f"workers_{w}_same_table"] = all(same[w])
                # Stage by stage: with an even number of rounds they need not add up to one run.
                row[f"workers_{w}_stages_s"] = {
                    k: round(float(np.median([s[k] for s in stages[w]])), 3) for k in stages[w][0]
                }
            if len(args.workers) >= 2:
                one, two = args.workers[0], args.workers[1]
                # Each round's own ratio (its two runs minutes apart), then their median: a ratio of
                # the median walls could pair runs of different rounds.
                ratios = [round(a / b, 2) for a, b in zip(walls[one], walls[two], strict=True)]
                row[f"speedup_{two}_over_{one}_workers"] = round(float(np.median(ratios)), 2)
                if args.rounds > 1:
                    row[f"speedup_{two}_over_{one}_workers_rounds"] = ratios
                # The stages whose work is on the workers (the overview and both passes; this process
                # still takes the overview's threshold and stores what the windows send back), without
                # what it does by itself (reading the plots, the ground's fit, writing).
                on_workers = {
                    w: [sum(s[k] for k in ("overview", "ground_grid", "windows")) for s in stages[w]]
                    for w in (one, two)
                }
                row[f"speedup_{two}_over_{one}_workers_their_stages"] = round(
                    float(np.median([a / b for a, b in zip(on_workers[one], on_workers[two], strict=True)])),
                    2,
                )
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(base, ignore_errors=True)
        else:
            print(f"kept {base}")
    return rows


if __name__ == "__main__":
    main()
