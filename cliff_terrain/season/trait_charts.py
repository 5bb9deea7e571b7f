"""Pictures of a season's traits (matplotlib, imported here only): the fitted growth curves over the measured
points, and one trait over the plot polygons with a colour bar (viridis, perceptual)."""

from __future__ import annotations

import datetime as dt

import numpy as np

from ..errors import CliffTerrainError
from .growth import fit_growth


def growth_curves_chart(rows, traits, path, *, color_by=None):
    """``growth.png``: every plot's measured height and cover (points) and fitted curves (lines),
    coloured by `color_by`."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.dates import DateFormatter

    from .traits import cover_curve

    if color_by is not None and traits and color_by not in traits[0]:
        raise CliffTerrainError(f"`color_by` must be a plot attribute or trait, got {color_by!r}")
    first = min(dt.date.fromisoformat(str(r["date"])) for r in rows)
    start = dt.datetime.combine(first, dt.time())  # fractions of a day need datetimes, not dates
    series = {"height_p90": {}, "cover": {}}
    for row in rows:
        day = (dt.date.fromisoformat(str(row["date"])) - first).days
        for column, by_plot in series.items():
            if not row.get("error") and row.get(column) not in (None, ""):
                by_plot.setdefault(str(row["plot"]), []).append((day, float(row[column])))
    colours = _colours([t.get(color_by) if color_by else None for t in traits], plt)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), dpi=110, constrained_layout=True)
    for ax, (column, label) in zip(
        axes, (("height_p90", "canopy height p90 (m)"), ("cover", "canopy cover")), strict=True
    ):
        for trait, colour in zip(traits, colours, strict=True):
            points = sorted(series[column].get(str(trait["plot"]), []))
            if len(points) < 3:
                continue
            days, values = np.array(points).T
            ax.plot([start + dt.timedelta(days=d) for d in days], values, ".", color=colour, ms=4, alpha=0.7)
            if column == "cover":
                curve = cover_curve(days, values)[0]
            elif trait.get("height_model"):
                curve = fit_growth(days, values, model=trait["height_model"]).curve
            else:
                continue
            t = np.linspace(days.min(), days.max(), 200)
            ax.plot(
                [start + dt.timedelta(days=float(d)) for d in t], curve(t), color=colour, lw=1.0, alpha=0.6
            )
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.xaxis.set_major_formatter(DateFormatter("%d %b"))
    fig.suptitle(f"Growth curves of {len(traits)} plots" + (f", coloured by {color_by}" if color_by else ""))
    fig.savefig(path, format="png")  # the path may be a temporary name without .png
    plt.close(fig)


def _colours(values, plt):
    numeric = [v for v in values if isinstance(v, int | float) and np.isfinite(v)]
    if values and values[0] is None:
        return ["tab:green"] * len(values)
    if len(numeric) == len(values):
        lo, hi = min(numeric), max(numeric)
        cmap = plt.get_cmap("viridis")
        return [cmap((v - lo) / (hi - lo) if hi > lo else 0.5) for v in values]
    labels = sorted({str(v) for v in values})
    cmap = plt.get_cmap("tab10")
    return [cmap(labels.index(str(v)) % 10) for v in values]


def traits_map(plots, traits, path, *, trait="max_height_m"):
    """``traits_map.png``: `trait` of every plot drawn over its polygon, with a colour bar."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    if not traits or trait not in traits[0]:
        raise CliffTerrainError(f"`trait` must be a column of traits.csv, got {trait!r}")
    value_of = {str(t["plot"]): t[trait] for t in traits}
    dated = trait.endswith("_date") or trait.startswith("date_")
    polygons, values = [], []
    for index, rings in enumerate(plots.polygons):
        value = value_of.get(str(index))
        polygons.append(rings[0][:, :2])
        if dated:  # ISO dates drawn as days, labelled as dates
            values.append(dt.date.fromisoformat(value).toordinal() if value else np.nan)
        else:
            values.append(float(value) if isinstance(value, int | float) else np.nan)
    values = np.array(values)
    points = np.concatenate(polygons)
    width, height = np.ptp(points, axis=0)
    # As wide as the field is, and a little more for the colour bar.
    fig, ax = plt.subplots(figsize=(9, float(np.clip(9 * height / max(width, 1e-9), 2.5, 9)) + 1.2), dpi=110,
                           constrained_layout=True)  # fmt: skip
    collection = PolyCollection(
        polygons, array=np.ma.masked_invalid(values), cmap="viridis", edgecolors="0.3"
    )
    ax.add_collection(collection)
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")  # map coordinates as they are, not +4.9e6
    ax.set_xlabel("map x (m)")
    ax.set_ylabel("map y (m)")
    bar = fig.colorbar(collection, ax=ax, label=trait.replace("_", " "), shrink=0.9, aspect=15)
    if dated:
        from matplotlib.ticker import FuncFormatter

        bar.ax.yaxis.set_major_formatter(
            FuncFormatter(lambda v, _: dt.date.fromordinal(int(round(v))).strftime("%d %b"))
        )
    ax.set_title(f"{trait} per plot")
    fig.savefig(path, format="png")  # the path may be a temporary name without .png
    plt.close(fig)
