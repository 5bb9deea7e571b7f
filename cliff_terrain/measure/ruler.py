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

import numpy as np

from ..errors import CliffTerrainError
from .field_book import UNITS, Ruler, read_ruler  # noqa: F401 (the ruler's reading, re-exported)

# |error| <= Z90 x standard error for 90 % of plots when the errors are normal (the two-sided 90 %
# interval): what an uncertainty "covers", here and on the validation page.
Z90 = 1.645
# An uncertainty that covers fewer of the ruler's plots than this is said to be too small.
COVERAGE_FLOOR = 0.8


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
