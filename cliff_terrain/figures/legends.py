"""What the legends say: the height colour map, round tick steps, display units and labels, and
the side view's vertical exaggeration (numpy only; the drawing is in :mod:`.annotate` and
:mod:`.sheet`).

The Blender side colours the mesh with :data:`HEIGHT_COLOURS` too, so every colour bar is the
mesh's own legend.
"""

from __future__ import annotations

import math

import numpy as np

from .._validate import check_float
from ..errors import CliffTerrainError

# Colour map of every height colouring (viridis: perceptually uniform, readable in grey and by
# colour-blind readers, unlike jet): (t, r, g, b), sRGB in [0, 1], matplotlib's viridis at 17 stops
# (linear between them, within 0.021 of it). The Blender side colours the mesh with the same table
# (the mesh view, Colour by Height and its overlay bar), so every colour bar is the mesh's own legend.
HEIGHT_COLOURS = np.array(
    [
        (0.0, 0.2670, 0.0049, 0.3294),
        (0.0625, 0.2823, 0.0950, 0.4173),
        (0.125, 0.2788, 0.1755, 0.4834),
        (0.1875, 0.2590, 0.2515, 0.5247),
        (0.25, 0.2297, 0.3224, 0.5457),
        (0.3125, 0.1994, 0.3876, 0.5546),
        (0.375, 0.1727, 0.4488, 0.5579),
        (0.4375, 0.1490, 0.5081, 0.5573),
        (0.5, 0.1276, 0.5669, 0.5506),
        (0.5625, 0.1206, 0.6258, 0.5335),
        (0.625, 0.1579, 0.6838, 0.5017),
        (0.6875, 0.2461, 0.7389, 0.4520),
        (0.75, 0.3692, 0.7889, 0.3829),
        (0.8125, 0.5160, 0.8312, 0.2943),
        (0.875, 0.6785, 0.8637, 0.1895),
        (0.9375, 0.8456, 0.8873, 0.0997),
        (1.0, 0.9932, 0.9062, 0.1439),
    ]
)
# The side view's relief rises to this share of the frame's width, at most (a 1000-pixel wide field
# to 300 pixels; rounding the factor down to 1, 2 or 5 keeps it above 12 %): tall enough to read plant
# heights, flat enough to stay a side view.
RELIEF_SHARE = 0.3


def height_colours(t):
    """sRGB colours (n, 3) in [0, 1] of heights `t` scaled to [0, 1] (the viridis colour map).

    Examples
    --------
    >>> height_colours([0.0, 1.0]).round(2).tolist()
    [[0.27, 0.0, 0.33], [0.99, 0.91, 0.14]]
    """
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return np.stack([np.interp(t, HEIGHT_COLOURS[:, 0], HEIGHT_COLOURS[:, k]) for k in (1, 2, 3)], axis=-1)


# --------------------------------------------------------------------------------------------
# Numbers for the legends
# --------------------------------------------------------------------------------------------


def nice_step(span, *, ticks=5):
    """A round step (1, 2 or 5 times a power of ten) giving about `ticks` intervals over `span`.

    Examples
    --------
    >>> nice_step(0.47), nice_step(130.0), nice_step(8.0, ticks=4)
    (0.1, 20.0, 2.0)
    """
    raw = span / ticks
    power = 10.0 ** math.floor(math.log10(raw))
    candidates = [float(f"{factor * power:.12g}") for factor in (1.0, 2.0, 5.0, 10.0)]
    return min(candidates, key=lambda step: abs(span / step - ticks))


def nice_below(value):
    """The largest 1, 2 or 5 times a power of ten that is <= `value` (> 0).

    Examples
    --------
    >>> nice_below(7.7), nice_below(0.34), nice_below(1.0)
    (5.0, 0.2, 1.0)
    """
    power = 10.0 ** math.floor(math.log10(value))
    for factor in (5.0, 2.0, 1.0):
        if factor * power <= value * 1.0000001:
            return float(f"{factor * power:.12g}")
    return power


def display_units(max_height, units):
    """How heights in `units` ("m" or "px") are labelled: (factor, unit name).

    Metres under 1 m are shown in cm (crop heights), larger ones in m; pixels stay pixels.

    Examples
    --------
    >>> display_units(0.42, "m"), display_units(3.0, "m"), display_units(25.0, "px")
    ((100.0, 'cm'), (1.0, 'm'), (1.0, 'px'))
    """
    if units == "m":
        return (100.0, "cm") if max_height < 1.0 else (1.0, "m")
    if units == "px":
        return 1.0, "px"
    raise CliffTerrainError(f'`units` must be "m" or "px", got {units!r}')


def format_value(value, step):
    """`value` with as many decimals as `step` needs (``format_value(0.25, 0.05)`` is ``'0.25'``)."""
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step < 1 else 0
    return f"{value:.{decimals}f}"


def format_length(metres):
    """A length for a label: mm, cm, m or km, whichever reads best ("50 cm", "2 m", "1.5 km")."""
    if metres >= 1000.0:
        return f"{metres / 1000.0:g} km"
    if metres >= 1.0:
        return f"{metres:g} m"
    if metres >= 0.01:
        return f"{metres * 100.0:g} cm"
    return f"{metres * 1000.0:g} mm"


def vertical_exaggeration(width, relief_height, *, share=RELIEF_SHARE):
    """Vertical exaggeration of the side view: a round factor (1, 2, 5, 10, 20, ...) that makes the
    relief rise to at most `share` of the view's width, and never less than 1 (no flattening).

    Parameters
    ----------
    width : float
        Width of the side view's subject (the relief or the transect), in any unit.
    relief_height : float
        Height of the relief, in the same unit.
    share : float, optional
        Height of the exaggerated relief as a share of `width`.

    Returns
    -------
    float

    Examples
    --------
    >>> vertical_exaggeration(1000.0, 26.0)  # 26 -> 260 pixels on a 1000-pixel wide view
    10.0
    >>> vertical_exaggeration(10.0, 4.0)  # already tall: shown as it is
    1.0
    """
    width = check_float("width", width, minimum=0.0, strict_minimum=True)
    share = check_float("share", share, minimum=0.0, strict_minimum=True, maximum=10.0)
    relief_height = check_float("relief_height", relief_height, minimum=0.0)
    if relief_height == 0.0:
        raise CliffTerrainError(
            "cannot choose a vertical exaggeration: `relief_height` must be > 0, got 0.0 (the relief is flat)"
        )
    return max(1.0, nice_below(share * width / relief_height))
