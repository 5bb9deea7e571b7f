"""Growth curves: a plot's height (or cover) against the day of the season, fitted by one of a few models.

Models (``t`` in days, SciPy's bounded least squares from several deterministic starts):

``logistic``
    ``A / (1 + exp(-k (t - t0)))``: the asymptote ``A``, the inflection ``t0`` (the date of the
    fastest growth, ``A k / 4`` per day).
``gompertz``
    ``A exp(-exp(-k (t - t0)))``: an earlier, slower approach to ``A`` (inflection at ``t0``).
``double``
    ``A (1 / (1 + exp(-k1 (t - t1))) - 1 / (1 + exp(-k2 (t - t2))))``, ``t2 > t1``: growth then
    decline (senescence).
``spline``
    A monotone curve through the data: isotonic regression (pool adjacent violators) joined by
    PCHIP, for irregular seasons (never overshoots, never decreases).
``auto``
    The model with the lowest AICc among those with at least two dates more than parameters (the
    spline counts one per isotonic step; the logistic when none qualifies), the double
    logistic only for series that fall after their peak; which one is recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import CliffTerrainError

MODELS = ("auto", "logistic", "gompertz", "double", "spline")
PARAMETERS = {"logistic": 3, "gompertz": 3, "double": 5, "spline": 2}
# Per start: a start that has not converged by then is one of several, and a worse one.
MAX_EVALUATIONS = 600
REFINED_STARTS = 3


def logistic(t, a, k, t0):
    from scipy.special import expit  # 1 / (1 + exp(-x)) without overflow

    return a * expit(k * (np.asarray(t, dtype=np.float64) - t0))


def gompertz(t, a, k, t0):
    x = np.clip(-k * (np.asarray(t, dtype=np.float64) - t0), -700.0, 700.0)
    return a * np.exp(-np.exp(x))


def double_logistic(t, a, k1, t1, k2, t2):
    from scipy.special import expit

    t = np.asarray(t, dtype=np.float64)
    return a * (expit(k1 * (t - t1)) - expit(k2 * (t - t2)))


def declines(values):
    """Whether a series falls clearly after its peak (last value under 75 % of the maximum)."""
    values = np.asarray(values, dtype=np.float64)
    peak = int(np.argmax(values))
    return peak < values.size - 1 and values[-1] < 0.75 * values[peak]


@dataclass
class GrowthFit:
    """A fitted curve: ``model``, its ``params``, and ``curve(t)`` for any days."""

    model: str
    params: tuple
    days: np.ndarray
    values: np.ndarray
    curve: object

    @property
    def residuals(self):
        return self.values - self.curve(self.days)

    @property
    def rmse(self):
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def r2(self):
        spread = float(np.sum((self.values - self.values.mean()) ** 2))
        return 1.0 - float(np.sum(self.residuals**2)) / spread if spread > 0 else float("nan")

    @property
    def n_parameters(self):
        # The monotone spline spends one parameter per isotonic step (pooled blocks), plus its ends.
        return (
            len(np.unique(self.curve(self.days).round(12))) + 1
            if self.model == "spline"
            else PARAMETERS[self.model]
        )

    def aic(self):
        n, p = len(self.days), self.n_parameters
        rss = max(float(np.sum(self.residuals**2)), 1e-12 * n)
        aic = n * math.log(rss / n) + 2 * p
        # Too few dates for the correction: the model cannot be judged against the others.
        return aic + 2 * p * (p + 1) / (n - p - 1) if n - p - 1 > 0 else math.inf


def fit_growth(days, values, *, model="auto"):
    """Fit a growth curve to one plot's values against days.

    Parameters
    ----------
    days, values : 1-D arrays
        At least 3 finite pairs (NaN values are left out).
    model : {"auto", "logistic", "gompertz", "double", "spline"}, optional

    Returns
    -------
    GrowthFit

    Examples
    --------
    >>> t = np.arange(0.0, 120.0, 10.0)
    >>> fit = fit_growth(t, logistic(t, 0.8, 0.12, 55.0), model="logistic")
    >>> [round(float(v), 3) for v in fit.params]
    [0.8, 0.12, 55.0]
    """
    if model not in MODELS:
        raise CliffTerrainError(f"`model` must be one of {', '.join(map(repr, MODELS))}, got {model!r}")
    days = np.asarray(days, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    keep = np.isfinite(days) & np.isfinite(values)
    days, values = days[keep], values[keep]
    order = np.argsort(days)
    days, values = days[order], values[order]
    if days.size < 3:
        raise CliffTerrainError(f"a growth curve needs at least 3 dates with values, got {days.size}")
    if model != "auto":
        return _fit(model, days, values)
    # The double logistic only where the values fall after their peak: a rise alone is the others'.
    candidates = [m for m in MODELS[1:] if PARAMETERS[m] < days.size and (m != "double" or declines(values))]
    fits = [f for f in (_try(m, days, values) for m in candidates) if f is not None]
    return min(fits, key=lambda f: (f.aic(), MODELS.index(f.model)))


def _try(model, days, values):
    try:
        return _fit(model, days, values)
    except (RuntimeError, ValueError, CliffTerrainError):
        return None


def _fit(model, days, values):
    if model == "spline":
        return _spline(days, values)
    from scipy.optimize import curve_fit

    top = max(float(values.max()), 1e-6)
    span = float(days[-1] - days[0]) or 1.0
    first, last = float(days[0]), float(days[-1])
    # Starts on a grid of inflection dates and rates: the fit does not depend on a lucky guess.
    centres = np.linspace(first + 0.1 * span, last - 0.1 * span, 5)
    rates = (4.0 / span, 12.0 / span)
    if model in ("logistic", "gompertz"):
        function = logistic if model == "logistic" else gompertz
        bounds = ([0.0, 1e-4, first - span], [4.0 * top, 5.0, last + span])
        starts = [(top, k, c) for k in rates for c in centres]
    else:
        function = double_logistic
        peak = float(days[int(np.argmax(values))])
        bounds = (
            [0.0, 1e-4, first - span, 1e-4, first - span],
            [4.0 * top, 5.0, last + span, 5.0, last + 2 * span],
        )
        starts = [
            (top, k, c1, k, c2)
            for k in rates
            for c1 in (first, 0.5 * (first + peak))
            for c2 in (0.5 * (peak + last), last)
        ]
    best, best_cost = None, np.inf
    starts = [np.clip(st, np.asarray(bounds[0]) + 1e-9, np.asarray(bounds[1]) - 1e-9) for st in starts]
    # The whole grid of starts is scored, and the few closest to the data are refined.
    starts.sort(key=lambda st: float(np.sum((function(days, *st) - values) ** 2)))
    for start in starts[:REFINED_STARTS]:
        try:
            params, _ = curve_fit(function, days, values, p0=start, bounds=bounds, maxfev=MAX_EVALUATIONS)
        except (RuntimeError, ValueError):
            continue
        cost = float(np.sum((function(days, *params) - values) ** 2))
        if cost < best_cost:
            best, best_cost = params, cost
    if best is None:
        raise CliffTerrainError(f"the {model} curve did not converge")
    if model == "double" and best[4] <= best[2]:
        raise CliffTerrainError("the double logistic found no decline after the growth")
    params = tuple(float(p) for p in best)
    return GrowthFit(model, params, days, values, lambda t, f=function, p=params: f(np.asarray(t, float), *p))


def _spline(days, values):
    from scipy.interpolate import PchipInterpolator

    fitted = _isotonic(values)
    # PCHIP needs distinct days; equal isotonic steps give a flat, monotone curve.
    curve = PchipInterpolator(days, fitted, extrapolate=False)

    def evaluate(t, curve=curve, lo=days[0], hi=days[-1], a=fitted[0], b=fitted[-1]):
        t = np.asarray(t, dtype=np.float64)
        out = curve(np.clip(t, lo, hi))
        return np.where(t < lo, a, np.where(t > hi, b, out))

    return GrowthFit("spline", (), days, values, evaluate)


def _isotonic(values):
    """Pool adjacent violators: the non-decreasing sequence closest to `values` (least squares)."""
    blocks = [[float(v), 1] for v in values]
    merged = []
    for block in blocks:
        merged.append(block)
        while len(merged) > 1 and merged[-2][0] > merged[-1][0]:
            v2, n2 = merged.pop()
            v1, n1 = merged.pop()
            merged.append([(v1 * n1 + v2 * n2) / (n1 + n2), n1 + n2])
    return np.concatenate([np.full(n, v) for v, n in merged])
