"""Load a photo as RGB uint8, with the metadata that gives it a ground scale.

Decisions (each documented where it applies):

* **Formats**: JPEG, PNG, TIFF (GeoTIFF included), WebP and BMP, read with Pillow; the pixels of a
  colour or greyscale JPEG are decoded by OpenCV, in one call that releases the GIL, with the same
  libjpeg-turbo settings (the same pixels as Pillow's, bit for bit). Greyscale, palette,
  CMYK, YCbCr and 16-bit images become RGB; 16-bit greyscale is scaled by 255/65535 (rounded), 16-bit
  colour is reduced by Pillow to its high byte (the two differ by at most 1). Colour profiles (ICC)
  are not applied.
* **Transparency marks no-data** (orthophotos use alpha = 0 outside the surveyed area): such pixels
  are filled with black, partially transparent ones are composited over black, and
  ``metadata.valid_mask`` / ``metadata.valid_fraction`` say which pixels hold data. GDAL often
  writes the alpha of an RGBA orthophoto as an "unspecified" 4th sample; a 4th TIFF sample holding
  only 0 and its maximum is therefore read as the no-data mask too (any other 4th band, such as
  near-infrared, is ignored).
* **Not photos are refused**: a single-band floating-point (or 32-bit integer beyond 16-bit range)
  image is a raster of measurements, typically a DSM, not a photograph; it raises
  :class:`ImageReadError` saying so.
* **Truncated or corrupt pixel data is refused** (Pillow's default; ``ImageFile.LOAD_TRUNCATED_IMAGES``
  must stay False) rather than returned with a grey lower part, and so is a JPEG whose header claims
  far more pixels than its byte count could hold (over 4096 pixels per byte). Corruption that still
  decodes (a flipped bit in the entropy-coded data, or a cut file that still ends with an
  end-of-image marker) cannot be detected and gives a blotchy or partly grey image.
* **Memory guard**: the image is decoded only when its decoded size is at most `max_pixels`
  (:data:`MAX_PIXELS` = 150 megapixels by default, about 0.45 GB as RGB). Decoding peaks at about
  3 bytes per pixel plus the file for a colour JPEG, 7 for other images (8 with alpha; rows are
  copied out of Pillow in bands), so about 1.1 GB at the limit; ``np.asarray(Image.open(path))``
  alone peaks at 10. A JPEG with `max_size` is decoded
  reduced by 2, 4 or 8 (libjpeg scales while decoding, so a 100 MP photo never exists at full size
  in memory); anything else beyond the limit raises :class:`ImageTooLargeError`. Pillow's own
  decompression-bomb check is replaced by this one.
* **Ground scale** (metres per original pixel), first available of: the caller's `gsd`; a GeoTIFF's
  pixel scale in a projected system in metres or feet (not Web Mercator); the height above ground
  (the caller's, else DJI's XMP ``RelativeAltitude``) with the EXIF focal length and sensor width
  (see :mod:`.camera`). GPS altitude is above sea level and is never used as a height.
* **EXIF orientation** is applied, so the array is the photo as viewed; ``width``/``height`` are after
  orientation. Of a multi-page TIFF or multi-frame file only the first image is read.
"""

from __future__ import annotations

import contextlib
import os
import stat
import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np
from PIL import Image, JpegImagePlugin, PngImagePlugin, TiffImagePlugin

from . import camera
from ._deps import environment_error
from ._validate import check_float, check_int
from .errors import CliffTerrainError, ImageReadError, ImageTooLargeError

#: Largest decoded image, in pixels, that :func:`load_image` decodes by default (150 megapixels,
#: about 0.45 GB as RGB uint8). A larger JPEG is decoded reduced when `max_size` allows it.
MAX_PIXELS = 150_000_000

#: Fewest rows and columns an image may have (a 1-pixel-wide image has no surface to relieve).
MIN_SIDE = 2

#: Pillow formats :func:`load_image` opens (a JPEG with extra frames opens as "MPO", handled as JPEG).
SUPPORTED_FORMATS = ("JPEG", "PNG", "TIFF", "WEBP", "BMP")

_JPEG_FORMATS = ("JPEG", "MPO")
_JPEG_REDUCTIONS = (8, 4, 2)
# OpenCV's flags for a colour decode reduced by libjpeg while decoding (RGB order is added).
_CV2_REDUCED = {
    1: cv2.IMREAD_COLOR,
    2: cv2.IMREAD_REDUCED_COLOR_2,
    4: cv2.IMREAD_REDUCED_COLOR_4,
    8: cv2.IMREAD_REDUCED_COLOR_8,
}
# A flat grey JPEG with optimised Huffman tables stores about 250 pixels per byte; a header claiming
# 16 times more than that for the file's size describes data that is not there (a patched header or
# a cut file that libjpeg would silently fill with grey).
_JPEG_MAX_PIXELS_PER_BYTE = 4096
# Rows are copied out of Pillow in bands of about this many bytes, so no full-size temporary copy
# (Pillow's tobytes) exists next to the decoded image and the result.
_BAND_BYTES = 1 << 20
_SIXTEEN_BIT_MODES = ("I;16", "I;16L", "I;16B", "I;16N")


@dataclass(frozen=True)
class ImageMetadata:
    """What is known about a loaded photo.

    Attributes
    ----------
    path : str
        The file, as given.
    format : str
        Pillow's format name ("JPEG", "PNG", "TIFF", ...).
    mode : str
        Pillow's mode of the stored pixels before conversion to RGB ("RGB", "RGBA", "I;16", "CMYK", ...).
    width, height : int
        Size of the full-resolution image in pixels, after EXIF orientation (columns, rows).
    decoded_width, decoded_height : int
        Size of the returned array after orientation (its columns and rows); smaller than
        `width`, `height` when decoded reduced.
    reduction : int
        1, 2, 4 or 8: the factor the JPEG was reduced by while decoding.
    orientation : int
        EXIF orientation (1-8) that was applied; 1 when absent.
    camera_make, camera_model : str or None
        EXIF Make and Model.
    focal_length_mm, focal_length_35mm : float or None
        EXIF focal length and its 35 mm equivalent.
    sensor_width_mm : float or None
        Sensor width along the stored image's columns, from the 35 mm equivalent (preferred) or the
        EXIF focal-plane resolution.
    gps_altitude_m : float or None
        EXIF GPS altitude above sea level (recorded, never used as height above ground).
    relative_altitude_m : float or None
        DJI XMP ``drone-dji:RelativeAltitude``: height above the take-off point.
    height_above_ground_m : float or None
        The height used for the GSD: the caller's `height_above_ground`, else `relative_altitude_m`.
    gsd_m_per_px : float or None
        Ground sampling distance of a full-resolution pixel (metres per original pixel).
    gsd_source : str or None
        Where `gsd_m_per_px` came from: "user" (the `gsd` argument), "geotiff" (the GeoTIFF pixel
        scale in a projected system), "height_above_ground" (the caller's height with the camera's
        EXIF), "exif-xmp" (DJI relative altitude with the camera's EXIF), or None.
    valid_fraction : float or None
        Fraction of pixels holding data (not transparent); 1.0 without transparency; None from
        :func:`read_metadata`, which decodes no pixels.
    valid_mask : (decoded_height, decoded_width) bool ndarray or None
        True where a pixel holds data; None when every pixel does. Not part of equality.
    """

    path: str
    format: str
    mode: str
    width: int
    height: int
    decoded_width: int
    decoded_height: int
    reduction: int = 1
    orientation: int = 1
    camera_make: str | None = None
    camera_model: str | None = None
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    sensor_width_mm: float | None = None
    gps_altitude_m: float | None = None
    relative_altitude_m: float | None = None
    height_above_ground_m: float | None = None
    gsd_m_per_px: float | None = None
    gsd_source: str | None = None
    valid_fraction: float | None = None
    valid_mask: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def decoded_gsd_m_per_px(self):
        """Ground sampling distance of a pixel of the returned (possibly reduced) array, or None."""
        if self.gsd_m_per_px is None:
            return None
        return self.gsd_m_per_px * self.width / self.decoded_width


def load_image(path, *, max_size=None, gsd=None, height_above_ground=None, max_pixels=MAX_PIXELS):
    """Read a photo as an RGB uint8 array, with its metadata and ground sampling distance.

    Parameters
    ----------
    path : str or os.PathLike
        A JPEG, PNG, TIFF, WebP or BMP file.
    max_size : int, optional
        Longest side (pixels) the caller will process. A JPEG at least twice as large is decoded
        reduced by 2, 4 or 8 while keeping its longest side >= `max_size`; other formats are decoded
        at full size. The image is never resized to exactly `max_size` here. At least 16.
    gsd : float, optional
        Ground sampling distance of a full-resolution pixel (metres per pixel, > 0); overrides any
        derived value.
    height_above_ground : float, optional
        Camera height above the ground in metres (> 0), used with the EXIF focal length and sensor
        width to derive the GSD; overrides DJI's XMP relative altitude.
    max_pixels : int, optional
        Largest decoded image in pixels (default :data:`MAX_PIXELS`, 150 MP).

    Returns
    -------
    rgb : (rows, cols, 3) uint8 ndarray
        C-contiguous, EXIF orientation applied, no-data (transparent) pixels black.
    metadata : ImageMetadata
        Sizes, camera fields, GSD and the valid-pixel mask.

    Raises
    ------
    ImageReadError
        The file is missing, a directory, empty, not an image, truncated or corrupt, smaller than
        2x2 pixels, or not a photograph (such as a floating-point DSM).
    ImageTooLargeError
        The decoded image would exceed `max_pixels` and cannot be decoded reduced.

    Examples
    --------
    >>> rgb, meta = load_image("IMG_9370.jpg", max_size=1000)  # doctest: +SKIP
    >>> rgb.shape, meta.reduction, (meta.width, meta.height)  # doctest: +SKIP
    ((750, 1000, 3), 4, (4000, 3000))
    """
    with open_image(
        path, max_size=max_size, gsd=gsd, height_above_ground=height_above_ground, max_pixels=max_pixels
    ) as image:
        return image.decode()


def read_metadata(path, *, max_size=None, gsd=None, height_above_ground=None, max_pixels=MAX_PIXELS):
    """The :class:`ImageMetadata` :func:`load_image` would return, from the header alone.

    No pixel is decoded, so truncated pixel data (and a 32-bit integer raster's range) goes unnoticed,
    and ``valid_fraction`` and ``valid_mask`` are None. Parameters and errors are otherwise those of
    :func:`load_image`: a photo too large to decode, or a DSM, is refused here as well, so a caller
    can check a file before loading it.

    Examples
    --------
    >>> meta = read_metadata("IMG_9370.jpg", height_above_ground=100)  # doctest: +SKIP
    >>> meta.camera_model, round(meta.gsd_m_per_px, 4)  # doctest: +SKIP
    ('Canon PowerShot SX260 HS', 0.0344)
    """
    with _open_checked(path, max_size, gsd, height_above_ground, max_pixels, read_jpeg=False) as image:
        return image.metadata


def open_image(path, *, max_size=None, gsd=None, height_above_ground=None, max_pixels=MAX_PIXELS):
    """Open a photo and check its header; :meth:`OpenImage.decode` reads the pixels later.

    :func:`load_image` in two steps, so that a caller learns the decoded size (and any error the
    header shows) at once, and can decode elsewhere, for example in a worker thread while it
    prepares for an image of that size. Parameters and errors are those of :func:`load_image`;
    errors of the pixel data itself come from :meth:`OpenImage.decode`. The bytes of a colour or
    greyscale JPEG are read here as well, so that decoding it is a single call that releases the
    GIL (see :meth:`OpenImage.decode`).

    Returns
    -------
    OpenImage
        Holds the file open until decoded or closed; use it as a context manager.

    Examples
    --------
    >>> with open_image("IMG_9370.jpg", max_size=1000) as image:  # doctest: +SKIP
    ...     print(image.shape)
    ...     rgb, meta = image.decode()
    (750, 1000)
    """
    return _open_checked(path, max_size, gsd, height_above_ground, max_pixels, read_jpeg=True)


def _open_checked(path, max_size, gsd, height_above_ground, max_pixels, *, read_jpeg):
    name, max_size, gsd, height_above_ground, max_pixels = _check_arguments(
        path, max_size, gsd, height_above_ground, max_pixels
    )
    with _reading(name):
        # Float or planar orthophotos (OpenDroneMap's) that Pillow cannot open, or opens as one
        # float band (Pillow 12+): tifffile reads them (None when the file is not such a photo).
        from .tiff_photo import open_tiff_photo

        try:
            im = _open(name)
        except ImageReadError:
            photo = open_tiff_photo(name, gsd, height_above_ground, max_pixels)
            if photo is None:
                raise
            return photo
        try:
            info = _header(im, name, max_size, max_pixels)
            try:
                _refuse_non_photo(im, name)
            except ImageReadError:
                photo = open_tiff_photo(name, gsd, height_above_ground, max_pixels)
                if photo is None:
                    raise
                im.close()
                return photo
            return OpenImage(name, im, info, gsd, height_above_ground, read_jpeg=read_jpeg)
        except BaseException:
            im.close()
            raise


class OpenImage:
    """A photo whose header has been read and checked, its pixels not yet decoded (see :func:`open_image`).

    Attributes
    ----------
    shape : tuple of int
        (rows, cols) of the array :meth:`decode` returns: after EXIF orientation and any JPEG
        reduction.
    metadata : ImageMetadata
        What the header tells, as :func:`read_metadata` returns it.
    """

    def __init__(self, name, im, info, gsd, height_above_ground, *, read_jpeg=True):
        self._name, self._im, self._info = name, im, info
        self._gsd, self._height_above_ground = gsd, height_above_ground
        width, height = _oriented(im.size, info["orientation"])
        self.shape = (height, width)
        # Read now, so that decode() is one call that releases the GIL from start to end.
        self._jpeg_data = _jpeg_data(im, name) if read_jpeg else None

    @property
    def metadata(self):
        info = dict(self._info, decoded_width=self.shape[1], decoded_height=self.shape[0])
        info["valid_fraction"] = None
        info["valid_mask"] = None
        return _metadata(self._name, info, self._gsd, self._height_above_ground)

    def decode(self):
        """Decode the pixels (once) and close the file: ``(rgb, metadata)`` as :func:`load_image` returns.

        A colour or greyscale JPEG is decoded by OpenCV in one call that releases the GIL, so a
        thread decoding it keeps going while another holds the GIL; its pixels are Pillow's, bit
        for bit. Other images are decoded by Pillow.
        """
        if self._im is None:
            raise CliffTerrainError(f"image {self._name!r} was already decoded or closed")
        with _reading(self._name):
            try:
                rgb, alpha = None, None
                if self._jpeg_data is not None:
                    stored_shape = (self._im.size[1], self._im.size[0])
                    rgb = _decode_jpeg_at_once(self._jpeg_data, stored_shape, self._info["reduction"])
                if rgb is None:
                    rgb, alpha = _decode(self._im, self._name)
            finally:
                self.close()
        info = dict(self._info)
        valid = None
        if alpha is not None:
            valid = _composite_over_black(rgb, alpha)
        rgb = _orient(rgb, info["orientation"])
        if rgb.shape[:2] != self.shape:  # callers size their work by `shape` before decoding
            raise ImageReadError(
                f"cannot read image {self._name!r}: its pixel data is {rgb.shape[1]}x{rgb.shape[0]}, "
                f"its header says {self.shape[1]}x{self.shape[0]}"
            )
        if valid is not None:
            valid = np.ascontiguousarray(_orient(valid, info["orientation"]))
        rgb = np.ascontiguousarray(rgb)
        info["decoded_height"], info["decoded_width"] = rgb.shape[:2]
        info["valid_fraction"] = 1.0 if valid is None else float(np.count_nonzero(valid)) / valid.size
        info["valid_mask"] = None if valid is None or valid.all() else valid
        return rgb, _metadata(self._name, info, self._gsd, self._height_above_ground)

    def close(self):
        """Close the file (decoding is then no longer possible); closing twice is harmless."""
        if self._im is not None:
            self._im.close()
            self._im = self._jpeg_data = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _check_arguments(path, max_size, gsd, height_above_ground, max_pixels):
    if isinstance(path, bytes) or not isinstance(path, str | os.PathLike):
        raise CliffTerrainError(f"`path` must be a str or os.PathLike, got {type(path).__name__}")
    name = os.fsdecode(os.fspath(path))
    if max_size is not None:
        max_size = check_int("max_size", max_size, minimum=16)
    gsd = check_float("gsd", gsd, minimum=0, strict_minimum=True, allow_none=True)
    height_above_ground = check_float(
        "height_above_ground", height_above_ground, minimum=0, strict_minimum=True, allow_none=True
    )
    max_pixels = check_int("max_pixels", max_pixels, minimum=MIN_SIDE * MIN_SIDE)
    return name, max_size, gsd, height_above_ground, max_pixels


@contextlib.contextmanager
def _reading(name):
    """Turn whatever Pillow raises or warns while reading `name` into Cliff Terrain errors."""
    try:
        with warnings.catch_warnings():
            # Corrupt-EXIF and decompression-bomb warnings: our own checks decide instead.
            warnings.simplefilter("ignore")
            yield
    except CliffTerrainError:
        raise
    except Image.DecompressionBombError as error:
        raise ImageTooLargeError(f"image {name!r} is too large to decode: {error}") from error
    except MemoryError as error:
        raise ImageTooLargeError(f"image {name!r}: ran out of memory while decoding it") from error
    except Exception as error:
        environment = environment_error(error, doing=f"cannot read image {name!r}")
        if environment is not None:
            raise environment from error
        text = str(error)
        if "truncated" in text:
            why = f"the file is truncated (its data ends before the image does: {text})"
        else:
            why = f"its data is corrupt or unsupported ({type(error).__name__}: {text})"
        raise ImageReadError(f"cannot read image {name!r}: {why}") from error


def _open(name):
    try:
        info = os.stat(name)
    except FileNotFoundError:
        raise ImageReadError(f"cannot read image {name!r}: no such file") from None
    except OSError as error:
        raise ImageReadError(f"cannot read image {name!r}: {error.strerror or error}") from None
    if stat.S_ISDIR(info.st_mode):
        raise ImageReadError(f"cannot read image {name!r}: it is a directory, not an image file")
    if not stat.S_ISREG(info.st_mode):
        raise ImageReadError(f"cannot read image {name!r}: it is not a regular file")
    if info.st_size == 0:
        raise ImageReadError(f"cannot read image {name!r}: the file is empty (0 bytes)")
    try:
        return Image.open(name, formats=SUPPORTED_FORMATS)
    except PermissionError:
        raise ImageReadError(f"cannot read image {name!r}: permission denied") from None
    except Image.UnidentifiedImageError:
        with open(name, "rb") as file:
            start = file.read(8)
        raise ImageReadError(
            f"cannot read image {name!r}: it is not a JPEG, PNG, TIFF, WebP or BMP image, or its header "
            f"is corrupt (it starts with {start!r})"
        ) from None
    except Image.DecompressionBombError:
        # Pillow's guard fires before the header can be inspected; open the header without it so our
        # own limit decides (and a JPEG can still be decoded reduced).
        return _open_without_bomb_check(name)


def _open_without_bomb_check(name):
    with open(name, "rb") as file:
        start = file.read(8)
    if start[:3] == b"\xff\xd8\xff":
        return JpegImagePlugin.JpegImageFile(name)
    if start == b"\x89PNG\r\n\x1a\n":
        return PngImagePlugin.PngImageFile(name)
    if start[:4] in (b"II*\x00", b"MM\x00*"):
        return TiffImagePlugin.TiffImageFile(name)
    raise ImageTooLargeError(f"image {name!r} is too large to decode: its header passes Pillow's limit")


def _header(im, name, max_size, max_pixels):
    """Check the size, set up reduced JPEG decoding, and read the metadata; returns a dict of fields."""
    width, height = im.size
    if width < MIN_SIDE or height < MIN_SIDE:
        raise ImageReadError(
            f"cannot read image {name!r}: it is {width}x{height} pixels; an image needs at least "
            f"{MIN_SIDE}x{MIN_SIDE}"
        )
    if im.format in _JPEG_FORMATS:
        size = os.path.getsize(name)
        if width * height > _JPEG_MAX_PIXELS_PER_BYTE * size:
            raise ImageReadError(
                f"cannot read image {name!r}: its header claims {width}x{height} pixels but the file holds "
                f"only {size} bytes; it is truncated or corrupt"
            )
    reduction = 1
    if max_size is not None and im.format in _JPEG_FORMATS:
        reduction = _jpeg_reduction(width, height, max_size)
    decoded = -(-width // reduction) * -(-height // reduction)
    if decoded > max_pixels:
        raise ImageTooLargeError(_too_large_message(name, im, width, height, reduction, max_size, max_pixels))
    if reduction > 1:
        # libjpeg decodes directly at 1/2, 1/4 or 1/8 of the size: (W // s, H // s) makes Pillow pick s.
        im.draft(im.mode, (width // reduction, height // reduction))
        reduction = round(width / im.size[0])
        if im.size[0] * im.size[1] > max_pixels:
            raise ImageTooLargeError(_too_large_message(name, im, width, height, 1, max_size, max_pixels))

    info = dict(format=im.format, mode=im.mode, reduction=reduction)
    info.update(camera.read_camera(_exif(im), width=width, height=height))
    info["width"], info["height"] = _oriented((width, height), info["orientation"])
    info["relative_altitude_m"] = camera.relative_altitude(_xmp(im))
    info["geotiff_gsd"] = camera.geotiff_pixel_size(im.tag_v2) if im.format == "TIFF" else None
    return info


def _jpeg_reduction(width, height, max_size):
    """Largest libjpeg reduction (8, 4, 2) keeping the longest side >= `max_size`, else 1."""
    longest = max(width, height)
    for scale in _JPEG_REDUCTIONS:
        if -(-longest // scale) >= max_size and min(width, height) // scale >= MIN_SIDE:
            return scale
    return 1


def _too_large_message(name, im, width, height, reduction, max_size, max_pixels):
    megapixels = width * height / 1e6
    text = (
        f"image {name!r} is {width}x{height} pixels ({megapixels:.1f} MP); decoding it would pass the "
        f"limit of max_pixels={max_pixels} ({max_pixels / 1e6:.1f} MP, about {3 * max_pixels / 1e9:.2f} GB "
        "as RGB)"
    )
    if im.format not in _JPEG_FORMATS:
        return text + f"; only JPEG can be decoded reduced and this is {im.format}"
    if max_size is None:
        return text + "; pass `max_size` to decode this JPEG reduced by up to 8"
    return (
        text
        + f"; even reduced by {reduction} for max_size={max_size} it is too large: use a smaller max_size"
    )


def _exif(im):
    try:
        return im.getexif()
    except Exception:  # corrupt EXIF is missing metadata, not an unreadable photo
        return None


def _xmp(im):
    xmp = im.info.get("xmp") or im.info.get("XML:com.adobe.xmp")
    if xmp is None and im.format == "TIFF":
        xmp = im.tag_v2.get(700)
    return xmp


def _oriented(size, orientation):
    width, height = size
    return (height, width) if orientation in (5, 6, 7, 8) else (width, height)


def _refuse_non_photo(im, name):
    kind = {"F": "32-bit floating-point", "I;16S": "signed 16-bit"}.get(im.mode)
    if kind is None and im.mode.startswith("I;32"):
        kind = "32-bit integer"
    if kind is not None:
        raise ImageReadError(
            f"cannot read image {name!r}: it holds {kind} values (Pillow mode {im.mode!r}), a raster of "
            "measurements such as a DSM, not a photograph; give an 8- or 16-bit RGB or greyscale photo"
        )


def _decode(im, name):
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


def _jpeg_data(im, name):
    """The bytes of a colour or greyscale JPEG, for :func:`_decode_jpeg_at_once`; else None."""
    if im.format not in _JPEG_FORMATS or im.mode not in ("RGB", "L"):
        return None  # CMYK: Pillow's conversion to RGB
    with open(name, "rb") as file:
        return file.read()


def _decode_jpeg_at_once(data, shape, reduction):
    """A JPEG's pixels as (rows, cols, 3) uint8 RGB in stored orientation, or None.

    OpenCV decodes the whole file in one call that releases the GIL, where Pillow returns to
    Python every 64 KiB of data and every band of rows: a thread decoding a photo keeps going
    while another holds the GIL (as Blender's bulk calls do). Both bundle libjpeg-turbo with the
    same settings, so the pixels are Pillow's, bit for bit, at every reduction (tested). None, and
    Pillow decodes instead (and words any error), when OpenCV cannot decode the data (a truncated
    file: its decoder stops rather than filling with grey) or its size disagrees with the
    (rows, cols) `shape` Pillow read from the header.
    """
    flags, swap = _cv2_colour_flags(reduction)
    if swap and data.rfind(b"\xff\xd9") < data.rfind(b"\xff\xda"):
        # No end-of-image marker after the last scan: the file is cut. OpenCV 4.11 and newer (those
        # with IMREAD_COLOR_RGB) return nothing then; older releases fill the missing rows with
        # grey, so the bytes are checked for them only. Pillow words the error.
        return None
    try:
        rgb = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error:
        return None  # an OpenCV that refuses these flags: Pillow decodes the same pixels
    if rgb is None or rgb.shape != (*shape, 3):
        return None
    if swap:
        cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB, dst=rgb)  # in place, and it releases the GIL too
    return rgb


def _cv2_colour_flags(reduction):
    """OpenCV's imread flags for a colour decode in RGB order, and whether BGR must still be swapped.

    OpenCV 4.11 added ``IMREAD_COLOR_RGB``; OpenCV 5 refuses it beside the BGR bit that the reduced
    colour modes carry (``IMREAD_REDUCED_COLOR_2 = IMREAD_COLOR_BGR | 16``), so that bit is cleared.
    Older releases decode BGR, swapped afterwards.
    """
    flags = _CV2_REDUCED[reduction] | cv2.IMREAD_IGNORE_ORIENTATION
    rgb_flag = getattr(cv2, "IMREAD_COLOR_RGB", None)
    if rgb_flag is None:
        return flags, True
    return (flags & ~getattr(cv2, "IMREAD_COLOR_BGR", cv2.IMREAD_COLOR)) | rgb_flag, False


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


def _composite_over_black(rgb, alpha):
    """Composite `rgb` over black in place by `alpha`; return the mask of pixels holding data (alpha > 0)."""
    valid = alpha > 0
    rgb[~valid] = 0
    partial = valid & (alpha < 255)
    if partial.any():
        weight = alpha[partial].astype(np.uint16)[:, None]
        rgb[partial] = ((rgb[partial].astype(np.uint16) * weight + 127) // 255).astype(np.uint8)
    return valid


# EXIF orientation -> the view of the stored array that shows the photo upright.
_ORIENT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: a.swapaxes(0, 1),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
    8: lambda a: np.rot90(a, 1),
}


def _orient(array, orientation):
    return _ORIENT.get(orientation, _ORIENT[1])(array)


def _metadata(name, info, gsd, height_above_ground):
    """Assemble :class:`ImageMetadata`, choosing the GSD: user > GeoTIFF > height with camera EXIF."""
    height_used = height_above_ground
    if height_used is None and info["relative_altitude_m"] is not None and info["relative_altitude_m"] > 0:
        height_used = info["relative_altitude_m"]
    source, value = None, None
    if gsd is not None:
        source, value = "user", gsd
    elif info["geotiff_gsd"] is not None:
        source, value = "geotiff", info["geotiff_gsd"]
    elif height_used is not None and info["sensor_width_mm"] and info["focal_length_mm"]:
        stored_width = info["height"] if info["orientation"] in (5, 6, 7, 8) else info["width"]
        value = camera.ground_sampling_distance(
            height_above_ground=height_used,
            sensor_width_mm=info["sensor_width_mm"],
            focal_length_mm=info["focal_length_mm"],
            image_width=stored_width,
        )
        source = "height_above_ground" if height_above_ground is not None else "exif-xmp"
    fields = {k: v for k, v in info.items() if k != "geotiff_gsd"}
    return ImageMetadata(
        path=name, height_above_ground_m=height_used, gsd_m_per_px=value, gsd_source=source, **fields
    )


__all__ = ["MAX_PIXELS", "ImageMetadata", "OpenImage", "load_image", "open_image", "read_metadata"]
