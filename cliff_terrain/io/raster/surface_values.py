"""Which heights of a surface model are a surface: what the readers keep before any resampling
(:func:`surface_heights`, the one rule of the whole file's reader and the windows'), and how a
declared no-data value and a GDAL scale are read."""

from __future__ import annotations

import math

import numpy as np

# ODM and GDAL write -3.4e38 (or -3.4028234663852886e38) for float32 rasters: anything this low is no data.
_FLOAT_NODATA_FLOOR = -1e38


def surface_data(dsm):
    """Where `dsm` has a surface: finite, above 1 km below sea level and below 100 km above it.

    No land lies that low (the Dead Sea's shore, the lowest, is 430 m below sea level; ellipsoidal
    heights differ by at most about 110 m) and nothing a drone flies over that high: such values are
    a no-data marker the file did not declare (OpenDroneMap's -3.4e38, GDAL's habitual -9999,
    int16's -32767), and one of them would drag every lower percentile and read as a plant 0 m tall.
    The readers (:func:`~cliff_terrain.io.raster.geotiff.read_surface` and the windowed one) drop them before any resampling: mixed
    into its neighbours by the bilinear weights, -9999 gave plausible heights that pulled the ground
    metres down (canopy heights of 19 m on a potato field).

    Examples
    --------
    >>> surface_data(np.array([101.5, np.nan, -3.4e38, -9999.0, -32767.0, -120.0], np.float32)).tolist()
    [True, False, False, False, False, True]
    """
    return np.isfinite(dsm) & (dsm > -1e3) & (dsm < 1e5)


def zero_fill(corners, *, nodata):
    """Whether a surface model's exact zeros are the fill outside its footprint, from its corner
    samples as stored (before any scale) and its declared no-data value.

    ``gdalwarp`` without ``-dstnodata`` fills what lies outside a warped DSM with 0 and declares
    nothing: read as heights, a field 270 m above sea level stood on a ground dragged toward 0 and
    its plants measured 100 m tall (with the held-out check passing). A photogrammetric surface in
    floating point never holds exactly 0.0 at a corner of its rectangle (its heights are continuous,
    and even at sea level an exact 0.0 is one value among billions), so a float file without a
    declared no-data value and with a corner at exactly 0 has its exact zeros taken as no data, in
    memory and in windows alike (the decision is the file's, from its corners). Integer files
    (centimetres, millimetres) keep theirs: 0 is a plausible stored height there.

    Examples
    --------
    >>> zero_fill(np.array([0.0, 271.2, 270.9, 0.0], np.float32), nodata=None)
    True
    >>> zero_fill(np.array([270.1, 271.2, 270.9, 270.5], np.float32), nodata=None)
    False
    >>> zero_fill(np.array([0, 27120, 27090, 0], np.int16), nodata=None)
    False
    """
    corners = np.asarray(corners)
    return nodata is None and corners.dtype.kind == "f" and bool(np.any(corners == 0))


def check_scaled(dtype, scale_offset, name):
    """Refuse a surface model stored as whole numbers without a GDAL scale.

    Crop heights need centimetres: in whole metres a surface cannot show a plant, and in whole
    centimetres or millimetres (how integer DSMs are kept) its heights read 100 or 1000 times too
    tall. Without the scale the file cannot say which: an int16 DSM in centimetres was refused for
    "no ground candidate" (plants 100 times too tall), one in millimetres for "holds no data".

    Examples
    --------
    >>> check_scaled(np.dtype(np.float32), (1.0, 0.0), "dsm.tif")
    >>> check_scaled(np.dtype(np.int16), (0.01, 0.0), "dsm.tif")
    >>> check_scaled(np.dtype(np.int16), (1.0, 0.0), "dsm.tif")
    Traceback (most recent call last):
    ...
    cliff_terrain.errors.RasterReadError: surface model 'dsm.tif' stores whole numbers (int16) without \
a scale: ...
    """
    from ...errors import RasterReadError

    if np.dtype(dtype).kind in "iu" and tuple(scale_offset)[0] == 1.0:
        raise RasterReadError(
            f"surface model {name!r} stores whole numbers ({np.dtype(dtype).name}) without a scale: in metres "
            "it cannot show a plant, in centimetres or millimetres its heights read 100 or 1000 times too "
            "tall; give it its unit as a GDAL scale (gdal_edit.py -scale 0.01 for centimetres) or save it "
            "in floating point"
        )


def is_nodata(array, nodata):
    """Where `array` holds the declared no-data value `nodata` (NaN; anything below -1e38 for
    OpenDroneMap's float -3.4e38; else the value in the array's own type)."""
    if math.isnan(nodata):
        return np.isnan(array)
    if array.dtype.kind == "f" and nodata < _FLOAT_NODATA_FLOOR:
        return array < _FLOAT_NODATA_FLOOR
    return array == np.asarray(nodata).astype(array.dtype) if array.dtype.kind == "f" else array == nodata


def scaled(data, scale_offset):
    """`data` (float32) times the GDAL scale plus the offset (:func:`._geokeys.scale_offset`), in place
    when there is either."""
    scale, offset = scale_offset
    if scale != 1.0:
        data *= np.float32(scale)
    if offset != 0.0:
        data += np.float32(offset)
    return data


def surface_heights(raw, *, nodata, scale_offset, zero_fill):
    """Stored samples `raw` of a surface model as heights: float32, scaled (:func:`scaled`), NaN where
    the file declares no data (`nodata`), where `zero_fill` (:func:`zero_fill`) says its exact zeros
    are gdalwarp's fill, and where the value is no surface (:func:`surface_data`). The one rule of both
    readers, the whole file's and the windows'.

    Examples
    --------
    >>> surface_heights(np.array([0.0, 271.5, -9999.0], np.float32), nodata=None, scale_offset=(1.0, 0.0),
    ...                 zero_fill=True).tolist()
    [nan, 271.5, nan]
    """
    data = np.asarray(raw).astype(np.float32, copy=True)
    invalid = ~np.isfinite(data)
    if nodata is not None:
        invalid |= is_nodata(raw, nodata)
    elif zero_fill:
        invalid |= raw == 0  # gdalwarp's fill outside the footprint, undeclared
    data = scaled(data, scale_offset)
    invalid |= ~surface_data(data)  # an undeclared -9999 is no surface either
    data[invalid] = np.nan
    return data
