"""The plant pixels canopy cover counts: the photo's vegetation index above its plant threshold.

The relief's mask also fills the holes inside its plants and drops its specks, which shapes the
domes; cover counts the index's pixels, which the windowed measure, reading a field window by
window, counts too (:func:`cliff_terrain.measure.canopy.cover_pixels`).
"""

from __future__ import annotations

import numpy as np

from .._threads import map_row_bands
from .vegetation import blurred_index

# The blurred index's reach (pixels): cv2's Gaussian of sigma 1 on float32 has a 9-pixel kernel,
# so rows computed with this many around them are the whole photo's (here in bands, and in the
# windowed measure's windows: cliff_terrain.measure.window_tasks).
BLUR_REACH = 4
# Output pixels computed at once (a band of rows, about 1 MB of float32 index).
_BAND_PIXELS = 262_144


def index_plants(image, *, index, threshold, valid=None):
    """Pixels whose :func:`blurred_index` lies above `threshold` (and with data): the plant pixels
    canopy cover counts, computed in bands of rows with the blur's reach around each, so that the
    pixels are those of the whole photo's index and of the windowed measure's, and memory stays a
    band's (the whole index of a 150 MP photo would be 600 MB).

    Examples
    --------
    >>> img = np.full((40, 40, 3), (120, 90, 60), np.uint8); img[10:20, 10:20] = (40, 160, 40)
    >>> vi, _ = blurred_index(img, index="green")
    >>> bool((index_plants(img, index="green", threshold=0.14) == (vi > 0.14)).all())
    True
    """
    rows = image.shape[0]
    out = np.zeros(image.shape[:2], bool)

    def band(r0, r1):
        a, b = max(0, r0 - BLUR_REACH), min(rows, r1 + BLUR_REACH)
        vi, _ = blurred_index(image[a:b], index=index)
        out[r0:r1] = vi[r0 - a : r1 - a] > threshold

    map_row_bands(band, rows, max(16, _BAND_PIXELS // max(1, image.shape[1])))
    if valid is not None:
        out &= valid
    return out
