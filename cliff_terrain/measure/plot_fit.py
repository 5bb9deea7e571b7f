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
are cut by the alleys and guard rows often are not. The report says how much of one column's or
row's share of the score the grid loses when shifted by one (``confidence``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import CliffTerrainError
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
        ``confidence`` (0-1: the score lost by shifting the grid one column or row, over one
        column's or row's share of the chosen score; the smaller of the two), ``moved_m`` (how far the grid's centre moved) and ``rotated_deg``.
    """

    layout: Layout
    placement: Placement
    report: dict


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

    Returns
    -------
    GridFit
    """
    from ..io.transform import as_affine

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
    if fit_pitch:
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
        )
        if best is None or result["score"] > best["score"]:
            best = result
    fitted_layout = _with_pitch(layout, (best["pc"], best["pr"])) if fit_pitch else layout
    u_axis, v_axis = axes(best["theta"])
    corner = pivot + best["u0"] * u_axis + best["v0"] * v_axis
    fitted = Placement.rigid(corner, best["theta"], fitted_layout.extent)
    moved = 0.0 if centre is None else float(np.hypot(*(fitted.to_map(0.5, 0.5) - centre)))
    report = {
        "angle_deg": round(best["theta"], 3),
        "column_pitch_m": round(float(best["pc"]), 4),
        "row_pitch_m": round(float(best["pr"]), 4),
        "plant_share_in_plots": round(best["inside"] / len(points), 4),
        "plant_share_in_alleys": round(best["gaps"] / max(best["inside"] + best["gaps"], 1), 4),
        "confidence": round(best["confidence"], 3),
        "moved_m": round(moved, 3),
        "rotated_deg": round(best["theta"] - start_angle, 3),
    }
    return GridFit(fitted_layout, fitted, report)


# What a soil pixel inside a plot costs against a plant pixel inside it: plots that grow over bare
# soil beyond the field's edge lose, while the soil between the crop rows inside a plot is tolerated.
SOIL_COST = 0.5


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


def _fit_at(points, soil, theta, pivot, layout, b, scale_ranges, pinned_origin, centre):
    """Best shift (and pitch) at direction `theta`, in the frame centred on `pivot`."""
    u_axis, v_axis = axes(theta)
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
        prof_u = _profile(hist, v_lo, b, v0 + rows_off, layout.length, axis=1)
        soil_u = _profile(hist_soil, v_lo, b, v0 + rows_off, layout.length, axis=1)
        hull_u = _profile(hist, v_lo, b, np.array([v0]), rows_off[-1] + layout.length, axis=1)
        u0, cols_off, su, alt_u = _best_1d(
            (prof_u, hull_u, soil_u), u_lo, b, u_range, cols_off, layout.width, scale_ranges[0]
        )
        prof_v = _profile(hist, u_lo, b, u0 + cols_off, layout.width, axis=0)
        soil_v = _profile(hist_soil, u_lo, b, u0 + cols_off, layout.width, axis=0)
        hull_v = _profile(hist, u_lo, b, np.array([u0]), cols_off[-1] + layout.width, axis=0)
        v0, rows_off, sv, alt_v = _best_1d(
            (prof_v, hull_v, soil_v), v_lo, b, v_range, rows_off, layout.length, scale_ranges[1]
        )
        best = (u0, v0, cols_off, rows_off, sv, alt_u, alt_v)
    u0, v0, cols_off, rows_off, (inside, hull, soil_in), alt_u, alt_v = best
    score = 2 * inside - hull - SOIL_COST * soil_in
    # What shifting the grid by one column (row) loses, as a share of one column's (row's) part of
    # the score: about 1 when the field tells the chosen columns from their neighbours, about 0 when a
    # shifted grid fits as well (a guard row that looks like a plot column). The plain ratio of the
    # two scores would say 0.1 for a perfect fit of ten rows.
    margins = [(score - alt) * n / score for alt, n in ((alt_u, layout.columns), (alt_v, layout.rows))]
    confidence = 0.0 if score <= 0 else float(np.clip(min(margins), 0.0, 1.0))
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
    }


def _profile(hist, lo, b, starts, size, *, axis):
    """Projection of `hist` onto the other axis, summed over the windows [start, start + size) along `axis`."""
    cum = np.concatenate([np.zeros((hist.shape[0], 1)) if axis == 1 else np.zeros((1, hist.shape[1])),
                          np.cumsum(hist, axis=axis)], axis=axis)  # fmt: skip
    n = hist.shape[axis]
    a = np.clip(np.round((starts - lo) / b).astype(np.int64), 0, n)
    e = np.clip(np.round((starts + size - lo) / b).astype(np.int64), 0, n)
    if axis == 1:
        return (cum[:, e] - cum[:, a]).sum(axis=1)
    return (cum[e, :] - cum[a, :]).sum(axis=0)


def _best_1d(profiles, lo, b, shift_range, offsets, size, scale_range):
    """Shift (and uniform pitch) of windows `offsets` (+ `size`) along the profiles (plants in the
    other axis's windows, plants in the grid's outline, soil in the windows) maximising
    2 * inside - hull - SOIL_COST * soil inside; returns (shift, offsets, (inside, hull, soil inside),
    best score one pitch away)."""
    profile, hull_profile, soil_profile = profiles
    cum = np.concatenate([[0.0], np.cumsum(profile)])
    cum_h = np.concatenate([[0.0], np.cumsum(hull_profile)])
    cum_s = np.concatenate([[0.0], np.cumsum(soil_profile)])
    n = profile.size
    if shift_range[1] > shift_range[0]:
        shifts = np.arange(shift_range[0], shift_range[1] + 0.25 * b, 0.5 * b)
    else:
        shifts = np.array([float(shift_range[0])])
    count = offsets.size
    base = float(np.diff(offsets).mean()) if count > 1 else size
    scales = np.array([1.0])
    if scale_range is not None and count > 1:
        # Every 0.25 % of the pitch near the layout's; every 1 % (then 0.1 % around the best) when found.
        low, high = scale_range
        scales = np.linspace(
            low, high, int(round((high - low) / (0.0025 if high - low <= 0.1 else 0.01))) + 1
        )
        # Plots never overlap: the pitch stays at least the plot's size.
        scales = (
            scales[scales * base >= size - 1e-9] if (scales * base >= size - 1e-9).any() else np.array([1.0])
        )

    def evaluate(shift, scale):
        """(inside, hull) for every shift in the array `shift` at one pitch scale."""
        offs = offsets * scale
        a = np.clip(np.round((shift[:, None] + offs[None] - lo) / b).astype(np.int64), 0, n)
        e = np.clip(np.round((shift[:, None] + offs[None] + size - lo) / b).astype(np.int64), 0, n)
        inside = (cum[e] - cum[a]).sum(axis=1)
        soil_in = (cum_s[e] - cum_s[a]).sum(axis=1)
        ha = np.clip(np.round((shift - lo) / b).astype(np.int64), 0, n)
        he = np.clip(np.round((shift + offs[-1] + size - lo) / b).astype(np.int64), 0, n)
        return inside, cum_h[he] - cum_h[ha], soil_in

    def search(scales):
        best, best_key = -np.inf, None
        for scale in scales:
            inside, hull, soil_in = evaluate(shifts, scale)
            score = 2 * inside - hull - SOIL_COST * soil_in
            k = int(np.argmax(score))
            if score[k] > best:
                best, best_key = (
                    score[k],
                    (float(shifts[k]), float(scale), float(inside[k]), float(hull[k]), float(soil_in[k])),
                )
        return best_key

    best_key = search(scales)
    if scales.size > 1 and scales[1] - scales[0] > 0.005:  # a found pitch: refine around the best
        fine = best_key[1] + np.arange(-0.01, 0.0101, 0.001)
        best_key = search(fine[fine * base >= size - 1e-9])
    shift, scale, inside, hull, soil_in = best_key
    # The same windows one pitch either way: a guard row taken for a plot column.
    pitch = base * scale
    i2, h2, s2 = evaluate(np.array([shift - pitch, shift + pitch]), scale)
    alternative = float(np.max(2 * i2 - h2 - SOIL_COST * s2))
    return shift, offsets * scale, (inside, hull, soil_in), alternative
