"""Camera metadata of a photo (EXIF, DJI XMP, GeoTIFF) and the ground sampling distance it implies.

Everything here is best effort: a missing, malformed or implausible field reads as ``None``, never as
an error, because metadata is optional for building a relief (without a ground scale the relief is in
pixels).

The ground sampling distance (GSD, metres of ground per pixel) of a nadir photo is

    GSD = height_above_ground * sensor_width / (focal_length * image_width)

(pixels are square, so the same holds along the diagonal). GPS altitude is above *sea level*, not
above the ground, so it is recorded but never used for the GSD.
"""

from __future__ import annotations

import math
import re

from ..._validate import check_float, check_int
from ..raster._geokeys import (
    GEO_KEY_DIRECTORY,
    GT_MODEL_TYPE,
    MODEL_PIXEL_SCALE,
    MODEL_PROJECTED,
    MODEL_TRANSFORMATION,
    PROJ_LINEAR_UNITS,
    PROJECTED_CS_TYPE,
    code_metres,
    geo_keys,
    unit_metres,
)

#: Diagonal of a 35 mm film frame (36 x 24 mm), the reference of "35 mm equivalent" focal lengths.
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)

# EXIF tag numbers (EXIF 2.32).
_MAKE, _MODEL, _ORIENTATION = 0x010F, 0x0110, 0x0112
_EXIF_IFD, _GPS_IFD = 0x8769, 0x8825
_FOCAL_LENGTH, _FOCAL_35MM = 0x920A, 0xA405
_PIXEL_X_DIMENSION = 0xA002
_FOCAL_PLANE_X_RES, _FOCAL_PLANE_UNIT = 0xA20E, 0xA210
_GPS_ALTITUDE_REF, _GPS_ALTITUDE = 0x05, 0x06
# Millimetres per FocalPlaneResolutionUnit (2 = inch is the EXIF default; 4 and 5 are EXIF 2.3+).
_FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
# Plausible ranges that reject garbage without excluding real cameras (phone to medium format).
_SENSOR_WIDTH_RANGE_MM = (0.5, 100.0)
_FOCAL_LENGTH_RANGE_MM = (0.5, 2000.0)

# DJI writes `drone-dji:RelativeAltitude="+50.20"` (attribute) or as an element; accept both.
_RELATIVE_ALTITUDE = re.compile(
    rb"drone-dji:RelativeAltitude\s*(?:=\s*[\"']\s*([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)"
    rb"|>\s*([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?))"
)

# Web Mercator "metres" are stretched by 1/cos(latitude): they are not ground metres.
_WEB_MERCATOR = {3857, 3785, 900913, 102100, 102113}


def ground_sampling_distance(*, height_above_ground, sensor_width_mm, focal_length_mm, image_width):
    """Metres of ground per pixel of a nadir photo.

    Parameters
    ----------
    height_above_ground : float
        Camera height above the ground, in metres (> 0).
    sensor_width_mm : float
        Sensor width along the image's columns (stored, unrotated image), in mm (> 0).
    focal_length_mm : float
        True (not 35 mm equivalent) focal length, in mm (> 0).
    image_width : int
        Number of columns of the full-size stored image that spans `sensor_width_mm`.

    Returns
    -------
    float
        Ground sampling distance in metres per pixel.

    Examples
    --------
    >>> round(ground_sampling_distance(height_above_ground=100, sensor_width_mm=13.2,
    ...                                focal_length_mm=8.8, image_width=5472), 4)
    0.0274
    """
    height = check_float("height_above_ground", height_above_ground, minimum=0, strict_minimum=True)
    sensor = check_float("sensor_width_mm", sensor_width_mm, minimum=0, strict_minimum=True)
    focal = check_float("focal_length_mm", focal_length_mm, minimum=0, strict_minimum=True)
    width = check_int("image_width", image_width, minimum=1)
    return height * sensor / (focal * width)


def sensor_width_from_35mm(*, focal_length_mm, focal_length_35mm, width, height):
    """Sensor width (mm, along the image's columns) from the 35 mm equivalent focal length.

    The crop factor is ``focal_length_35mm / focal_length_mm``; the sensor diagonal is the full-frame
    diagonal (43.27 mm) divided by it, and the width follows from the image's aspect ratio.
    Returns None when the result is implausible.
    """
    crop = focal_length_35mm / focal_length_mm
    if not 0.2 <= crop <= 20.0:
        return None
    width_mm = FULL_FRAME_DIAGONAL_MM / crop * width / math.hypot(width, height)
    return _in_range(width_mm, _SENSOR_WIDTH_RANGE_MM)


def read_camera(exif, *, width, height):
    """Camera fields of a Pillow ``Image.Exif`` for a stored (unrotated) image of `width` x `height`.

    Returns a dict with keys ``orientation`` (1-8, 1 when absent or invalid), ``camera_make``,
    ``camera_model``, ``focal_length_mm``, ``focal_length_35mm``, ``sensor_width_mm`` and
    ``gps_altitude_m`` (above sea level; negative below it); absent or implausible values are None.

    The sensor width comes from the 35 mm equivalent focal length when present, else from the
    focal-plane resolution (pixels per unit of sensor at ``PixelXDimension`` columns). The latter
    assumes the stored image spans the whole sensor (a resized, not cropped, photo).
    """
    fields = dict(
        orientation=1,
        camera_make=None,
        camera_model=None,
        focal_length_mm=None,
        focal_length_35mm=None,
        sensor_width_mm=None,
        gps_altitude_m=None,
    )
    if exif is None:
        return fields
    orientation = _number(exif.get(_ORIENTATION))
    if orientation is not None and orientation in range(1, 9):
        fields["orientation"] = int(orientation)
    fields["camera_make"] = _text(exif.get(_MAKE))
    fields["camera_model"] = _text(exif.get(_MODEL))

    exif_ifd = _ifd(exif, _EXIF_IFD)
    focal = _in_range(_number(exif_ifd.get(_FOCAL_LENGTH)), _FOCAL_LENGTH_RANGE_MM)
    focal_35 = _in_range(_number(exif_ifd.get(_FOCAL_35MM)), _FOCAL_LENGTH_RANGE_MM)
    fields["focal_length_mm"] = focal
    fields["focal_length_35mm"] = focal_35
    sensor = None
    if focal is not None and focal_35 is not None:
        sensor = sensor_width_from_35mm(
            focal_length_mm=focal, focal_length_35mm=focal_35, width=width, height=height
        )
    if sensor is None:
        sensor = _sensor_from_focal_plane(exif_ifd, width)
    fields["sensor_width_mm"] = sensor

    gps = _ifd(exif, _GPS_IFD)
    altitude = _number(gps.get(_GPS_ALTITUDE), allow_zero=True)
    if altitude is not None:
        ref = gps.get(_GPS_ALTITUDE_REF)
        below = ref in (1, b"\x01") or (isinstance(ref, bytes) and ref[:1] == b"\x01")
        fields["gps_altitude_m"] = -altitude if below else altitude
    return fields


def relative_altitude(xmp):
    """DJI ``drone-dji:RelativeAltitude`` (metres above the take-off point) from an XMP packet, or None."""
    if isinstance(xmp, str):
        xmp = xmp.encode("utf-8", "replace")
    elif isinstance(xmp, tuple):  # Pillow may give a TIFF XMLPacket as a tuple of byte values
        try:
            xmp = bytes(xmp)
        except (TypeError, ValueError):
            return None
    if not isinstance(xmp, bytes | bytearray):
        return None
    match = _RELATIVE_ALTITUDE.search(xmp)
    if match is None:
        return None
    value = float(match.group(1) or match.group(2))
    return value if math.isfinite(value) else None


def geotiff_pixel_size(tags):
    """Ground size (metres) of a GeoTIFF pixel from its tags (a mapping tag -> value), or None.

    Only projected coordinate systems in known linear units count (geographic degrees and Web
    Mercator's stretched metres do not); map units in feet are converted by the unit's own factor
    (see :mod:`..raster._geokeys`). The result is the mean of the column and row sizes.
    """
    keys = geo_keys(tags.get(GEO_KEY_DIRECTORY))
    if keys.get(GT_MODEL_TYPE) != MODEL_PROJECTED or keys.get(PROJECTED_CS_TYPE) in _WEB_MERCATOR:
        return None
    unit = unit_metres(keys.get(PROJ_LINEAR_UNITS))
    if unit is None and PROJ_LINEAR_UNITS not in keys:
        unit = code_metres(keys.get(PROJECTED_CS_TYPE))
    if unit is None:
        return None
    size = None
    scale = tags.get(MODEL_PIXEL_SCALE)
    matrix = tags.get(MODEL_TRANSFORMATION)
    try:
        if scale is not None and len(scale) >= 2:
            size = (abs(float(scale[0])) + abs(float(scale[1]))) / 2
        elif matrix is not None and len(matrix) >= 6:
            m = [float(v) for v in matrix[:6]]
            size = (math.hypot(m[0], m[4]) + math.hypot(m[1], m[5])) / 2
    except (TypeError, ValueError):
        return None
    if size is None or not math.isfinite(size) or size <= 0:
        return None
    return size * unit


def _sensor_from_focal_plane(exif_ifd, width):
    resolution = _number(exif_ifd.get(_FOCAL_PLANE_X_RES))
    unit_mm = _FOCAL_PLANE_UNIT_MM.get(_number(exif_ifd.get(_FOCAL_PLANE_UNIT)) or 2)
    if resolution is None or unit_mm is None:
        return None
    # The resolution refers to the camera's own pixel count, which a resized copy no longer has.
    columns = _number(exif_ifd.get(_PIXEL_X_DIMENSION)) or width
    return _in_range(columns / resolution * unit_mm, _SENSOR_WIDTH_RANGE_MM)


def _ifd(exif, tag):
    try:
        return exif.get_ifd(tag)
    except Exception:  # a corrupt sub-IFD pointer: Pillow raises various types
        return {}


def _number(value, *, allow_zero=False):
    """A positive (or zero) finite float from an EXIF value (int, rational, 1-tuple), else None."""
    if isinstance(value, tuple | list) and len(value) == 1:
        value = value[0]
    try:
        number = float(value)
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None
    if not math.isfinite(number) or number < 0 or (number == 0 and not allow_zero):
        return None
    return number


def _text(value):
    if isinstance(value, bytes):
        value = value.decode("latin-1")
    if not isinstance(value, str):
        return None
    value = value.replace("\x00", " ").strip()
    return value or None


def _in_range(value, bounds):
    if value is None or not bounds[0] <= value <= bounds[1]:
        return None
    return float(value)
