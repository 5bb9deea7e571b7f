"""One season task: an image's relief and plot table, cached; run on a Dask worker or in this process.

Each task hashes its photo, looks it up in the cache and writes the entry it computes, so the
workers need Cliff Terrain importable and the photos, DSMs, plots file and output folder at the
same paths (a shared file system); only the table rows come back to the caller.
"""

from __future__ import annotations

import os
import platform
import time

from .._memory import peak_rss
from ..io.raster.crs import crs_record
from ..params import ReliefParams
from .cache import Cache, cache_key, file_hash

# Read by OpenCV when it is imported: the number of threads of its pool.
OPENCV_THREADS = "OPENCV_FOR_THREADS_NUM"


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
        if job.get("indices"):  # the index maps are part of the entry
            extra.append(f"indices={','.join(job['indices'])};bands={','.join(job.get('bands') or ())}")
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
        exact_opencv()
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


def exact_opencv():
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

    from ..build import build_relief
    from ..io.raster.geotiff import read_georeference

    params = job["params"]
    photo_transform, crs = read_georeference(job["path"])
    relief = build_relief(
        job["path"],
        ReliefParams.from_properties({**params, "dsm": job.get("dsm") or ""}),
        gsd=float(np.hypot(*photo_transform[:2, 0])),
        mesh=None,  # the table needs the heights only
        bands=job.get("bands"),
    )
    shape = relief.heights.shape
    # The processing grid resamples the photo's pixels: its pixels are larger by these factors.
    meta = relief.metadata
    transform = photo_transform @ np.diag([*meta.grid_scale(shape), 1.0])
    maps = {}
    if job.get("indices"):
        from ..io.raster.bands import read_bands
        from ..photo_heights.indices import index_maps

        maps = index_maps(read_bands(job["path"], names=job.get("bands")), job["indices"], shape=shape)
    from ..measure.canopy import cover_pixels

    table = _table(_plots(job["plots"]), transform, cover_pixels(relief), relief.heights, relief.units, maps)
    return {
        "table": [_plain(row) for row in table],
        "height_mode": params["height_source"],
        "height_units": relief.units,
        "grid": {"transform": transform[:2].tolist(), "shape": list(shape), "crs": crs_record(crs)},
        "arrays": {
            "heights": np.ascontiguousarray(relief.heights, dtype=np.float32),
            "mask": np.packbits(relief.mask, axis=None),
            **{f"index_{name}": np.ascontiguousarray(m, dtype=np.float32) for name, m in maps.items()},
        },
    }


def _table(plot_set, transform, mask, heights, units, index_maps=None):
    """The plots' rows of one date: its grid (`transform`: pixel -> map), plant mask, heights and
    index maps ({name: map} on the grid)."""
    import numpy as np

    from ..measure.field_plots import plot_layers, plot_table

    labels = plot_layers(plot_set, transform=transform, shape=mask.shape)
    rows = plot_table(
        plot_set,
        labels,
        mask=mask,
        heights=heights,
        pixel_area_m2=float(abs(np.linalg.det(np.asarray(transform)[:2, :2]))),
        height_units=units,
        index_maps=index_maps,
    )
    return [_plain(row) for row in rows]


def aligned_result(job, result, plot_set):
    """A date's result read where its pixels show the plots: its content lies ``job.shift`` (map
    metres) from where the season's consensus puts it, so its grid's pixel q shows map(q) - shift.

    The table is taken again from the cached grid (the relief does not depend on the shift, so a
    season that gains a date recomputes no relief, only these tables).
    """
    import numpy as np

    from ..io.raster.geotiff import read_georeference

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
    maps = {name: arrays[f"index_{name}"] for name in job.indices}
    return {
        **result,
        "table": _table(plot_set, aligned, mask, arrays["heights"], result["height_units"], maps),
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
        from ..io.vector.plot_polygons import read_plots

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
