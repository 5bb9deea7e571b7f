"""A plot grid snapped to the crop: direction, pitch and position of the columns and rows from the plant mask.

The plant pixels are projected into the grid's frame (u across the columns, v along them) and
binned into a 2-D histogram. A placement's score is the number of plant pixels inside its plots
minus the number inside the grid's outline but between the plots (the alleys and gaps): plots that
sit on the crop rows and alleys that sit on bare soil. For one direction the score of every shift
and pitch along u comes from one cumulative sum of the histogram's projection onto u (summed over
the plots' v-windows), and the same along v; the two are optimised in turn. The direction is
searched around the starting one (or, with no placement, over all directions, starting from the
one along which the projection is most contrasted: the direction of the crop rows).

A guard row beside the trial looks like a plot column; what tells them apart is that plot columns
are cut by the alleys and guard rows often are not. The report says how much the grid would lose
to the same grid shifted by one pitch (``confidence``, see :class:`GridFit`).

With the corners as constraints (``tolerance``) the shifts and pitches searched are those that keep
every corner within the tolerance, the score adds the crop's periodicity (plant pixels weighted by a
cosine of the pitch, highest on each plot's centre line: touching single-row plots lock on their
rows), the alternative for the confidence is half a pitch away, and a fit that is unsure or pulled
against the tolerance is not accepted (:func:`cliff_terrain.measure.fit_flags.fitted_plots` then keeps the unfitted plots, flagged).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import check_float
from ..errors import CliffTerrainError
from .grid_search import SOIL_COST, best_1d, edge_bounds, profile
from .plot_grid import Layout, Placement, axes


@dataclass(frozen=True)
class GridFit:
    """The fitted grid and how well it fits.

    Attributes
    ----------
    layout : Layout
        With the fitted pitches (unless the spacing was uneven or pinned).
    placement : Placement
    report : dict
        ``angle_deg``, ``column_pitch_m``, ``row_pitch_m``, ``plant_share_in_plots`` (plant
        pixels inside the plots over all plant pixels), ``plant_share_in_alleys`` (plant pixels
        between the plots inside the grid's outline, over those inside the outline),
        ``confidence`` (0-1, see below), ``moved_m`` (how far the grid's centre moved) and
        ``rotated_deg``, ``plots_with_crop`` (the share of the plots with at least
        :data:`MIN_COVER` plant cover), ``score`` (the objective maximised, in plant pixels as
        sampled: with ``tolerance=0`` the score of the given grid itself); with corners as constraints also ``tolerance_m``, ``corner_shift_m`` and
        ``accepted``.

    Notes
    -----
    The confidence scale: the score the fitted grid would lose if it were replaced by the
    alternative grid, in units of one column's (for the shift across) or one row's (along) plant
    pixels inside the plots, clipped to 0-1; the smaller of the two axes. The alternative is the
    same grid shifted by one whole pitch (placement-free fit: a guard row taken for a plot column)
    or, with corners as constraints (which rule out a whole pitch), by half a pitch (the plots
    centred on the gaps between the crop rows). 0: the crop does not tell the fitted grid from the
    alternative; 1: the alternative loses at least one column's (row's) worth of plant pixels.
    Below :data:`CONFIDENT` (0.5) the fit is not accepted.
    """

    layout: Layout
    placement: Placement
    report: dict
    plot_cover: np.ndarray | None = None  # plant cover (0-1) of each fitted plot, (row, column) order


def fit_grid(
    plants,
    transform,
    layout,
    *,
    placement=None,
    angle=None,
    pitch=None,
    origin=None,
    search_deg=3.0,
    valid=None,
    tolerance=None,
):
    """Snap a plot grid to the crop in a plant mask.

    Parameters
    ----------
    plants : (rows, cols) bool array
        Plant pixels.
    transform : (3, 3) or (2, 3) array
        Pixel (col, row) -> map (x, y) of `plants`.
    layout : Layout
        The grid's columns, rows, plot size and (starting) spacing.
    placement : Placement, optional
        A rough placement (corners clicked within about a quarter of a pitch). Without it the
        grid is placed from the mask alone.
    angle : float, optional
        Pins the direction of u (degrees from the map's x axis).
    pitch : (float, float), optional
        Pins the column and row pitch. Else it is fitted within 5 % of the layout's; with no
        placement and touching plots on an axis (no spacing given), found between the plot's size
        and twice it.
    origin : (float, float), optional
        Pins the map point of the grid's (u, v) = (0, 0) corner.
    search_deg : float, optional
        How far the direction is searched around the starting one.
    valid : (rows, cols) bool array, optional
        Pixels with data (the rest is neither plant nor soil).
    tolerance : float, optional
        With a `placement`: its corners are constraints. The fitted grid's outer edges stay within
        `tolerance` metres of the given corners, along each of the grid's axes, so the pitch is what
        the corners and the counts imply, refined within that; and the score adds the crop's
        periodicity across and along the rows (the plant pixels' projection weighted by a cosine of
        the pitch, peaking on each plot's centre line), which locks touching single-row plots on
        their rows. The report then also says ``corner_shift_m`` (how far the farthest corner
        moved along either axis of the grid: the quantity `tolerance` bounds),
        ``corner_distance_m`` (the same, Euclidean) and ``accepted`` (see :data:`CONFIDENT`). Without it the fit is the
        placement-free one described above.

    Returns
    -------
    GridFit

    Examples
    --------
    Three touching single-row plots of 0.8 m on a synthetic crop whose rows are 0.8 m apart, with the
    corners given 0.2 m off: the fit puts each plot back on its row.

    >>> from cliff_terrain.measure.plot_grid import grid_layout, placement_from_corners
    >>> plants = np.zeros((1100, 340), bool)  # 1 cm pixels; plot rows 5 m long, 10 cm wide, 0.8 m apart
    >>> for x in (0.9, 1.7, 2.5):
    ...     plants[300:800, int(100 * x) - 5:int(100 * x) + 5] = True
    >>> transform = [[0.01, 0.0, 0.0], [0.0, -0.01, 11.0]]
    >>> layout = grid_layout(3, 1, plot_size=(0.8, 5.0))
    >>> given = placement_from_corners([(0.7, 3.1), (3.1, 3.1), (3.1, 8.1), (0.7, 8.1)], layout.extent)
    >>> fit = fit_grid(plants, transform, layout, placement=given, tolerance=0.4, search_deg=0.0)
    >>> np.round(fit.placement.corners[0], 2).tolist(), fit.report["accepted"]
    ([0.5, 3.0], True)
    """
    from ..io.raster.transform import as_affine

    if tolerance is not None:
        tolerance = check_float("tolerance", tolerance, minimum=0.0)
        if placement is None:
            raise CliffTerrainError(
                "`tolerance` holds the fit to a placement's corners: give `placement` too"
            )
    plants = np.asarray(plants, dtype=bool)
    t = as_affine(transform)
    rr, cc = np.nonzero(plants)
    if rr.size < 100:
        raise CliffTerrainError(
            f"the orthophoto shows {rr.size} plant pixels: too few to fit a plot grid to; place it with --corners"
        )
    step = max(1, rr.size // 400_000)
    rr, cc = rr[::step] + 0.5, cc[::step] + 0.5
    points = _map_points(t, rr, cc)
    # Bare soil, sampled as densely as the plants (weighted to the same units): plots on soil cost.
    soil = ~plants if valid is None else ~plants & np.asarray(valid, dtype=bool)
    sr, sc = np.nonzero(soil)
    soil_step = max(1, sr.size // 400_000)
    soil_points = _map_points(t, sr[::soil_step] + 0.5, sc[::soil_step] + 0.5)
    soil_weight = soil_step / step
    pixel = math.sqrt(abs(np.linalg.det(t[:2, :2])))
    uniform = _uniform(layout.column_offsets) and _uniform(layout.row_offsets)
    fit_pitch = pitch is None and uniform
    # The pitch scales searched per axis: within 5 % of the layout's; from the plot's size to twice it
    # when the grid is placed from the mask alone and the layout gives no spacing on that axis (plots
    # touching: the user did not say how far apart they are); none when pinned or uneven.
    scale_ranges = (None, None)
    if tolerance is not None:
        scale_ranges = (None, None)  # the corners bound the pitch instead (see edge_bounds)
    elif fit_pitch:
        find = placement is None and origin is None
        scale_ranges = tuple(
            FIND_PITCH if find and _touching(offsets, size) else NEAR_PITCH
            for offsets, size in ((layout.column_offsets, layout.width), (layout.row_offsets, layout.length))
        )
    if pitch is not None:
        layout = _with_pitch(layout, pitch)
    bin_size = max(min(layout.width, layout.length) / 8.0, 0.5 * pixel)

    if placement is None and origin is None:
        start_angle = _crop_direction(points, bin_size) if angle is None else float(angle)
        centre = None
        angles = _around(start_angle, 5.0, 0.25) if angle is None else [float(angle)]
    else:
        if placement is not None:
            start_angle = placement.angle if angle is None else float(angle)
            centre = placement.to_map(0.5, 0.5)
        else:
            start_angle = 0.0 if angle is None else float(angle)
            centre = None
        angles = _around(start_angle, search_deg, 0.1) if angle is None else [float(angle)]
        if tolerance is not None and angle is None:
            # Turning the grid by a moves its far corners by about a * half its diagonal: no
            # further than the corners allow.
            half = 0.5 * math.hypot(*layout.extent)
            reach = min(search_deg, math.degrees(2 * tolerance / max(half, 1e-9)))
            angles = _around(start_angle, reach, 0.1)
    pivot = np.asarray(origin, dtype=np.float64) if origin is not None else centre
    if pivot is None:
        pivot = points.mean(axis=0)

    best = None
    for theta in angles:
        result = _fit_at(
            points,
            (soil_points, soil_weight),
            theta,
            pivot,
            layout,
            bin_size,
            scale_ranges,
            origin is not None,
            centre,
            None if tolerance is None else (placement.corners, tolerance),
        )
        if result is not None and (best is None or result["score"] > best["score"]):
            best = result
    if best is None:
        raise CliffTerrainError(
            f"no rectangular grid of {layout.columns} x {layout.rows} plots has its corners within the "
            f"tolerance of {tolerance:g} m of the given ones; check --corners or raise --tolerance"
        )
    fitted_layout = (
        _with_pitch(layout, (best["pc"], best["pr"])) if fit_pitch or tolerance is not None else layout
    )
    u_axis, v_axis = axes(best["theta"])
    corner = pivot + best["u0"] * u_axis + best["v0"] * v_axis
    fitted = Placement.rigid(corner, best["theta"], fitted_layout.extent)
    moved = 0.0 if centre is None else float(np.hypot(*(fitted.to_map(0.5, 0.5) - centre)))
    cover = _plot_cover(points - corner, step * pixel**2, u_axis, v_axis, fitted_layout)
    with_crop = float((cover >= MIN_COVER).mean())
    # A margin that one patch of crop earns tells nothing of the plots without any: the grid's
    # confidence is the share of its plots that hold crop times the margin.
    best["confidence"] *= with_crop
    report = {
        "angle_deg": round(best["theta"], 3),
        "column_pitch_m": round(float(best["pc"]), 4),
        "row_pitch_m": round(float(best["pr"]), 4),
        "plant_share_in_plots": round(best["inside"] / len(points), 4),
        "plant_share_in_alleys": round(best["gaps"] / max(best["inside"] + best["gaps"], 1), 4),
        "confidence": round(best["confidence"], 3),
        "moved_m": round(moved, 3),
        "rotated_deg": round(best["theta"] - start_angle, 3),
        "plots_with_crop": round(with_crop, 4),
        "score": round(float(best["score"]), 1),
    }
    if tolerance is not None:
        # Along the grid's axes, as the search bounds them (Euclidean: up to sqrt(2) times that).
        moved_by = fitted.corners - placement.corners
        shift = float(np.abs(moved_by @ np.column_stack([u_axis, v_axis])).max())
        report["tolerance_m"] = round(tolerance, 4)
        report["corner_shift_m"] = round(shift, 3)
        report["corner_distance_m"] = round(float(np.hypot(*moved_by.T).max()), 3)
        # A best grid against the tolerance's bound would move a corner beyond it, were it free to.
        report["at_tolerance"] = bool(best["at_tolerance"])
        reasons = [
            why
            for why, bad in (
                (
                    f"a corner would move {shift:.2f} m (tolerance {tolerance:.2f} m)",
                    shift > tolerance + 1e-9,
                ),
                ("the crop pulls the grid against the tolerance", best["at_tolerance"]),
                (f"confidence {best['confidence']:.2f} < {CONFIDENT}", best["confidence"] < CONFIDENT),
            )
            if bad
        ]
        report["accepted"] = not reasons
        report["refused_because"] = "; ".join(reasons)
    return GridFit(fitted_layout, fitted, report, cover)


# The grid confidence below which a fit keeps the unfitted plots and flags them: half of the definition's
# scale (the alternative grid loses half a column's or row's share of the score). Set from the
# definition, not from a trial.
CONFIDENT = 0.5


# A plot holds crop when plants cover at least this share of it (1 %: a few plants; a bare or
# senesced plot has none to lock on).
MIN_COVER = 0.01


def _plot_cover(rel, point_area, u_axis, v_axis, layout):
    """Plant cover of every plot, (row, column) order, from plant points relative to the grid's
    (0, 0) corner, each standing for `point_area` square metres."""
    u, v = rel @ u_axis, rel @ v_axis
    c = np.searchsorted(layout.column_offsets, u, side="right") - 1
    r = np.searchsorted(layout.row_offsets, v, side="right") - 1
    inside = (c >= 0) & (r >= 0)
    inside &= u < layout.column_offsets[np.clip(c, 0, None)] + layout.width
    inside &= v < layout.row_offsets[np.clip(r, 0, None)] + layout.length
    counts = np.bincount(r[inside] * layout.columns + c[inside], minlength=layout.rows * layout.columns)
    return counts * point_area / (layout.width * layout.length)


# Pitch scales searched: near the layout's spacing, or from touching plots to twice the plot's size.
NEAR_PITCH = (0.95, 1.05)
FIND_PITCH = (1.0, 2.0)


def _touching(offsets, size):
    """True when the plots of one axis touch (their pitch is their size: no spacing was given)."""
    return offsets.size > 1 and abs(float(np.diff(offsets).mean()) - size) <= 1e-6 * max(size, 1.0)


def _uniform(offsets):
    steps = np.diff(offsets)
    return steps.size == 0 or np.allclose(steps, steps[0], rtol=1e-6, atol=1e-9)


def _with_pitch(layout, pitch):
    pc, pr = pitch
    pc, pr = max(float(pc), layout.width), max(float(pr), layout.length)
    return Layout(
        layout.columns,
        layout.rows,
        layout.width,
        layout.length,
        np.arange(layout.columns) * pc,
        np.arange(layout.rows) * pr,
    )


def _around(centre, half, step):
    n = int(round(half / step))
    return [centre + k * step for k in range(-n, n + 1)]


def _crop_direction(points, bin_size):
    """The u direction (degrees) across which the plant pixels' projection is most contrasted:
    across the crop rows (every degree, then every tenth around the best)."""
    coarse = max(np.arange(0.0, 180.0, 1.0), key=lambda theta: _contrast(points, theta, bin_size))
    fine = np.arange(coarse - 1.0, coarse + 1.01, 0.1)
    return float(max(fine, key=lambda theta: _contrast(points, theta, bin_size)))


def _contrast(points, theta, bin_size):
    """Spread over mean of the plant pixels' projection onto direction `theta`, in bins."""
    u = points @ axes(theta)[0]
    counts = np.bincount(((u - u.min()) / bin_size).astype(np.int64))
    return counts.std() / max(counts.mean(), 1e-9)


def _map_points(t, rr, cc):
    return np.column_stack([t[0, 0] * cc + t[0, 1] * rr + t[0, 2], t[1, 0] * cc + t[1, 1] * rr + t[1, 2]])


def _fit_at(points, soil, theta, pivot, layout, b, scale_ranges, pinned_origin, centre, constraint=None):
    """Best shift (and pitch) at direction `theta`, in the frame centred on `pivot`; None when
    `constraint` (given corners, tolerance) leaves no grid at this direction."""
    u_axis, v_axis = axes(theta)
    bounds = (None, None)
    if constraint is not None:
        bounds = edge_bounds(constraint, pivot, u_axis, v_axis, layout)
        if bounds is None:
            return None
    rel = points - pivot
    u, v = rel @ u_axis, rel @ v_axis
    soil_points, soil_weight = soil
    soil_u, soil_v = (soil_points - pivot) @ u_axis, (soil_points - pivot) @ v_axis
    across, along = layout.extent
    # The histogram's range: the points, and a grid's length beyond them for the shifts to try.
    u_lo, v_lo = min(u.min(), -across) - across, min(v.min(), -along) - along
    nu = int((max(u.max(), across) + across - u_lo) / b) + 2
    nv = int((max(v.max(), along) + along - v_lo) / b) + 2
    hist = np.zeros((nu, nv))
    np.add.at(hist, (((u - u_lo) / b).astype(np.int64), ((v - v_lo) / b).astype(np.int64)), 1.0)
    hist_soil = np.zeros((nu, nv))
    keep = (soil_u >= u_lo) & (soil_u < u_lo + nu * b) & (soil_v >= v_lo) & (soil_v < v_lo + nv * b)
    iu = ((soil_u[keep] - u_lo) / b).astype(np.int64)
    iv = ((soil_v[keep] - v_lo) / b).astype(np.int64)
    np.add.at(hist_soil, (iu, iv), soil_weight)
    if pinned_origin:
        u_range = v_range = (0.0, 0.0)
    elif constraint is not None:
        u_range, v_range = bounds[0][0], bounds[1][0]
    elif centre is not None:
        # A rough placement: its (0, 0) corner lies half the extent before the centre, within a pitch.
        pc0 = np.diff(layout.column_offsets).mean() if layout.columns > 1 else layout.width
        pr0 = np.diff(layout.row_offsets).mean() if layout.rows > 1 else layout.length
        u_range = (-across / 2 - 0.6 * pc0, -across / 2 + 0.6 * pc0)
        v_range = (-along / 2 - 0.6 * pr0, -along / 2 + 0.6 * pr0)
    else:
        u_range = (u.min() - 0.5 * across, u.max() - 0.5 * across)
        v_range = (v.min() - 0.5 * along, v.max() - 0.5 * along)
    cols_off, rows_off = layout.column_offsets.copy(), layout.row_offsets.copy()
    u0, v0 = float(np.mean(u_range)), float(np.mean(v_range))
    best = None
    for _ in range(3):
        prof_u = profile(hist, v_lo, b, v0 + rows_off, layout.length, axis=1)
        soil_u = profile(hist_soil, v_lo, b, v0 + rows_off, layout.length, axis=1)
        hull_u = profile(hist, v_lo, b, np.array([v0]), rows_off[-1] + layout.length, axis=1)
        found = best_1d(
            (prof_u, hull_u, soil_u), u_lo, b, u_range, cols_off, layout.width, scale_ranges[0], bounds[0]
        )
        if found is None:
            return None
        u0, cols_off, su, alt_u, edge_u = found
        prof_v = profile(hist, u_lo, b, u0 + cols_off, layout.width, axis=0)
        soil_v = profile(hist_soil, u_lo, b, u0 + cols_off, layout.width, axis=0)
        hull_v = profile(hist, u_lo, b, np.array([u0]), cols_off[-1] + layout.width, axis=0)
        found = best_1d(
            (prof_v, hull_v, soil_v), v_lo, b, v_range, rows_off, layout.length, scale_ranges[1], bounds[1]
        )
        if found is None:
            return None
        v0, rows_off, sv, alt_v, edge_v = found
        best = (u0, v0, cols_off, rows_off, sv, alt_u, alt_v)
    u0, v0, cols_off, rows_off, (inside, hull, soil_in, wave_v), alt_u, alt_v = best
    score_u = 2 * su[0] - su[1] - SOIL_COST * su[2] + su[3]
    score_v = 2 * inside - hull - SOIL_COST * soil_in + wave_v
    score = score_v + su[3]  # the periodicity across the columns and along the rows
    # What shifting the grid by one column (row) loses, in units of one column's (row's) plant
    # pixels: about 1 when the field tells the chosen columns from their neighbours, about 0 when a
    # shifted grid fits as well (a guard row that looks like a plot column). The plain ratio of the
    # two scores would say 0.1 for a perfect fit of ten rows; a ratio to the score itself fails on
    # sparse crops, whose score is negative (more soil than plants inside the plots). With corners as constraints the
    # alternative is the grid shifted by half a pitch (plots centred on the gaps between the rows):
    # the corners rule out a whole pitch, the crop must tell the rows from the gaps.
    margins = [
        (own - alt) * n / max(own_inside, 1.0)
        for own, alt, n, own_inside in (
            (score_u, alt_u, layout.columns, su[0]),
            (score_v, alt_v, layout.rows, inside),
        )
    ]
    confidence = float(np.clip(min(margins), 0.0, 1.0))
    pc = float(np.diff(cols_off).mean()) if layout.columns > 1 else layout.width
    pr = float(np.diff(rows_off).mean()) if layout.rows > 1 else layout.length
    return {
        "theta": float(theta),
        "u0": float(u0),
        "v0": float(v0),
        "pc": pc,
        "pr": pr,
        "score": float(score),
        "inside": float(inside),
        "gaps": float(hull - inside),
        "confidence": confidence,
        "at_tolerance": edge_u or edge_v,
    }
