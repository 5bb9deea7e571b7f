"""Progress bars of the commands (heights, relief, plots, season): tqdm's, on stderr, only on a terminal.

tqdm (the ``progress`` extra; command line only, never imported by the extension) draws the bar
with its ETA. Without a terminal (a pipe, a log file, a test) or with ``--no-progress`` there is no
bar, so stderr holds only the one-line error; without tqdm installed there is no bar either. The bar
is removed when the command ends (``leave=False``): the terminal keeps the summary line only.
"""

from __future__ import annotations

import shutil
import sys
import time
from contextlib import contextmanager


def add_progress_argument(parser):
    parser.add_argument(
        "--no-progress", action="store_true", help="no progress bar (drawn only on a terminal)"
    )


def _tqdm(enabled):
    if not enabled or not sys.stderr.isatty():
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # the optional extra is not installed: no bar
        return None
    return tqdm


def _columns():
    # A terminal that reports no size (a fresh pseudo-terminal) would get an empty bar from tqdm.
    return shutil.get_terminal_size(fallback=(80, 24)).columns


@contextmanager
def stage_bar(label, *, enabled=True):
    """A bar over one job's stages: yields ``progress(fraction, stage)`` (as
    :func:`cliff_terrain.build.build_relief` calls it), or None when there is no bar."""
    tqdm = _tqdm(enabled)
    if tqdm is None:
        yield None
        return
    bar = tqdm(
        total=100,
        desc=label,
        file=sys.stderr,
        leave=False,
        ncols=_columns(),
        bar_format="{desc} {percentage:3.0f}%|{bar}| {elapsed}<{remaining}{postfix}",
    )

    def progress(fraction, stage):
        bar.n = min(100, round(100 * fraction))
        bar.set_postfix_str(stage, refresh=False)
        bar.refresh()

    try:
        yield progress
    finally:
        bar.close()


@contextmanager
def count_bar(label, total, *, enabled=True, unit="images"):
    """A bar over `total` items: yields ``step(name, ok)``, which does nothing without a bar."""
    tqdm = _tqdm(enabled and total > 0)
    if tqdm is None:
        yield lambda name, ok=True: None
        return
    bar = tqdm(total=total, desc=label, unit=f" {unit}", file=sys.stderr, leave=False, ncols=_columns())
    failed = 0

    def step(name, ok=True):
        nonlocal failed
        failed += not ok
        bar.set_postfix_str(f"{name}{f', {failed} failed' if failed else ''}", refresh=False)
        bar.update(1)

    try:
        yield step
    finally:
        bar.close()


class StageClock:
    """Times a run's stages into `timings` (``{stage: seconds}``) and reports ``progress(fraction,
    stage)`` as each one starts (when given a fraction); ``start(None)`` ends the last. With `digits`, the seconds are
    rounded (for a summary file). The build's stages and the windowed heights' share it.

    Examples
    --------
    >>> timings = {}
    >>> clock = StageClock(None, timings, digits=1)
    >>> clock.start("load"); clock.start("mesh"); clock.start(None)
    >>> sorted(timings), timings["load"] >= 0.0
    (['load', 'mesh'], True)
    """

    def __init__(self, progress, timings, *, digits=None):
        self.progress = progress
        self.timings = timings
        self.digits = digits
        self.stage = None
        self.t0 = time.perf_counter()

    def start(self, stage, fraction=None):
        now = time.perf_counter()
        if self.stage is not None:
            elapsed = now - self.t0
            self.timings[self.stage] = elapsed if self.digits is None else round(elapsed, self.digits)
        self.stage, self.t0 = stage, now
        if self.progress is not None and fraction is not None:
            self.progress(fraction, stage or "done")
