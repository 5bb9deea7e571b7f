"""Where a season's tasks run: this process when the work is small, else a Dask cluster.

:func:`choose_runner` estimates the work from the photos' headers; :func:`run_on_dask` submits one
task per image to a local cluster (:func:`local_cluster`), a scheduler or a given client. Dask is
imported only when it is used.
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

from .._dask import as_completed_results
from .._threads import usable_cores
from ..errors import CliffTerrainError
from .cache import Cache, cache_key, file_hash
from .task import OPENCV_THREADS, process_image

# What a season's tasks cost in one process, estimated before any work from the photos' headers:
# seconds per megapixel of photo (and DSM) decoded and resized, per megapixel of the processing grid
# (segmentation, domes, plot statistics) and per image. Fitted to the soybean season at 0.9 and 9 MP
# a date, max_size 1000 and 2000 (bench/bench_season.py --auto; 2-core Xeon VM).
TASK_S_PER_PHOTO_MP = 0.035


TASK_S_PER_GRID_MP = 0.15


TASK_S_PER_IMAGE = 0.02


# A local cluster pays only when its tasks would take longer than this in one process: it starts in
# 0.8-1.2 s, each worker then imports the pipeline, and 2 workers run the tasks at best 1.7x faster,
# so it loses below about 2.4 x 1.5 s (see docs/concepts/season.md for the measurements).
CLUSTER_PAYS_S = 4.0


@dataclasses.dataclass
class Work:
    """What a season's tasks will cost, estimated from the photos' headers (:func:`estimate_work`)."""

    images: int  # to compute (not in the cache)
    cached: int
    megapixels: float  # of the photos (and DSMs) to compute
    seconds: float  # estimated, in one process

    def describe(self):
        cached = f" ({self.cached} cached)" if self.cached else ""
        return (
            f"{self.images} image{'s' * (self.images != 1)}{cached}, {self.megapixels:.1f} MP of work "
            f"(about {self.seconds:.1f} s in one process)"
        )


def estimate_work(jobs):
    """Estimate the work of `jobs` (cache, plots hash and version set, as :func:`run_season` does).

    Reads only the photos' and DSMs' TIFF headers; an image already in the cache costs nothing (its
    photo is hashed only when the cache holds entries at all).

    Parameters
    ----------
    jobs : list of Job

    Returns
    -------
    Work
    """
    from ..io.raster.geotiff import raster_size

    cache = Cache(jobs[0].cache) if jobs else None
    hashing = cache is not None and cache.folder.is_dir() and any(cache.folder.glob("*.json"))
    images = cached = 0
    megapixels = seconds = 0.0
    for job in jobs:
        if hashing and cache.has(_job_key(job)):
            cached += 1
            continue
        rows, cols = raster_size(job.path)
        photo_mp = rows * cols / 1e6
        if job.dsm:
            dsm_rows, dsm_cols = raster_size(job.dsm)
            photo_mp += dsm_rows * dsm_cols / 1e6
        scale = min(1.0, job.params["max_size"] / max(rows, cols))
        grid_mp = rows * cols * scale * scale / 1e6
        images += 1
        megapixels += photo_mp
        seconds += TASK_S_PER_IMAGE + TASK_S_PER_PHOTO_MP * photo_mp + TASK_S_PER_GRID_MP * grid_mp
    return Work(images=images, cached=cached, megapixels=megapixels, seconds=seconds)


def _job_key(job):
    extra = [job.plots_hash] + ([file_hash(job.dsm)] if job.dsm else [])
    return cache_key(
        image_hash=file_hash(job.path), params=job.params, version=job.version, extra_hashes=extra
    )


def choose_runner(jobs, *, workers=None, scheduler=None, client=None):
    """Where the tasks run: ``(workers, runner, reason)``, `workers` 0 for this process.

    A given `client` or `scheduler`, or `workers`, decides; by default (all None) a local cluster of
    one worker per core starts only when the estimated work (:func:`estimate_work`) exceeds
    ``CLUSTER_PAYS_S`` on two cores or more, else the tasks run in this process.
    """
    if client is not None:
        return None, "the given Dask client", "a client was given"
    if scheduler is not None:
        return None, f"the Dask scheduler {scheduler}", "a scheduler was given"
    if workers == 0:
        return 0, "in-process", "workers=0 asked for it"
    if workers is not None:
        return workers, _cluster_name(workers), f"workers={workers} asked for it"
    cores = usable_cores()
    work = estimate_work(jobs)
    if cores < 2:
        return 0, "in-process", f"{work.describe()}; one usable core, so a cluster cannot run two at once"
    if work.images < 2:
        return 0, "in-process", f"{work.describe()}; nothing to share between workers"
    if work.seconds < CLUSTER_PAYS_S:
        return (
            0,
            "in-process",
            f"{work.describe()}, under the {CLUSTER_PAYS_S:g} s a local cluster needs to pay off",
        )
    return (
        cores,
        _cluster_name(cores),
        f"{work.describe()}, over the {CLUSTER_PAYS_S:g} s a local cluster needs to pay off",
    )


def _cluster_name(workers):
    return f"local cluster, {workers} worker{'s' * (workers != 1)}"


def run_on_dask(jobs, finished, *, workers, scheduler, timeout, memory_limit, client=None, security=None):
    """Submit one task per image and hand each result to `finished(index, result)` as it arrives.

    A given `client` is used as it is and left open (its owner closes it).
    """
    if client is not None:
        _submit(client, jobs, finished)
        return
    with dask_client(
        workers=workers, scheduler=scheduler, timeout=timeout, memory_limit=memory_limit, security=security
    ) as client:
        _submit(client, jobs, finished)


@contextlib.contextmanager
def dask_client(*, workers=None, scheduler=None, timeout=10.0, memory_limit="auto", security=None):
    """A ``distributed.Client`` of the scheduler at `scheduler` (with `security`), or of a local
    cluster of `workers` processes (:func:`local_cluster`; default one per usable core), closed
    with the cluster on leaving.

    Raises
    ------
    CliffTerrainError
        Dask is not installed, the scheduler cannot be reached within `timeout` seconds, or
        `memory_limit` is not a size.
    """
    try:
        from distributed import Client
    except ImportError:
        raise CliffTerrainError(
            "Dask is not installed: pip install 'cliff-terrain[season]' (from a checkout of the repository: "
            "pip install '.[season]'), or run in this process with --workers 0"
        ) from None
    cluster = None
    try:
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout=timeout, set_as_default=False, security=security)
            except (OSError, TimeoutError) as exc:
                raise CliffTerrainError(
                    f"cannot reach the Dask scheduler `{scheduler}` within {timeout:g} s ({type(exc).__name__})"
                ) from None
        else:
            n = workers if workers is not None else usable_cores()
            if memory_limit != "auto":
                from dask.utils import parse_bytes

                try:
                    parse_bytes(memory_limit)
                except (ValueError, TypeError):
                    raise CliffTerrainError(
                        f"`memory_limit` must be a size such as 2GiB or 'auto', got {memory_limit!r}"
                    ) from None
            with _workers_ignore_ctrl_c():
                cluster = local_cluster(n, memory_limit=memory_limit)
                # Connected while Ctrl-C is still ignored: one pressed between the cluster's start
                # and the client's left a half-made client, whose close at exit waited 60 s for a
                # loop already gone and printed a traceback after "interrupted".
                client = Client(cluster, set_as_default=False)
        with client:
            try:
                yield client
            finally:
                if cluster is not None:
                    # Before the cluster closes, after success or an error alike: its workers may
                    # still send a heartbeat once the scheduler has let them go, and log a traceback
                    # for it (dask/distributed#7105). Suppressed: it never masks the run's own error.
                    with contextlib.suppress(Exception):
                        client.run(_quiet_heartbeat_failures, on_error="ignore")
    finally:
        if cluster is not None:
            cluster.close()


def _not_a_heartbeat_failure(record):
    """A logging filter: drop the worker's "failed to communicate during heartbeat" traceback."""
    return not record.getMessage().startswith("Failed to communicate with scheduler during heartbeat")


def _quiet_heartbeat_failures():
    """Run on each worker of a local cluster that is about to close, where a failed heartbeat is
    the expected end of a worker and not an error the user should see on stderr."""
    import logging

    logging.getLogger("distributed.worker").addFilter(_not_a_heartbeat_failure)


def _submit(client, jobs, finished):
    """One task per job on `client`, under names of this run only; results to `finished` as they come."""
    payloads = ((Path(job.path).name, job.as_dict()) for job in jobs)
    as_completed_results(client, process_image, payloads, finished, prefix="season")


def local_cluster(workers, *, memory_limit="auto"):
    """A ``distributed.LocalCluster`` of `workers` single-threaded processes on loopback, for a season.

    Three settings differ from Dask's defaults, all measured on the soybean season
    (``bench/bench_season.py``):

    - glibc's trimming stays at its default. Dask sets ``MALLOC_TRIM_THRESHOLD_=65536`` in new
      workers, which also turns off glibc's adaptive mmap threshold, so every array above 128 KiB
      comes from fresh pages; a task then takes 0.12 s instead of 0.09 s. A task's memory is
      bounded (about 170 MB a worker), so there is little to give back.
    - Dask's statistical profiler is off. Every 10 ms it walks the running task's stack while
      holding the GIL, for the dashboard's profile page, which this cluster does not serve: with
      it the 7 soybean dates ran 1.62-1.70x faster than serially, without it 1.74-1.77x.
    - OpenCV gets two threads per worker (see :func:`exact_opencv`), not one per core each.
    """
    import dask
    from distributed import LocalCluster

    config = {
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        "distributed.worker.profile.enabled": False,
    }
    from distributed.gc import disable_gc_diagnosis

    with dask.config.set(config), _workers_ignore_ctrl_c():
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            memory_limit=memory_limit,
            dashboard_address=None,
            host="127.0.0.1",
            env={OPENCV_THREADS: "2"},
        )
    # The scheduler, in this process, hooks a diagnosis into every garbage collection (it logs long
    # pauses, which nobody here reads): a Ctrl-C that lands in that hook is printed as "Exception
    # ignored" and lost, and the run went on to finish (the Ctrl-C test saw it once).
    disable_gc_diagnosis(force=True)
    return cluster


@contextlib.contextmanager
def _workers_ignore_ctrl_c():
    """Start the workers with Ctrl-C ignored: a terminal's Ctrl-C reaches every process of its group,
    and each worker printed its KeyboardInterrupt traceback (67 lines on stderr) before this process
    said "interrupted". A process started with SIGINT ignored keeps ignoring it (Python installs its
    KeyboardInterrupt handler only when SIGINT was not ignored); this process closes the cluster."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
