"""Legends drawn on rendered views after rendering (Pillow only): a height ruler for the side view,
a colour bar for the height-coloured mesh, a scale bar and north arrow for the top views, and a
labelled contact sheet (``summary.png``) for a report.

The renders themselves are never changed: every function here returns a new array, and
``render_views.py`` writes it beside the raw render (``xz.png`` -> ``xz_annotated.png``), so the
top views compared with the photo (PSNR, SSIM) stay pixel for pixel what Blender rendered.

Text size follows the image: ``font_size`` is about 1/45 of the longer side, never under 12 pixels,
so a label stays readable both on a 1000-pixel figure and shrunk into the contact sheet.

Transects (``--transect``) are described here too: a band of photo rows, or a line across the
field with a width, in the photo's pixels; the Blender side turns them into a side camera.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ._validate import check_float
from .errors import CliffTerrainError

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
# Ink and paper.
INK = (20, 20, 20)
PAPER = (255, 255, 255)
GRID = (200, 200, 200)
MIN_FONT = 12


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


# --------------------------------------------------------------------------------------------
# Drawing helpers
# --------------------------------------------------------------------------------------------


def font_size(image_shape):
    """Text height in pixels for an image of `image_shape` (rows, cols, ...): 1/45 of the longer
    side, at least 12."""
    return max(MIN_FONT, round(max(image_shape[0], image_shape[1]) / 45))


def _font(size):
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _as_rgb(image, name, background=PAPER):
    """`image` (rows, cols[, 3 or 4]) uint8 as an RGB Pillow image; transparency over `background`."""
    from PIL import Image

    array = np.asarray(image)
    if not isinstance(image, np.ndarray) or array.dtype != np.uint8:
        raise CliffTerrainError(
            f"`{name}` must be a uint8 numpy array, got {getattr(array, 'dtype', type(image))}"
        )
    if array.ndim == 2:
        array = np.repeat(array[..., None], 3, axis=-1)
    if array.ndim != 3 or array.shape[2] not in (3, 4) or min(array.shape[:2]) < 1:
        raise CliffTerrainError(f"`{name}` must have shape (rows, cols[, 3 or 4]), got {np.shape(image)}")
    if array.shape[2] == 3:
        return Image.fromarray(np.ascontiguousarray(array))
    paper = Image.new("RGBA", (array.shape[1], array.shape[0]), (*background, 255))
    return Image.alpha_composite(paper, Image.fromarray(np.ascontiguousarray(array))).convert("RGB")


def _text_size(draw, text, font):
    left, top, right, bottom = draw.textbbox((0, 0), text, font=font)
    return right - left, bottom - top


def _framed_text(draw, xy, text, font, *, anchor="la", pad=None):
    """Text on a white box (readable over a photo)."""
    pad = max(2, font.size // 5) if pad is None else pad
    box = draw.textbbox(xy, text, font=font, anchor=anchor)
    draw.rectangle((box[0] - pad, box[1] - pad, box[2] + pad, box[3] + pad), fill=PAPER)
    draw.text(xy, text, font=font, fill=INK, anchor=anchor)


def _extend(picture, *, left=0, top=0, right=0, bottom=0):
    from PIL import Image

    out = Image.new("RGB", (picture.width + left + right, picture.height + top + bottom), PAPER)
    out.paste(picture, (left, top))
    return out


# --------------------------------------------------------------------------------------------
# The side view: height ruler and vertical exaggeration
# --------------------------------------------------------------------------------------------


def annotate_side_view(image, *, ground_row, rows_per_unit, max_height, units, exaggeration=1.0, title=None):
    """The side view with a height ruler, light height lines behind the relief, and its vertical
    exaggeration written on it.

    Parameters
    ----------
    image : (rows, cols, 3 or 4) uint8 array
        The rendered side view (transparent background composited on white, behind the lines).
    ground_row : float
        Image row (from the top, may be fractional) of height 0.
    rows_per_unit : float
        Image rows per unit of height as drawn (vertical exaggeration included), > 0.
    max_height : float
        Highest point of the relief in `units`: the ruler runs from 0 to it.
    units : {"m", "px"}
        Units of the heights; metres are labelled in cm under 1 m.
    exaggeration : float, optional
        The vertical exaggeration the view was rendered with (written on the figure).
    title : str, optional
        First line of the caption (default "Side view from the south").

    Returns
    -------
    (rows', cols', 3) uint8 array
        The figure: the view with a ruler margin on the left and a caption above.

    Examples
    --------
    >>> view = np.zeros((60, 200, 4), np.uint8)
    >>> view[40:50, 20:180] = 200  # a 10-row high slab, opaque
    >>> out = annotate_side_view(view, ground_row=50, rows_per_unit=1.0, max_height=10.0, units="px")
    >>> out.shape[1] > 200 and out.dtype == np.uint8
    True
    """
    from PIL import Image, ImageDraw

    max_height = check_float("max_height", max_height, minimum=0.0)
    if max_height == 0.0:
        raise CliffTerrainError(
            "cannot label the height ruler: `max_height` must be > 0, got 0.0 (the relief has no height range)"
        )
    rows_per_unit = check_float("rows_per_unit", rows_per_unit, minimum=0.0, strict_minimum=True)
    ground_row = check_float("ground_row", ground_row)
    exaggeration = check_float("exaggeration", exaggeration, minimum=0.0, strict_minimum=True)
    factor, unit = display_units(max_height, units)
    array = np.asarray(image)
    rgb = _as_rgb(image, "image")
    rows, cols = rgb.height, rgb.width
    top_row = ground_row - max_height * rows_per_unit
    if top_row < -0.5 or ground_row > rows - 0.5 + 1e-6:
        raise CliffTerrainError(
            f"cannot label the height ruler: heights 0 to {max_height:g} {units} fall on rows "
            f"{ground_row:g} to {top_row:g}, outside the {rows}-row `image`"
        )
    size = font_size((max(rows, cols // 2), cols))
    font = _font(size)
    step = nice_step(max_height * factor, ticks=4)
    ticks = np.arange(0.0, max_height * factor * 1.0000001, step)
    labels = [format_value(t, step) for t in ticks]

    # Height lines behind the relief: drawn on the paper, then the render's opaque pixels over them.
    paper = Image.new("RGB", (cols, rows), PAPER)
    draw = ImageDraw.Draw(paper)
    tick_rows = [ground_row - t / factor * rows_per_unit for t in ticks]
    for r in tick_rows:
        draw.line((0, round(r), cols, round(r)), fill=GRID, width=1)
    if array.ndim == 3 and array.shape[2] == 4:
        colour = Image.fromarray(np.ascontiguousarray(array[..., :3]))
        paper.paste(colour, (0, 0), Image.fromarray(np.ascontiguousarray(array[..., 3])))
        view = paper
    else:
        view = rgb

    probe = ImageDraw.Draw(view)
    label_w = max(_text_size(probe, text, font)[0] for text in [*labels, unit])
    tick = max(4, size // 2)
    left = label_w + tick + size
    caption = [
        title or "Side view from the south",
        f"heights in {unit}, vertical exaggeration {exaggeration:g}x",
    ]
    line_h = round(1.3 * size)
    top = len(caption) * line_h + size
    bottom = size
    figure = _extend(view, left=left, top=top, bottom=bottom)
    draw = ImageDraw.Draw(figure)
    x = left - size // 2
    y0, y1 = top + ground_row, top + tick_rows[-1]
    draw.line((x, round(y0), x, round(y1)), fill=INK, width=max(1, size // 8))
    for r, text in zip(tick_rows, labels, strict=True):
        y = round(top + r)
        draw.line((x - tick, y, x, y), fill=INK, width=max(1, size // 8))
        draw.text((x - tick - 2, y), text, font=font, fill=INK, anchor="rm")
    draw.text((x - tick - 2, round(y1) - size), unit, font=font, fill=INK, anchor="rb")
    for i, text in enumerate(caption):
        draw.text((left, size // 2 + i * line_h), text, font=font, fill=INK)
    return np.asarray(figure)


# --------------------------------------------------------------------------------------------
# The height-coloured mesh: colour bar
# --------------------------------------------------------------------------------------------


def annotate_colour_bar(image, *, max_height, units, title="Height"):
    """The height-coloured view with a colour bar from 0 to `max_height` (in cm, m or px).

    Parameters
    ----------
    image : (rows, cols, 3 or 4) uint8 array
        The view coloured by :func:`height_colours` from height 0 to `max_height`.
    max_height : float
        Height of the top colour, in `units` (> 0).
    units : {"m", "px"}
    title : str, optional
        Label above the bar (the unit is added).

    Returns
    -------
    (rows, cols', 3) uint8 array
        The view with the bar in a margin on its right.
    """
    from PIL import Image, ImageDraw

    max_height = check_float("max_height", max_height, minimum=0.0)
    if max_height == 0.0:
        raise CliffTerrainError(
            "cannot label the colour bar: `max_height` must be > 0, got 0.0 (the relief has no height range)"
        )
    factor, unit = display_units(max_height, units)
    view = _as_rgb(image, "image")
    rows, cols = view.height, view.width
    size = font_size((rows, cols))
    font = _font(size)
    step = nice_step(max_height * factor, ticks=5)
    ticks = np.arange(0.0, max_height * factor * 1.0000001, step)
    labels = [format_value(t, step) for t in ticks]
    probe = ImageDraw.Draw(view)
    label_w = max(_text_size(probe, text, font)[0] for text in labels)
    title_text = f"{title} ({unit})"
    bar_w = max(8, size)
    margin = max(bar_w + size // 2 + label_w + size, _text_size(probe, title_text, font)[0] + size)
    figure = _extend(view, right=margin)
    draw = ImageDraw.Draw(figure)
    bar_top = 2 * size + size // 2
    bar_bottom = rows - size
    bar_h = max(2, bar_bottom - bar_top)
    t = 1.0 - (np.arange(bar_h) + 0.5) / bar_h
    ramp = np.round(height_colours(t) * 255.0).astype(np.uint8)
    strip = np.repeat(ramp[:, None, :], bar_w, axis=1)
    x0 = cols + size // 2
    figure.paste(Image.fromarray(strip), (x0, bar_top))
    draw.rectangle((x0 - 1, bar_top - 1, x0 + bar_w, bar_top + bar_h), outline=INK)
    for value, text in zip(ticks, labels, strict=True):
        y = round(bar_top + bar_h * (1.0 - value / (max_height * factor)))
        draw.line((x0 + bar_w, y, x0 + bar_w + size // 3, y), fill=INK)
        draw.text((x0 + bar_w + size // 2, y), text, font=font, fill=INK, anchor="lm")
    draw.text((cols + size // 2, size // 2), title_text, font=font, fill=INK)
    return np.asarray(figure)


# --------------------------------------------------------------------------------------------
# Top views: scale bar, north arrow, transect outline
# --------------------------------------------------------------------------------------------


def annotate_top_view(image, *, metres_per_pixel=None, georeferenced=False, transect=None, photo_shape=None):
    """A top view with a scale bar (when the ground size is known), a north arrow (when the photo
    is georeferenced: its rows run north to south) and the transect's outline (when given).

    Parameters
    ----------
    image : (rows, cols, 3 or 4) uint8 array
    metres_per_pixel : float, optional
        Ground size of one pixel of `image`; None draws "scale unknown" instead of a bar.
    georeferenced : bool, optional
        Whether the image's top is north (a north-up GeoTIFF).
    transect : Transect, optional
        Outlined on the view; needs `photo_shape`.
    photo_shape : tuple, optional
        (rows, cols) of the photo the transect's pixels refer to.

    Returns
    -------
    (rows, cols, 3) uint8 array
    """
    from PIL import ImageDraw

    view = _as_rgb(image, "image")
    rows, cols = view.height, view.width
    size = font_size((rows, cols))
    font = _font(size)
    draw = ImageDraw.Draw(view)
    margin = size
    if transect is not None:
        if photo_shape is None:
            raise CliffTerrainError("`photo_shape` is needed to draw a `transect`")
        sy, sx = rows / photo_shape[0], cols / photo_shape[1]
        corners = [(c * sx, r * sy) for r, c in transect.corners()]
        draw.polygon(corners, outline=(255, 255, 0), width=max(2, size // 6))
    if metres_per_pixel is not None:
        metres_per_pixel = check_float("metres_per_pixel", metres_per_pixel, minimum=0.0, strict_minimum=True)
        length = nice_below(0.25 * cols * metres_per_pixel)
        bar = length / metres_per_pixel
        thick = max(4, size // 2)
        x0, y0 = margin, rows - margin - thick
        label = format_length(length)
        tw, th = _text_size(draw, label, font)
        pad = max(3, size // 4)
        draw.rectangle((x0 - pad, y0 - th - 2 * pad, x0 + max(bar, tw) + pad, y0 + thick + pad), fill=PAPER)
        halves = 2
        for i in range(halves):
            fill = INK if i % 2 == 0 else PAPER
            xa, xb = x0 + bar * i / halves, x0 + bar * (i + 1) / halves
            draw.rectangle((round(xa), y0, round(xb), y0 + thick), fill=fill, outline=INK)
        draw.text((x0, y0 - pad), label, font=font, fill=INK, anchor="ld")
    else:
        _framed_text(draw, (margin, rows - margin), "scale unknown (no GSD)", font, anchor="ld")
    if georeferenced:
        h = 2 * size
        x, y = cols - margin - size, margin + size + h
        pad = max(3, size // 4)
        draw.rectangle((x - size - pad, margin - pad, x + size + pad, y + pad), fill=PAPER)
        draw.polygon([(x, y - h), (x - size * 0.6, y), (x, y - h * 0.35)], fill=INK)
        draw.polygon([(x, y - h), (x + size * 0.6, y), (x, y - h * 0.35)], outline=INK, fill=PAPER)
        draw.text((x, margin), "N", font=font, fill=INK, anchor="mt")
    return np.asarray(view)


# --------------------------------------------------------------------------------------------
# Transects
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Transect:
    """A strip across the field, in the photo's pixels: from `start` to `end` ((row, col) each, pixel
    corners, so (0, 0) is the photo's top-left corner) and `width` pixels wide, centred on the line.

    The side view of a transect looks at the strip square to its line, from its right-hand side
    (a transect drawn left to right is seen from the south, as the full side view).
    """

    start: tuple
    end: tuple
    width: float
    text: str = ""

    @property
    def length(self):
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])

    def corners(self):
        """The strip's four corners (row, col), in order around it."""
        (r0, c0), (r1, c1) = self.start, self.end
        dr, dc = (r1 - r0) / self.length, (c1 - c0) / self.length
        # Unit normal (row, col) to the line; half the width either side.
        nr, nc = -dc * self.width / 2, dr * self.width / 2
        return [(r0 + nr, c0 + nc), (r1 + nr, c1 + nc), (r1 - nr, c1 - nc), (r0 - nr, c0 - nc)]


_NUMBER = r"\s*([-+]?\d+(?:\.\d*)?)\s*"


def parse_transect(text, *, shape, name="transect"):
    """A transect from its text, checked against a photo of `shape` (rows, cols).

    Two forms, in the photo's pixels (rows from the top, columns from the left):

    * ``rows=R0:R1`` -- the band of rows R0 to R1 across the whole field (seen from the south);
    * ``line=R0,C0,R1,C1[,WIDTH]`` -- the line from (R0, C0) to (R1, C1), WIDTH pixels wide
      (default 2 % of the photo's longer side).

    Parameters
    ----------
    text : str
    shape : tuple of int
        (rows, cols) of the photo.
    name : str, optional
        The setting's name in error messages (``--transect`` on the command line).

    Returns
    -------
    Transect

    Examples
    --------
    >>> parse_transect("rows=100:140", shape=(400, 600))
    Transect(start=(120.0, 0.0), end=(120.0, 600.0), width=40.0, text='rows=100:140')
    >>> parse_transect("line=0,0,400,600,10", shape=(400, 600)).width
    10.0
    """
    rows, cols = int(shape[0]), int(shape[1])
    source = str(text).strip()
    kind, _, values = source.partition("=")
    kind = kind.strip().lower()
    if kind == "rows":
        match = re.fullmatch(_NUMBER + ":" + _NUMBER, values)
        if match is None:
            raise CliffTerrainError(
                f"`{name}` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got {source!r}"
            )
        r0, r1 = sorted(float(v) for v in match.groups())
        _inside(name, source, [(r0, 0.0), (r1, 0.0)], rows, cols)
        if r1 - r0 <= 0:
            raise CliffTerrainError(f"`{name}` must span at least one row, got {source!r}")
        middle = (r0 + r1) / 2
        return Transect((middle, 0.0), (middle, float(cols)), r1 - r0, source)
    if kind == "line":
        parts = values.split(",")
        if len(parts) not in (4, 5) or not all(re.fullmatch(_NUMBER, p) for p in parts):
            raise CliffTerrainError(
                f"`{name}` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got {source!r}"
            )
        r0, c0, r1, c1 = (float(p) for p in parts[:4])
        width = float(parts[4]) if len(parts) == 5 else max(1.0, round(0.02 * max(rows, cols)))
        if width <= 0:
            raise CliffTerrainError(f"`{name}` WIDTH must be > 0, got {source!r}")
        _inside(name, source, [(r0, c0), (r1, c1)], rows, cols)
        if math.hypot(r1 - r0, c1 - c0) < 1.0:
            raise CliffTerrainError(f"`{name}` must be at least one pixel long, got {source!r}")
        return Transect((r0, c0), (r1, c1), width, source)
    raise CliffTerrainError(f"`{name}` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got {source!r}")


def _inside(name, source, points, rows, cols):
    for r, c in points:
        if not (0.0 <= r <= rows and 0.0 <= c <= cols):
            raise CliffTerrainError(
                f"`{name}` point (row {r:g}, column {c:g}) is outside the {cols} x {rows} photo "
                f"(rows 0 to {rows}, columns 0 to {cols}), got {source!r}"
            )


# --------------------------------------------------------------------------------------------
# The contact sheet
# --------------------------------------------------------------------------------------------


def contact_sheet(panels, *, facts=(), title=None, tile=480, columns=3):
    """A labelled contact sheet: each panel's image scaled into its tile with its label above, and
    the key figures (`facts`, one per line) in a last tile.

    Parameters
    ----------
    panels : sequence of (str, array) or (str, array, int)
        Label, image ((rows, cols[, 3 or 4]) uint8; transparency shown on white) and, optionally,
        how many columns the tile spans (a wide side view reads better over two).
    facts : sequence of str, optional
        Lines of the key-figures tile.
    title : str, optional
        A line above the sheet.
    tile : int, optional
        Side of each tile in pixels (>= 64).
    columns : int, optional

    Returns
    -------
    (rows, cols, 3) uint8 array

    Examples
    --------
    >>> sheet = contact_sheet([("a", np.zeros((10, 20, 3), np.uint8))], facts=["one"], tile=100)
    >>> sheet.shape[1] > 200
    True
    """
    from PIL import Image, ImageDraw

    if not panels:
        raise CliffTerrainError("`panels` must hold at least one (label, image), got none")
    if int(tile) < 64:
        raise CliffTerrainError(f"`tile` must be >= 64, got {tile}")
    tile, columns = int(tile), max(1, int(columns))
    items = [(str(p[0]), p[1], min(columns, int(p[2]) if len(p) > 2 else 1)) for p in panels]
    if facts:
        items.append(("Key figures", None, 1))
    size = max(MIN_FONT, tile // 22)
    font = _font(size)
    label_h = round(1.6 * size)
    gap = size
    # Flow the tiles into rows, a spanning tile going to the next row when it does not fit.
    cells, row, col = [], 0, 0
    for _, _, span in items:
        if col + span > columns:
            row, col = row + 1, 0
        cells.append((row, col))
        col += span
    grid_rows = row + 1
    title_h = round(2.0 * size) if title else 0
    used = max(c + s for (_, c), (_, _, s) in zip(cells, items, strict=True))
    width = used * tile + (used + 1) * gap
    height = title_h + grid_rows * (tile + label_h) + (grid_rows + 1) * gap
    sheet = Image.new("RGB", (width, height), PAPER)
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((gap, gap), title, font=_font(round(1.2 * size)), fill=INK)
    for index, ((label, image, span), (r, c)) in enumerate(zip(items, cells, strict=True)):
        x = gap + c * (tile + gap)
        y = title_h + gap + r * (tile + label_h + gap)
        draw.text((x, y), label, font=font, fill=INK)
        if image is None:
            line_h = round(1.45 * size)
            for i, line in enumerate(facts):
                draw.text((x, y + label_h + i * line_h), str(line), font=font, fill=INK)
            continue
        picture = _as_rgb(image, f"panels[{index}]")
        box_w = span * tile + (span - 1) * gap
        scale = min(box_w / picture.width, tile / picture.height)
        shown = (max(1, round(picture.width * scale)), max(1, round(picture.height * scale)))
        resample = Image.Resampling.LANCZOS if scale < 1 else Image.Resampling.NEAREST
        picture = picture.resize(shown, resample)
        top = y + label_h + (tile - shown[1]) // 2
        left = x + (box_w - shown[0]) // 2
        sheet.paste(picture, (left, top))
        draw.rectangle((left - 1, top - 1, left + shown[0], top + shown[1]), outline=GRID)
    return np.asarray(sheet)
