"""Load a photo as RGB uint8, with the metadata that gives it a ground scale.

Decisions (each documented where it applies):

* **Formats**: JPEG, PNG, TIFF (GeoTIFF included), WebP and BMP, read with Pillow; the pixels of a
  colour or greyscale JPEG are decoded by OpenCV, in one call that releases the GIL, with the same
  libjpeg-turbo settings (the same pixels as Pillow's, bit for bit). Greyscale, palette,
  CMYK, YCbCr and 16-bit images become RGB; 16-bit greyscale is scaled by 255/65535 (rounded), 16-bit
  colour is reduced by Pillow to its high byte (the two differ by at most 1). Colour profiles (ICC)
  are not applied.
* **Two readers, one protocol** (:class:`~cliff_terrain.io.photo.PhotoReader`): :func:`open_image`
  picks the reader by the file's header: tifffile's (:mod:`._tiff`) for a TIFF of three or more
  float or greyscale-tagged samples (OpenDroneMap's orthophoto), which Pillow cannot read, and for
  a GeoTIFF orthophoto (its pixels as the windowed heights read them: 16-bit colour scaled by the
  bit depth used, alpha and no-data as masks); Pillow's
  (:class:`OpenImage`, JPEG decoding in :mod:`._jpeg`, pixels in :mod:`._pillow_pixels`) for the rest.
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
  (see :mod:`._camera`). GPS altitude is above sea level and is never used as a height.
* **EXIF orientation** is applied, so the array is the photo as viewed; ``width``/``height`` are after
  orientation. Of a multi-page TIFF or multi-frame file only the first image is read.
"""

from __future__ import annotations

import os
import stat

import numpy as np
from PIL import Image, JpegImagePlugin, PngImagePlugin, TiffImagePlugin

from ..._validate import check_float, check_int
from ...errors import CliffTerrainError, ImageReadError, ImageTooLargeError
from . import _camera as camera
from ._jpeg import JPEG_FORMATS, check_jpeg_size, decode_jpeg_at_once, jpeg_data, jpeg_reduction
from ._metadata import (
    ImageMetadata,
    header_metadata,
    image_metadata,
    orient,
    oriented_size,
    read_exif,
    read_xmp,
)
from ._pillow_pixels import composite_over_black, decode_pixels
from ._reader import MIN_SIDE, PhotoReader, reading
from ._tiff import open_tiff_photo

#: Largest decoded image, in pixels, that :func:`load_image` decodes by default (150 megapixels,
#: about 0.45 GB as RGB uint8). A larger JPEG is decoded reduced when `max_size` allows it.
MAX_PIXELS = 150_000_000

#: Pillow formats :func:`load_image` opens (a JPEG with extra frames opens as "MPO", handled as JPEG).
SUPPORTED_FORMATS = ("JPEG", "PNG", "TIFF", "WEBP", "BMP")


def load_image(path, *, max_size=None, gsd=None, height_above_ground=None, max_pixels=MAX_PIXELS, bands=None):
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
    bands : str or sequence of str, optional
        A multispectral TIFF's band names in order (``"B,G,R,RE,NIR"``) when the file gives none;
        it is returned in true colour (:func:`cliff_terrain.io.raster.bands.rgb_rendering`).

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
        path,
        max_size=max_size,
        gsd=gsd,
        height_above_ground=height_above_ground,
        max_pixels=max_pixels,
        bands=bands,
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


def open_image(path, *, max_size=None, gsd=None, height_above_ground=None, max_pixels=MAX_PIXELS, bands=None):
    """Open a photo and check its header; :meth:`OpenImage.decode` reads the pixels later.

    :func:`load_image` in two steps, so that a caller learns the decoded size (and any error the
    header shows) at once, and can decode elsewhere, for example in a worker thread while it
    prepares for an image of that size. Parameters and errors are those of :func:`load_image`;
    errors of the pixel data itself come from :meth:`OpenImage.decode`. The bytes of a colour or
    greyscale JPEG are read here as well, so that decoding it is a single call that releases the
    GIL (see :meth:`OpenImage.decode`). `bands` names a multispectral TIFF's bands in order
    (``"B,G,R,RE,NIR"``) when the file does not: it is then shown in true colour.

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
    return _open_checked(path, max_size, gsd, height_above_ground, max_pixels, read_jpeg=True, bands=bands)


def _open_checked(path, max_size, gsd, height_above_ground, max_pixels, *, read_jpeg, bands=None):
    name, max_size, gsd, height_above_ground, max_pixels = _check_arguments(
        path, max_size, gsd, height_above_ground, max_pixels
    )
    with reading(name):
        # The reader by the file's header: tifffile's for the TIFF orthophotos Pillow cannot read
        # (three or more float or greyscale-tagged samples, OpenDroneMap's) and for GeoTIFF
        # orthophotos (read as the windows read them), Pillow's for the rest.
        photo = open_tiff_photo(name, gsd, height_above_ground, max_pixels, bands=bands)
        if photo is not None:
            return photo
        im = _open(name)
        try:
            info = _header(im, name, max_size, max_pixels)
            _refuse_non_photo(im, name)
            return OpenImage(name, im, info, gsd, height_above_ground, read_jpeg=read_jpeg)
        except BaseException:
            im.close()
            raise


class OpenImage:
    """A photo whose header Pillow has read and checked, its pixels not yet decoded (see :func:`open_image`).

    The :class:`~cliff_terrain.io.photo.PhotoReader` of every format but the TIFFs
    :class:`~cliff_terrain.io.photo.TiffPhoto` reads.

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
        width, height = oriented_size(im.size, info["orientation"])
        self.shape = (height, width)
        # Read now, so that decode() is one call that releases the GIL from start to end.
        self._jpeg_data = jpeg_data(im, name) if read_jpeg else None

    @property
    def metadata(self):
        return header_metadata(self._name, self._info, self.shape, self._gsd, self._height_above_ground)

    def decode(self):
        """Decode the pixels (once) and close the file: ``(rgb, metadata)`` as :func:`load_image` returns.

        A colour or greyscale JPEG is decoded by OpenCV in one call that releases the GIL, so a
        thread decoding it keeps going while another holds the GIL; its pixels are Pillow's, bit
        for bit. Other images are decoded by Pillow.
        """
        if self._im is None:
            raise CliffTerrainError(f"image {self._name!r} was already decoded or closed")
        with reading(self._name):
            try:
                rgb, alpha = None, None
                if self._jpeg_data is not None:
                    stored_shape = (self._im.size[1], self._im.size[0])
                    rgb = decode_jpeg_at_once(self._jpeg_data, stored_shape, self._info["reduction"])
                if rgb is None:
                    rgb, alpha = decode_pixels(self._im, self._name)
            finally:
                self.close()
        info = dict(self._info)
        valid = None
        if alpha is not None:
            valid = composite_over_black(rgb, alpha)
        rgb = orient(rgb, info["orientation"])
        if rgb.shape[:2] != self.shape:  # callers size their work by `shape` before decoding
            raise ImageReadError(
                f"cannot read image {self._name!r}: its pixel data is {rgb.shape[1]}x{rgb.shape[0]}, "
                f"its header says {self.shape[1]}x{self.shape[0]}"
            )
        if valid is not None:
            valid = np.ascontiguousarray(orient(valid, info["orientation"]))
        rgb = np.ascontiguousarray(rgb)
        info["decoded_height"], info["decoded_width"] = rgb.shape[:2]
        info["valid_fraction"] = 1.0 if valid is None else float(np.count_nonzero(valid)) / valid.size
        info["valid_mask"] = None if valid is None or valid.all() else valid
        return rgb, image_metadata(self._name, info, self._gsd, self._height_above_ground)

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
    if im.format in JPEG_FORMATS:
        check_jpeg_size(name, width, height)
    reduction = 1
    if max_size is not None and im.format in JPEG_FORMATS:
        reduction = jpeg_reduction(width, height, max_size)
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
    info.update(camera.read_camera(read_exif(im), width=width, height=height))
    info["width"], info["height"] = oriented_size((width, height), info["orientation"])
    info["relative_altitude_m"] = camera.relative_altitude(read_xmp(im))
    info["geotiff_gsd"] = camera.geotiff_pixel_size(im.tag_v2) if im.format == "TIFF" else None
    return info


def _too_large_message(name, im, width, height, reduction, max_size, max_pixels):
    megapixels = width * height / 1e6
    text = (
        f"image {name!r} is {width}x{height} pixels ({megapixels:.1f} MP); decoding it would pass the "
        f"limit of max_pixels={max_pixels} ({max_pixels / 1e6:.1f} MP, about {3 * max_pixels / 1e9:.2f} GB "
        "as RGB)"
    )
    if im.format not in JPEG_FORMATS:
        return text + f"; only JPEG can be decoded reduced and this is {im.format}"
    if max_size is None:
        return text + "; pass `max_size` to decode this JPEG reduced by up to 8"
    return (
        text
        + f"; even reduced by {reduction} for max_size={max_size} it is too large: use a smaller max_size"
    )


def _refuse_non_photo(im, name):
    kind = {"F": "32-bit floating-point", "I;16S": "signed 16-bit"}.get(im.mode)
    if kind is None and im.mode.startswith("I;32"):
        kind = "32-bit integer"
    if kind is not None:
        raise ImageReadError(
            f"cannot read image {name!r}: it holds {kind} values (Pillow mode {im.mode!r}), a raster of "
            "measurements such as a DSM, not a photograph; give an 8- or 16-bit RGB or greyscale photo"
        )


__all__ = [
    "MAX_PIXELS",
    "ImageMetadata",
    "OpenImage",
    "PhotoReader",
    "load_image",
    "open_image",
    "read_metadata",
]
