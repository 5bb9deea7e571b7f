"""Which heights of a surface model are a surface: what the readers keep before any resampling."""

from __future__ import annotations

import numpy as np


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
