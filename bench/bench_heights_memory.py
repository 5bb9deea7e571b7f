"""Benchmark: the peak memory of ``cliff-terrain heights`` against its own estimate (issue 40).

The shared OpenDroneMap pair (``../shared/data/dsm/fieldimager_ex2``) tiled n x n times (an
orthophoto of n^2 x 0.29 MP and its DSM, the same georeference), measured at full size and on a
coarser grid (``--max-size``). Each run is a fresh process that reports its own peak resident set
(VmHWM). Then fine orthophotos, whose ground is fitted on its own 5 cm grid: the synthetic 1 cm
field of ``bench/bench_canopy.py`` (its DSM at 3 cm, 80 plots) at ``--fine`` sizes. The peer is
:func:`cliff_terrain.commands.memory_estimate.grid_estimate`, which the command refuses on before
any work: it must never be below the measured peak (ratio >= 1), and the closer to 1 the fewer runs
it refuses needlessly.

    python bench/bench_heights_memory.py [--tiles 4 7] [--max-size 2000 1000] [--fine 4000x3000 6000x4500]

`main(argv=None)` returns the rows as a list of dicts.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from cliff_terrain.commands.memory_estimate import grid_estimate  # noqa: E402
from cliff_terrain.io.raster.geotiff import geotiff_tags, read_surface, write_geotiff  # noqa: E402

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


def fine_field(size, folder):
    """The synthetic 1 cm field of bench/bench_canopy.py as files: orthophoto, DSM (3 cm), plots."""
    import tifffile
    from bench_canopy import CRS, field

    from cliff_terrain.io.vector.plot_files import write_plots

    cols, rows = (int(v) for v in size.lower().split("x"))
    image, transform, dsm, _, plots, _ = field(rows, cols)
    tifffile.imwrite(
        folder / "ortho.tif",
        image,
        photometric="rgb",
        compression="zlib",
        tile=(256, 256),
        extratags=geotiff_tags(transform, CRS),
    )
    write_geotiff(
        folder / "dsm.tif",
        np.nan_to_num(dsm.data, nan=-3.4e38),
        transform=dsm.transform,
        crs=CRS,
        nodata=-3.4e38,
    )
    write_plots(plots, folder / "plots.geojson", crs=CRS)
    return (rows, cols), dsm.data.shape


def measure(folder, ortho_shape, dsm_shape, size=None, plots=False):
    """One fresh run's peak against the estimate, as a row."""
    extra = [] if size is None else ["--max-size", str(size)]
    extra += ["--plots", str(folder / "plots.geojson")] if plots else []
    command = ["heights", str(folder / "ortho.tif"), "--dsm", str(folder / "dsm.tif")]
    command += ["--out", str(folder / f"out{size}"), "--no-progress", "--max-memory", "1000", *extra]
    done = subprocess.run([sys.executable, "-c", RUN, *command], capture_output=True, text=True, cwd=ROOT)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    files = [math.prod(ortho_shape) / 1e6, math.prod(dsm_shape) / 1e6]
    longest = max(ortho_shape) if size is None else min(size, max(ortho_shape))
    estimate, g_cols, g_rows = grid_estimate(folder / "ortho.tif", files, longest)
    summary = json.loads((folder / f"out{size}" / "summary.json").read_text())
    peak = result["peak"] / 2**30
    return {
        "ortho_mp": round(files[0], 2),
        "grid_mp": round(g_rows * g_cols / 1e6, 2),
        "ground_pixel_m": round(summary["ground_check"]["ground_pixel_m"], 3),
        "plots": bool(plots),
        "peak_gib": round(peak, 2),
        "estimate_gib": round(estimate, 2),
        "estimate/peak": round(estimate / peak, 2),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiles", type=int, nargs="*", default=[4, 7])
    parser.add_argument("--max-size", type=int, nargs="*", default=[2000, 1000])
    parser.add_argument("--fine", nargs="*", default=["4000x3000", "6000x4500"], help="COLSxROWS at 1 cm")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.tiles:
            folder = Path(tmp) / f"t{n}"
            folder.mkdir()
            shapes = tiled_pair(n, folder)
            for size in [None, *args.max_size]:
                rows.append(measure(folder, *shapes, size))
                print(rows[-1], flush=True)
        for size in args.fine:
            folder = Path(tmp) / f"fine{size}"
            folder.mkdir()
            shapes = fine_field(size, folder)
            rows.append(measure(folder, *shapes, plots=True))
            print(rows[-1], flush=True)
    return rows


if __name__ == "__main__":
    main()
