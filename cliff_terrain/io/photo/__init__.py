"""Photos: JPEG, PNG, TIFF, WebP and BMP as RGB uint8, with the metadata that gives them a ground
scale (EXIF, DJI XMP, GeoTIFF) and the camera's ground sampling distance.

One protocol (:class:`PhotoReader`), two readers: Pillow's (:class:`OpenImage`, JPEGs decoded by OpenCV)
and tifffile's (:class:`TiffPhoto`) for the TIFF orthophotos Pillow cannot read. The modules are private;
the names below are the package's API, loaded when first used.
"""

from ..._lazy import attach

# Public name -> the module of this package that defines it (imported when the name is first used).
_EXPORTS = {
    "ImageMetadata": "_metadata",
    "MAX_PIXELS": "_open",
    "MIN_SIDE": "_reader",
    "OpenImage": "_open",
    "PhotoReader": "_reader",
    "SUPPORTED_FORMATS": "_open",
    "TiffPhoto": "_tiff",
    "ground_sampling_distance": "_camera",
    "load_image": "_open",
    "open_image": "_open",
    "read_camera": "_camera",
    "read_metadata": "_open",
}

__getattr__, __dir__, __all__ = attach(__name__, _EXPORTS)
