"""A breeder's ruler: measured plot heights read from a CSV, compared with the DSM's, and a calibration.

A field book gives one measured height per plot (a ruler or a stick, to the top of the canopy).
:func:`read_ruler` matches its rows to the plot polygons by an id the two share, :func:`agreement`
reports r, RMSE, bias and Lin's concordance correlation coefficient (CCC; Lin 1989, Biometrics
45(1)) of the DSM's heights against it, and whether their uncertainty covers the ruler's readings;
:func:`calibrate` fits the linear correction ruler = a + b x DSM height on the ruler's plots, with
its leave-one-out error and each plot's prediction error, so that it can be applied to every plot
of the trial.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CliffTerrainError, RulerError

# The inch is exact (0.0254 m since 1959): field books of North American trials often keep heights in it.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
_UNIT_NAMES = {"inch": "in", "inches": "in"}
_UNIT_IN_NAME = re.compile(r"(?:^|[_\s(\[])(m|cm|mm|in|inch|inches)[)\]]?$", re.IGNORECASE)
_UNIT_COLUMNS = ("unit", "units")
# Field books abbreviate the trait: HT, PH, PHT, PLHT, PLTHT (plant height, as in the Crop
# Ontology's trait names and breeding databases' exports), alone or beside a unit or a date.
_HEIGHT_WORDS = {"ht", "ph", "pht", "plht", "pltht", "planthgt", "hgt"}
# |error| <= Z90 x standard error for 90 % of plots when the errors are normal (the two-sided 90 %
# interval): what an uncertainty "covers", here and on the validation page.
Z90 = 1.645
# An uncertainty that covers fewer of the ruler's plots than this is said to be too small.
COVERAGE_FLOOR = 0.8


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
        The file's columns; default: the column whose values match the plots best (when they name
        as many plots through two plot fields, the field named as the column, else a
        :class:`RulerError`), and the one column named like a height: its name holds "height", or
        it is a field book's abbreviation (``HT``, ``PH``, ``PHT``, ``PLHT``, ``PLTHT``, ``HGT``)
        with at most a unit and a date beside it.
    units : {"m", "cm", "mm", "in"}, optional
        The heights' unit; default: from a ``unit``/``units`` column, else from the height column's
        name (``height_cm``, ``Height (m)``, ``PH_in``; ``inch`` and ``inches`` are ``in``). One of
        them must say it.

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
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):  # UTF-16 with its BOM: Excel's "Unicode Text"
        try:
            text = raw.decode("utf-16")
        except UnicodeDecodeError:
            raise RulerError(f"the ruler file {name!r} is not a text CSV (broken UTF-16)") from None
    elif b"\x00" in raw[:4096]:
        raise RulerError(f"the ruler file {name!r} is not a text CSV (it holds binary data)")
    else:
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    rows = list(csv.DictReader(text.splitlines()))
    columns = [c for c in (rows[0].keys() if rows else ()) if c is not None]
    if not rows or not columns:
        raise RulerError(f"the ruler file {name!r} has no rows under a header")
    if len(columns) == 1 and any(c in columns[0] for c in ";\t|"):
        raise RulerError(
            f"the ruler file {name!r}: its header is one column, {columns[0]!r}: save it comma-separated"
        )
    height_column = _height_column(name, columns, height_column)
    # The 0-based index as `plot`, unless an attribute is named so (then it stands for it).
    fields = {field: [_key(a.get(field, "")) for a in plots.attributes] for field in plots.fields}
    fields.setdefault("plot", [str(i) for i in range(len(plots))])
    id_column, plot_field, index = _id_column(
        name, rows, columns, id_column, fields, height_column, plots_fields=plots.fields
    )
    unit = _unit(name, rows, columns, height_column, units)
    heights = np.full(len(plots), np.nan)
    unmatched = 0
    seen = {}
    for number_row, row in enumerate(rows, start=2):
        key = _key(row.get(id_column, ""))
        value = (row.get(height_column) or "").strip()
        if key not in index:
            unmatched += 1
            continue
        if key in seen:
            raise RulerError(
                f"the ruler file {name!r}: plot {row.get(id_column)!r} appears twice (rows {seen[key]} and "
                f"{number_row}); give one height per plot"
            )
        seen[key] = number_row
        if not value or value.lower() in ("na", "nan"):
            continue
        try:
            number = float(value)
        except ValueError:
            raise RulerError(
                f"the ruler file {name!r}: height {value!r} of plot {row.get(id_column)!r} "
                f"(column {height_column!r}) is not a number"
            ) from None
        # A height below 0 or infinite is a sign or a unit gone wrong: a calibration on it would
        # turn every plot's height upside down.
        if not np.isfinite(number) or number < 0:
            raise RulerError(
                f"the ruler file {name!r}: height {value!r} of plot {row.get(id_column)!r} "
                f"(column {height_column!r}, row {number_row}) is not a height (below 0 or infinite)"
            )
        heights[index[key]] = number * UNITS[unit]
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
    found = [c for c in columns if _names_a_height(c)]
    if len(found) != 1:
        why = "no column named like a height" if not found else f"several height columns ({', '.join(found)})"
        raise RulerError(
            f"the ruler file {name!r} has {why}; name it with --ruler-height (columns: {', '.join(columns)})"
        )
    return found[0]


def _names_a_height(column):
    """Whether a column's name names a height: holds "height", or is a field book's abbreviation of
    it with at most a unit and a date beside it (``HT``, ``PH_cm``, ``PLTHT (in)``, ``PH 2023-07-26``).
    Not a name that merely holds its letters (``WEIGHT``, ``phase``) nor one that says more of it
    (``soil_pH``, ``HT_notes``, ``PH_date``, ``PHT_flag``)."""
    text = column.strip().lower()
    if "height" in text:
        return True
    words = [w for w in re.split(r"[^a-z]+", text) if w and w not in (*UNITS, *_UNIT_NAMES)]
    return len(words) == 1 and words[0] in _HEIGHT_WORDS


def _id_column(name, rows, columns, wanted, fields, height_column, plots_fields=()):
    index_is_row = "plot" not in plots_fields
    candidates = [wanted] if wanted is not None else [c for c in columns if c != height_column]
    if wanted is not None and wanted not in columns:
        raise RulerError(f"the ruler file {name!r} has no column {wanted!r} (it has {', '.join(columns)})")
    best = (0, None, None)
    shared = (0, None, None)  # the best match with an attribute that names several plots each
    tied = []  # the fields that name as many of the best column's ids as the best
    for column in candidates:
        keys = [_key(r.get(column, "")) for r in rows]
        for field, values in fields.items():
            hits = sum(k in set(values) for k in keys)
            if len(set(values)) < len(values):  # an attribute that does not name each plot once is no id
                if hits > shared[0]:
                    shared = (hits, column, field)
                continue
            if hits > best[0]:
                best, tied = (hits, column, field), [field]
            elif hits == best[0] and hits and column == best[1]:
                tied.append(field)
    if len(tied) > 1:
        # The ids name as many plots through two fields (a 0-based index and a 1-based number): one of
        # them joins every height to a neighbour. The field named as the column is meant; else ask.
        # (`plot`, the 0-based row, only by that exact name: the column plots.csv writes; a field
        # book's "Plot" is the breeder's number.)
        column = best[1].strip()
        named = [
            f
            for f in tied
            if (column == "plot" if f == "plot" and index_is_row else f.strip().lower() == column.lower())
        ]
        if len(named) != 1:
            raise RulerError(
                f"the ruler file {name!r}: the ids of its column {best[1]!r} name as many plots through "
                f"the plots' {' and '.join(repr(f) for f in tied)} ('plot' is the 0-based row); name "
                "the column as the one meant"
            )
        best = (best[0], best[1], named[0])
    if shared[0] and shared[0] >= best[0] and (best[0] == 0 or best[2] == "plot"):
        # The ids name plots through an attribute several plots share (a plot number repeated in
        # each trial); the 0-based index matching them instead would join every height to another
        # plot.
        raise RulerError(
            f"the ruler file {name!r}: its column {shared[1]!r} matches the plots' {shared[2]!r}, which "
            "names several plots each; give ids that name one plot each (or --ruler-id naming such a column)"
        )
    if best[0] == 0:
        raise RulerError(
            f"the ruler file {name!r}: none of its ids names a plot of the plot file "
            f"(tried columns {', '.join(candidates) or 'none'} against the plots' {', '.join(fields)})"
        )
    _, column, field = best
    return column, field, {v: i for i, v in enumerate(fields[field])}


def _unit(name, rows, columns, height_column, units):
    unit_column = next((c for c in columns if c.strip().lower() in _UNIT_COLUMNS), None)
    if unit_column is not None:
        seen = {_unit_name((r.get(unit_column) or "").strip().lower()) for r in rows} - {""}
        if len(seen) > 1:
            raise RulerError(
                f"the ruler file {name!r} mixes units in column {unit_column!r} ({', '.join(sorted(seen))}); "
                "give every height in one unit"
            )
        if seen:
            (found,) = seen
            if found not in UNITS:
                raise RulerError(f"the ruler file {name!r}: unit {found!r} is not one of m, cm, mm, in")
            if units is not None and units != found:
                raise RulerError(f"the ruler file {name!r} says {found!r} but --ruler-units says {units!r}")
            return found
    match = _UNIT_IN_NAME.search(height_column.strip())
    if match:
        found = _unit_name(match.group(1).lower())
        if units is not None and units != found:
            raise RulerError(
                f"the ruler file {name!r}: column {height_column!r} says {found!r} but --ruler-units says {units!r}"
            )
        return found
    if units is None:
        raise RulerError(
            f"the ruler file {name!r} does not say the unit of {height_column!r}; "
            "give --ruler-units m, cm, mm or in (or a 'unit' column)"
        )
    return units


def _unit_name(text):
    """A unit as :data:`UNITS` names it: ``inch`` and ``inches`` are ``in``."""
    return _UNIT_NAMES.get(text, text)


def agreement(estimate, truth, *, err=None):
    """r, RMSE, bias and Lin's CCC of `estimate` against `truth` over the plots where both exist.

    With `err` (each plot's standard error, as ``height_p90_err_m``) also ``coverage``: the share of
    those plots with a finite, positive `err` whose ``|estimate - truth| <= Z90 x err`` (about 0.9
    when `err` is right; None without `err`, or when no plot has one: a terrain model given has none).

    Examples
    --------
    >>> a = agreement(np.array([0.5, 0.6, 0.7, np.nan]), np.array([0.55, 0.65, 0.75, 0.8]))
    >>> a["n"], round(a["r"], 3), round(a["rmse_m"], 3), round(a["bias_m"], 3), round(a["ccc"], 3)
    (3, 1.0, 0.05, -0.05, 0.842)
    >>> agreement([0.5, 0.6, 0.7], [0.55, 0.65, 0.75], err=[0.04, 0.02, 0.04])["coverage"]
    0.667
    """
    estimate = np.asarray(estimate, np.float64)
    truth = np.asarray(truth, np.float64)
    ok = np.isfinite(estimate) & np.isfinite(truth)
    a, b = estimate[ok], truth[ok]
    out = {"n": int(a.size), "r": None, "rmse_m": None, "bias_m": None, "ccc": None}
    if err is not None:
        e = np.asarray(err, np.float64)[ok]
        has = np.isfinite(e) & (e > 0)
        covered = np.abs(a - b)[has] <= Z90 * e[has]
        out["coverage"] = round(float(covered.mean()), 3) if has.any() else None
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

    Ordinary least squares. Its standard error at a height x, for a plot the ruler did not measure,
    is the textbook prediction error s sqrt(1 + 1/n + (x - mean)² / Sxx), s the residuals' standard
    deviation on n - 2 degrees of freedom (:func:`calibrated_err`). Its check without new labels:
    ``coverage``, the share of ruler plots whose leave-one-out error is within ``Z90`` times that
    error computed without them (the externally studentised residuals within ``Z90``).

    Returns ``{"a_m", "b", "n", "loo_rmse_m", "loo": agreement of the leave-one-out predictions,
    "residual_sd_m", "mean_m", "sxx_m2", "coverage"}``; ``residual_sd_m`` and ``coverage`` need four
    plots (None with three).

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
    n = x.size
    sd = coverage = None
    if n > 3:
        sse = float(np.sum(residual**2))
        sd = float(np.sqrt(sse / (n - 2)))
        # The residual variance without plot i (n - 3 degrees of freedom), and the prediction error
        # at x_i of the fit without it: s_(i) / sqrt(1 - h_i). Their ratio is the studentised residual.
        sd_without = np.sqrt(np.maximum(sse - residual**2 / np.maximum(1 - leverage, 1e-12), 0.0) / (n - 3))
        bound = Z90 * sd_without / np.sqrt(np.maximum(1 - leverage, 1e-12))
        coverage = round(float(np.mean(np.abs(loo_residual) <= bound)), 3)
    return {
        "a_m": float(coef[0]),
        "b": float(coef[1]),
        "n": int(n),
        "loo_rmse_m": float(np.sqrt(np.mean(loo_residual**2))),
        "loo": agreement(loo_prediction, y),
        "residual_sd_m": sd,
        "mean_m": float(x.mean()),
        "sxx_m2": float(np.sum((x - x.mean()) ** 2)),
        "coverage": coverage,
    }


def calibrated_err(fit, estimate):
    """The standard error of :func:`calibrate`'s corrected height at each of `estimate`'s heights.

    s sqrt(1 + 1/n + (x - mean)² / Sxx): the residual scatter about the line (the ruler against the
    DSM, ground and canopy errors together) and the line's own uncertainty, which grows away from
    the ruler plots' mean. NaN where `estimate` is, or when `fit` has no ``residual_sd_m``.

    Examples
    --------
    >>> x = np.array([0.4, 0.5, 0.6, 0.7, 0.8]); y = 0.1 + 1.2 * x + np.array([0.01, -0.01, 0, 0.01, -0.01])
    >>> err = calibrated_err(calibrate(x, y), np.array([0.6, 1.2]))
    >>> bool(err[0] < err[1])  # farther from the ruler's plots, less sure
    True
    """
    x = np.asarray(estimate, np.float64)
    if fit.get("residual_sd_m") is None:
        return np.full(x.shape, np.nan)
    spread = 1.0 + 1.0 / fit["n"] + (x - fit["mean_m"]) ** 2 / max(fit["sxx_m2"], 1e-12)
    return fit["residual_sd_m"] * np.sqrt(spread)


def ruler_columns(rows, ruler, *, calibrate_heights=False):
    """Add ``ruler_height_m`` (and ``height_calibrated_m``, ``height_calibrated_err_m``) to plot `rows`;
    return (columns, record).

    `rows` are :func:`cliff_terrain.measure.field_plots.plot_table`'s, in plot order. The record
    holds the agreement of ``height_p90_m`` with the ruler (with the coverage of
    ``height_p90_err_m`` when the rows have it) and, with `calibrate_heights`, the calibration
    (:func:`calibrate`), applied to every plot's ``height_p90_m`` with its standard error
    (:func:`calibrated_err`). ``warning`` says when the uncertainty covers fewer than
    ``COVERAGE_FLOOR`` of the ruler's plots: the ruler does not read the height the DSM shows.
    """
    ours = np.array([float(r["height_p90_m"]) for r in rows])
    err = None
    if rows and all("height_p90_err_m" in r for r in rows):
        err = np.array([float(r["height_p90_err_m"]) for r in rows])
    for row, measured in zip(rows, ruler.heights_m, strict=True):
        row["ruler_height_m"] = float(measured)
    against = agreement(ours, ruler.heights_m, err=err)
    record = {
        "file": ruler.path,
        "id_column": ruler.id_column,
        "height_column": ruler.height_column,
        "plot_field": ruler.plot_field,
        "unit": ruler.unit,
        "plots_matched": ruler.matched,
        "rows_unmatched": ruler.unmatched,
        "height_p90_m": against,
    }
    columns = ["ruler_height_m"]
    if against.get("coverage") is not None and against["coverage"] < COVERAGE_FLOOR and against["n"] >= 3:
        record["warning"] = (
            f"height_p90_err_m covers only {against['coverage']:.0%} of the ruler's plots (|error| <= "
            f"{Z90} x err; bias {against['bias_m'] * 100:+.1f} cm): that uncertainty is the ground's, and "
            "the ruler reads another height than the DSM's p90 (a photogrammetric DSM sees a canopy's "
            "top below a ruler's reading)"
            + (
                ""
                if calibrate_heights
                else "; --calibrate corrects the heights on the ruler and gives their error"
            )
        )
    if calibrate_heights:
        fit = calibrate(ours, ruler.heights_m)
        corrected = fit["a_m"] + fit["b"] * ours
        for row, value, sd in zip(rows, corrected, calibrated_err(fit, ours), strict=True):
            row["height_calibrated_m"] = float(value)
            row["height_calibrated_err_m"] = float(sd)
        record["calibration"] = fit
        columns += ["height_calibrated_m", "height_calibrated_err_m"]
    return columns, record


def ruler_line(record):
    """The ruler's part of the heights command's one-line summary ("" without a ruler or figures)."""
    if not record or record["height_p90_m"]["r"] is None:
        return ""
    a = record["height_p90_m"]
    line = f"; against the ruler ({a['n']} plots) r {a['r']:.2f}, RMSE {a['rmse_m'] * 100:.1f} cm"
    if a.get("coverage") is not None:
        line += f", its uncertainty covering {a['coverage']:.0%} of them"
        if "warning" in record:
            line += " (too few: see the ruler's warning in summary.json)"
    fit = record.get("calibration")
    if fit is not None:
        line += f", calibrated leave-one-out RMSE {fit['loo_rmse_m'] * 100:.1f} cm"
        if fit["coverage"] is not None:
            line += f" (its error covering {fit['coverage']:.0%})"
    return line
