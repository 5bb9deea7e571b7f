"""The machine a benchmark ran on, printed beside its figures (ratios only mean something with it)."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def machine():
    """CPU model, cores (all and usable), 1-minute load average, OS and Python."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "loadavg_1min": load,
        "system": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
    }


def describe(info=None):
    """One line for a report."""
    info = machine() if info is None else info
    return (
        f"{info['cpu']}, {info['cores']} cores, load {info['loadavg_1min']:.2f}, "
        f"{info['system']}, Python {info['python']}"
    )
