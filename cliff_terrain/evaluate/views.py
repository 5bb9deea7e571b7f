"""How the rendered top views of a relief compare with its photo (numpy only, no bpy).

The reference is the photo area-averaged in linear light (OpenCV ``INTER_AREA`` between sRGB
decoding and encoding), as a renderer averages texels: averaging the sRGB code values instead makes
every high-contrast edge darker than any render of it (8 dB on the soybean orthophotos' black no-data
borders). At the photo's own size the reference is the photo itself. The shading measure says how
much the lit view's light shows the relief: the brightness difference between the lit and the flat
top views over sloped pixels against level ones.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CliffTerrainError
from ..settings import MAX_RESOLUTION, MIN_VIEW_SIDE, PAPER_TABLE4, SSIM_MIN_SIDE

# Slopes (degrees) that count as sloped and as level when measuring how much the shading shows.
SLOPED_DEG = 15.0
LEVEL_DEG = 2.0
# Rec. 709 luma of sRGB values (the shading measure compares brightness, not hue).
LUMA = np.array([0.2126, 0.7152, 0.0722])
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def slope_degrees(corner_heights, cell):
    """Slope of each grid cell in degrees from the heights at its corners (cell size `cell`)."""
    z = np.asarray(corner_heights, dtype=np.float64)
    dx = ((z[:-1, 1:] - z[:-1, :-1]) + (z[1:, 1:] - z[1:, :-1])) / (2 * cell)
    dy = ((z[:-1, :-1] - z[1:, :-1]) + (z[:-1, 1:] - z[1:, 1:])) / (2 * cell)
    return np.degrees(np.arctan(np.hypot(dx, dy)))


def resize_nearest(array, size):
    """`array` (rows, cols, ...) resampled to `size` = (cols', rows') by nearest pixel centres."""
    rows, cols = array.shape[:2]
    out_cols, out_rows = size
    r = np.minimum(((np.arange(out_rows) + 0.5) * rows / out_rows).astype(np.intp), rows - 1)
    c = np.minimum(((np.arange(out_cols) + 0.5) * cols / out_cols).astype(np.intp), cols - 1)
    return array[r[:, None], c[None, :]]


def shading_measure(lit, flat, slope):
    """How much the lit view's shading shows the relief.

    Mean absolute brightness difference (Rec. 709 luma, 8-bit grey levels) between the lit and the
    flat top views over sloped pixels (slope >= SLOPED_DEG) and over level ones (< LEVEL_DEG).

    Returns
    -------
    dict
        ``shading_sloped``, ``shading_level``, ``shading_contrast`` (their difference; None when
        nothing is sloped), ``sloped_fraction``.
    """
    diff = np.abs(lit[..., :3].astype(np.float64) @ LUMA - flat[..., :3].astype(np.float64) @ LUMA)
    sloped = slope >= SLOPED_DEG
    level = slope < LEVEL_DEG
    s = float(diff[sloped].mean()) if sloped.any() else None
    lv = float(diff[level].mean()) if level.any() else None
    return {
        "shading_sloped": s,
        "shading_level": lv,
        "shading_contrast": None if s is None or lv is None else s - lv,
        "sloped_fraction": float(sloped.mean()),
        "sloped_deg": SLOPED_DEG,
        "level_deg": LEVEL_DEG,
    }


def srgb_to_linear(rgb):
    """8-bit sRGB values to linear light, float32 in [0, 1] (the piecewise sRGB curve)."""
    c = np.arange(256, dtype=np.float64) / 255.0
    lut = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)
    return lut[rgb]


def linear_to_srgb(linear):
    """Linear light in [0, 1] to 8-bit sRGB values (rounded)."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.round(255.0 * srgb).astype(np.uint8)


def view_resolution(requested, rows, cols, *, name="resolution"):
    """Longest side of the views of a `rows` x `cols` grid: `requested`, or by default one view pixel
    per grid cell, enlarged (up to MAX_RESOLUTION) until the shorter side has MIN_VIEW_SIDE pixels.

    The shorter side is ``max(1, round(resolution * shorter / longer))``, as the view rig's
    ``frame_size`` makes it. A resolution that leaves it under SSIM_MIN_SIDE is refused with a CliffTerrainError
    naming the setting (`name`) and the resolution needed: the top views could not be compared
    with the photo. `requested` of None or 0 means the default.
    """
    longest, shortest = max(rows, cols), min(rows, cols)
    if requested:
        resolution = int(requested)
    else:
        resolution = min(MAX_RESOLUTION, max(longest, -(-MIN_VIEW_SIDE * longest // shortest)))
    across = max(1, round(resolution * shortest / longest))
    if across < SSIM_MIN_SIDE:
        views = f"{across} pixel{'' if across == 1 else 's'} across the {cols} x {rows} grid"
        needed = -(-SSIM_MIN_SIDE * longest // shortest)
        if requested and needed <= MAX_RESOLUTION:
            raise CliffTerrainError(
                f"{name} {requested} makes the top views {views}; comparing them with the photo "
                f"needs at least {SSIM_MIN_SIDE}: use {name} {needed} or more"
            )
        raise CliffTerrainError(
            f"the photo is too thin to render: even {MAX_RESOLUTION} pixels long, the top views are "
            f"{views}; comparing them with the photo needs at least {SSIM_MIN_SIDE}"
        )
    return resolution


def reference_image(path, size, *, bands=None):
    """The photo as the top views are compared with it, at the render size.

    The photo is read as the core reads it (EXIF orientation applied, transparent pixels black; a
    JPEG more than 4 times larger than the render is decoded reduced by 2, 4 or 8) and area-averaged
    (OpenCV INTER_AREA) to `size` in linear light, as a renderer averages texels: averaging the sRGB
    values instead makes every high-contrast edge darker than any render of it (up to 50 grey levels
    at a black no-data border, 8 dB on the soybean orthophotos).

    Parameters
    ----------
    path : str
    size : tuple of int
        (cols, rows) of the render.
    bands : sequence of str, optional
        A multispectral photo's band names when its file gives none (its true colour is compared).

    Returns
    -------
    reference : (rows, cols, 3) uint8 array
    description : str
        What the reference is, for metrics.json.
    """
    import cv2

    from ..io.photo import load_image

    # (load_image's smallest max_size is 16: views of tiny photos are enlarged, not the photo.)
    rgb, meta = load_image(path, max_size=max(16, 4 * max(size)), bands=bands)
    how = "decoded at full resolution" if meta.reduction == 1 else f"decoded reduced by {meta.reduction}"
    if (rgb.shape[1], rgb.shape[0]) != tuple(size):
        rgb = linear_to_srgb(cv2.resize(srgb_to_linear(rgb), tuple(size), interpolation=cv2.INTER_AREA))
    return rgb, (
        f"the input photo {how}, area-resized (OpenCV INTER_AREA) in linear light to the render size "
        f"{size[0]}x{size[1]}"
    )


def read_png(path):
    """An 8-bit PNG as an array (rows, cols, channels)."""
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGBA" if "A" in image.mode else "RGB"))


def compare_top_views(reference, lit, flat, slope=None):
    """PSNR and SSIM of the lit and flat top views against `reference`, and the shading measure.

    Parameters
    ----------
    reference, lit, flat : (rows, cols, 3) uint8 arrays
    slope : (rows, cols) array, optional
        Slope in degrees of each rendered pixel.

    Returns
    -------
    dict
    """
    from .metrics import psnr, ssim

    lit, flat = lit[..., :3], flat[..., :3]
    result = {
        "psnr_xy": psnr(reference, lit),
        "ssim_xy": ssim(reference, lit),
        "psnr_xy_flat": psnr(reference, flat),
        "ssim_xy_flat": ssim(reference, flat),
    }
    if slope is not None:
        result.update(shading_measure(lit, flat, slope))
    return result


def psnr_text(value):
    """A PSNR for people: ``"17.73 dB"``, or ``"identical"`` when it is infinite (no pixel differs).

    A float32 store of infinity (Blender's FloatProperty keeps float32's largest value) reads as
    infinite too: no real PSNR comes near it.

    Examples
    --------
    >>> psnr_text(17.7312), psnr_text(float("inf")), psnr_text(float(np.finfo(np.float32).max))
    ('17.73 dB', 'identical', 'identical')
    """
    return "identical" if value >= _FLOAT32_MAX else f"{value:.2f} dB"


def metrics_summary(metrics):
    """One line of the top views' PSNR and SSIM against the photo (from :func:`compare_top_views`).

    Examples
    --------
    >>> metrics_summary({"psnr_xy": 21.5, "ssim_xy": 0.91, "psnr_xy_flat": float("inf"), "ssim_xy_flat": 1.0})
    'lit top view PSNR 21.50 dB, SSIM 0.9100; flat PSNR identical, SSIM 1.0000'
    """
    return (
        f"lit top view PSNR {psnr_text(metrics['psnr_xy'])}, SSIM {metrics['ssim_xy']:.4f}; "
        f"flat PSNR {psnr_text(metrics['psnr_xy_flat'])}, SSIM {metrics['ssim_xy_flat']:.4f}"
    )


def paper_summary():
    """The paper's Table 4 values, for beside :func:`metrics_summary`."""
    return f"paper: {PAPER_TABLE4['psnr']} dB, {PAPER_TABLE4['ssim']}"


def json_safe(value):
    """A copy of `value` (dicts, lists, numbers) that JSON can hold: non-finite floats become None.

    An infinite PSNR (identical images) is written as ``null``.

    Examples
    --------
    >>> json_safe({"psnr_xy": float("inf"), "runs": [1.5, float("nan")]})
    {'psnr_xy': None, 'runs': [1.5, None]}
    """
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
