"""Orthophoto TIFFs, read by tifffile: those Pillow cannot read (float32 0-255 or 0-1, or 3+ bands tagged greyscale), and GeoTIFFs.

OpenDroneMap's standard orthophoto is one: float32 samples in [0, 255], stored planar and tagged
greyscale. :func:`cliff_terrain.io.photo.open_image` asks :func:`open_tiff_photo` first: for such a
file (told by its header) it returns a :class:`TiffPhoto`, a :class:`~cliff_terrain.io.photo.PhotoReader`
like Pillow's, so the photo loads like any other (with its GeoTIFF GSD and no-data mask).
"""

from __future__ import annotations

from ...errors import (
    GeoreferenceError,
    ImageReadError,
    ImageTooLargeError,
    RasterReadError,
    TruncatedFileError,
)
from ..raster._geokeys import GDAL_NODATA, MODEL_TIEPOINT, MODEL_TRANSFORMATION, georeference, nodata_value
from ..raster._tiff_window import TiffRaster
from ..raster.bands import is_multispectral, read_bands, rgb_rendering
from ..raster.geotiff import read_tiff
from ..raster.photo_samples import photo_bands
from ..raster.transform import pixel_size
from . import _camera as camera
from ._metadata import header_metadata, image_metadata
from ._reader import reading

_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
# TIFF SampleFormat 3 (IEEE float) and PhotometricInterpretation 0/1 (grey): Pillow reads neither
# with three or more samples (it refuses the file, or opens one float band).
_FLOAT, _GREY, _CMYK = 3, (0, 1), 5


def open_tiff_photo(name, gsd, height_above_ground, max_pixels, *, bands=None):
    """A :class:`TiffPhoto` when `name` is a TIFF photo Pillow cannot read, else None (Pillow's to read).

    Decided by the header: a TIFF whose first image has three or more samples per pixel that are
    floats, tagged greyscale, or neither 8 nor 16 bits, that declare a no-data value (GDAL_NODATA,
    which Pillow ignores), or that are georeferenced (an orthophoto: read as the windowed heights
    read it, :func:`~cliff_terrain.io.raster.photo_samples.photo_bands`); or a multispectral orthomosaic (more than
    four bands, bands named other than red, green, blue (see :mod:`..raster.bands`), or bands named by
    `bands`), shown in true colour.
    """
    try:
        with open(name, "rb") as file:
            if file.read(4) not in _TIFF_SIGNATURES:
                return None
    except OSError:
        return None  # missing or unreadable: Pillow's reader words the error
    try:
        tiff = TiffRaster(name, what="image", error=ImageReadError)
    except TruncatedFileError:
        raise  # a file cut short is told as such (Pillow's libtiff prints to stderr, then fails)
    except ImageReadError:
        return None  # a broken header: Pillow's reader words the error
    with tiff:
        page = tiff.page
        bits = set(page.bitspersample) if isinstance(page.bitspersample, tuple) else {page.bitspersample}
        odd = page.sampleformat == _FLOAT or page.photometric in _GREY or not bits <= {8, 16}
        shape, tags, samples = tiff.shape, tiff.tags, tiff.samples
        cmyk = page.photometric == _CMYK
    # A GeoTIFF that declares its no-data value (GDAL_NODATA): Pillow ignores it, and would read the
    # area outside the flight as black soil; photo_bands reads it as the windows do. So is every
    # orthophoto of three or four bands: photo_bands takes the black collar of one without alpha for
    # no data, and scales 16 bits by the depth used (Pillow keeps the high byte: a 16-bit RGBA
    # orthophoto's cover differed from the windows' by 0.17 points), as the windows do.
    georeferenced = MODEL_TIEPOINT in tags or MODEL_TRANSFORMATION in tags
    odd = odd or GDAL_NODATA in tags or (georeferenced and samples >= 3)
    multispectral = samples >= 3 and (bands is not None or is_multispectral(name))
    if not multispectral and (samples < 3 or len(page.shape) != 3 or not odd or cmyk):
        return None  # Pillow's (it converts CMYK; photo_bands would take K for alpha)
    rows, cols = shape
    if rows * cols > max_pixels:
        raise ImageTooLargeError(
            f"image {name!r} is {cols}x{rows} pixels, more than the limit of {max_pixels}"
        )
    photo = TiffPhoto(name, shape, gsd, height_above_ground, camera.geotiff_pixel_size(tags))
    photo.multispectral = multispectral
    photo.band_names = bands
    return photo


class TiffPhoto:
    """A TIFF orthophoto decoded by tifffile (see :func:`open_tiff_photo`): a
    :class:`~cliff_terrain.io.photo.PhotoReader`, as :class:`~cliff_terrain.io.photo.OpenImage` is.

    Attributes
    ----------
    shape : tuple of int
        (rows, cols) of the array :meth:`decode` returns.
    metadata : ImageMetadata
        What the header tells.
    """

    def __init__(self, name, shape, gsd, height_above_ground, geotiff_gsd):
        self._name, self._gsd, self._height_above_ground = name, gsd, height_above_ground
        self._open = True
        self.multispectral = False  # multispectral bands rendered in true colour (see open_tiff_photo)
        self.band_names = None  # their names, when the file gives none
        self.bands = None  # the multispectral bands decode() read (Bands), kept for their indices
        self.shape = shape
        rows, cols = shape
        self._info = dict(format="TIFF", mode="RGB", reduction=1, width=cols, height=rows)
        self._info.update(camera.read_camera({}, width=cols, height=rows))
        self._info["width"], self._info["height"] = cols, rows
        self._info["relative_altitude_m"] = None
        self._info["geotiff_gsd"] = geotiff_gsd

    @property
    def metadata(self):
        return header_metadata(self._name, self._info, self.shape, self._gsd, self._height_above_ground)

    def decode(self):
        """Decode the pixels (once): ``(rgb, metadata)`` as :func:`cliff_terrain.io.photo.load_image` returns."""
        if not self._open:
            raise RasterReadError(f"image {self._name!r} was already decoded or closed")
        self._open = False
        with reading(self._name):  # whatever a corrupt file makes the decoders raise: one clear error
            return self._decode()

    def _decode(self):
        # A multispectral file's pixels are decoded once, by read_bands; here only its tags.
        name, array, tags = read_tiff(self._name, pixels=not self.multispectral)
        try:
            transform, _ = georeference(tags, name)
            gsd = sum(pixel_size(transform)) / 2
        except (RasterReadError, GeoreferenceError):
            gsd = self._info["geotiff_gsd"]  # without a usable georeference: still a photo
        if self.multispectral:
            bands = self.bands = read_bands(name, names=self.band_names)
            rgb, valid = rgb_rendering(bands)
        else:
            nodata = nodata_value(tags.get(GDAL_NODATA), name)
            rgb, valid = photo_bands(array, name, nodata=nodata, planar=tags["planar"])
        info = dict(self._info, geotiff_gsd=gsd)
        info["band_names"] = bands.names if self.multispectral else None
        info["decoded_height"], info["decoded_width"] = rgb.shape[:2]
        info["valid_fraction"] = 1.0 if valid is None else float(valid.mean())
        info["valid_mask"] = valid
        return rgb, image_metadata(self._name, info, self._gsd, self._height_above_ground)

    def close(self):
        """Close (nothing stays open between the header and decoding); decoding is then refused."""
        self._open = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
