"""Benchmark: the peak memory of ``cliff-terrain heights`` against its own estimate (issue 40).

The shared OpenDroneMap pair (``../shared/data/dsm/fieldimager_ex2``) tiled n x n times (an
orthophoto of n^2 x 0.29 MP and its DSM, the same georeference), measured at full size and on a
coarser grid (``--max-size``). Each run is a fresh process that reports its own peak resident set
(VmHWM). The peer is :func:`cliff_terrain.commands.memory_estimate.heights_estimate`, which the
command refuses on before any work: it must never be below the measured peak (ratio >= 1), and the
closer to 1 the fewer runs it refuses needlessly.

    python bench/bench_heights_memory.py [--tiles 4 7] [--max-size 2000 1000]

`main(argv=None)` returns the rows as a list of dicts.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cliff_terrain.commands.memory_estimate import heights_estimate  # noqa: E402
from cliff_terrain.io.raster.geotiff import read_surface, write_geotiff  # noqa: E402

PAIR = ROOT.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"
RUN = (
    "import sys, json\nfrom cliff_terrain.cli import main\nfrom cliff_terrain._memory import peak_rss\n"
    "code = main(sys.argv[1:])\nprint(json.dumps({'code': code, 'peak': peak_rss()}))\n"
)


def tiled_pair(n, folder):
    import tifffile

    with tifffile.TiffFile(PAIR / "odm_orthophoto.tif") as tif:
        page = tif.pages[0]
        ortho = page.asarray()
        keep = [(t.code, t.dtype, t.count, t.value, True) for t in page.tags.values() if t.code >= 33550]
    tiled = np.tile(ortho, (1, n, n))
    tifffile.imwrite(
        folder / "ortho.tif", tiled, planarconfig="separate", photometric="minisblack", extratags=keep,
        compression="zlib", tile=(256, 256),
    )  # fmt: skip
    dsm = read_surface(PAIR / "dsm.tif")
    write_geotiff(
        folder / "dsm.tif",
        np.tile(np.nan_to_num(dsm.data, nan=-3.4e38), (n, n)),
        transform=dsm.transform,
        crs=dsm.crs,
        nodata=-3.4e38,
    )
    return tiled.shape[1:], tuple(s * n for s in dsm.shape)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiles", type=int, nargs="+", default=[4, 7])
    parser.add_argument("--max-size", type=int, nargs="+", default=[2000, 1000])
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.tiles:
            folder = Path(tmp) / f"t{n}"
            folder.mkdir()
            (orows, ocols), (drows, dcols) = tiled_pair(n, folder)
            for size in [None, *args.max_size]:
                extra = [] if size is None else ["--max-size", str(size)]
                command = ["heights", str(folder / "ortho.tif"), "--dsm", str(folder / "dsm.tif")]
                command += [
                    "--out",
                    str(folder / f"out{size}"),
                    "--no-progress",
                    "--max-memory",
                    "1000",
                    *extra,
                ]
                done = subprocess.run(
                    [sys.executable, "-c", RUN, *command], capture_output=True, text=True, cwd=ROOT
                )
                result = json.loads(done.stdout.strip().splitlines()[-1])
                scale = 1.0 if size is None else min(1.0, size / max(orows, ocols))
                grid_mp = orows * ocols * scale**2 / 1e6
                estimate = heights_estimate([orows * ocols / 1e6, drows * dcols / 1e6], grid_mp)
                peak = result["peak"] / 2**30
                rows.append(
                    {
                        "ortho_mp": round(orows * ocols / 1e6, 2),
                        "grid_mp": round(grid_mp, 2),
                        "peak_gib": round(peak, 2),
                        "estimate_gib": round(estimate, 2),
                        "estimate/peak": round(estimate / peak, 2),
                    }
                )
                print(rows[-1], flush=True)
    return rows


if __name__ == "__main__":
    main()
