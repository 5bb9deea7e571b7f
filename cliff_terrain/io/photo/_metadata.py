"""What a photo's header tells: :class:`ImageMetadata`, EXIF and XMP, orientation, and the GSD chosen.

Shared by the two photo readers (:mod:`._open`'s Pillow one and :mod:`._tiff`'s tifffile one).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _camera as camera


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
    band_names : tuple of str or None
        A multispectral photo's bands in order (``("blue", "green", "red", "rededge", "nir")``), from
        its file or the caller's `bands`; None for an RGB photo.
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
    band_names: tuple | None = None

    @property
    def decoded_gsd_m_per_px(self):
        """Ground sampling distance of a pixel of the returned (possibly reduced) array, or None."""
        return self.grid_pixel_size((self.decoded_height, self.decoded_width))

    def grid_scale(self, shape):
        """(x, y): the photo's pixels per pixel of a grid of `shape` (rows, cols) over the whole photo."""
        rows, cols = shape[:2]
        return self.width / cols, self.height / rows

    def grid_pixel_size(self, shape):
        """Metres per pixel (along the columns) of a grid of `shape` over the photo; None without a GSD."""
        if not self.gsd_m_per_px:
            return None
        return float(self.gsd_m_per_px) * self.width / shape[1]  # = gsd * grid_scale(shape)[0]


def read_exif(im):
    try:
        return im.getexif()
    except Exception:  # corrupt EXIF is missing metadata, not an unreadable photo
        return None


def read_xmp(im):
    xmp = im.info.get("xmp") or im.info.get("XML:com.adobe.xmp")
    if xmp is None and im.format == "TIFF":
        xmp = im.tag_v2.get(700)
    return xmp


def oriented_size(size, orientation):
    width, height = size
    return (height, width) if orientation in (5, 6, 7, 8) else (width, height)


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


def orient(array, orientation):
    return _ORIENT.get(orientation, _ORIENT[1])(array)


def image_metadata(name, info, gsd, height_above_ground):
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


def header_metadata(name, info, shape, gsd, height_above_ground):
    """What a reader knows before decoding: `info` from the file's header, at the `shape` (rows, cols)
    it will decode to; the valid mask comes with the pixels."""
    info = dict(info, decoded_width=shape[1], decoded_height=shape[0], valid_fraction=None, valid_mask=None)
    return image_metadata(name, info, gsd, height_above_ground)
