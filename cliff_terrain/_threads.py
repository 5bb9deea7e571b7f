"""Work on bands of rows, on threads: numpy's and OpenCV's kernels release the GIL.

Bands of a few hundred thousand pixels stay in the cache between the steps of a chain of
array operations (each step over a whole 20 MP image would stream it from memory again).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

MAX_THREADS = 4


def usable_cores():
    """The cores this process may run on (its affinity where the OS tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def map_row_bands(function, rows, band):
    """Call ``function(r0, r1)`` for every band [r0, r1) of `band` rows covering ``range(rows)``.

    The bands run on up to :data:`MAX_THREADS` threads (one call when there is a single band);
    `function` writes its own rows of a shared output. Exceptions are raised here.
    """
    band = max(1, int(band))
    starts = range(0, int(rows), band)
    threads = min(MAX_THREADS, usable_cores(), len(starts))
    if threads <= 1:
        for r0 in starts:
            function(r0, min(rows, r0 + band))
        return
    with ThreadPoolExecutor(threads, thread_name_prefix="cliff_terrain_bands") as pool:
        for job in [pool.submit(function, r0, min(rows, r0 + band)) for r0 in starts]:
            job.result()
