"""A Pillow image's pixels as RGB uint8 and alpha: modes converted, 16 bits scaled, bands copied out.

Rows are copied out of Pillow in bands, so no full-size temporary copy exists next to the decoded
image and the result (see :mod:`._open`'s memory guard).
"""

from __future__ import annotations

import numpy as np

from ...errors import ImageReadError

# Rows are copied out of Pillow in bands of about this many bytes, so no full-size temporary copy
# (Pillow's tobytes) exists next to the decoded image and the result.
_BAND_BYTES = 1 << 20


_SIXTEEN_BIT_MODES = ("I;16", "I;16L", "I;16B", "I;16N")


def decode_pixels(im, name):
    """Decode `im` into (rgb (rows, cols, 3) uint8, alpha (rows, cols) uint8 or None), stored orientation."""
    im.load()
    mode = im.mode
    if mode == "P":
        im = im.convert("RGBA" if "transparency" in im.info else "RGB")
    elif mode in ("PA", "RGBa"):
        im = im.convert("RGBA")
    elif mode == "La":
        im = im.convert("LA")
    elif mode not in ("RGB", "RGBA", "L", "LA", "1", "I") + _SIXTEEN_BIT_MODES:
        try:
            im = im.convert("RGB")  # CMYK, YCbCr, HSV, RGBX
        except ValueError as error:
            raise ImageReadError(
                f"cannot read image {name!r}: colour mode {mode!r} is not supported"
            ) from error

    width, height = im.size
    rgb = np.empty((height, width, 3), dtype=np.uint8)
    alpha = np.empty((height, width), dtype=np.uint8) if im.mode in ("RGBA", "LA") else None
    if im.mode == "I":
        low, high = _int_range(im)
        if low < 0 or high > 65535:
            raise ImageReadError(
                f"cannot read image {name!r}: it holds 32-bit integers from {low} to {high}, a raster of "
                "measurements, not a photograph; give an 8- or 16-bit RGB or greyscale photo"
            )
    for top, band in _bands(im):
        rows = slice(top, top + band.shape[0])
        if im.mode in ("RGB", "RGBA"):
            rgb[rows] = band[..., :3]
        elif im.mode == "LA":
            rgb[rows] = band[..., :1]
        elif im.mode == "1":
            rgb[rows] = (band.astype(np.uint8) * 255)[..., None]
        elif im.mode in _SIXTEEN_BIT_MODES or im.mode == "I":
            rgb[rows] = _sixteen_to_eight(band)[..., None]
        else:  # L
            rgb[rows] = band[..., None]
        if alpha is not None:
            alpha[rows] = band[..., -1]
    if alpha is None and mode == "RGB" and im.format == "TIFF":
        alpha = _unspecified_alpha(im, name, rgb.shape[:2])
    return rgb, alpha


def _bands(im):
    """Yield (first row, ndarray of a band of rows) covering `im`."""
    width, height = im.size
    bytes_per_row = max(1, width * len(im.getbands()) * (4 if im.mode.startswith("I") else 1))
    step = max(1, _BAND_BYTES // bytes_per_row)
    for top in range(0, height, step):
        bottom = min(height, top + step)
        yield top, np.asarray(im.crop((0, top, width, bottom)))


def _int_range(im):
    low, high = None, None
    for _, band in _bands(im):
        low = int(band.min()) if low is None else min(low, int(band.min()))
        high = int(band.max()) if high is None else max(high, int(band.max()))
    return low, high


def _sixteen_to_eight(values):
    """Scale 0..65535 to 0..255 with rounding (the inverse of 8 -> 16 bit replication, v * 257)."""
    return ((values.astype(np.uint32) + 128) // 257).astype(np.uint8)


def _unspecified_alpha(im, name, shape):
    """The 4th sample of an RGB TIFF whose extra sample is "unspecified" (GDAL's alpha), if it is a mask."""
    samples = im.tag_v2.get(277)  # SamplesPerPixel
    extra = im.tag_v2.get(338)  # ExtraSamples: 0 unspecified, 1 associated, 2 unassociated alpha
    if samples != 4 or extra not in (0, (0,)):
        return None
    try:
        import tifffile

        with tifffile.TiffFile(name) as tif:
            fourth = tif.pages[0].asarray()[..., 3]
    except Exception:  # a codec tifffile lacks: keep Pillow's RGB and treat every pixel as data
        return None
    if fourth.shape != shape or fourth.dtype.kind != "u":
        return None
    top = np.iinfo(fourth.dtype).max
    if not np.all((fourth == 0) | (fourth == top)):
        return None  # a real band (e.g. near-infrared), not a no-data mask
    return np.where(fourth == top, 255, 0).astype(np.uint8)


def composite_over_black(rgb, alpha):
    """Composite `rgb` over black in place by `alpha`; return the mask of pixels holding data (alpha > 0)."""
    valid = alpha > 0
    rgb[~valid] = 0
    partial = valid & (alpha < 255)
    if partial.any():
        weight = alpha[partial].astype(np.uint16)[:, None]
        rgb[partial] = ((rgb[partial].astype(np.uint16) * weight + 127) // 255).astype(np.uint8)
    return valid
