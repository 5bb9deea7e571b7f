"""The one-dimensional search of :mod:`cliff_terrain.measure.plot_fit`: along one axis of the grid's
frame, the shift (and uniform pitch) of the plot windows that maximises the fit's score over the
plant pixels' projection, optionally bounded by the given corners (:func:`edge_bounds`), in which
case the score also counts the crop's periodicity across the rows.
"""

from __future__ import annotations

import math

import numpy as np

# What a soil pixel inside a plot costs against a plant pixel inside it: plots that grow over bare
# soil beyond the field's edge lose, while the soil between the crop rows inside a plot is tolerated.
SOIL_COST = 0.5


def profile(hist, lo, b, starts, size, *, axis):
    """Projection of `hist` onto the other axis, summed over the windows [start, start + size) along `axis`."""
    cum = np.concatenate([np.zeros((hist.shape[0], 1)) if axis == 1 else np.zeros((1, hist.shape[1])),
                          np.cumsum(hist, axis=axis)], axis=axis)  # fmt: skip
    n = hist.shape[axis]
    a = np.clip(np.round((starts - lo) / b).astype(np.int64), 0, n)
    e = np.clip(np.round((starts + size - lo) / b).astype(np.int64), 0, n)
    if axis == 1:
        return (cum[:, e] - cum[:, a]).sum(axis=1)
    return (cum[e, :] - cum[a, :]).sum(axis=0)


def edge_bounds(constraint, pivot, u_axis, v_axis, layout):
    """Per axis ((first edge low, high), (last edge low, high)) in the frame about `pivot`: where the
    grid's outer edges may lie for every corner to stay within the tolerance along that axis; None
    when no grid fits."""
    corners, tolerance = constraint
    rel = np.asarray(corners, dtype=np.float64) - pivot
    gu, gv = rel @ u_axis, rel @ v_axis
    out = []
    for g, first, last, offsets, size in (
        (gu, (0, 3), (1, 2), layout.column_offsets, layout.width),
        (gv, (0, 1), (3, 2), layout.row_offsets, layout.length),
    ):
        lo = (max(g[first[0]], g[first[1]]) - tolerance, min(g[first[0]], g[first[1]]) + tolerance)
        hi = (max(g[last[0]], g[last[1]]) - tolerance, min(g[last[0]], g[last[1]]) + tolerance)
        # The grid's extent must lie between (hi - lo) at its narrowest and widest, with plots that
        # do not overlap (extent >= count * size).
        if lo[0] > lo[1] or hi[0] > hi[1] or hi[1] - lo[0] < offsets.size * size - 1e-9:
            return None
        out.append((lo, hi))
    return tuple(out)


def best_1d(profiles, lo, b, shift_range, offsets, size, scale_range, bounds=None):
    """Shift (and uniform pitch) of windows `offsets` (+ `size`) along the profiles (plants in the
    other axis's windows, plants in the grid's outline, soil in the windows) maximising
    2 * inside - hull - SOIL_COST * soil inside; returns (shift, offsets, (inside, hull, soil inside),
    best score one pitch away). With `bounds` (see :func:`edge_bounds`) the first edge stays in
    the first range and the last in the second, the pitch follows, and the score adds the crop's
    periodicity, and the last value returned says whether the best grid lies against a bound;
    returns None when no shift fits the bounds."""
    profile, hull_profile, soil_profile = profiles
    cum = np.concatenate([[0.0], np.cumsum(profile)])
    cum_h = np.concatenate([[0.0], np.cumsum(hull_profile)])
    cum_s = np.concatenate([[0.0], np.cumsum(soil_profile)])
    n = profile.size
    if shift_range[1] > shift_range[0]:
        shifts = np.arange(shift_range[0], shift_range[1] + 0.25 * b, 0.5 * b)
        if bounds is not None:  # the corners' bounds are hard: the last step lands on the bound
            shifts = np.minimum(shifts, shift_range[1])
    else:
        shifts = np.array([float(shift_range[0])])
    count = offsets.size
    base = float(np.diff(offsets).mean()) if count > 1 else size
    scales = np.array([1.0])
    if bounds is not None and count > 1:
        # The pitches the corners allow: from the narrowest to the widest extent, every half bin at
        # the last edge; never below the plot's size.
        (f_lo, f_hi), (l_lo, l_hi) = bounds
        low = max((l_lo - f_hi - size) / offsets[-1], size / base)
        high = (l_hi - f_lo - size) / offsets[-1]
        if high < low - 1e-12:
            return None
        steps = int(math.ceil((high - low) * offsets[-1] / (0.5 * b))) + 1
        scales = np.linspace(low, high, max(steps, 1)) if high > low else np.array([low])
    elif scale_range is not None and count > 1:
        # Every 0.25 % of the pitch near the layout's; every 1 % (then 0.1 % around the best) when found.
        low, high = scale_range
        scales = np.linspace(
            low, high, int(round((high - low) / (0.0025 if high - low <= 0.1 else 0.01))) + 1
        )
        # Plots never overlap: the pitch stays at least the plot's size.
        scales = (
            scales[scales * base >= size - 1e-9] if (scales * base >= size - 1e-9).any() else np.array([1.0])
        )

    centres = lo + (np.arange(n) + 0.5) * b

    def periodic(shift, scale, ha, he):
        """Plant pixels in the grid's outline weighted by cos(2 pi (x - plot centre) / pitch): high
        when the plots sit on the crop rows, negative when they sit on the gaps between them."""
        if bounds is None or count == 1:  # one plot on this axis: no period to lock on
            return np.zeros(len(shift))
        pitch = base * scale
        wave = np.concatenate([[0.0], np.cumsum(profile * np.exp(2j * np.pi * centres / pitch))])
        phase = np.exp(-2j * np.pi * (shift + 0.5 * size) / pitch)
        return np.real(phase * (wave[he] - wave[ha]))

    def evaluate(shift, scale):
        """(inside, hull, soil inside, periodic) for every shift in the array `shift` at one pitch scale."""
        offs = offsets * scale
        a = np.clip(np.round((shift[:, None] + offs[None] - lo) / b).astype(np.int64), 0, n)
        e = np.clip(np.round((shift[:, None] + offs[None] + size - lo) / b).astype(np.int64), 0, n)
        inside = (cum[e] - cum[a]).sum(axis=1)
        soil_in = (cum_s[e] - cum_s[a]).sum(axis=1)
        ha = np.clip(np.round((shift - lo) / b).astype(np.int64), 0, n)
        he = np.clip(np.round((shift + offs[-1] + size - lo) / b).astype(np.int64), 0, n)
        return inside, cum_h[he] - cum_h[ha], soil_in, periodic(shift, scale, ha, he)

    def search(scales):
        best, best_key = -np.inf, None
        for scale in scales:
            inside, hull, soil_in, wave = evaluate(shifts, scale)
            score = 2 * inside - hull - SOIL_COST * soil_in + wave
            if bounds is not None:  # the last edge within its bounds too
                last = shifts + offsets[-1] * scale + size
                score = np.where(
                    (last >= bounds[1][0] - 1e-9) & (last <= bounds[1][1] + 1e-9), score, -np.inf
                )
            k = int(np.argmax(score))
            if score[k] > best:
                best, best_key = (
                    score[k],
                    (
                        float(shifts[k]),
                        float(scale),
                        float(inside[k]),
                        float(hull[k]),
                        float(soil_in[k]),
                        float(wave[k]),
                    ),
                )
        return best_key

    best_key = search(scales)
    if best_key is None:
        return None
    if bounds is None and scales.size > 1 and scales[1] - scales[0] > 0.005:  # a found pitch: refine
        fine = best_key[1] + np.arange(-0.01, 0.0101, 0.001)
        best_key = search(fine[fine * base >= size - 1e-9])
    shift, scale, inside, hull, soil_in, wave = best_key
    # The same windows one pitch either way: a guard row taken for a plot column. With corners, half
    # a pitch either way (see _fit_at).
    pitch = base * scale if count > 1 else size
    away = 0.5 * pitch if bounds is not None else pitch
    i2, h2, s2, w2 = evaluate(np.array([shift - away, shift + away]), scale)
    alternative = float(np.max(2 * i2 - h2 - SOIL_COST * s2 + w2))
    # The best grid against a bound: the crop pulls it further than the corners allow. That counts
    # where the grid half a pitch away (the plots on the gaps between the rows) could lie within the
    # bounds: elsewhere (rows metres long) a bound only stops a slide along a flat score.
    edge = (
        bounds is not None
        and 0.5 * pitch <= bounds[0][1] - bounds[0][0]
        and (
            min(shift - bounds[0][0], bounds[0][1] - shift) < 0.5 * b
            and bounds[0][1] - bounds[0][0] > b
            or min(
                shift + offsets[-1] * scale + size - bounds[1][0],
                bounds[1][1] - shift - offsets[-1] * scale - size,
            )
            < 0.5 * b
            and bounds[1][1] - bounds[1][0] > b
        )
    )
    return shift, offsets * scale, (inside, hull, soil_in, wave), alternative, bool(edge)
