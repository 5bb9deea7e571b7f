"""The crop's key figures, defined once: plants, cover, plant height and canopy height.

``render_views.py`` (``metrics.json``), ``cliff-terrain heights`` (``summary.json``), the sidebar and
the Render Views operator all take them from :func:`key_figures`, so equal inputs and settings give
equal numbers everywhere. The definitions (also in the README):

plants
    The number of plant regions of the segmentation: the plant mask split into single plants by
    the watershed (the rows of ``regions.csv``).
cover
    The share of plant pixels among the pixels with data (the photo's, and the surface model's
    when there is one): the pixels whose vegetation index lies above the photo's plant threshold
    (:func:`~cliff_terrain.measure.canopy.cover_pixels`), before the relief fills the holes inside its plants and drops its specks
    (that shapes the domes, not the cover), as the windowed measure counts them.
plant height
    Per plant, the highest point of its region: of the canopy height model with a surface
    model, else of the relief's heights (before exaggeration). Reported as the median and the 90th
    percentile over the plants.
canopy height
    The canopy height at every plant pixel with data: the canopy height model (DSM minus ground)
    with a surface model, else the relief's heights (before exaggeration). Reported as its 50th
    and 90th percentiles.

Heights are in metres with a surface model or a ground sample distance (keys ending ``_m``),
else in processing pixels (``_px``).
"""

from __future__ import annotations

import numpy as np


def relief_valid(relief):
    """Pixels of the relief's grid with data: the photo's (an orthophoto's alpha) and the DSM's."""
    from .canopy import photo_valid

    valid = photo_valid(relief.metadata, relief.mask.shape)
    if valid is None:
        valid = np.ones(relief.mask.shape, dtype=bool)
    if relief.canopy is not None:
        valid &= np.isfinite(relief.canopy.chm)
    return valid


def plant_cover(relief, *, valid=None):
    """The key figure ``cover``: :func:`~cliff_terrain.measure.canopy.cover_pixels` among the pixels with data (`valid`, default
    :func:`relief_valid`)."""
    from .canopy import cover_pixels

    valid = relief_valid(relief) if valid is None else valid
    return float(np.count_nonzero(cover_pixels(relief) & valid) / max(1, np.count_nonzero(valid)))


def canopy_heights(relief):
    """The height map the figures are taken from, and its unit (``"m"`` or ``"px"``).

    The canopy height model with a surface model; else the relief's heights before exaggeration.
    """
    if relief.canopy is not None:
        return relief.canopy.chm, "m"
    exaggeration = float(relief.params.get("exaggeration") or 1.0)
    return relief.heights / np.float32(exaggeration), relief.units


def key_figures(relief):
    """Plants, cover, canopy height p50/p90 and plant height median/p90 of a relief.

    Parameters
    ----------
    relief : cliff_terrain.build.Relief

    Returns
    -------
    dict
        ``plants`` (int), ``cover`` (0-1), ``units`` (``"m"`` or ``"px"``) and, with that unit as
        suffix, ``canopy_height_p50_m``, ``canopy_height_p90_m``, ``plant_height_median_m``,
        ``plant_height_p90_m`` (None without plant pixels).

    Examples
    --------
    >>> from cliff_terrain import build_relief
    >>> img = np.full((60, 60, 3), (120, 90, 60), np.uint8); img[20:40, 20:40] = (40, 160, 40)
    >>> figures = key_figures(build_relief(img, mesh=None))
    >>> figures["plants"], round(figures["cover"], 3), figures["units"]
    (1, 0.133, 'px')
    """
    from ..photo_heights.labels import label_max

    heights, unit = canopy_heights(relief)
    valid = relief_valid(relief)
    plants = relief.mask & valid
    n = int(relief.n_regions)
    figures = {"plants": n, "cover": plant_cover(relief, valid=valid), "units": unit}
    values = heights[plants]
    values = values[np.isfinite(values)]
    p50, p90 = (float(v) for v in np.percentile(values, (50, 90))) if values.size else (None, None)
    tops = np.asarray([], dtype=np.float64)
    if n:
        labels = relief.labels if valid.all() else np.where(valid, relief.labels, 0)
        if not np.isfinite(heights).all():
            heights = np.nan_to_num(heights)
        # Each plant's highest point (any sign: a canopy height model dips below the ground). The
        # heights are finite, so a plant with a pixel has a top above -inf.
        tops = label_max(heights, labels, initial=-np.inf, dtype=heights.dtype)
        tops = np.pad(tops, (0, max(0, n + 1 - len(tops))), constant_values=-np.inf)[1 : n + 1]
        tops = tops[tops > -np.inf].astype(np.float64)
    figures.update(
        {
            f"canopy_height_p50_{unit}": p50,
            f"canopy_height_p90_{unit}": p90,
            f"plant_height_median_{unit}": float(np.median(tops)) if tops.size else None,
            f"plant_height_p90_{unit}": float(np.percentile(tops, 90)) if tops.size else None,
        }
    )
    return figures


def figures_line(figures, *, cover_note=""):
    """The figures as one line of text (the CLI's and the log's); `cover_note` follows the cover
    (:func:`undecided_cover`)."""

    def height(key):
        value = figures.get(f"{key}_{figures['units']}")
        if value is None:
            return "n/a"
        return f"{value * 100:.1f} cm" if figures["units"] == "m" else f"{value:.3g} px"

    return (
        f"{figures['plants']} plants, cover {figures['cover']:.1%}{cover_note}, canopy height p50 {height('canopy_height_p50')}, "
        f"p90 {height('canopy_height_p90')}, plant height median {height('plant_height_median')}"
    )


def undecided_cover(threshold):
    """The summary line's clause when the image could not tell plants from soil, else ``""``.

    `threshold` is the record of ``summary.json``'s ``threshold`` (a ``source`` and a ``note``): an
    image of one colour (``uniform``: the prior band's threshold decided), or a split left undecided
    (source ``band``, ``note`` starting ``undecided``: the DSM did not decide it either, and only
    what lies above the index floor counts). The cover then follows a default threshold, not a split
    the image showed, and the line says so. A photo's own split (``photo``, ``photo (upper
    valley)``, ``photo (dsm)``...) and a closed canopy's one class (the band, ``one class``) say
    nothing.

    Examples
    --------
    >>> undecided_cover({"source": "band", "note": ""})
    ''
    >>> undecided_cover({"source": "uniform", "note": "uniform: the photo has one colour"})
    " (the image cannot tell plants from soil here: a default threshold decided, see summary.json's threshold)"
    """
    source, note = threshold.get("source"), threshold.get("note") or ""
    if source == "uniform" or (source == "band" and note.startswith("undecided")):
        return " (the image cannot tell plants from soil here: a default threshold decided, see summary.json's threshold)"
    return ""
