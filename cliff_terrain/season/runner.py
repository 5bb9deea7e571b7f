"""A season of flights on Dask: one image is one task, results cached, one tidy table at the end.

:func:`plan_season` checks everything it can before any work (files, dates, CRS, plots), so bad
input is one error at once. :func:`run_season` then computes what the cache lacks, serially
(``workers=0``), on a local cluster of worker processes, or on an existing ``dask.distributed``
scheduler, and writes ``season.csv``, ``season.json`` (what the Blender animation reads) and
``growth.png``. Dask is imported only when it is used.

Each task hashes its photo, looks it up in the cache and writes the entry it computes, so the
workers need Cliff Terrain importable and the photos, DSMs, plots file and output folder at the
same paths (a shared file system); only the table rows come back to this process.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import platform
import sys
import time
import uuid
from pathlib import Path

from .. import settings
from .._memory import peak_rss
from .._validate import check_choice, check_float, check_int
from ..errors import CliffTerrainError
from .cache import Cache, cache_key, file_hash
from .dates import photo_date

# Read by OpenCV when it is imported: the number of threads of its pool.
OPENCV_THREADS = "OPENCV_FOR_THREADS_NUM"
IMAGE_SUFFIXES = (".tif", ".tiff", ".jpg", ".jpeg", ".png", ".webp")
# The table's columns; the plots' attributes go between `plot` and `area_m2`.
LEAD_COLUMNS = ("date", "date_source", "image", "plot")
VALUE_COLUMNS = (
    "area_m2",
    "cover",
    "volume_m3",
    "height_mean",
    "height_p50",
    "height_p90",
    "height_max",
    "height_mode",
    "height_units",
    "reason",
    "error",
)
# plot_table's keys for the value columns above.
_FROM_TABLE = {
    "area_m2": "area_m2",
    "cover": "cover",
    "volume_m3": "volume_m3",
    "height_mean": "height_mean_m",
    "height_p50": "height_p50_m",
    "height_p90": "height_p90_m",
    "height_max": "height_max_m",
    "reason": "error",  # plot_table's why a plot has no or partial figures ("" when whole)
}


@dataclasses.dataclass
class Job:
    """One image of the season: what a worker needs to compute it."""

    path: str
    date: str
    date_source: str
    plots: str
    params: dict
    dsm: str | None = None
    shift: list | None = (
        None  # map (x, y) metres of its content from the season's consensus (None: not aligned)
    )
    align_score: float | None = None
    cache: str = ""  # the cache folder (set by run_season)
    plots_hash: str = ""
    version: str = ""

    def as_dict(self):
        return dataclasses.asdict(self)


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

    @property
    def table(self):
        return self.out / "season.csv"


def find_images(inputs):
    """Files and folders (their image files, not recursive) to a sorted list of unique paths."""
    found = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
            if not files:
                raise CliffTerrainError(
                    f"no images in folder {str(path)!r} (looked for {', '.join(IMAGE_SUFFIXES)})"
                )
            found.extend(files)
        elif path.is_file():
            found.append(path)
        else:
            raise CliffTerrainError(f"input {str(path)!r} is neither a file nor a folder")
    if not found:
        raise CliffTerrainError("no input images given")
    unique = sorted({p.resolve() for p in found})
    return [str(p) for p in unique]


def pair_dsm(images, dsm):
    """Each image's DSM: `dsm` is a file (one image), a folder, or a pattern with ``{stem}``.

    A folder is searched for a file holding the image's date or stem, e.g. ``20180815_dsm.tif``.
    """
    if dsm is None:
        return {image: None for image in images}
    text = str(dsm)
    pairs = {}
    for image in images:
        stem = Path(image).stem
        if "{stem}" in text:
            candidate = Path(text.format(stem=stem))
        elif Path(text).is_dir():
            candidate = _dsm_in_folder(Path(text), Path(image))
        elif len(images) == 1:
            candidate = Path(text)
        else:
            raise CliffTerrainError(
                f"`--dsm` must be a folder or a pattern with {{stem}} for {len(images)} images, got {text!r}"
            )
        if candidate is None or not candidate.is_file():
            raise CliffTerrainError(f"no DSM for {image!r} (`--dsm` {text!r})")
        pairs[image] = str(candidate)
    return pairs


def _dsm_in_folder(folder, image):
    from .dates import date_in_name

    date = date_in_name(image.name)
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in (".tif", ".tiff") or path.resolve() == image.resolve():
            continue
        if image.stem in path.stem or (date is not None and date_in_name(path.name) == date):
            return path
    return None


def plan_season(
    inputs,
    *,
    plots,
    dates=None,
    dsm=None,
    max_size=settings.DEFAULT_MAX_SIZE,
    segmentation=settings.DEFAULT_SEGMENTATION,
    profile=settings.DEFAULT_PROFILE,
    exaggeration=settings.DEFAULT_EXAGGERATION,
    heights=None,
):
    """Check the inputs and list the season's jobs, sorted by date.

    Parameters
    ----------
    inputs : list of str or os.PathLike
        Photos, or folders of photos.
    plots : str or os.PathLike
        The plot polygons (GeoJSON), in the photos' CRS.
    dates : dict, optional
        ``{file name or path: datetime.date}`` for photos whose file holds no date.
    dsm : str, optional
        Surface models: see :func:`pair_dsm`.
    max_size, segmentation, profile, exaggeration
        As for :func:`cliff_terrain.build_relief`.
    heights : {"inflated", "calibrated", "measured"}, optional
        As for :func:`cliff_terrain.build_relief`: "measured" (the default with `dsm`) and
        "calibrated" need `dsm`; "inflated" is the only mode without one.
    Returns
    -------
    jobs : list of Job
    plot_set : PlotSet

    Raises
    ------
    CliffTerrainError
        For a missing file, a photo without a date, two photos of one date, or a photo whose CRS
        differs from the plots'.
    """
    from ..georaster import read_georeference
    from ..plots import check_plot_crs, read_plots

    params = {
        "max_size": check_int("max_size", max_size, minimum=settings.MIN_SIZE, maximum=settings.MAX_SIZE),
        "segmentation": check_choice("segmentation", segmentation, settings.ids(settings.SEGMENTATIONS)),
        "profile": check_choice("profile", profile, settings.ids(settings.PROFILES)),
        "exaggeration": check_float("exaggeration", exaggeration, minimum=0.0, strict_minimum=True),
        "heights": check_choice(
            "heights",
            heights or ("inflated" if dsm is None else "measured"),
            settings.ids(settings.HEIGHT_MODES),
        ),
    }
    if dsm is None and params["heights"] != "inflated":
        raise CliffTerrainError(f"`heights` {params['heights']!r} needs `dsm` (surface models), got None")
    plot_set = read_plots(plots)
    images = find_images(inputs)
    dsms = pair_dsm(images, dsm)
    jobs, seen = [], {}
    for image in images:
        date, source = photo_date(image, given=dates)
        if date in seen:
            raise CliffTerrainError(
                f"two photos of {date.isoformat()}: {seen[date]!r} and {image!r}; a season has one "
                "orthophoto per date (mosaic the tiles of one flight first)"
            )
        seen[date] = image
        _, crs = read_georeference(image)
        check_plot_crs(plot_set, crs, raster=image)
        jobs.append(
            Job(
                path=image,
                date=date.isoformat(),
                date_source=source,
                plots=str(Path(plots).resolve()),
                params=params,
                dsm=dsms[image],
            )
        )
    jobs.sort(key=lambda job: job.date)
    return jobs, plot_set


def process_image(job):
    """One task (on a worker, or in this process): an image's cache entry, computed if missing.

    The task hashes the photo (and its DSM), looks its key up in the cache folder and, if the entry
    is missing, builds the relief, computes the plots' statistics and writes the entry itself, so
    neither the hashing nor the height grids pass through the client. It returns the entry's
    record (table rows, grid, timings) with ``key`` and ``cached``.

    Never raises: a failure comes back as ``{"ok": False, "error": ...}`` so the others go on; it
    is not cached, so the next run tries that image again.
    """
    started = time.perf_counter()
    cpu = time.process_time()
    key = None
    try:
        extra = [job["plots_hash"]] + ([file_hash(job["dsm"])] if job.get("dsm") else [])
        key = cache_key(
            image_hash=file_hash(job["path"]),
            params=job["params"],
            version=job["version"],
            extra_hashes=extra,
        )
        cache = Cache(job["cache"])
        record = cache.load_record(key) if cache.has(key) else None
        if record is not None:
            return {**record, "key": key, "cached": True}
        _exact_opencv()
        record = _process(job)
        arrays = record.pop("arrays")
        record.update(
            ok=True,
            seconds=time.perf_counter() - started,
            cpu_seconds=time.process_time() - cpu,
            peak_rss=peak_rss(),
            worker=f"{platform.node()}:{os.getpid()}",
        )
        cache.store(key, record, arrays)
    except Exception as exc:  # a task's failure is its image's rows, not the run's end
        message = str(exc) or type(exc).__name__
        error = f"{type(exc).__name__}: {message}".replace("\n", " ")
        return {"ok": False, "error": error, "key": key, "cached": False}
    return {**record, "key": key, "cached": False}


def _exact_opencv():
    """Give OpenCV at least two threads in this process (a worker, or a serial run).

    OpenCV 4.11's precise distance transform (the relief's domes) is exact, equal to SciPy's
    Euclidean distance transform, when its thread pool has two threads or more; on one thread it
    is off by up to 8e-6 pixel in a way that changes with the heap, so a worker with one core would
    not write the table a laptop writes. Measured in tests/test_season.py.
    """
    import cv2

    if cv2.getNumThreads() < 2:
        cv2.setNumThreads(2)


def _process(job):
    import numpy as np

    from ..georaster import read_georeference
    from ..pipeline import build_relief

    params = job["params"]
    photo_transform, crs = read_georeference(job["path"])
    surface = {"dsm": job["dsm"], "heights": params["heights"]} if job.get("dsm") else {}
    relief = build_relief(
        job["path"],
        max_size=params["max_size"],
        segmentation=params["segmentation"],
        profile=params["profile"],
        exaggeration=params["exaggeration"],
        gsd=float(np.hypot(*photo_transform[:2, 0])),
        mesh=None,  # the table needs the heights only
        **surface,
    )
    shape = relief.heights.shape
    # The processing grid resamples the photo's pixels: its pixels are larger by these factors.
    meta = relief.metadata
    transform = photo_transform @ np.diag([meta.width / shape[1], meta.height / shape[0], 1.0])
    table = _table(_plots(job["plots"]), transform, relief.mask, relief.heights, relief.units)
    return {
        "table": [_plain(row) for row in table],
        "height_mode": params["heights"],
        "height_units": relief.units,
        "grid": {"transform": transform[:2].tolist(), "shape": list(shape), "crs": crs},
        "arrays": {
            "heights": np.ascontiguousarray(relief.heights, dtype=np.float32),
            "mask": np.packbits(relief.mask, axis=None),
        },
    }


def _table(plot_set, transform, mask, heights, units):
    """The plots' rows of one date: its grid (`transform`: pixel -> map), plant mask and heights."""
    import numpy as np

    from ..plots import plot_table, rasterize_plots

    labels = rasterize_plots(plot_set, transform=transform, shape=mask.shape)
    rows = plot_table(
        plot_set,
        labels,
        mask=mask,
        heights=heights,
        pixel_area_m2=float(abs(np.linalg.det(np.asarray(transform)[:2, :2]))),
        height_units=units,
    )
    return [_plain(row) for row in rows]


def aligned_result(job, result, plot_set):
    """A date's result read where its pixels show the plots: its content lies ``job.shift`` (map
    metres) from where the season's consensus puts it, so its grid's pixel q shows map(q) - shift.

    The table is taken again from the cached grid (the relief does not depend on the shift, so a
    season that gains a date recomputes no relief, only these tables).
    """
    import numpy as np

    from ..georaster import read_georeference

    dx, dy = job.shift
    grid = result["grid"]
    transform = np.vstack([np.asarray(grid["transform"], dtype=np.float64), [0.0, 0.0, 1.0]])
    aligned = np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]]) @ transform
    arrays = Cache(job.cache).load_arrays(result["key"])
    mask = (
        np.unpackbits(arrays["mask"], count=int(np.prod(grid["shape"]))).reshape(grid["shape"]).astype(bool)
    )
    photo_transform, _ = read_georeference(job.path)
    cols, rows = np.linalg.solve(photo_transform[:2, :2], [dx, dy])
    return {
        **result,
        "table": _table(plot_set, aligned, mask, arrays["heights"], result["height_units"]),
        "grid": {**grid, "transform": aligned[:2].tolist()},
        "align": {
            "shift_px": [round(float(rows), 3), round(float(cols), 3)],
            "shift_m": round(float(np.hypot(dx, dy)), 4),
            "align_score": round(float(job.align_score), 3),
        },
    }


_PLOTS = {}


def _plots(path):
    """The plots, read once per worker process."""
    if path not in _PLOTS:
        from ..plots import read_plots

        _PLOTS[path] = read_plots(path)
    return _PLOTS[path]


def _plain(value):
    """numpy scalars and tuples to JSON's types (the rows travel and are cached as JSON)."""
    import numpy as np

    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# ---- running ----


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
        Local worker processes: None for one per core, 0 to run serially in this process.
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
        Draw a progress bar on stderr.
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
    if align and len(jobs) > 1:
        from .align import season_shifts

        for job, found in zip(jobs, season_shifts([job.path for job in jobs]), strict=True):
            job.shift, job.align_score = [float(v) for v in found["shift"]], found["score"]
    bar = _Bar(len(jobs), enabled=progress)
    results = {}
    peaks = {}

    def finished(index, result):
        if result.get("ok") and not result.get("cached"):
            peaks[result["worker"]] = max(peaks.get(result["worker"], 0), result["peak_rss"] or 0)
        results[index] = result
        bar.step(Path(jobs[index].path).name, ok=result.get("ok", False))

    if client is None and scheduler is None and workers == 0:
        for index, job in enumerate(jobs):
            finished(index, process_image(job.as_dict()))
    elif jobs:
        _run_on_dask(
            jobs,
            finished,
            workers=workers,
            scheduler=scheduler,
            security=security,
            timeout=timeout,
            memory_limit=memory_limit,
            client=client,
        )
    bar.close()

    rows, failures, dates = [], [], []
    for index, job in enumerate(jobs):
        result = results.get(index) or {"ok": False, "error": "no result (the task was lost)", "key": None}
        if result["ok"] and job.shift is not None:
            result = aligned_result(job, result, plot_set)
        if not result["ok"]:
            failures.append((job.path, result["error"]))
        rows.extend(_rows(job, result, plot_set))
        dates.append(_date_record(job, result, out))
    _flag_shifts(dates, plot_set)
    columns = _columns(plot_set)
    _write_csv(out / "season.csv", rows, columns)
    manifest = {
        "version": __version__,
        "plots": jobs[0].plots if jobs else None,
        "crs": plot_set.crs,
        "params": jobs[0].params if jobs else {},
        "color_by": color_by,
        "dates": dates,
    }
    (out / "season.json").write_text(json.dumps(manifest, indent=2) + "\n")
    if chart:
        from .charts import growth_chart

        growth_chart(_typed(rows), out / "growth.png", color_by=color_by)
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
    )


def _run_on_dask(jobs, finished, *, workers, scheduler, timeout, memory_limit, client=None, security=None):
    """Submit one task per image and hand each result to `finished(index, result)` as it arrives.

    A given `client` is used as it is and left open (its owner closes it).
    """
    try:
        from distributed import Client
    except ImportError:
        raise CliffTerrainError(
            "Dask is not installed: pip install 'cliff-terrain[season]', or run serially with --workers 0"
        ) from None
    cluster = None
    try:
        if client is not None:
            _submit(client, jobs, finished)
            return
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout=timeout, set_as_default=False, security=security)
            except (OSError, TimeoutError) as exc:
                raise CliffTerrainError(
                    f"cannot reach the Dask scheduler `{scheduler}` within {timeout:g} s ({type(exc).__name__})"
                ) from None
        else:
            n = workers if workers is not None else _usable_cores()
            if memory_limit != "auto":
                from dask.utils import parse_bytes

                try:
                    parse_bytes(memory_limit)
                except (ValueError, TypeError):
                    raise CliffTerrainError(
                        f"`memory_limit` must be a size such as 2GiB or 'auto', got {memory_limit!r}"
                    ) from None
            cluster = local_cluster(n, memory_limit=memory_limit)
            client = Client(cluster, set_as_default=False)
        with client:
            _submit(client, jobs, finished)
    finally:
        if cluster is not None:
            cluster.close()


def _submit(client, jobs, finished):
    """One task per job on `client`, under names of this run only; results to `finished` as they come."""
    from distributed import as_completed

    futures = {}
    run = uuid.uuid4().hex[:8]  # task names of this run only, whoever else uses the scheduler
    for index, job in enumerate(jobs):
        name = f"season-{run}-{index}-{Path(job.path).name}"
        futures[client.submit(process_image, job.as_dict(), key=name, pure=False)] = index
    for future in as_completed(futures, loop=client.loop):
        try:
            result = future.result()
        except Exception as exc:  # the worker died (memory limit) or the task was lost
            result = {"ok": False, "error": f"{type(exc).__name__}: {exc}".replace("\n", " ")}
        finished(futures[future], result)


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
    - OpenCV gets two threads per worker (see :func:`_exact_opencv`), not one per core each.
    """
    import dask
    from distributed import LocalCluster

    config = {
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        "distributed.worker.profile.enabled": False,
    }
    with dask.config.set(config):
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            memory_limit=memory_limit,
            dashboard_address=None,
            host="127.0.0.1",
            env={OPENCV_THREADS: "2"},
        )


def _usable_cores():
    """The cores this process may run on (a container's or a batch job's share, not the machine's)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def _rows(job, result, plot_set):
    """The image's rows: one per plot, the error on each when the image failed."""
    base = {"date": job.date, "date_source": job.date_source, "image": Path(job.path).name}
    rows = []
    if result["ok"]:
        for entry in result["table"]:
            i = int(entry["plot"])
            row = {**base, "plot": i, **_attributes(plot_set, i)}
            for column, key in _FROM_TABLE.items():
                row[column] = entry.get(key)
            row["reason"] = row["reason"] or None
            row["height_mode"] = result["height_mode"]
            row["height_units"] = result["height_units"]
            row["error"] = None
            rows.append(row)
    else:
        for i in range(len(plot_set.polygons)):
            row = {**base, "plot": i, **_attributes(plot_set, i)}
            row.update({column: None for column in VALUE_COLUMNS})
            row["error"] = result["error"]
            rows.append(row)
    return rows


def _attributes(plot_set, i):
    return {_attribute_column(name): plot_set.attributes[i].get(name) for name in plot_set.fields}


def _attribute_column(name):
    """An attribute's column; one named like a table column is prefixed so nothing is overwritten."""
    return f"attr_{name}" if name in LEAD_COLUMNS or name in VALUE_COLUMNS else name


def _columns(plot_set):
    return (*LEAD_COLUMNS, *(_attribute_column(n) for n in plot_set.fields), *VALUE_COLUMNS)


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


def _date_record(job, result, out):
    record = {
        "date": job.date,
        "date_source": job.date_source,
        "image": job.path,
        "dsm": job.dsm,
        "key": result.get("key"),
        "error": None if result["ok"] else result["error"],
    }
    if result["ok"]:
        if result.get("align"):  # in the date's photo pixels [rows, cols], and its length in metres
            record.update(result["align"])  # shift_px, shift_m and the correlation (align_score)
        record.update(
            {
                "arrays": f"cache/{result['key']}.npz",
                "grid": result["grid"],
                "height_mode": result["height_mode"],
                "height_units": result["height_units"],
                "seconds": round(result["seconds"], 3),
            }
        )
    return record


def _cell(value):
    """One CSV cell, the same text whichever process computed it."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "" if value != value else f"{value:.6g}"
    return str(value)


def _write_csv(path, rows, columns):
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row.get(column)) for column in columns])
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(buffer.getvalue())
    os.replace(tmp, path)


def _typed(rows):
    """Rows as the chart wants them: values as in the CSV (rounded), so the chart shows the table."""
    return [{k: (_cell(v) if isinstance(v, float) else v) for k, v in row.items()} for row in rows]


class _Bar:
    """A one-line progress bar on stderr: ``season [#####-----] 3/7 20180829.tif``."""

    WIDTH = 30

    def __init__(self, total, *, enabled):
        self.total, self.done, self.failed = total, 0, 0
        self.enabled = enabled and total > 0
        self.tty = sys.stderr.isatty()
        self.started = time.perf_counter()
        if self.enabled:
            self._draw("")

    def step(self, name, *, ok):
        self.done += 1
        self.failed += not ok
        if self.enabled:
            self._draw(name)

    def _draw(self, name):
        filled = self.WIDTH * self.done // max(self.total, 1)
        bar = "#" * filled + "-" * (self.WIDTH - filled)
        failed = f", {self.failed} failed" if self.failed else ""
        line = (
            f"season [{bar}] {self.done}/{self.total} images{failed} "
            f"{time.perf_counter() - self.started:5.1f} s {name}"
        )
        if self.tty:
            sys.stderr.write("\r" + line[:120].ljust(120))
        else:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()

    def close(self):
        if self.enabled and self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()
