"""Legends drawn on rendered views after rendering (Pillow only): a height ruler for the side view,
a colour bar for the height-coloured mesh, a scale bar and north arrow for the top views.

The renders themselves are never changed: every function here returns a new array, and
``render_views.py`` writes it beside the raw render (``xz.png`` -> ``xz_annotated.png``), so the
top views compared with the photo (PSNR, SSIM) stay pixel for pixel what Blender rendered.
"""

from __future__ import annotations

import numpy as np

from .._validate import check_float
from ..errors import CliffTerrainError
from .drawing import GRID, INK, PAPER, as_rgb, extend, font_size, framed_text, load_font, text_size
from .legends import display_units, format_length, format_value, height_colours, nice_below, nice_step

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
    rgb = as_rgb(image, "image")
    rows, cols = rgb.height, rgb.width
    top_row = ground_row - max_height * rows_per_unit
    if top_row < -0.5 or ground_row > rows - 0.5 + 1e-6:
        raise CliffTerrainError(
            f"cannot label the height ruler: heights 0 to {max_height:g} {units} fall on rows "
            f"{ground_row:g} to {top_row:g}, outside the {rows}-row `image`"
        )
    size = font_size((max(rows, cols // 2), cols))
    font = load_font(size)
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
    label_w = max(text_size(probe, text, font)[0] for text in [*labels, unit])
    tick = max(4, size // 2)
    left = label_w + tick + size
    caption = [
        title or "Side view from the south",
        f"heights in {unit}, vertical exaggeration {exaggeration:g}x",
    ]
    line_h = round(1.3 * size)
    top = len(caption) * line_h + size
    bottom = size
    figure = extend(view, left=left, top=top, bottom=bottom)
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
    view = as_rgb(image, "image")
    rows, cols = view.height, view.width
    size = font_size((rows, cols))
    font = load_font(size)
    step = nice_step(max_height * factor, ticks=5)
    ticks = np.arange(0.0, max_height * factor * 1.0000001, step)
    labels = [format_value(t, step) for t in ticks]
    probe = ImageDraw.Draw(view)
    label_w = max(text_size(probe, text, font)[0] for text in labels)
    title_text = f"{title} ({unit})"
    bar_w = max(8, size)
    margin = max(bar_w + size // 2 + label_w + size, text_size(probe, title_text, font)[0] + size)
    figure = extend(view, right=margin)
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

    view = as_rgb(image, "image")
    rows, cols = view.height, view.width
    size = font_size((rows, cols))
    font = load_font(size)
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
        tw, th = text_size(draw, label, font)
        pad = max(3, size // 4)
        draw.rectangle((x0 - pad, y0 - th - 2 * pad, x0 + max(bar, tw) + pad, y0 + thick + pad), fill=PAPER)
        halves = 2
        for i in range(halves):
            fill = INK if i % 2 == 0 else PAPER
            xa, xb = x0 + bar * i / halves, x0 + bar * (i + 1) / halves
            draw.rectangle((round(xa), y0, round(xb), y0 + thick), fill=fill, outline=INK)
        draw.text((x0, y0 - pad), label, font=font, fill=INK, anchor="ld")
    else:
        framed_text(draw, (margin, rows - margin), "scale unknown (no GSD)", font, anchor="ld")
    if georeferenced:
        h = 2 * size
        x, y = cols - margin - size, margin + size + h
        pad = max(3, size // 4)
        draw.rectangle((x - size - pad, margin - pad, x + size + pad, y + pad), fill=PAPER)
        draw.polygon([(x, y - h), (x - size * 0.6, y), (x, y - h * 0.35)], fill=INK)
        draw.polygon([(x, y - h), (x + size * 0.6, y), (x, y - h * 0.35)], outline=INK, fill=PAPER)
        draw.text((x, margin), "N", font=font, fill=INK, anchor="mt")
    return np.asarray(view)
