"""Every choice, default and limit of Cliff Terrain, in one place.

The core, the Blender operator properties, the sidebar, ``render_views.py`` and the ``cliff-terrain``
command all take their settings from here. This module is cheap to import: it needs no bpy, SciPy,
OpenCV or even numpy, so argument parsers can use it before anything heavy is loaded.

Each choice is a tuple of ``(identifier, label, description)``; ``ids(CHOICES)`` gives the identifiers.
"""

from __future__ import annotations

# Processing grid: the longest side of the photo as processed (the mesh has about max_size**2 vertices).
MIN_SIZE = 16
MAX_SIZE = 16384
DEFAULT_MAX_SIZE = 1000

SEGMENTATIONS = (
    (
        "vegetation",
        "Vegetation",
        "Plants found by a vegetation index (also false-colour NIR photos), split into single plants",
    ),
    (
        "paper",
        "Paper (Otsu)",
        "The paper's method: Otsu threshold of the quaternion-filtered photo (bright objects rise)",
    ),
)
DEFAULT_SEGMENTATION = "vegetation"

PROFILES = (
    ("circular", "Circular", "Each region rises as a dome with a circular cross-section"),
    ("poisson", "Poisson", "Each region rises as a smooth membrane (a solution of Poisson's equation)"),
)
DEFAULT_PROFILE = "circular"

DEFAULT_EXAGGERATION = 1.0
MIN_EXAGGERATION = 0.0  # exclusive

# Rendered views: the longest side of a view, and the shorter side that default views are enlarged
# to (SSIM's 7x7 window needs 7 pixels on each side).
MAX_RESOLUTION = 16384
MIN_VIEW_SIDE = 16
SSIM_MIN_SIDE = 7

# The paper's Table 4: its lit top view against the photo.
PAPER_TABLE4 = {"psnr": 17.73, "ssim": 0.8713}


def ids(choices):
    """The identifiers of a tuple of ``(identifier, label, description)`` choices."""
    return tuple(choice[0] for choice in choices)
