"""This process's peak resident memory, for reports (the season's table, benchmarks, tests)."""

from __future__ import annotations

import sys


def peak_rss():
    """This process's own peak resident set size in bytes, or None where it cannot be read.

    On Linux it is ``VmHWM`` of ``/proc/self/status``: ``getrusage``'s ``ru_maxrss`` carries the
    parent's peak over fork and exec, so a worker or a script started from a large process (a
    test runner, a benchmark driver) would report its parent's peak instead of its own.
    """
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmHWM:"))
    except (OSError, StopIteration, ValueError):
        pass
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024
