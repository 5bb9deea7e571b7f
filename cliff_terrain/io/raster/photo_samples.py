"""How an orthophoto's stored samples become RGB uint8 and a valid mask: one rule for a file read
whole and for its windows.

:func:`photo_bands` reads 1, 3 or 4 bands (the 4th alpha) of uint8, uint16 or float samples. Two of
its decisions belong to the whole file, not to the pixels at hand, so that a window reads what the
whole file reads there:

* **The collar** (:func:`black_corner`): exact black is no data when a corner of the file is exact
  black and it has neither alpha nor a declared no-data value.
* **The scale of the samples** (:func:`sample_scale`): 12-bit cameras store 0..4095 in 16 bits, so
  16-bit samples are scaled by the bit depth the file uses (:func:`colour_scale`), and float samples
  are in [0, 1] or [0, 255]; both are taken from the file's largest colour sample on the overview
  grid (every :func:`overview_step`-th pixel, the grid the windowed heights' threshold is taken
  on). Taken window by window, a dark window (most of it collar or soil) was scaled as if 12 bits
  were 11, twice as bright as the file around it (a float window of collar and a few values under
  1 as if the file were in [0, 1]). A sample above the scale (a glint the overview grid missed)
  saturates at 255.

Pixels without data (alpha 0, the no-data value, the collar) are black in the RGB, as Pillow's
composite over black gives them: filters and resampling that run before the mask is applied see no
colour from under the no-data area.
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import RasterReadError
from .surface_values import is_nodata

#: The overview that fixes the windowed heights' threshold and a file's sample scale: at most this many pixels.
OVERVIEW_PIXELS = 4_000_000


def overview_step(shape, *, max_pixels=OVERVIEW_PIXELS):
    """The integer step (every step-th row and column) that reduces `shape` to at most `max_pixels`.

    Examples
    --------
    >>> overview_step((1000, 1000)), overview_step((16500, 16050))
    (1, 9)
    """
    rows, cols = shape[:2]
    return max(1, math.ceil(math.sqrt(rows * cols / max_pixels)))


def colour_scale(top):
    """The value 16-bit colour samples reach at full scale, from the largest one `top`: 255 for
    8-bit values, else the bit depth used (4095 for 12 bits, 65535 for 16).

    Examples
    --------
    >>> colour_scale(200), colour_scale(4000), colour_scale(4096), colour_scale(65000)
    (255, 4095, 8191, 65535)
    """
    top = int(top)
    return 255 if top <= 255 else (1 << max(8, top.bit_length())) - 1


def sample_scale(samples, *, nodata=None):
    """The value a file's full-scale colour samples reach, from `samples` ((rows, cols, bands) of the
    file, its overview grid: :func:`overview_step`): :func:`colour_scale` for 16 bits; 1.0 or 255.0
    for floats (in [0, 1] when no sample with data exceeds 1); None for 8 bits.

    Examples
    --------
    >>> sample_scale(np.array([[[0.2, 0.5, 0.9]]], np.float32)), sample_scale(np.full((1, 1, 3), 3000, np.uint16))
    (1.0, 4095)
    """
    colour = samples[..., :3] if samples.shape[2] >= 3 else samples[..., :1]
    if samples.dtype == np.uint16:
        return colour_scale(colour.max(initial=0))
    if samples.dtype.kind != "f":
        return None
    values = colour[_float_data(colour, nodata)]
    return 1.0 if not values.size or float(values.max()) <= 1.0 + 1e-6 else 255.0


def _float_data(colour, nodata):
    """Where float `colour` samples ((rows, cols, bands)) hold data: finite, not the declared no-data
    value, and not exact zeros in every band (OpenDroneMap fills the area outside the flight so)."""
    data = np.all(np.isfinite(colour), axis=2) & np.any(colour != 0, axis=2)
    if nodata is not None:
        data &= ~np.all(is_nodata(colour, nodata), axis=2)
    return data


def photo_bands(array, name, *, nodata=None, planar=False, collar=None, scale=None):
    """RGB uint8 and a valid mask (or None) from a photo's decoded samples (1, 3 or 4 bands).

    `collar`: whether the file's exact black is the collar outside a mosaic's footprint (no data),
    for integer samples without alpha or a declared no-data value; None decides it from `array`'s
    own corners (:func:`black_corner`), as for a whole file. Float files' exact zeros are always no
    data (OpenDroneMap's). `scale`: the value full-scale 16-bit or float samples reach
    (:func:`sample_scale`); None decides it from `array` as a whole file (its overview grid).
    Pixels without data are black.
    """
    if array.ndim == 3 and planar:
        array = np.moveaxis(array, 0, -1)
    elif array.ndim == 3 and array.shape[2] > 4 and array.shape[0] <= 4:
        array = np.moveaxis(array, 0, -1)
    if array.ndim == 2:
        array = array[..., None]
    bands = array.shape[2]
    if bands not in (1, 2, 3, 4):
        raise RasterReadError(f"orthophoto {name!r} has {bands} bands, expected 1, 3 or 4")
    if scale is None and array.dtype != np.uint8:
        step = overview_step(array.shape)
        scale = sample_scale(array[::step, ::step], nodata=nodata)
    colour = array[..., :3] if bands >= 3 else np.repeat(array[..., :1], 3, axis=2)
    valid = np.ones(array.shape[:2], dtype=bool)
    if array.dtype.kind == "f":
        valid &= _float_data(colour, nodata)
        values = colour[valid]
        top = float(values.max()) if values.size else 1.0
        low = float(values.min()) if values.size else 0.0
        if low < 0.0 or top > 255.0 + 1e-3:
            raise RasterReadError(
                f"orthophoto {name!r} holds float values in [{low:.3g}, {top:.3g}], not a photo in [0, 1] or [0, 255]"
            )
        gain = np.float32(255.0 / float(scale))
        scaled = np.where(valid[..., None], colour, 0.0).astype(np.float32) * gain + np.float32(0.5)
        rgb = np.clip(scaled, 0, 255).astype(np.uint8)
    elif array.dtype == np.uint8:
        rgb = np.ascontiguousarray(colour)
        if nodata is not None and 0 <= nodata <= 255:
            valid &= ~np.all(colour == nodata, axis=2)
    elif array.dtype == np.uint16:
        if nodata is not None and 0 <= nodata <= 65535:
            valid &= ~np.all(colour == nodata, axis=2)
        scaled = colour.astype(np.float32) * np.float32(255.0 / int(scale)) + np.float32(0.5)
        rgb = np.clip(scaled, 0, 255).astype(np.uint8)  # a glint above the file's scale saturates
    else:
        raise RasterReadError(
            f"orthophoto {name!r} has samples of type {array.dtype}, expected uint8, uint16 or float"
        )
    if bands in (2, 4):
        alpha = array[..., -1]
        valid &= alpha > 0
    elif array.dtype.kind != "f" and nodata is None and (black_corner(colour) if collar is None else collar):
        # No alpha and no declared no-data, and a corner exactly black: the collar a mosaic's export
        # leaves outside the flight (`gdal_translate -b 1 -b 2 -b 3`, a GIS's "rendered image"), as
        # in OpenDroneMap's float files above. Taken for black soil, a 16 % collar had the soil
        # threshold find no bare soil at all. Only then: a photo's own darkest soil (broccoli on
        # black earth) holds exact black too, and is soil.
        valid &= np.any(colour != 0, axis=2)
    if valid.all():
        return np.ascontiguousarray(rgb), None
    rgb = np.array(rgb)  # black where there is no data (a copy: `rgb` may be a view of the samples)
    rgb[~valid] = 0
    return rgb, valid


def black_corner(colour):
    """Whether any of the four corner pixels of `colour` ((rows, cols, bands)) is exact black in every
    band: a mosaic's footprint never fills its rectangle, a photo's corners are the scene."""
    corners = colour[[0, 0, -1, -1], [0, -1, 0, -1]]
    return bool(np.any(np.all(corners == 0, axis=-1)))
