"""Benchmark: build_relief from a 12 MP JPEG (decode included) to the finished relief.

Goals (issue 2): at max_size=1000, <= 1.5 s to heights on a 2-core machine and <= 1 GB peak memory;
max_size=4000 is reported as well. The peer, in the same run, is a plain full-resolution decode of
the same JPEG with Pillow (`np.asarray(Image.open(path))`): the whole pipeline is measured as a
multiple of just reading the photo. Each case runs in a fresh subprocess so the peak RSS is its own.

    python bench/bench_pipeline.py [--image PATH] [--repeat 3]

`main(argv=None)` returns the figures as a dict (for bench/run_all.py).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import describe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL_IMAGE = ROOT.parent / "shared" / "data" / "uav" / "caliterra" / "IMG_9370.jpg"  # 4000x3000 frame

_CASE = r"""
import json, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from PIL import Image
from cliff_terrain import build_relief
from cliff_terrain._memory import peak_rss
case, path, repeat = sys.argv[1], sys.argv[2], int(sys.argv[3])
times, timings = [], None
for _ in range(repeat):
    t = time.perf_counter()
    if case == "decode":
        with Image.open(path) as im:
            np.asarray(im.convert("RGB"))
    else:
        relief = build_relief(path, max_size=int(case))
        timings = relief.timings
    times.append(time.perf_counter() - t)
peak = peak_rss()  # this process's own, not bench/run_all.py's (see cliff_terrain._memory)
print(json.dumps({{"best_s": min(times), "peak_rss_bytes": peak, "timings": timings}}))
"""


def _run(case, image, repeat):
    code = _CASE.format(root=str(ROOT))
    out = subprocess.run(
        [sys.executable, "-c", code, case, str(image), str(repeat)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image", type=Path, default=REAL_IMAGE)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    if not args.image.is_file():
        print(f"bench_pipeline: image not found: {args.image} (../shared is absent?)", file=sys.stderr)
        return {}
    print(f"machine: {describe()}")
    decode = _run("decode", args.image, args.repeat)
    print(
        f"peer  full Pillow decode            {decode['best_s']:7.3f} s  peak RSS {decode['peak_rss_bytes'] / 2**20:6.0f} MiB"
    )
    decode_mib = decode["peak_rss_bytes"] / 2**20
    results = {"machine": describe(), "image": args.image.name, "decode_s": decode["best_s"], "rows": []}
    for size in (1000, 4000):
        r = _run(str(size), args.image, args.repeat if size == 1000 else 1)
        to_heights = sum(v for k, v in r["timings"].items() if k != "mesh")
        ratio = r["best_s"] / decode["best_s"]
        print(
            f"build_relief max_size={size:<5}         {r['best_s']:7.3f} s  peak RSS {r['peak_rss_bytes'] / 2**20:6.0f} MiB"
            f"  ({ratio:.2f}x the decode; to heights {to_heights:.3f} s)"
        )
        print("   stages: " + ", ".join(f"{k} {v:.3f}" for k, v in r["timings"].items()))
        stages = ", ".join(f"{k} {v:.2f}" for k, v in r["timings"].items())
        results["rows"].append(
            (
                f"`build_relief`, {args.image.name}, max_size={size}, decode included (`bench/bench_pipeline.py`)",
                f"{r['best_s']:.3f} s (stages to heights {to_heights:.3f} s), peak RSS {r['peak_rss_bytes'] / 2**20:.0f} MiB; stages (s): {stages}",
                f"full Pillow decode of the same JPEG: {decode['best_s']:.3f} s, {decode_mib:.0f} MiB",
                f"{ratio:.2f}x a decode",
                "<= 1.5 s to heights, <= 1 GB" if size == 1000 else "reported",
            )
        )
        results[f"max_size_{size}"] = {
            "total_s": r["best_s"],
            "to_heights_s": to_heights,
            "peak_rss_mib": r["peak_rss_bytes"] / 2**20,
            "ratio_to_decode": ratio,
            "timings": r["timings"],
        }
    m = results["max_size_1000"]
    print(
        f"goal max_size=1000: to heights {m['to_heights_s']:.3f} s (<= 1.5 s: {'met' if m['to_heights_s'] <= 1.5 else 'NOT met'}),"
        f" peak {m['peak_rss_mib']:.0f} MiB (<= 1024 MiB: {'met' if m['peak_rss_mib'] <= 1024 else 'NOT met'})"
    )
    return results


if __name__ == "__main__":
    main()
