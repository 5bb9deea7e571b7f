"""Per-region and per-plot tables, written as CSV and (when georeferenced) GeoJSON, atomically."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os

import numpy as np

from .field_plots import HEIGHT_COLUMNS, region_figures
from .index_figures import index_columns, index_figures

# The tables' file names, wherever they are written (render_views.py, the operators, the commands).
REGIONS_CSV, REGIONS_GEOJSON = "regions.csv", "regions.geojson"
PLOTS_CSV, PLOTS_GEOJSON = "plots.csv", "plots.geojson"
TABLES = (REGIONS_CSV, REGIONS_GEOJSON, PLOTS_CSV, PLOTS_GEOJSON)

REGION_COLUMNS = (
    "id",
    "row",
    "col",
    "x",
    "y",
    "area_m2",
    "area_px",
    "equivalent_diameter_m",
    "cover",
    *HEIGHT_COLUMNS,
    "volume_m3",
)


def region_columns(indices=()):
    """The columns of :func:`region_table`: :data:`REGION_COLUMNS`, then those of `indices`."""
    return (*REGION_COLUMNS, *index_columns(indices))


def region_table(labels, *, heights=None, pixel_size=None, transform=None, valid=None, index_maps=None):
    """One row per region (plant) of a segmentation.

    Parameters
    ----------
    labels : (rows, cols) int array
        0 for soil, 1..n for the regions.
    heights : (rows, cols) float array, optional
        Canopy height in metres (NaN = no data); without it the height columns are NaN.
    pixel_size : float, optional
        Metres per pixel; without it areas are in pixels only (``area_m2`` NaN).
    transform : (3, 3) array, optional
        Pixel (col, row) -> map (x, y): gives the centroids' map coordinates.
    valid : (rows, cols) bool array, optional
        Pixels with data (for `cover`); default all.
    index_maps : dict, optional
        Vegetation index name -> (rows, cols) map (:func:`cliff_terrain.photo_heights.indices.index_maps`):
        adds ``ndvi_mean``, ``ndvi_median``, ``ndvi_plant_mean``, ``ndvi_plant_median`` ... (see
        :mod:`cliff_terrain.measure.index_figures`; a region's pixels are its plant pixels).

    Returns
    -------
    list of dict
        ``id``, centroid ``row``/``col`` (pixel centres at +0.5) and ``x``/``y`` (map, NaN without
        a transform), ``area_m2``, ``area_px``, ``equivalent_diameter_m`` (of a disc of the same area;
        NaN, as ``area_m2``, when there is no GSD), ``cover`` (the region's share of the pixels with data),
        heights over the region's pixels (``height_mean_m`` ... ``height_max_m``) and ``volume_m3``.

    Examples
    --------
    >>> labels = np.zeros((4, 4), int); labels[1:3, 1:3] = 1
    >>> row = region_table(labels, heights=labels * 0.5, pixel_size=0.1)[0]
    >>> row["id"], row["row"], row["col"], round(row["area_m2"], 4), row["height_max_m"], round(row["volume_m3"], 4)
    (1, 2.0, 2.0, 0.04, 0.5, 0.02)
    """
    labels = np.asarray(labels)
    n = int(labels.max(initial=0))
    if n == 0:
        return []
    area = 1.0 if pixel_size is None else float(pixel_size) ** 2
    figures = region_figures(labels, n, mask=labels > 0, heights=heights, pixel_area_m2=area)
    ids = labels.ravel()
    rr, cc = np.indices(labels.shape)
    count = np.bincount(ids, minlength=n + 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        row_c = np.bincount(ids, weights=rr.ravel() + 0.5, minlength=n + 1) / count
        col_c = np.bincount(ids, weights=cc.ravel() + 0.5, minlength=n + 1) / count
    total = int(labels.size if valid is None else np.count_nonzero(valid))
    indices = index_figures(labels, n, maps=index_maps, mask=labels > 0) if index_maps else None
    rows = []
    for k in range(1, n + 1):
        f = figures[k - 1]
        x = y = math.nan
        if transform is not None:
            t = np.asarray(transform, dtype=np.float64)
            x = float(t[0, 0] * col_c[k] + t[0, 1] * row_c[k] + t[0, 2])
            y = float(t[1, 0] * col_c[k] + t[1, 1] * row_c[k] + t[1, 2])
        diameter_px = 2.0 * math.sqrt(count[k] / math.pi)
        rows.append(
            {
                "id": k,
                "row": float(row_c[k]),
                "col": float(col_c[k]),
                "x": x,
                "y": y,
                "area_m2": f["area_m2"] if pixel_size is not None else math.nan,
                "area_px": int(count[k]),
                # Without a GSD no metre is known: NaN, as the area's (`area_px` holds the size).
                "equivalent_diameter_m": diameter_px * pixel_size if pixel_size is not None else math.nan,
                "cover": count[k] / total if total else math.nan,
                **{name: f[name] for name in HEIGHT_COLUMNS},
                "volume_m3": f["volume_m3"] if pixel_size is not None else math.nan,
                **(indices[k - 1] if indices else {}),
            }
        )
    return rows


def _cell(value):
    if value is None:
        return ""
    if isinstance(value, float | np.floating):
        return "" if not math.isfinite(value) else repr(round(float(value), 6))
    return str(value)


def table_csv(rows, columns=None, *, lines=None):
    """CSV text of `rows` (NaN as empty cells); `lines`, when given, are the rows' own
    (:func:`csv_lines`, made where the rows were: on a cluster's workers)."""
    columns = list(columns or (rows[0].keys() if rows else ()))
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(columns)
    return out.getvalue() + "".join(csv_lines(rows, columns) if lines is None else lines)


def csv_lines(rows, columns):
    """Each row's line of :func:`table_csv` (its newline included)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    lines = []
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in columns])
        lines.append(out.getvalue())
        out.seek(0)
        out.truncate()
    return lines


def text_writer(make):
    """A writer for :func:`write_files` of the text ``make()`` returns, made when it is written (on
    the writers' threads, beside the other files)."""

    def write(tmp):
        text = make()
        with open(tmp, "w", encoding="utf-8", newline="") as file:
            file.write(text)

    return write


# Written beside a run's outputs while they are renamed into place, removed once all are.
RENAMING_JOURNAL = ".cliff-terrain-renaming"


def previous_outputs(out, names, *, record=None, markers=()):
    """The `names` in folder `out` that an earlier run of the command wrote there, as it says: listed
    in its `record` (a JSON file of that run with ``"outputs"``, its summary) or in the renaming
    journal an interrupted run left; with `markers` (a folder only the command writes to), every
    name when one of them is there. A run that does not write them (`heights` without
    ``--plots``, or windowed: no regions) removes them as it writes its own, so that the folder
    never holds two runs' outputs side by side. Files the earlier run did not write are the user's:
    kept (a field book saved as plots.geojson beside a run without plots)."""
    if not out.is_dir():
        return []
    written = set()
    journal = out / RENAMING_JOURNAL
    with contextlib.suppress(OSError, UnicodeDecodeError):
        written.update(journal.read_text(encoding="utf-8").splitlines())
    if record is not None:
        with contextlib.suppress(OSError, ValueError, TypeError, LookupError):  # no record: nothing
            written.update(str(n) for n in json.loads((out / record).read_text(encoding="utf-8"))["outputs"])
    if any((out / name).exists() for name in markers):
        written.update(names)
    return [out / name for name in names if name in written and (out / name).is_file()]


def write_files(files, *, threads=1, remove=()):
    """Write {path: text or bytes-writer} all or nothing: each to a temporary name, then all renamed.

    Values are ``str`` (written as UTF-8 text) or callables ``write(tmp_path)``. With `threads`
    above 1 the callables run that many at once (they must be thread-safe: the windowed rasters,
    whose compression and reading release the GIL, and :func:`text_writer` s of tables made beside
    them); the first error is raised once all stopped. The paths in `remove` (an earlier run's
    outputs this one does not write) are removed with the renames, once every file is written.
    """
    from concurrent.futures import ThreadPoolExecutor

    temporary = []
    try:
        with ThreadPoolExecutor(max(1, int(threads))) as pool:
            jobs = []
            for path, content in files.items():
                tmp = f"{os.fspath(path)}.part-{os.getpid()}"
                temporary.append((tmp, path))
                if not callable(content):
                    with open(tmp, "w", encoding="utf-8", newline="") as file:
                        file.write(content)
                elif threads > 1:
                    jobs.append(pool.submit(content, tmp))
                else:
                    content(tmp)
            for job in jobs:
                job.result()
        # A journal beside the outputs while they are renamed: a run killed between two renames
        # leaves it, so that its outputs are told from files of the user's of the same names
        # (:func:`cliff_terrain.commands.out_folder.finished_outputs`), which are never replaced.
        journals = []
        for folder in dict.fromkeys(os.path.dirname(os.path.abspath(path)) for _, path in temporary):
            journal = os.path.join(folder, RENAMING_JOURNAL)
            with open(journal, "w", encoding="utf-8") as file:
                file.write("\n".join(os.path.basename(path) for _, path in temporary) + "\n")
            journals.append(journal)
        for path in remove:  # within the journal's window: a run killed here looks unfinished
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)
        for tmp, path in temporary:
            os.replace(tmp, path)
        for journal in journals:
            os.remove(journal)
    finally:
        for tmp, _ in temporary:
            if os.path.exists(tmp):
                os.remove(tmp)
