"""bench/bench_scale.py's memory sampling: the peak it reports for a local cluster is the process
tree's, so a child's memory must count."""

from __future__ import annotations

import subprocess
import sys
import time

import psutil
from conftest import REPO, load_script


def test_sample_tree_counts_a_childs_memory():
    bench = load_script(REPO / "bench" / "bench_scale.py", "bench_scale")
    own = psutil.Process().memory_info().rss
    peak = bench.sample_tree(interval=0.02)
    # A child holding 300 MB (written, so resident) for a second, then gone.
    child = subprocess.run(
        [sys.executable, "-c", "import time; b = bytearray(300 * 2**20); b[::4096] = b'x' * len(b[::4096]); time.sleep(1)"],
        timeout=60,
    )  # fmt: skip
    assert child.returncode == 0
    time.sleep(0.1)
    assert peak[0] >= own + 250 * 2**20
    # The command's runner is valid Python that imports the sampler from the bench's folder.
    compile(bench.OURS, "<ours>", "exec")
