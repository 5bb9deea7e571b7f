"""The season's table and record, defined once: ``season.csv``'s columns and cells, and the date
records of ``season.json`` (what the chart, the traits and the Blender animation read)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from ..measure.index_figures import index_columns

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


def plot_rows(job, result, plot_set):
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
            row.update({column: entry.get(column) for column in index_columns(job.indices)})
            row["error"] = None
            rows.append(row)
    else:
        for i in range(len(plot_set.polygons)):
            row = {**base, "plot": i, **_attributes(plot_set, i)}
            row.update({column: None for column in (*VALUE_COLUMNS, *index_columns(job.indices))})
            row["error"] = result["error"]
            rows.append(row)
    return rows


def _attributes(plot_set, i):
    return {_attribute_column(name): plot_set.attributes[i].get(name) for name in plot_set.fields}


def _attribute_column(name):
    """An attribute's column: its own name, unless it is one of the table's (then with ``_attr``
    appended, as in ``plots.csv``: a layout's 1-based ``plot`` number is ``plot_attr`` in both)."""
    return f"{name}_attr" if name in LEAD_COLUMNS or name in VALUE_COLUMNS else name


def season_columns(plot_set, indices=()):
    """``season.csv``'s columns; those of `indices` (``ndvi_mean`` ...) come after ``height_units``."""
    values = list(VALUE_COLUMNS)
    at = values.index("height_units") + 1
    values[at:at] = index_columns(indices)
    return (*LEAD_COLUMNS, *(_attribute_column(n) for n in plot_set.fields), *values)


def date_record(job, result, out):
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


def season_csv(rows, columns):
    """``season.csv``'s text: the `columns`' header, then one line per row."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row.get(column)) for column in columns])
    return buffer.getvalue()


def chart_rows(rows):
    """Rows as the chart wants them: values as in the CSV (rounded), so the chart shows the table."""
    return [{k: (_cell(v) if isinstance(v, float) else v) for k, v in row.items()} for row in rows]
