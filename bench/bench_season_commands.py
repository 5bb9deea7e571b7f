"""Benchmark: whole `cliff-terrain season` commands (interpreter start, alignment, chart included),
in this process against a local cluster, at the soybean season's own size and at about 9 MP a date.

The 7 Lamberton soybean dates (0.93 MP each) run with the default (a season this small runs in the
calling process), ``--workers 0`` and ``--workers 2``; then the same dates upscaled to about 9 MP
(bicubic, their georeference scaled to match, in a temporary folder outside the repository) with
``--workers 0``, ``--workers 2`` and the default. Each command is a fresh process from an empty
output folder, alternating, `--repeat` times; the best and the median are printed.

    python bench/bench_season_commands.py [--repeat 3] [--scale 3.11]

`main(argv=None)` returns the figures as a dict.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import describe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEASON = ROOT.parent / "shared" / "data" / "uav" / "lamberton_soybean"


def upscale(source, target, factor):
    """The season's GeoTIFFs `factor` times larger on each side, pixel size divided to match; returns
    their mean megapixels."""
    import cv2
    import tifffile

    megapixels = []
    for path in sorted(source.glob("*.tif")):
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            data = page.asarray()
            tags = {tag.code: tag.value for tag in page.tags.values()}
        rows, cols = round(data.shape[0] * factor), round(data.shape[1] * factor)
        big = cv2.resize(data, (cols, rows), interpolation=cv2.INTER_CUBIC)
        megapixels.append(rows * cols / 1e6)
        sx, sy, sz = tags[33550]
        scale = (sx * data.shape[1] / cols, sy * data.shape[0] / rows, sz)
        geo = [
            (33550, 12, 3, scale),
            (33922, 12, 6, tags[33922]),
            (34735, 3, len(tags[34735]), tags[34735]),
            (34737, 2, 0, tags[34737]),
        ]
        tifffile.imwrite(target / path.name, big, photometric="rgb", extrasamples=[2], extratags=geo)
    return statistics.mean(megapixels)


def command(photos, out, args):
    """Seconds of one `cliff-terrain season` in a fresh interpreter, and its 'ran ...' line."""
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    started = time.perf_counter()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "cliff_terrain",
            "season",
            str(photos),
            "--plots",
            str(SEASON / "plots.geojson"),
        ]
        + ["--out", str(out), "--no-progress", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=out.parent,
    )
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-2000:])
    ran = next(line for line in done.stdout.splitlines() if line.startswith("ran "))
    return seconds, ran


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--scale", type=float, default=3.11, help="side factor (3.11: about 9 MP a date)")
    args = parser.parse_args(argv)
    if not (SEASON / "plots.geojson").is_file():
        print(f"skipped: the soybean season is not at {SEASON}")
        return {}
    print(describe())
    work = Path(tempfile.mkdtemp(prefix="bench_season_commands_"))
    try:
        big = work / "big"
        big.mkdir()
        megapixels = upscale(SEASON, big, args.scale)
        cases = {
            "small default": (SEASON, []),
            "small workers 0": (SEASON, ["--workers", "0"]),
            "small workers 2": (SEASON, ["--workers", "2"]),
            "9MP workers 0": (big, ["--workers", "0"]),
            "9MP workers 2": (big, ["--workers", "2"]),
            "9MP default": (big, []),
        }
        times = {name: [] for name in cases}
        lines = {}
        for _ in range(args.repeat):
            for name, (photos, extra) in cases.items():
                seconds, lines[name] = command(photos, work / "out", extra)
                times[name].append(seconds)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    figures = {
        "mp_per_date_upscaled": megapixels,
        **{f"{name} best_s": min(t) for name, t in times.items()},
        **{f"{name} median_s": statistics.median(t) for name, t in times.items()},
        "small default/workers 0": min(times["small default"]) / min(times["small workers 0"]),
        "9MP workers 0/workers 2": min(times["9MP workers 0"]) / min(times["9MP workers 2"]),
    }
    print(json.dumps({k: round(v, 3) for k, v in figures.items()}, indent=2))
    for name, line in lines.items():
        print(f"{name}: {line}")
    return figures


if __name__ == "__main__":
    main()
