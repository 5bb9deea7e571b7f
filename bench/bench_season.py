"""Benchmark: a season (the 7 Lamberton soybean dates) on a local Dask cluster of 2 workers against serial.

Goal (issue 14): at least 1.7x on 2 cores with 2 workers, in one run, and the peak memory per worker.
Both sides are warm (imports done, the cluster started, which is timed on its own) and write the
same table from an empty cache; each is run `--repeat` times, alternating, best time kept. The
per-image costs measured on the way (a task's wall and CPU seconds, a run whose every image is
already cached, a Dask round trip of an empty task, what a task sends back) feed the estimate for
10 000 images on 100 workers.

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
    import cliff_terrain.build  # noqa: F401
    import cliff_terrain.measure.field_plots  # noqa: F401
    import cliff_terrain.season.runner  # noqa: F401

    return True


def _noop(i):
    return i


def _pool_task(job):
    """One image in a fresh cache, as a task of the multiprocessing peer."""
    from cliff_terrain.season.task import process_image

    with tempfile.TemporaryDirectory(prefix="bench_season_pool_") as cache:
        result = process_image({**job, "cache": cache})
    assert result["ok"], result
    return result


def pool_peer(jobs, workers, repeat):
    """The same tasks on a plain ``multiprocessing`` pool (no scheduler, no Dask): the speed-up
    two processes reach on this machine at all, against a serial loop of the same tasks."""
    import multiprocessing

    serial_s, pool_s = [], []
    with multiprocessing.get_context("spawn").Pool(workers) as pool:
        pool.map(_pool_task, jobs[:workers], chunksize=1)  # imports and first calls, as for Dask
        for _ in range(repeat):
            t = time.perf_counter()
            for job in jobs:
                _pool_task(job)
            serial_s.append(time.perf_counter() - t)
            t = time.perf_counter()
            pool.map(_pool_task, jobs, chunksize=1)
            pool_s.append(time.perf_counter() - t)
    return min(serial_s), min(pool_s)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--max-size", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    if not (SEASON / "plots.geojson").is_file():
        print(f"skipped: the soybean season is not at {SEASON}")
        return {}

    from distributed import Client

    from cliff_terrain.season.cluster import local_cluster
    from cliff_terrain.season.plan import plan_season
    from cliff_terrain.season.runner import run_season

    print(describe())
    jobs, plots = plan_season([SEASON], plots=SEASON / "plots.geojson", max_size=args.max_size)
    _warm()
    # First-call costs (lazy imports, caches) out of the timing.
    with tempfile.TemporaryDirectory(prefix="bench_season_warm_") as warm:
        run_season(jobs[:1], plots, out=warm, workers=0, progress=False, chart=False)

    started = time.perf_counter()
    cluster = local_cluster(args.workers)  # the cluster `run_season(workers=N)` starts
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
                kwargs = {"workers": 0} if mode == "serial" else {"client": client}
                t = time.perf_counter()
                # The tasks alone: the alignment runs in this process either way (timed below).
                season = run_season(jobs, plots, out=out, progress=False, chart=False, align=False, **kwargs)
                elapsed = time.perf_counter() - t
                assert not season.failures, season.failures
                (serial_s if mode == "serial" else parallel_s).append(elapsed)
                tables[mode] = (out / "season.csv").read_bytes()
                if mode == "parallel":
                    for worker, peak in season.worker_peaks.items():
                        peaks[worker] = max(peaks.get(worker, 0), peak)
        manifest = json.loads((work / "serial0" / "season.json").read_text())
        image_s = [d["seconds"] for d in manifest["dates"]]
        records = [json.loads(p.read_text()) for p in sorted((work / "serial0" / "cache").glob("*.json"))]
        cpu_s = [r["cpu_seconds"] for r in records]
        record_bytes = statistics.mean(len(json.dumps(r)) for r in records)
        entry_bytes = statistics.mean(p.stat().st_size for p in (work / "serial0" / "cache").iterdir())
        # Everything cached: hashing the photos on the workers, reading the records, the round trips.
        t = time.perf_counter()
        again = run_season(
            jobs,
            plots,
            out=work / "parallel0",
            client=client,
            progress=False,
            chart=False,
            align=False,
        )
        cached_s = time.perf_counter() - t
        assert again.cached == len(jobs)
    finally:
        client.close()
        cluster.close()
        shutil.rmtree(work, ignore_errors=True)

    # The dates' alignment (run_season's default), before the tasks, in the calling process.
    from cliff_terrain.season.align import season_shifts

    align_s = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        season_shifts([job.path for job in jobs])
        align_s.append(time.perf_counter() - t)

    # The peer: what two processes reach here without Dask (the same task function).
    from cliff_terrain import __version__
    from cliff_terrain.season.cache import file_hash

    plain = [{**j.as_dict(), "plots_hash": file_hash(j.plots), "version": __version__} for j in jobs]
    pool_serial, pool_parallel = pool_peer(plain, args.workers, args.repeat)

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
        "pool_serial_s": pool_serial,
        "pool_parallel_s": pool_parallel,
        "pool_speedup": pool_serial / pool_parallel,
        "align_s": min(align_s),
        "cluster_startup_s": startup,
        "image_s_mean": statistics.mean(image_s),
        "image_s_max": max(image_s),
        "image_cpu_s_mean": statistics.mean(cpu_s),
        "cached_run_s": cached_s,
        "task_roundtrip_ms": per_task * 1e3,
        "record_kb_per_image": record_bytes / 1e3,
        "cache_entry_kb_per_file": entry_bytes / 1e3,
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
    print(
        f"peer, a multiprocessing pool of {args.workers} processes running the same tasks (no Dask): "
        f"serial loop {pool_serial:.2f} s, pool {pool_parallel:.2f} s -> {figures['pool_speedup']:.2f}x"
    )
    print(f"aligning the {len(jobs)} dates (before the tasks, in this process): {min(align_s):.2f} s")
    print(estimate(figures))
    return figures


def estimate(f, images=10_000, workers=100):
    """What `images` would take on `workers`, from the per-image costs measured here."""
    compute = images * f["image_cpu_s_mean"] / workers
    scheduler = images * f["task_roundtrip_ms"] / 1e3
    read_gb = images * f["photo_mb"] / 1e3
    back_mb = images * f["record_kb_per_image"] / 1e3
    return (
        f"Estimate for {images} images on {workers} workers (one free core each): compute "
        f"{compute:.0f} s ({f['image_cpu_s_mean']:.2f} CPU s per image / {workers}); the scheduler, "
        f"at the {f['task_roundtrip_ms']:.1f} ms per task measured here, {scheduler:.0f} s; "
        f"{read_gb:.0f} GB of photos read by the workers, {read_gb / max(compute, 1e-9):.1f} GB/s to "
        f"keep up; {back_mb:.0f} MB of table rows back to the client; peak memory "
        f"{workers} x {max(f['worker_peak_rss_mb'] or [0])} MB."
    )


if __name__ == "__main__":
    main()
