"""Orthophoto TIFFs that Pillow cannot open (float32 0-255 or 0-1, planar, 3+ bands), read by tifffile.

OpenDroneMap's standard orthophoto is one: float32 samples in [0, 255], stored planar and tagged
greyscale. :func:`cliff_terrain.image_io.open_image` falls back to :func:`open_tiff_photo` when
Pillow refuses a TIFF, so such a photo loads like any other (with its GeoTIFF GSD and no-data mask).
"""

from __future__ import annotations

from . import camera
from .errors import GeoreferenceError, ImageTooLargeError, RasterReadError
from .georaster import _quiet_tifffile, read_orthophoto
from .image_io import OpenImage, _metadata, _reading

_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def open_tiff_photo(name, gsd, height_above_ground, max_pixels):
    """An :class:`OpenImage` for a TIFF photo Pillow cannot read, or None when it is not a TIFF photo."""
    try:
        with open(name, "rb") as file:
            if file.read(4) not in _TIFF_SIGNATURES:
                return None
    except OSError:
        return None  # missing or unreadable: image_io's own message says which
    import tifffile

    try:
        with _quiet_tifffile(), tifffile.TiffFile(name) as tif:
            page = tif.pages[0]
            bands, shape = page.samplesperpixel, page.shape
            rows, cols = page.imagelength, page.imagewidth
            tags = {tag.code: tag.value for tag in page.tags.values() if tag.code in (33550, 34264, 34735)}
    except Exception:
        return None
    if bands < 3 or len(shape) != 3:
        return None  # a single-band raster (a DSM) is not a photo: image_io says why
    if rows * cols > max_pixels:
        raise ImageTooLargeError(
            f"image {name!r} is {cols}x{rows} pixels, more than the limit of {max_pixels}"
        )
    return TiffPhoto(name, (rows, cols), gsd, height_above_ground, camera.geotiff_pixel_size(tags))


class TiffPhoto(OpenImage):
    """A TIFF orthophoto decoded by tifffile (see :func:`open_tiff_photo`); the API of OpenImage."""

    def __init__(self, name, shape, gsd, height_above_ground, geotiff_gsd):
        self._name, self._gsd, self._height_above_ground = name, gsd, height_above_ground
        self._im = self._jpeg_data = None
        self._open = True
        self.shape = shape
        rows, cols = shape
        self._info = dict(format="TIFF", mode="RGB", reduction=1, width=cols, height=rows)
        self._info.update(camera.read_camera({}, width=cols, height=rows))
        self._info["width"], self._info["height"] = cols, rows
        self._info["relative_altitude_m"] = None
        self._info["geotiff_gsd"] = geotiff_gsd

    def decode(self):
        if not self._open:
            raise RasterReadError(f"image {self._name!r} was already decoded or closed")
        self._open = False
        with _reading(self._name):  # whatever a corrupt file makes the decoders raise: one clear error
            return self._decode()

    def _decode(self):
        try:
            raster = read_orthophoto(self._name)
            gsd = sum(raster.pixel_size) / 2
        except (RasterReadError, GeoreferenceError) as exc:
            if isinstance(exc, RasterReadError) and "georeference" not in str(exc) and "CRS" not in str(exc):
                raise
            raster, gsd = None, self._info["geotiff_gsd"]  # without a usable georeference: still a photo
        if raster is None:
            from .georaster import _read_tiff, photo_bands

            name, array, tags = _read_tiff(self._name)
            rgb, valid = photo_bands(array, name, planar=tags.get("planar", False))
        else:
            rgb, valid = raster.data, raster.valid
        info = dict(self._info, geotiff_gsd=gsd)
        info["decoded_height"], info["decoded_width"] = rgb.shape[:2]
        info["valid_fraction"] = 1.0 if valid is None else float(valid.mean())
        info["valid_mask"] = valid
        return rgb, _metadata(self._name, info, self._gsd, self._height_above_ground)

    def close(self):
        self._open = False
