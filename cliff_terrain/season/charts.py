"""``growth.png``: cover and height of every plot against date (matplotlib, imported here only).

Every plot is a thin line; the median and the interquartile band across plots are drawn bold. With
``color_by``, the plots are coloured by that attribute: a few categories (a treatment, a genotype)
each get a colour and their own median and band; many numeric values get a colour map instead.
"""

from __future__ import annotations

import datetime as dt
import math

from ..errors import CliffTerrainError
from .table import LEAD_COLUMNS, VALUE_COLUMNS

# At most this many categories get their own colour, median and band.
MAX_GROUPS = 10
PANELS = (("cover", "Canopy cover", "fraction of plot"), ("height_p90", "Height (p90)", None))


def growth_chart(rows, path, *, color_by=None, title=None):
    """Draw the season's rows (dicts as in ``season.csv``) into a PNG at `path`.

    Parameters
    ----------
    rows : list of dict
        One per date and plot, with ``date`` (ISO), ``plot``, ``cover``, ``height_p90`` and
        ``height_units``; rows with an error or no value are left out of the lines.
    path : str or os.PathLike
        The PNG to write.
    color_by : str, optional
        An attribute column to colour the plots by.
    title : str, optional
        The figure's title.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np

    if color_by is not None and rows and color_by not in rows[0]:
        fields = ", ".join(k for k in rows[0] if k not in _NOT_ATTRIBUTES)
        raise CliffTerrainError(f"`color_by` must be a plot attribute ({fields}), got {color_by!r}")
    dates = sorted({row["date"] for row in rows})
    x = [dt.date.fromisoformat(d) for d in dates]
    plots = sorted({row["plot"] for row in rows})
    where = {d: i for i, d in enumerate(dates)}
    which = {p: i for i, p in enumerate(plots)}
    units = next((row["height_units"] for row in rows if row.get("height_units")), "")
    modes = sorted({row["height_mode"] for row in rows if row.get("height_mode")})
    label_of = {}
    series = {}
    for column, _, _ in PANELS:
        values = np.full((len(plots), len(dates)), np.nan)
        for row in rows:
            value = row.get(column)
            if value not in (None, "") and not row.get("error"):
                values[which[row["plot"]], where[row["date"]]] = float(value)
        series[column] = values
    for row in rows:
        label_of[row["plot"]] = row.get(color_by) if color_by else None

    groups, colours, scalar = _colours(plots, label_of, color_by, plt, np)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), dpi=110, constrained_layout=True)
    for ax, (column, name, unit) in zip(axes, PANELS, strict=True):
        values = series[column]
        for i in range(len(plots)):
            ax.plot(x, values[i], color=colours[i], lw=0.6, alpha=0.45, marker=".", ms=2)
        for label, members, colour in groups:
            _median_band(ax, x, values[members], colour, label, np)
        ax.set_title(f"{name}, {' / '.join(modes)}" if column != "cover" and modes else name)
        ax.set_ylabel(unit or (f"height ({units})" if units else "height"))
        ax.grid(alpha=0.3)
        ax.set_xticks(x)
        ax.set_xticklabels([d.strftime("%d %b") for d in x], rotation=45, ha="right")
    if scalar is not None:
        fig.colorbar(scalar, ax=axes, label=color_by, shrink=0.8)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8, loc="best", title=color_by if len(groups) > 1 else None)
    fig.suptitle(title or f"{len(plots)} plots, {len(dates)} dates")
    fig.savefig(path, format="png")  # the path may be a temporary name without .png
    plt.close(fig)


# The table's own columns: everything else in a row is a plot attribute.
_NOT_ATTRIBUTES = {*LEAD_COLUMNS, *VALUE_COLUMNS}


def _colours(plots, label_of, color_by, plt, np):
    """(groups [(label, member indices, colour)], colour per plot, a ScalarMappable or None)."""
    everyone = [("median and IQR of all plots", np.arange(len(plots)), "black")]
    if color_by is None:
        return everyone, ["0.45"] * len(plots), None
    labels = [label_of[p] for p in plots]
    distinct = sorted({str(v) for v in labels})
    if len(distinct) <= MAX_GROUPS:
        cmap = plt.get_cmap("tab10")
        colour_of = {v: cmap(i) for i, v in enumerate(distinct)}
        groups = [
            (f"{v}", np.array([i for i, lab in enumerate(labels) if str(lab) == v]), colour_of[v])
            for v in distinct
        ]
        return groups, [colour_of[str(lab)] for lab in labels], None
    numbers = [_number(v) for v in labels]
    if any(n is None for n in numbers):
        raise CliffTerrainError(
            f"`color_by` {color_by!r} has {len(distinct)} distinct values; a text attribute can colour "
            f"at most {MAX_GROUPS} groups"
        )
    norm = plt.Normalize(min(numbers), max(numbers))
    cmap = plt.get_cmap("viridis")
    scalar = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    return everyone, [cmap(norm(n)) for n in numbers], scalar


def _median_band(ax, x, values, colour, label, np):
    """The median line and the 25-75 % band across plots, at dates where some plot has a value."""
    has = np.isfinite(values).any(axis=0)
    if not has.any():
        return
    xs = [d for d, h in zip(x, has, strict=True) if h]
    v = values[:, has]
    q25, q50, q75 = (np.nanpercentile(v, q, axis=0) for q in (25, 50, 75))
    ax.fill_between(xs, q25, q75, color=colour, alpha=0.22, lw=0)
    ax.plot(xs, q50, color=colour, lw=2.6, label=label)


def _number(value):
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None
