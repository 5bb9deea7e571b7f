"""A breeder's ruler: measured plot heights read from a CSV, compared with the DSM's, and a calibration.

A field book gives one measured height per plot (a ruler or a stick, to the top of the canopy).
:func:`read_ruler` matches its rows to the plot polygons by an id the two share, :func:`agreement`
reports r, RMSE, bias and Lin's concordance correlation coefficient (CCC; Lin 1989, Biometrics
45(1)) of the DSM's heights against it, and :func:`calibrate` fits the linear correction
ruler = a + b x DSM height on the ruler's plots, with its leave-one-out error, so that it can be
applied to every plot of the trial.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CliffTerrainError, RulerError

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_UNIT_IN_NAME = re.compile(r"(?:^|[_\s(\[])(m|cm|mm)[)\]]?$", re.IGNORECASE)
_UNIT_COLUMNS = ("unit", "units")


@dataclass
class Ruler:
    """Measured heights matched to a plot set.

    Attributes
    ----------
    heights_m : (n_plots,) float64
        The measured height of each plot in metres, NaN where the file has none.
    id_column, height_column : str
        The file's columns used.
    plot_field : str
        The plot attribute the ids matched (``"plot"``: the 0-based index in the plot file).
    unit : str
        ``"m"``, ``"cm"`` or ``"mm"``: the file's unit.
    unmatched : int
        Rows of the file whose id names no plot.
    path : str
    """

    heights_m: np.ndarray
    id_column: str
    height_column: str
    plot_field: str
    unit: str
    unmatched: int
    path: str

    @property
    def matched(self):
        return int(np.count_nonzero(np.isfinite(self.heights_m)))


def _key(value):
    """An id as text: '12', '12.0' and 12 are the same plot; case and outer spaces do not matter."""
    text = str(value).strip()
    try:
        number = float(text)
    except ValueError:
        return text.lower()
    return str(int(number)) if number.is_integer() else repr(number)


def read_ruler(path, plots, *, id_column=None, height_column=None, units=None):
    """Read a CSV of measured plot heights and match it to `plots`.

    Parameters
    ----------
    path : path
        A CSV file with a header: a plot id column and a height column.
    plots : PlotSet
        The plots (:func:`cliff_terrain.io.vector.plot_polygons.read_plots`); an id matches one of their
        attributes (the one that matches most rows) or ``plot``, the 0-based index.
    id_column, height_column : str, optional
        The file's columns; default: the column whose values match the plots best, and the column
        whose name holds "height" (or is ``ph``).
    units : {"m", "cm", "mm"}, optional
        The heights' unit; default: from a ``unit``/``units`` column, else from the height column's
        name (``height_cm``, ``Height (m)``). One of them must say it.

    Returns
    -------
    Ruler

    Raises
    ------
    RulerError
        The file is missing, not a text CSV, has no such column, mixes units, has heights that are
        not numbers, or names none of the plots; the message names the file.

    Examples
    --------
    >>> import tempfile, os
    >>> from cliff_terrain.io.vector.plot_polygons import PlotSet
    >>> square = [np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])]
    >>> plots = PlotSet([square] * 3, [{"id": "A1"}, {"id": "A2"}, {"id": "A3"}], ("id",), None, "")
    >>> folder = tempfile.mkdtemp(); path = os.path.join(folder, "ruler.csv")
    >>> _ = open(path, "w").write("plot_id,height_cm\\nA1,71\\nA3,80\\n")
    >>> ruler = read_ruler(path, plots)
    >>> ruler.heights_m.tolist(), ruler.plot_field, ruler.unit
    ([0.71, nan, 0.8], 'id', 'cm')
    """
    from .._validate import check_choice

    name = str(path)
    path = Path(path)
    if units is not None:
        check_choice("--ruler-units", units, tuple(UNITS))
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RulerError(f"cannot read the ruler file {name!r}: {exc.strerror or exc}") from None
    if b"\x00" in raw[:4096]:
        raise RulerError(f"the ruler file {name!r} is not a text CSV (it holds binary data)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    rows = list(csv.DictReader(text.splitlines()))
    columns = [c for c in (rows[0].keys() if rows else ()) if c is not None]
    if not rows or not columns:
        raise RulerError(f"the ruler file {name!r} has no rows under a header")
    height_column = _height_column(name, columns, height_column)
    fields = {"plot": [str(i) for i in range(len(plots))]}
    for field in plots.fields:
        fields[field] = [_key(a.get(field, "")) for a in plots.attributes]
    id_column, plot_field, index = _id_column(name, rows, columns, id_column, fields, height_column)
    unit = _unit(name, rows, columns, height_column, units)
    heights = np.full(len(plots), np.nan)
    unmatched = 0
    for row in rows:
        key = _key(row.get(id_column, ""))
        value = (row.get(height_column) or "").strip()
        if key not in index:
            unmatched += 1
            continue
        if not value or value.lower() in ("na", "nan"):
            continue
        try:
            heights[index[key]] = float(value) * UNITS[unit]
        except ValueError:
            raise RulerError(
                f"the ruler file {name!r}: height {value!r} of plot {row.get(id_column)!r} "
                f"(column {height_column!r}) is not a number"
            ) from None
    if not np.isfinite(heights).any():
        raise RulerError(f"the ruler file {name!r} gives no height for any of the plots it names")
    return Ruler(heights, id_column, height_column, plot_field, unit, unmatched, name)


def _height_column(name, columns, wanted):
    if wanted is not None:
        if wanted not in columns:
            raise RulerError(
                f"the ruler file {name!r} has no column {wanted!r} (it has {', '.join(columns)})"
            )
        return wanted
    found = [c for c in columns if "height" in c.lower() or c.strip().lower() == "ph"]
    if len(found) != 1:
        why = "no column named like a height" if not found else f"several height columns ({', '.join(found)})"
        raise RulerError(
            f"the ruler file {name!r} has {why}; name it with --ruler-height (columns: {', '.join(columns)})"
        )
    return found[0]


def _id_column(name, rows, columns, wanted, fields, height_column):
    candidates = [wanted] if wanted is not None else [c for c in columns if c != height_column]
    if wanted is not None and wanted not in columns:
        raise RulerError(f"the ruler file {name!r} has no column {wanted!r} (it has {', '.join(columns)})")
    best = (0, None, None)
    for column in candidates:
        keys = [_key(r.get(column, "")) for r in rows]
        for field, values in fields.items():
            if len(set(values)) < len(values):
                continue  # an attribute that does not name each plot once is no id
            index = {v: i for i, v in enumerate(values)}
            hits = sum(k in index for k in keys)
            if hits > best[0]:
                best = (hits, column, field)
    if best[0] == 0:
        raise RulerError(
            f"the ruler file {name!r}: none of its ids names a plot of the plot file "
            f"(tried columns {', '.join(candidates)} against the plots' {', '.join(fields)})"
        )
    _, column, field = best
    return column, field, {v: i for i, v in enumerate(fields[field])}


def _unit(name, rows, columns, height_column, units):
    unit_column = next((c for c in columns if c.strip().lower() in _UNIT_COLUMNS), None)
    if unit_column is not None:
        seen = {(r.get(unit_column) or "").strip().lower() for r in rows} - {""}
        if len(seen) > 1:
            raise RulerError(
                f"the ruler file {name!r} mixes units in column {unit_column!r} ({', '.join(sorted(seen))}); "
                "give every height in one unit"
            )
        if seen:
            (found,) = seen
            if found not in UNITS:
                raise RulerError(f"the ruler file {name!r}: unit {found!r} is not one of m, cm, mm")
            if units is not None and units != found:
                raise RulerError(f"the ruler file {name!r} says {found!r} but --ruler-units says {units!r}")
            return found
    match = _UNIT_IN_NAME.search(height_column.strip())
    if match:
        found = match.group(1).lower()
        if units is not None and units != found:
            raise RulerError(
                f"the ruler file {name!r}: column {height_column!r} says {found!r} but --ruler-units says {units!r}"
            )
        return found
    if units is None:
        raise RulerError(
            f"the ruler file {name!r} does not say the unit of {height_column!r}; "
            "give --ruler-units m, cm or mm (or a 'unit' column)"
        )
    return units


def agreement(estimate, truth):
    """r, RMSE, bias and Lin's CCC of `estimate` against `truth` over the plots where both exist.

    Examples
    --------
    >>> a = agreement(np.array([0.5, 0.6, 0.7, np.nan]), np.array([0.55, 0.65, 0.75, 0.8]))
    >>> a["n"], round(a["r"], 3), round(a["rmse_m"], 3), round(a["bias_m"], 3), round(a["ccc"], 3)
    (3, 1.0, 0.05, -0.05, 0.842)
    """
    estimate = np.asarray(estimate, np.float64)
    truth = np.asarray(truth, np.float64)
    ok = np.isfinite(estimate) & np.isfinite(truth)
    a, b = estimate[ok], truth[ok]
    out = {"n": int(a.size), "r": None, "rmse_m": None, "bias_m": None, "ccc": None}
    if a.size < 3:
        return out
    out["rmse_m"] = float(np.sqrt(np.mean((a - b) ** 2)))
    out["bias_m"] = float(np.mean(a - b))
    va, vb = float(np.var(a)), float(np.var(b))
    cov = float(np.mean((a - a.mean()) * (b - b.mean())))
    if va > 0 and vb > 0:
        out["r"] = float(cov / np.sqrt(va * vb))
    denominator = va + vb + (a.mean() - b.mean()) ** 2
    out["ccc"] = float(2 * cov / denominator) if denominator > 0 else None
    return out


def calibrate(estimate, truth):
    """The linear correction truth = a + b x estimate on the plots with both, and its leave-one-out error.

    Returns ``{"a_m", "b", "n", "loo_rmse_m", "loo": agreement of the leave-one-out predictions}``.

    Examples
    --------
    >>> x = np.array([0.40, 0.50, 0.60, 0.70]); y = 0.1 + 1.2 * x
    >>> fit = calibrate(x, y)
    >>> round(fit["a_m"], 3), round(fit["b"], 3), round(fit["loo_rmse_m"], 6)
    (0.1, 1.2, 0.0)
    """
    estimate = np.asarray(estimate, np.float64)
    truth = np.asarray(truth, np.float64)
    ok = np.isfinite(estimate) & np.isfinite(truth)
    x, y = estimate[ok], truth[ok]
    if x.size < 3 or np.ptp(x) == 0:
        raise CliffTerrainError(
            f"a calibration needs at least 3 ruler plots with different measured heights, got {x.size}"
        )
    design = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ coef
    # Leave-one-out residuals of a linear fit: residual / (1 - leverage), no refitting needed.
    leverage = np.einsum("ij,ji->i", design, np.linalg.pinv(design.T @ design) @ design.T)
    loo_residual = residual / np.maximum(1 - leverage, 1e-12)
    loo_prediction = y - loo_residual
    return {
        "a_m": float(coef[0]),
        "b": float(coef[1]),
        "n": int(x.size),
        "loo_rmse_m": float(np.sqrt(np.mean(loo_residual**2))),
        "loo": agreement(loo_prediction, y),
    }


def ruler_columns(rows, ruler, *, calibrate_heights=False):
    """Add ``ruler_height_m`` (and ``height_calibrated_m``) to plot `rows`; return (columns, record).

    `rows` are :func:`cliff_terrain.measure.field_plots.plot_table`'s, in plot order. The record
    holds the agreement of ``height_p90_m`` with the ruler and, with `calibrate_heights`, the
    calibration (:func:`calibrate`), applied to every plot's ``height_p90_m``.
    """
    ours = np.array([float(r["height_p90_m"]) for r in rows])
    for row, measured in zip(rows, ruler.heights_m, strict=True):
        row["ruler_height_m"] = float(measured)
    record = {
        "file": ruler.path,
        "id_column": ruler.id_column,
        "height_column": ruler.height_column,
        "plot_field": ruler.plot_field,
        "unit": ruler.unit,
        "plots_matched": ruler.matched,
        "rows_unmatched": ruler.unmatched,
        "height_p90_m": agreement(ours, ruler.heights_m),
    }
    columns = ["ruler_height_m"]
    if calibrate_heights:
        fit = calibrate(ours, ruler.heights_m)
        for row, value in zip(rows, fit["a_m"] + fit["b"] * ours, strict=True):
            row["height_calibrated_m"] = float(value)
        record["calibration"] = fit
        columns.append("height_calibrated_m")
    return columns, record
