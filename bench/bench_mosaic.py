"""Benchmark: a big tiled GeoTIFF orthomosaic (>= 400 MP) built in tiles: throughput and peak memory.

The mosaic is generated in a temporary folder (a synthetic field repeated, written tile by tile,
zlib-compressed; never decoded whole, never committed). Ours: cliff_terrain.mosaic.tiles (overview for
the shared settings, then every 4096-pixel tile with a 512-pixel margin: mask, regions, heights)
plus an adaptive mesh per tile, in a subprocess whose peak resident memory is read from the OS;
then the same with the tiles as Dask tasks on a local cluster (``relief_tiles(client=...)``, the
meshes built in the client as they come, as Blender would), against the one-process run.
The peer, in the same run: the single-photo pipeline (``build_relief``) on a 12 MP photo at full
resolution (``max_size=4000``), the route that holds the whole image in memory.

    python bench/bench_mosaic.py [--side 20480] [--tiles N] [--workers 2] [--repeat 1]

With ``--repeat N`` the peer and the one-process run alternate N times (peer, ours, peer, ours, ...),
so that both see the same load on a shared machine; the figures are then ranges.

`main(argv=None)` returns the figures as a dict (for bench/run_all.py).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import describe, machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PHOTO_12MP = ROOT.parent / "shared" / "data" / "uav" / "caliterra" / "IMG_9370.jpg"
MEMORY_GOAL_GB = 4.0

WRITE = textwrap.dedent(
    """
    import sys
    import numpy as np, tifffile
    from cliff_terrain.data.synthetic import synthetic_field
    path, side, tile = sys.argv[1], int(sys.argv[2]), 512
    field, _ = synthetic_field(shape=(2048, 2048), seed=5)
    keys = (1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32633, 3076, 0, 1, 9001)
    def tiles():
        for r in range(0, side, tile):
            for c in range(0, side, tile):
                yield field[r % 2048 : r % 2048 + tile, c % 2048 : c % 2048 + tile]
    tifffile.imwrite(path, tiles(), shape=(side, side, 3), dtype=np.uint8, tile=(tile, tile),
        photometric="rgb", compression="zlib", compressionargs={"level": 1}, bigtiff=True,
        extratags=[(33550, 12, 3, (0.01, 0.01, 0.0), True),
                   (33922, 12, 6, (0.0, 0.0, 0.0, 500000.0, 5200000.0, 0.0), True),
                   (34735, 3, len(keys), keys, True)])
    """
)

RUN = textwrap.dedent(
    """
    import contextlib, itertools, json, sys, time
    import numpy as np
    from cliff_terrain._memory import peak_rss
    from cliff_terrain.mesh.adaptive import adaptive_mesh
    from cliff_terrain.mosaic.meshes import mosaic_max_error
    from cliff_terrain.io.raster.mosaic import MosaicReader
    from cliff_terrain.mosaic.tiles import mosaic_settings, relief_tiles, tile_windows
    path, limit, workers = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    start = time.perf_counter()
    with contextlib.ExitStack() as stack:
        client = None
        if workers:  # the tiles as Dask tasks on a local cluster; the meshes here, as Blender would
            from distributed import Client
            from cliff_terrain.season.cluster import local_cluster
            client = stack.enter_context(Client(stack.enter_context(local_cluster(workers))))
        cluster_s = time.perf_counter() - start
        reader = stack.enter_context(MosaicReader(path))
        settings = mosaic_settings(reader)
        settings_s = time.perf_counter() - start - cluster_s
        n_tiles = len(tile_windows(reader.shape))
        n_tiles = min(limit, n_tiles) if limit else n_tiles
        pixels = plants = triangles = 0
        max_error, _ = mosaic_max_error(0.01)  # Import Mosaic's default: half of the 1 cm pixels, 5 mm
        tiles = relief_tiles(reader, settings=settings, client=client)
        for tile in itertools.islice(tiles, n_tiles):
            mesh = adaptive_mesh(
                tile.heights * np.float32(0.01), max_error=max_error, pixel_size=0.01, two_sided=False
            )
            pixels += tile.heights.size
            plants += int(tile.labels.max(initial=0))
            triangles += len(mesh.front_triangles())
        tiles.close()
        seconds = time.perf_counter() - start - cluster_s
        shape = reader.shape
        peak = peak_rss() / 1e9
        worker_peaks = []
        if client is not None:
            worker_peaks = sorted(v / 1e9 for v in client.run(peak_rss).values())
    print(json.dumps({"shape": shape, "tiles": n_tiles, "pixels": pixels, "plants": plants,
        "triangles": triangles, "cluster_s": cluster_s, "settings_s": settings_s, "seconds": seconds,
        "peak_rss_gb": peak, "worker_peak_rss_gb": worker_peaks}))
    """
)

PEER = textwrap.dedent(
    """
    import json, sys, time
    from cliff_terrain._memory import peak_rss
    from cliff_terrain.build import build_relief
    start = time.perf_counter()
    relief = build_relief(sys.argv[1], max_size=4000)
    seconds = time.perf_counter() - start
    rows, cols = relief.heights.shape
    print(json.dumps({"pixels": rows * cols, "seconds": seconds,
        "peak_rss_gb": peak_rss() / 1e9}))
    """
)


def _python(script, *args):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-c", script, *map(str, args)], capture_output=True, text=True, env=env
    )
    if proc.returncode:
        raise RuntimeError(proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "failed")
    return json.loads(proc.stdout.strip().splitlines()[-1]) if proc.stdout.strip() else None


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--side", type=int, default=20480, help="the mosaic's side in pixels (20480: 419 MP)")
    parser.add_argument("--tiles", type=int, default=0, help="process only the first N tiles (0: all)")
    parser.add_argument(
        "--workers", type=int, default=2, help="also run the tiles on N Dask workers (0: not)"
    )
    parser.add_argument(
        "--repeat", type=int, default=1, help="alternate the peer and the one-process run N times"
    )
    args = parser.parse_args(argv)
    info = machine()
    print(f"machine: {describe(info)}")
    with tempfile.TemporaryDirectory(prefix="cliff_terrain_mosaic_") as tmp:
        path = Path(tmp) / "mosaic.tif"
        start = time.perf_counter()
        _python(WRITE, path, args.side)
        print(
            f"mosaic: {args.side} x {args.side} ({args.side**2 / 1e6:.0f} MP), {path.stat().st_size / 1e6:.0f} MB "
            f"on disk, written in {time.perf_counter() - start:.1f} s"
        )
        rounds = []
        for _ in range(max(1, args.repeat)):
            peer = _python(PEER, PHOTO_12MP) if PHOTO_12MP.is_file() else None
            ours = _python(RUN, path, args.tiles, 0)
            mps = ours["pixels"] / 1e6 / ours["seconds"]
            print(
                f"ours, one process: {ours['tiles']} tiles, {ours['pixels'] / 1e6:.0f} MP in {ours['seconds']:.1f} s "
                f"(overview and settings {ours['settings_s']:.1f} s): {mps:.2f} MP/s, peak memory "
                f"{ours['peak_rss_gb']:.2f} GB (goal <= {MEMORY_GOAL_GB:g} GB), {ours['plants']} plants, "
                f"{ours['triangles']} triangles"
            )
            if peer is not None:
                peer_mps = peer["pixels"] / 1e6 / peer["seconds"]
                print(
                    f"peer (build_relief, 12 MP photo whole at max_size=4000), just before: {peer_mps:.2f} MP/s, "
                    f"peak memory {peer['peak_rss_gb']:.2f} GB; ratio ours/peer {mps / peer_mps:.2f}x"
                )
            rounds.append((ours, mps, peer))
        if len(rounds) > 1:
            ratios = [m / (p["pixels"] / 1e6 / p["seconds"]) for _, m, p in rounds if p is not None]
            print(
                f"{len(rounds)} rounds: ours {min(r[1] for r in rounds):.2f}-{max(r[1] for r in rounds):.2f} MP/s"
                + (f", ratio ours/peer {min(ratios):.2f}-{max(ratios):.2f}x" if ratios else "")
            )
        ours, mps, peer = rounds[-1]
        result = {"machine": info, "side": args.side, "ours": ours, "ours_mp_per_s": mps}
        if args.workers:
            dask = _python(RUN, path, args.tiles, args.workers)
            dask_mps = dask["pixels"] / 1e6 / dask["seconds"]
            print(
                f"ours, tiles as Dask tasks on {args.workers} local workers (meshes in the client): "
                f"{dask['pixels'] / 1e6:.0f} MP in {dask['seconds']:.1f} s (cluster start "
                f"{dask['cluster_s']:.1f} s, not counted): {dask_mps:.2f} MP/s, {dask_mps / mps:.2f}x "
                f"one process; peak memory client {dask['peak_rss_gb']:.2f} GB, workers "
                + ", ".join(f"{gb:.2f}" for gb in dask["worker_peak_rss_gb"])
                + f" GB; same plants and triangles: {(dask['plants'], dask['triangles']) == (ours['plants'], ours['triangles'])}"
            )
            result.update(dask=dask, dask_mp_per_s=dask_mps, dask_ratio=dask_mps / mps)
    if peer is not None:
        peer_mps = peer["pixels"] / 1e6 / peer["seconds"]
        result.update(peer=peer, peer_mp_per_s=peer_mps, ratio=mps / peer_mps)
    result["rounds"] = [{"ours_mp_per_s": m, "peer": p} for _, m, p in rounds]
    return result


if __name__ == "__main__":
    main()
