"""A labelled contact sheet (``summary.png``) of a relief's figures for a report (Pillow only)."""

from __future__ import annotations

import numpy as np

from ..errors import CliffTerrainError
from .drawing import GRID, INK, MIN_FONT, PAPER, as_rgb, load_font


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
    font = load_font(size)
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
        draw.text((gap, gap), title, font=load_font(round(1.2 * size)), fill=INK)
    for index, ((label, image, span), (r, c)) in enumerate(zip(items, cells, strict=True)):
        x = gap + c * (tile + gap)
        y = title_h + gap + r * (tile + label_h + gap)
        draw.text((x, y), label, font=font, fill=INK)
        if image is None:
            line_h = round(1.45 * size)
            for i, line in enumerate(facts):
                draw.text((x, y + label_h + i * line_h), str(line), font=font, fill=INK)
            continue
        picture = as_rgb(image, f"panels[{index}]")
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
