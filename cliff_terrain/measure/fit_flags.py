"""The plots of a fit as written: each with how far the fit moved it, how sure the fit is of it, and
a flag where the fit was refused and the plot keeps the place the user gave
(:func:`fitted_plots`; the fit is :func:`cliff_terrain.measure.plot_fit.fit_grid`).
"""

from __future__ import annotations

import numpy as np

from .plot_fit import MIN_COVER


def fitted_plots(layout, placement, fit, **numbering):
    """The numbered plots of a fit, each with how far the fit moved it and how sure it is.

    Parameters
    ----------
    layout, placement : Layout, Placement
        The unfitted grid (as the user gave it).
    fit : GridFit
        :func:`fit_grid`'s result from that grid.
    **numbering
        ``numbering``, ``start``, ``buffer``, ``field_book``, ``crs``: see
        :func:`cliff_terrain.measure.plot_grid.plots_from`.

    Returns
    -------
    PlotSet
        With three more attributes per plot: ``fit_shift_m`` (how far the fit moves the plot's
        centre, metres), ``fit_confidence`` (the grid's confidence: the fit moves the grid as one
        rigid body, so every plot rests on the whole grid's evidence; 0 for a plot with less than
        :data:`cliff_terrain.measure.plot_fit.MIN_COVER` plant cover, whose place comes from its neighbours alone) and ``fit_flag`` (1 when the
        fit was not accepted: a corner would move beyond the tolerance, or the confidence is below
        :data:`cliff_terrain.measure.plot_fit.CONFIDENT`; the plot then keeps its unfitted place and ``fit_shift_m`` says how far
        the refused fit would have moved it).
    """
    from .plot_grid import numbered, plots_from

    given = plots_from(layout, placement, **numbering)
    moved = plots_from(fit.layout, fit.placement, **numbering)
    accepted = bool(fit.report.get("accepted", True))
    confidence = float(fit.report["confidence"])
    cover = fit.plot_cover
    # Plot number -> its index in the grid's own (row, column) order, in which the cover is.
    ids = numbered(fit.layout, fit.placement, numbering=numbering.get("numbering", "serpentine"),
                   start=numbering.get("start", "top-left"))  # fmt: skip
    frame_index = {number: i for i, (number, _, _) in enumerate(ids)}
    by_number = {
        a["plot"]: rings[0][:4].mean(axis=0)
        for a, rings in zip(moved.attributes, moved.polygons, strict=True)
    }
    chosen = moved if accepted else given
    attributes = []
    for a, rings in zip(given.attributes, given.polygons, strict=True):
        shift = float(np.hypot(*(by_number[a["plot"]] - rings[0][:4].mean(axis=0))))
        own = confidence
        if cover is not None:
            own = confidence if cover[frame_index[a["plot"]]] >= MIN_COVER else 0.0
        attributes.append(
            {"fit_shift_m": round(shift, 3), "fit_confidence": round(own, 3), "fit_flag": int(not accepted)}
        )
    extra = {a["plot"]: e for a, e in zip(given.attributes, attributes, strict=True)}
    from ..io.vector.plot_polygons import PlotSet

    return PlotSet(
        chosen.polygons,
        [{**a, **extra[a["plot"]]} for a in chosen.attributes],
        tuple(chosen.fields) + ("fit_shift_m", "fit_confidence", "fit_flag"),
        chosen.crs,
        chosen.path,
    )
