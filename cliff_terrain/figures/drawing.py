"""Drawing on figures with Pillow: ink and paper colours, text sized to the image, images as RGB.

Shared by the annotated views (:mod:`.annotate`) and the contact sheet (:mod:`.sheet`). Text size
follows the image: :func:`font_size` is about 1/45 of the longer side, never under 12 pixels, so a
label stays readable both on a 1000-pixel figure and shrunk into the contact sheet.
"""

from __future__ import annotations

import numpy as np

from ..errors import CliffTerrainError

# Ink and paper.
INK = (20, 20, 20)
PAPER = (255, 255, 255)
GRID = (200, 200, 200)
MIN_FONT = 12


def font_size(image_shape):
    """Text height in pixels for an image of `image_shape` (rows, cols, ...): 1/45 of the longer
    side, at least 12."""
    return max(MIN_FONT, round(max(image_shape[0], image_shape[1]) / 45))


def load_font(size):
    """Pillow's default font (scalable since Pillow 10.1) at `size` pixels."""
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def as_rgb(image, name, background=PAPER):
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


def text_size(draw, text, font):
    left, top, right, bottom = draw.textbbox((0, 0), text, font=font)
    return right - left, bottom - top


def framed_text(draw, xy, text, font, *, anchor="la", pad=None):
    """Text on a white box (readable over a photo)."""
    pad = max(2, font.size // 5) if pad is None else pad
    box = draw.textbbox(xy, text, font=font, anchor=anchor)
    draw.rectangle((box[0] - pad, box[1] - pad, box[2] + pad, box[3] + pad), fill=PAPER)
    draw.text(xy, text, font=font, fill=INK, anchor=anchor)


def extend(picture, *, left=0, top=0, right=0, bottom=0):
    from PIL import Image

    out = Image.new("RGB", (picture.width + left + right, picture.height + top + bottom), PAPER)
    out.paste(picture, (left, top))
    return out
