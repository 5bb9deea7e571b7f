"""Benchmark: a season (the 7 Lamberton soybean dates) on a local Dask cluster of 2 workers against serial.

Goal (issue 14): at least 1.7x on 2 cores with 2 workers, in one run, and the peak memory per worker.
Both sides are warm (imports done, the cluster started, which is timed on its own) and write the
same table from an empty cache; each is run `--repeat` times, alternating, best time kept. The
per-image costs measured on the way (relief, hashing, the cache entry written by the client, a
Dask round trip of an empty task) feed the estimate for 10 000 images on 100 workers.

    python bench/bench_season.py [--repeat 3] [--max-size 1000]

`main(argv=None)` returns the figures as a dict (for bench/run_all.py).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import describe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SEASON = ROOT.parent / "shared" / "data" / "uav" / "lamberton_soybean"


def _warm():
    """Import what a task needs (run once on each worker, and here, before timing)."""
    import cliff_terrain.pipeline  # noqa: F401
    import cliff_terrain.plots  # noqa: F401
    import cliff_terrain.season.runner  # noqa: F401

    return True


def _noop(i):
    return i


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--max-size", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    if not (SEASON / "plots.geojson").is_file():
        print(f"skipped: the soybean season is not at {SEASON}")
        return {}

    from distributed import Client, LocalCluster

    from cliff_terrain.season.cache import Cache, file_hash
    from cliff_terrain.season.runner import plan_season, process_image, run_season

    print(describe())
    jobs, plots = plan_season([SEASON], plots=SEASON / "plots.geojson", max_size=args.max_size)
    _warm()
    process_image(jobs[0].as_dict())  # first-call costs (lazy imports, caches) out of the timing

    started = time.perf_counter()
    cluster = LocalCluster(
        n_workers=args.workers,
        threads_per_worker=1,
        processes=True,
        memory_limit="auto",
        dashboard_address=None,
        host="127.0.0.1",
    )
    client = Client(cluster)
    client.run(_warm)
    startup = time.perf_counter() - started
    # A task round trip with nothing to compute: the scheduler's and the network's share.
    client.gather(client.map(_noop, range(20), pure=False))
    t = time.perf_counter()
    client.gather(client.map(_noop, range(1000), pure=False))
    per_task = (time.perf_counter() - t) / 1000

    work = Path(tempfile.mkdtemp(prefix="bench_season_"))
    serial_s, parallel_s, tables, peaks = [], [], {}, {}
    try:
        for i in range(args.repeat):
            for mode in ("serial", "parallel"):
                out = work / f"{mode}{i}"
                kwargs = {"workers": 0} if mode == "serial" else {"scheduler": cluster.scheduler_address}
                t = time.perf_counter()
                season = run_season(jobs, plots, out=out, progress=False, chart=False, **kwargs)
                elapsed = time.perf_counter() - t
                assert not season.failures, season.failures
                (serial_s if mode == "serial" else parallel_s).append(elapsed)
                tables[mode] = (out / "season.csv").read_bytes()
                if mode == "parallel":
                    for worker, peak in season.worker_peaks.items():
                        peaks[worker] = max(peaks.get(worker, 0), peak)
        manifest = json.loads((work / "serial0" / "season.json").read_text())
        image_s = [d["seconds"] for d in manifest["dates"]]
        # The client's own per-image costs: hashing the photo and writing the cache entry.
        t = time.perf_counter()
        for job in jobs:
            file_hash(job.path)
        hash_s = (time.perf_counter() - t) / len(jobs)
        cache = Cache(work / "serial0" / "cache")
        arrays = cache.load_arrays(jobs[0].key)
        record = cache.load_record(jobs[0].key)
        t = time.perf_counter()
        for k in range(5):
            cache.store(f"bench{k}", record, arrays)
        store_s = (time.perf_counter() - t) / 5
        entry_bytes = sum(p.stat().st_size for p in cache.paths(jobs[0].key))
        result_bytes = sum(a.nbytes for a in arrays.values())
    finally:
        client.close()
        cluster.close()
        shutil.rmtree(work, ignore_errors=True)

    photo_mb = statistics.mean(Path(j.path).stat().st_size for j in jobs) / 1e6
    speedup = min(serial_s) / min(parallel_s)
    figures = {
        "images": len(jobs),
        "plots": len(plots.polygons),
        "max_size": args.max_size,
        "workers": args.workers,
        "serial_s": min(serial_s),
        "parallel_s": min(parallel_s),
        "speedup": speedup,
        "tables_identical": tables["serial"] == tables["parallel"],
        "cluster_startup_s": startup,
        "image_s_mean": statistics.mean(image_s),
        "image_s_max": max(image_s),
        "task_roundtrip_ms": per_task * 1e3,
        "hash_ms_per_image": hash_s * 1e3,
        "cache_store_ms_per_image": store_s * 1e3,
        "result_mb_per_image": result_bytes / 1e6,
        "cache_entry_mb_per_image": entry_bytes / 1e6,
        "photo_mb": photo_mb,
        "worker_peak_rss_mb": sorted(round(p / 2**20) for p in peaks.values()),
    }
    print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in figures.items()}, indent=2))
    print(
        f"{len(jobs)} dates x {len(plots.polygons)} plots at max_size {args.max_size}: serial "
        f"{min(serial_s):.2f} s, {args.workers} Dask workers {min(parallel_s):.2f} s -> {speedup:.2f}x "
        f"(goal >= 1.7x; 7 equal tasks on 2 workers cannot beat 7/4 = 1.75x); tables identical: "
        f"{figures['tables_identical']}; peak RSS per worker {figures['worker_peak_rss_mb']} MB"
    )
    print(estimate(figures))
    return figures


def estimate(f, images=10_000, workers=100):
    """What `images` would take on `workers`, from the per-image costs measured here."""
    compute = images * f["image_s_mean"] / workers
    client = images * (f["hash_ms_per_image"] + f["cache_store_ms_per_image"]) / 1e3
    scheduler = images * f["task_roundtrip_ms"] / 1e3
    read_gb = images * f["photo_mb"] / 1e3
    back_gb = images * f["result_mb_per_image"] / 1e3
    return (
        f"Estimate for {images} images on {workers} workers: compute {compute:.0f} s "
        f"({f['image_s_mean']:.2f} s per image / {workers}); the client's serial share (hash + cache "
        f"entry) {client:.0f} s; scheduler round trips {scheduler:.0f} s if not overlapped; "
        f"{read_gb:.0f} GB of photos read by the workers, {back_gb:.0f} GB of height grids sent back "
        "to the client."
    )


if __name__ == "__main__":
    main()
