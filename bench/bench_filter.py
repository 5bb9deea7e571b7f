"""Benchmark: quaternion_filter against the direct quaternion convolution with numpy-quaternion.

The peer evaluates Sangwine's mask literally: every pixel a quaternion, and for each of the six
non-zero taps the shifted array product L * q * R added up (vectorised over pixels). Both run on
the same image in the same process; the figures that matter are the ratio and the agreement.

    python bench/bench_filter.py [--size 4000x3000] [--repeat 5] [--peer-rows N]

`main(argv=None)` returns the figures as a dict (for bench/run_all.py).
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import cv2
import numpy as np
import quaternion
from machine_info import machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cliff_terrain.photo_heights.quaternion import DEFAULT_SCALE, quaternion_filter  # noqa: E402

UAV = ROOT.parent / "shared" / "data" / "uav"
REAL_IMAGE = UAV / "caliterra" / "IMG_9370.jpg"  # a real 4000x3000 UAV frame
TOLERANCE = 1e-5
GOAL = 10.0


def peer_filter(image, scale=DEFAULT_SCALE):
    """Direct two-sided quaternion convolution (QTFM conv2 semantics, reflected borders).

    Lean for numpy-quaternion: every tap is a whole-array Hamilton product on *contiguous* data
    (a shift of the flattened padded image; strided quaternion views are several times slower),
    written into one reused buffer. Outputs land on the padded width; the two extra columns are
    dropped at the end.
    """
    rows, cols = image.shape[:2]
    width = cols + 2
    pixels = image / 255.0 if image.dtype == np.uint8 else image.astype(np.float64)
    padded = np.pad(pixels, ((1, 1), (1, 1), (0, 0)), mode="reflect").reshape(-1, 3)
    flat = quaternion.from_vector_part(padded)
    coefficient = scale * np.exp(quaternion.quaternion(0, 1, 1, 1) / np.sqrt(3) * np.pi / 4)
    n = rows * width - 2  # the last output pixel sits at (rows - 1) * width + cols - 1
    acc = np.zeros(rows * width, dtype=np.quaternion)
    product = np.empty(n, dtype=np.quaternion)
    # Mask tap (a, b) of a true convolution reads padded pixel (r + 2 - a, c + 2 - b); output
    # (r, c) sits at r * width + c. Row a = 0 holds R, row a = 2 conj(R); right mask = conj(left).
    for a, left in ((0, coefficient), (2, coefficient.conj())):
        for b in range(3):
            shift = (2 - a) * width + (2 - b)
            np.multiply(left, flat[shift : shift + n], out=product)
            np.multiply(product, left.conj(), out=product)
            np.add(acc[:n], product, out=acc[:n])
    vectors = quaternion.as_vector_part(acc).reshape(rows, width, 3)
    return vectors[:, :cols].astype(np.float32)


def load_image(rows, cols):
    """The real 12 MP UAV frame (resized if another size is asked), else a synthetic colour field."""
    if REAL_IMAGE.is_file():
        bgr = cv2.imread(str(REAL_IMAGE), cv2.IMREAD_COLOR)
        if bgr is not None:
            if bgr.shape[:2] != (rows, cols):
                bgr = cv2.resize(bgr, (cols, rows), interpolation=cv2.INTER_AREA)
            return np.ascontiguousarray(bgr[..., ::-1]), str(REAL_IMAGE.relative_to(ROOT.parent))
    rng = np.random.default_rng(0)
    coarse = rng.integers(0, 256, (max(2, rows // 40), max(2, cols // 40), 3), dtype=np.uint8)
    field = cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_CUBIC)
    noise = rng.integers(-12, 13, field.shape)
    return np.clip(field + noise, 0, 255).astype(np.uint8), "synthetic colour field (real frame absent)"


def _timed(fn, repeat):
    """Median and best wall time of `repeat` calls, and the last result."""
    times = []
    for _ in range(max(1, repeat)):
        result = None  # free the previous result first: each run allocates its own
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), float(min(times)), result


def _read_status(key):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(key)


def peak_memory(fn):
    """Peak bytes allocated through Python/numpy (tracemalloc) and peak RSS growth, or None."""
    rss = None
    try:
        Path("/proc/self/clear_refs").write_text("5")  # resets the RSS high-water mark
        base = _read_status("VmRSS")
        fn()
        rss = _read_status("VmHWM") - base
    except (OSError, KeyError):
        pass
    tracemalloc.start()
    try:
        fn()
        traced = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return traced, rss


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="4000x3000", help="COLSxROWS of the test image (default 4000x3000)")
    parser.add_argument("--repeat", type=int, default=5, help="runs of quaternion_filter (median)")
    parser.add_argument("--peer-repeat", type=int, default=2, help="runs of the peer (median)")
    parser.add_argument(
        "--peer-rows",
        type=int,
        default=None,
        help="time the peer on the top N rows only and scale per megapixel (default: the whole image)",
    )
    args = parser.parse_args(argv)
    try:
        cols, rows = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        parser.error(f"--size must look like 4000x3000, got {args.size!r}")

    image, source = load_image(rows, cols)
    info = machine()
    megapixels = rows * cols / 1e6
    print(
        f"machine: {info['cpu']}, {info['cores']} cores ({info['usable_cores']} usable), load {info['loadavg_1min']:.2f}"
    )
    print(f"numpy {np.__version__}, OpenCV {cv2.__version__}, numpy-quaternion {quaternion.__version__}")
    print(f"image: {source}, {cols}x{rows} ({megapixels:.1f} MP) uint8")

    quaternion_filter(image)  # warm-up: OpenCV's first calls, first touches of fresh memory
    ours_s, ours_best, ours = _timed(lambda: quaternion_filter(image), args.repeat)
    vertical_s, _, _ = _timed(lambda: quaternion_filter(image, orientation="vertical"), args.repeat)

    peer_image = image if args.peer_rows is None else np.ascontiguousarray(image[: args.peer_rows])
    peer_mp = peer_image.shape[0] * peer_image.shape[1] / 1e6
    peer_filter(peer_image)  # warm-up too: first touches of fresh memory are slow on some VMs
    peer_s, peer_best, peer = _timed(lambda: peer_filter(peer_image), args.peer_repeat)
    ours_rate, peer_rate = megapixels / ours_s, peer_mp / peer_s
    ratio = ours_rate / peer_rate

    # Agreement: on the peer's whole input, and on a crop with the borders of its own.
    ours_on_peer_input = ours if args.peer_rows is None else quaternion_filter(peer_image)
    diff_full = float(np.abs(ours_on_peer_input - peer).max())
    del ours, peer, ours_on_peer_input
    r0, c0 = rows // 3, cols // 3
    crop = np.ascontiguousarray(image[r0 : r0 + 256, c0 : c0 + 256])
    diff_crop = float(np.abs(quaternion_filter(crop) - peer_filter(crop)).max())
    diff_vertical = float(
        np.abs(
            quaternion_filter(crop, orientation="vertical")
            - peer_filter(np.ascontiguousarray(crop.transpose(1, 0, 2))).transpose(1, 0, 2)
        ).max()
    )
    max_diff = max(diff_full, diff_crop, diff_vertical)

    ours_traced, ours_rss = peak_memory(lambda: quaternion_filter(image))
    peer_traced, peer_rss = peak_memory(lambda: peer_filter(peer_image))
    output_mb = image.size * 4 / 1e6

    def mb(value):
        return None if value is None else round(value / 1e6, 1)

    peer_note = (
        "" if args.peer_rows is None else f" (timed on the top {peer_image.shape[0]} rows, scaled per MP)"
    )
    print(
        f"quaternion_filter: {ours_s * 1e3:8.1f} ms median ({ours_best * 1e3:.1f} best) {ours_rate:7.1f} MP/s"
    )
    print(
        f"quaternion_filter, vertical orientation: {vertical_s * 1e3:8.1f} ms median {megapixels / vertical_s:7.1f} MP/s"
    )
    print(
        f"peer (numpy-quaternion direct convolution): {peer_s * 1e3:8.1f} ms median for {peer_mp:.1f} MP"
        f" {peer_rate:7.1f} MP/s{peer_note}"
    )
    print(f"ratio: {ratio:.1f}x (goal >= {GOAL:.0f}x: {'met' if ratio >= GOAL else 'NOT met'})")
    print(
        f"agreement: max |difference| {max_diff:.2e} (whole peer input {diff_full:.1e}, 256x256 crop {diff_crop:.1e},"
        f" vertical {diff_vertical:.1e}; tolerance {TOLERANCE:.0e}: {'ok' if max_diff <= TOLERANCE else 'FAILED'})"
    )
    print(
        f"peak memory (output alone {output_mb:.0f} MB): quaternion_filter {mb(ours_traced)} MB traced,"
        f" {mb(ours_rss)} MB RSS growth; peer {mb(peer_traced)} MB traced, {mb(peer_rss)} MB RSS growth"
        f" for {peer_mp:.1f} MP"
    )
    rows = [
        (
            f"`quaternion_filter`, {cols}x{rows} uint8 (`bench/bench_filter.py`)",
            f"{ours_s * 1e3:.1f} ms, {ours_rate:.0f} MP/s",
            f"direct quaternion convolution with numpy-quaternion: {peer_s * 1e3:.0f} ms, "
            f"{peer_rate:.1f} MP/s{peer_note}",
            f"{ratio:.1f}x, same output to {max_diff:.1e}",
            f">= {GOAL:.0f}x ({'met' if ratio >= GOAL else 'not met'})",
        ),
        (
            "filter peak memory (traced)",
            f"{mb(ours_traced)} MB (the output is {output_mb:.0f} MB)",
            f"{mb(peer_traced)} MB for {peer_mp:.1f} MP",
            "",
            "",
        ),
    ]
    return {
        "rows": rows,
        "benchmark": "quaternion_filter",
        "image": source,
        "size": f"{cols}x{rows}",
        "megapixels": megapixels,
        "ours_seconds": ours_s,
        "ours_mp_per_s": ours_rate,
        "ours_vertical_mp_per_s": megapixels / vertical_s,
        "peer": "numpy-quaternion direct convolution",
        "peer_megapixels": peer_mp,
        "peer_scaled_from_strip": args.peer_rows is not None,
        "peer_seconds": peer_s,
        "peer_mp_per_s": peer_rate,
        "ratio": ratio,
        "goal_ratio": GOAL,
        "goal_met": ratio >= GOAL,
        "max_abs_difference": max_diff,
        "agree": max_diff <= TOLERANCE,
        "ours_peak_traced_mb": mb(ours_traced),
        "ours_peak_rss_growth_mb": mb(ours_rss),
        "peer_peak_traced_mb": mb(peer_traced),
        "peer_peak_rss_growth_mb": mb(peer_rss),
        "output_mb": output_mb,
        **info,
    }


if __name__ == "__main__":
    main()
