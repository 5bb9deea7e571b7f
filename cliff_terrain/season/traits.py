"""Breeders' traits per plot from a season's table: growth curves of height and cover, and the dates on them.

Reads the rows of ``season.csv`` (one per date and plot), fits each plot's height (p90) and cover
against the day of the season (:mod:`cliff_terrain.season.growth`) and reads the traits off the
fitted curves on a grid of tenths of a day:

``max_height_m``
    The asymptote (logistic, Gompertz), else the curve's maximum.
``max_growth_rate_m_per_day``, ``max_growth_date``
    The steepest rise of the height curve and its date.
``date_50pct``, ``date_90pct``
    When the height curve first reaches 50 % and 90 % of ``max_height_m`` (empty if not in the season).
``canopy_closure_date``
    When the cover curve first reaches `closure` (0.9); if it never does, when it reaches 95 % of
    its own maximum (its plateau; the flag says so).
``senescence_date``
    After its peak, when the cover curve falls back to half its maximum (empty if it never does).
    A declining cover is fitted by the double logistic when it fits (R² >= 0.9), else followed by a
    shape-preserving (PCHIP) curve through the measured covers.
``auc_m_days``
    The area under the height curve over the season.
``fit_r2``, ``fit_rmse_m``, ``height_model``, ``flag``
    The height fit's quality and model; ``flag`` lists: fewer than 4 dates, no growth, poor fit
    (R² < 0.8), a date dropped as an outlier (a residual beyond 3 robust standard deviations and
    5 % of the maximum; refitted without it).
"""

from __future__ import annotations

import datetime as dt
import math

import numpy as np

from ..errors import CliffTerrainError
from .growth import MODELS, declines, fit_growth

TRAIT_COLUMNS = (
    "height_model",
    "max_height_m",
    "max_growth_rate_m_per_day",
    "max_growth_date",
    "date_50pct",
    "date_90pct",
    "canopy_closure_date",
    "senescence_date",
    "auc_m_days",
    "fit_r2",
    "fit_rmse_m",
    "dates",
    "flag",
)
# season.csv's own columns (the rest of a row are the plot's attributes).
SEASON_COLUMNS = {
    "date", "date_source", "image", "plot", "area_m2", "cover", "volume_m3", "height_mean", "height_p50",
    "height_p90", "height_max", "height_mode", "height_units", "reason", "error",
}  # fmt: skip
STEP_DAYS = 0.1
#: The files `cliff-terrain traits` writes, in the order it writes them (the last marks a finished
#: run); the season's runner removes them when the table they were fitted on changes.
TRAITS_OUTPUTS = ("traits.csv", "traits.geojson", "growth.png", "traits_map.png")


def season_traits(rows, *, model="auto", closure=0.9):
    """One row of traits per plot from the rows of ``season.csv``.

    Parameters
    ----------
    rows : list of dict
        ``date`` (ISO), ``plot``, ``cover``, ``height_p90`` and the plot's attributes (strings or
        numbers; empty values and rows with an ``error`` are left out).
    model : {"auto", "logistic", "gompertz", "double", "spline"}, optional
        The height curve's model.
    closure : float, optional
        Cover at which the canopy counts as closed (0-1).

    Returns
    -------
    list of dict
        ``plot``, the attributes, then :data:`TRAIT_COLUMNS`; dates ISO, missing values NaN or "".
    """
    if model not in MODELS:
        raise CliffTerrainError(f"`model` must be one of {', '.join(map(repr, MODELS))}, got {model!r}")
    if not 0.0 < float(closure) <= 1.0:
        raise CliffTerrainError(f"`closure` must be in (0, 1], got {closure}")
    if not rows:
        raise CliffTerrainError("the season has no rows")
    first = min(dt.date.fromisoformat(str(row["date"])) for row in rows)
    plots = {}
    for row in rows:
        plots.setdefault(str(row["plot"]), []).append(row)
    out = []
    for plot, plot_rows in plots.items():
        attributes = {k: v for k, v in plot_rows[0].items() if k not in SEASON_COLUMNS}
        days = np.array([(dt.date.fromisoformat(str(r["date"])) - first).days for r in plot_rows], float)
        ok = [not r.get("error") for r in plot_rows]
        heights = np.array(
            [_number(r.get("height_p90")) if good else np.nan for r, good in zip(plot_rows, ok, strict=True)]
        )
        cover = np.array(
            [_number(r.get("cover")) if good else np.nan for r, good in zip(plot_rows, ok, strict=True)]
        )
        traits = plot_traits(days, heights, cover, model=model, closure=closure)
        for key in ("max_growth_date", "date_50pct", "date_90pct", "canopy_closure_date", "senescence_date"):
            traits[key] = _iso(first, traits[key])
        out.append({"plot": _plot_id(plot), **attributes, **traits})
    return sorted(out, key=lambda r: (isinstance(r["plot"], str), r["plot"]))


def plot_traits(days, heights, cover, *, model="auto", closure=0.9):
    """The traits of one plot (dates as days of the season, NaN when missing); see the module."""
    traits = {key: math.nan for key in TRAIT_COLUMNS}
    traits.update(height_model="", flag="")
    flags = []
    good = np.isfinite(days) & np.isfinite(heights)
    traits["dates"] = int(good.sum())
    if good.sum() < 4:
        flags.append("fewer than 4 dates")
    if good.sum() >= 3:
        fit, dropped = _robust_fit(days[good], heights[good], model)
        if dropped is not None:
            flags.append(f"day {dropped:g} dropped as an outlier")
        t = np.arange(days[good].min(), days[good].max() + STEP_DAYS / 2, STEP_DAYS)
        y = fit.curve(t)
        top = float(fit.params[0]) if fit.model in ("logistic", "gompertz") else float(np.max(y))
        rate = np.gradient(y, t)
        k = int(np.argmax(rate))
        traits.update(
            height_model=fit.model,
            max_height_m=top,
            max_growth_rate_m_per_day=float(rate[k]),
            max_growth_date=float(t[k]),
            date_50pct=_first_reach(t, y, 0.5 * top),
            date_90pct=_first_reach(t, y, 0.9 * top),
            auc_m_days=float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t))),  # trapezoids
            fit_r2=fit.r2,
            fit_rmse_m=fit.rmse,
        )
        spread = float(np.nanmax(heights) - np.nanmin(heights))
        rises = int(np.nanargmax(heights[good])) > 0  # the season starts below its peak
        if not spread > 0.05 * max(abs(float(np.nanmax(heights))), 1e-9) or rate[k] <= 1e-9 or not rises:
            flags.append("no growth")
        elif not fit.r2 >= 0.8:
            flags.append("poor fit")
    closure_day, senescence_day, cover_flags = _cover_dates(days, cover, closure)
    traits.update(canopy_closure_date=closure_day, senescence_date=senescence_day)
    traits["flag"] = "; ".join(flags + cover_flags)
    return traits


def _robust_fit(days, values, model):
    """Fit; refit once without the worst date when its residual is an outlier."""
    fit = fit_growth(days, values, model=model)
    residual = np.abs(fit.residuals)
    if days.size >= 5:
        spread = 1.4826 * float(np.median(residual))
        worst = int(np.argmax(residual))
        if residual[worst] > max(3.0 * spread, 0.05 * float(np.max(values))):
            keep = np.arange(days.size) != worst
            return fit_growth(days[keep], values[keep], model=model), float(days[worst])
    return fit, None


def cover_curve(days, cover):
    """(curve, falls, flags) of a plot's cover: a double logistic where it falls after its peak and
    that fits (R² >= 0.9, no overshoot above 1.1 times the highest cover), else a shape-preserving
    curve through the measured covers; a growth curve where it does not fall."""
    falls = declines(cover)
    flags = []
    if not falls:
        return fit_growth(days, cover, model="auto").curve, False, flags
    try:
        fit = fit_growth(days, cover, model="double")
        # Between two flights a steep fit may overshoot far above every measured cover: not trusted.
        peak = float(np.max(fit.curve(np.linspace(days.min(), days.max(), 500))))
        if fit.r2 >= 0.9 and peak <= 1.1 * float(np.max(cover)):
            return fit.curve, True, flags
    except CliffTerrainError:
        pass
    from scipy.interpolate import PchipInterpolator

    flags.append("senescence read from the measured covers")
    return PchipInterpolator(days, cover), True, flags


def _cover_dates(days, cover, closure):
    """(closure day, senescence day, flags) from the cover series."""
    good = np.isfinite(days) & np.isfinite(cover)
    d, c = days[good], cover[good]
    if d.size < 3:
        return math.nan, math.nan, []
    order = np.argsort(d)
    d, c = d[order], c[order]
    curve, falls, flags = cover_curve(d, c)
    t = np.arange(d[0], d[-1] + STEP_DAYS / 2, STEP_DAYS)
    y = curve(t)
    top = float(np.max(y))
    closure_day = _first_reach(t, y, closure)
    if not np.isfinite(closure_day) and top > 0:
        closure_day = _first_reach(t, y, 0.95 * top)
        flags.append(f"canopy closure at the plateau (cover {top:.2f} < {closure:g})")
    senescence_day = math.nan
    if falls:
        after = np.arange(t.size) > int(np.argmax(y))
        below = np.flatnonzero(after & (y <= 0.5 * top))
        if below.size:
            senescence_day = float(t[below[0]])
    return closure_day, senescence_day, flags


def _first_reach(t, y, level):
    above = np.flatnonzero(y >= level)
    return float(t[above[0]]) if above.size else math.nan


def _number(value):
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _iso(first, day):
    if not np.isfinite(day):
        return ""
    return (first + dt.timedelta(days=round(float(day)))).isoformat()


def _plot_id(plot):
    try:
        return int(plot)
    except ValueError:
        return plot
