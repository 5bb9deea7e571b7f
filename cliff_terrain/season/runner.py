"""A season of flights: one image is one task, results cached, one tidy table at the end.

:func:`cliff_terrain.season.plan.plan_season` lists the jobs; :func:`run_season` computes what the
cache lacks (in this process when the work is small, else on Dask:
:mod:`cliff_terrain.season.cluster`), aligns the dates, and writes ``season.csv``, ``season.json``
(what the Blender animation reads) and ``growth.png``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from contextlib import ExitStack
from pathlib import Path

from .._progress import count_bar
from .._validate import check_float, check_int
from ..errors import CliffTerrainError
from ..io.raster.crs import crs_record
from ..measure.tables import write_files
from .cache import file_hash
from .cluster import choose_runner, run_on_dask
from .table import chart_rows, date_record, plot_rows, season_columns, season_csv
from .task import aligned_result, process_image


@dataclasses.dataclass
class Season:
    """What :func:`run_season` did."""

    rows: list
    failures: list  # (image, error)
    computed: int
    cached: int
    out: Path
    seconds: float
    worker_peaks: dict = dataclasses.field(default_factory=dict)  # worker -> peak RSS bytes
    dates: list = dataclasses.field(default_factory=list)  # season.json's date records
    removed: list = dataclasses.field(default_factory=list)  # the stale traits removed (paths)
    runner: str = ""  # where the tasks ran: "in-process", "local cluster, 2 workers", ...
    runner_reason: str = ""  # why there (the estimate of the work, or the setting that forced it)

    @property
    def table(self):
        return self.out / "season.csv"


def run_season(
    jobs,
    plot_set,
    *,
    out,
    workers=None,
    scheduler=None,
    security=None,
    client=None,
    timeout=10.0,
    memory_limit="auto",
    progress=True,
    chart=True,
    color_by=None,
    align=True,
):
    """Compute the jobs the cache lacks and write ``season.csv``, ``season.json`` and ``growth.png``.

    Parameters
    ----------
    jobs, plot_set
        From :func:`plan_season`.
    out : str or os.PathLike
        Output folder; its ``cache/`` holds one entry per computed image.
    workers : int, optional
        Local worker processes, 0 to run serially in this process; None (the default) runs in this
        process when the work is small and on a cluster of one worker per core when it pays
        (:func:`choose_runner`). The choice is in ``Season.runner`` and ``season.json``.
    scheduler : str, optional
        Address of an existing ``dask.distributed`` scheduler (wins over `workers`).
    security : distributed.security.Security, optional
        TLS credentials for a ``tls://`` `scheduler`
        (:func:`cliff_terrain.season.security.scheduler_security`).
    client : distributed.Client, optional
        A connected client (a notebook's, say) to run on, left open; wins over `scheduler`.
    timeout : float, optional
        Seconds to wait for `scheduler` before giving up.
    memory_limit : str or int, optional
        Per local worker (Dask's syntax, e.g. ``"2GiB"``; ``"auto"`` shares the machine's memory).
    progress : bool, optional
        Draw a progress bar (tqdm's, with its ETA) on stderr when it is a terminal.
    chart : bool, optional
        Draw ``growth.png`` (needs matplotlib).
    color_by : str, optional
        Plot attribute that colours the chart's lines.
    align : bool, optional
        Measure each date's shift against the season's consensus georeference and read its plots
        where its pixels show them (:func:`cliff_terrain.season.align.season_shifts`); recorded in
        ``season.json`` as ``shift_px`` ([rows, cols] of the date's photo pixels), ``shift_m`` and
        ``align_score``.

    Returns
    -------
    Season
    """
    from .. import __version__

    started = time.perf_counter()
    out = Path(out)
    if color_by is not None and color_by not in plot_set.fields:
        raise CliffTerrainError(
            f"`color_by` must be one of the plots' attributes ({', '.join(plot_set.fields)}), got {color_by!r}"
        )
    if workers is not None:
        workers = check_int("workers", workers, minimum=0)
    if client is not None and not callable(getattr(client, "submit", None)):
        raise CliffTerrainError(f"`client` must be a distributed.Client, got {client!r}")
    timeout = check_float("timeout", timeout, minimum=0.0, strict_minimum=True)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliffTerrainError(f"cannot create `out` {str(out)!r}: {exc}") from None
    cache_dir = (out / "cache").resolve()
    plots_hash = file_hash(jobs[0].plots) if jobs else ""
    for job in jobs:
        job.cache, job.plots_hash, job.version = str(cache_dir), plots_hash, __version__
    workers, runner, reason = choose_runner(jobs, workers=workers, scheduler=scheduler, client=client)
    in_process = client is None and scheduler is None and workers == 0
    aligning = None
    if align and len(jobs) > 1:
        from concurrent.futures import ThreadPoolExecutor

        from .align import season_shifts

        # The tasks need no shift (reliefs are cached unshifted): beside a cluster, the dates are
        # aligned here while it starts and computes; in this process, first.
        with ThreadPoolExecutor(1) as pool:
            aligning = pool.submit(season_shifts, [job.path for job in jobs])
            if in_process:
                _set_shifts(jobs, aligning.result())
                aligning = None
            else:
                pool.shutdown(wait=False)
    stack = ExitStack()
    step = stack.enter_context(count_bar("season", len(jobs), enabled=progress))
    results = {}
    peaks = {}

    def finished(index, result):
        if result.get("ok") and not result.get("cached"):
            peaks[result["worker"]] = max(peaks.get(result["worker"], 0), result["peak_rss"] or 0)
        results[index] = result
        step(Path(jobs[index].path).name, ok=result.get("ok", False))

    with stack:  # the bar closes however the jobs end (an error, Ctrl-C)
        if in_process:
            for index, job in enumerate(jobs):
                finished(index, process_image(job.as_dict()))
        elif jobs:
            try:
                run_on_dask(
                    jobs,
                    finished,
                    workers=workers,
                    scheduler=scheduler,
                    security=security,
                    timeout=timeout,
                    memory_limit=memory_limit,
                    client=client,
                )
            finally:
                if aligning is not None:
                    _set_shifts(jobs, aligning.result())

    rows, failures, dates = [], [], []
    for index, job in enumerate(jobs):
        result = results.get(index) or {"ok": False, "error": "no result (the task was lost)", "key": None}
        if result["ok"] and job.shift is not None:
            result = aligned_result(job, result, plot_set)
        if not result["ok"]:
            failures.append((job.path, result["error"]))
        rows.extend(plot_rows(job, result, plot_set))
        dates.append(date_record(job, result, out))
    _flag_shifts(dates, plot_set)
    columns = season_columns(plot_set, jobs[0].indices if jobs else ())
    table = season_csv(rows, columns)
    manifest = {
        "version": __version__,
        "plots": jobs[0].plots if jobs else None,
        "crs": crs_record(plot_set.crs),
        "params": jobs[0].params if jobs else {},
        "color_by": color_by,
        "runner": {"runner": runner, "reason": reason},
        "dates": dates,
    }
    # Written whole or not at all (temporary names, then renamed, season.json last: the marker of a
    # finished season): a kill leaves no half file and no table beside another run's record.
    files = {out / "season.csv": table}
    if chart:
        from .charts import growth_chart

        files[out / "growth.png"] = lambda tmp: growth_chart(chart_rows(rows), tmp, color_by=color_by)
    files[out / "season.json"] = json.dumps(manifest, indent=2) + "\n"
    stale = _stale_traits(out, table)
    write_files(files, remove=stale)
    cached = sum(1 for r in results.values() if r.get("cached"))
    return Season(
        rows=rows,
        failures=failures,
        computed=len(jobs) - cached,
        cached=cached,
        out=out,
        seconds=time.perf_counter() - started,
        worker_peaks=peaks,
        dates=dates,
        runner=runner,
        runner_reason=reason,
        removed=stale,
    )


def _stale_traits(out, table):
    """The default traits folder's outputs (``out/traits``), fitted on the season this run replaces:
    removed when the table changes (other dates, plots or settings), kept when it is the same."""
    from ..measure.tables import previous_outputs
    from .traits import TRAITS_OUTPUTS

    old = out / "season.csv"
    try:  # bytes: a table saved again in another encoding has changed too
        if old.read_bytes() == table.encode("utf-8"):
            return []
    except OSError:
        return []
    return previous_outputs(out / "traits", TRAITS_OUTPUTS, markers=TRAITS_OUTPUTS[-2:])


def _set_shifts(jobs, found):
    for job, date in zip(jobs, found, strict=True):
        job.shift, job.align_score = [float(v) for v in date["shift"]], date["score"]


def _flag_shifts(dates, plot_set):
    """Flag dates shifted by more than a quarter of the smallest plot width: their plots may have been
    read beside themselves had the shift not been corrected, and a shift that large is worth a look
    (a wrong georeference, or a field that changed too much to compare)."""
    from .align import MIN_SCORE, smallest_plot_width

    limit = 0.25 * smallest_plot_width(plot_set)
    for record in dates:
        if record.get("align_score") is not None and record["align_score"] < MIN_SCORE:
            record["shift_flag"] = (
                f"not aligned: too little in common with the other dates (correlation "
                f"{record['align_score']:.2f} < {MIN_SCORE})"
            )
        elif record.get("shift_m") is not None and record["shift_m"] > limit:
            record["shift_flag"] = (
                f"shifted {record['shift_m']:.3f} m from the reference date, more than a quarter of the "
                f"smallest plot width ({limit:.3f} m)"
            )
