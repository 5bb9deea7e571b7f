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
    (
        "auto",
        "Auto",
        "Plateau in the vegetation mode; the paper's circular domes in the paper mode",
    ),
    ("circular", "Circular", "Each region rises as a dome with a circular cross-section"),
    ("poisson", "Poisson", "Each region rises as a smooth membrane (a solution of Poisson's equation)"),
    (
        "plateau",
        "Plateau",
        "Isolated plants rise as the circular domes; merged or wide canopy levels off at canopy height",
    ),
)
# "auto" measured better than "circular" on every shared photo in the vegetation mode (README).
DEFAULT_PROFILE = "auto"
# Canopy height of the plateau profile (a ceiling for the others), in metres with a GSD, else in
# processing pixels; None: estimated from the photo (the radius of a typical isolated plant).
DEFAULT_MAX_HEIGHT = None

DEFAULT_EXAGGERATION = 1.0
MIN_EXAGGERATION = 0.0  # exclusive

# The relief's front: one vertex per pixel corner, or a TIN within a vertical error (cliff_terrain/mesh/tin.py);
# "auto" picks one per build (cliff_terrain.mesh.adaptive.choose_mesh) and says which.
MESHES = (
    (
        "auto",
        "Auto",
        "The adaptive mesh from 1.5 MP up, where it builds faster; the grid below (see the README); the build says which",
    ),
    ("grid", "Grid", "One vertex per pixel corner: every pixel's height, and the most triangles"),
    (
        "adaptive",
        "Adaptive",
        "Few triangles where the ground is flat: a TIN within the maximum error of every pixel's height",
    ),
)
DEFAULT_MESH = "auto"
# "auto": processing grids of fewer pixels than this get the grid (None: always adaptive). From
# bench/bench_adaptive_mesh.py --auto (README "`mesh="auto"`, the default"): below about 1.5 MP the
# TIN costs the core about what the grid's faces cost Blender or more (grid/adaptive Build time
# 0.70-0.96, once 1.12, at 0.19-1.17 MP on two photos); from there up the adaptive mesh is faster
# (1.05-1.35 at 1.56-12 MP).
AUTO_GRID_BELOW_PIXELS = 1_500_000
# The adaptive mesh's default maximum vertical error (cliff_terrain.mesh.tin.default_max_error):
# heights from a shape prior (inflated, calibrated) hold nothing below the photo's resolution,
# so half a pixel in height units; measured ones (a DSM) the DSM's noise, at least this floor.
DEFAULT_MAX_ERROR_PIXELS = 0.5
DEFAULT_MAX_ERROR_FLOOR_M = 0.01

# Rendered views: the longest side of a view, and the shorter side that default views are enlarged
# to (SSIM's 7x7 window needs 7 pixels on each side).
MAX_RESOLUTION = 16384
MIN_VIEW_SIDE = 16
SSIM_MIN_SIDE = 7

# Engines of the lit views (the flat top view is always Cycles).
ENGINES = (
    ("CYCLES", "Cycles", "Path traced, with the calibrated sun and sky (colours stay the photo's)"),
    ("WORKBENCH", "Workbench", "Fast: the texture as it is with cavity shading (needs a GPU context)"),
    ("EEVEE", "EEVEE", "Rasterised with the calibrated sun and sky (slow to start without a GPU)"),
)
DEFAULT_ENGINE = "CYCLES"
# Samples per pixel of the lit views; fewer leave the sky-light shadows noisy (SSIM drops by about
# 0.01 at 8 on dense canopies).
DEFAULT_SAMPLES = 16
MAX_SAMPLES = 4096

# The light of the lit views: where the sun comes from (compass degrees, 0 = north = the image's
# top, 90 = east), how high (degrees), and the share of the sky light on level ground (the sun
# gives the rest). Why these values: scene/rig.py.
DEFAULT_SUN_AZIMUTH = 315.0
DEFAULT_SUN_ELEVATION = 70.0
DEFAULT_AMBIENT = 0.4
MAX_AMBIENT = 0.99

# The paper's Table 4: its lit top view against the photo.
PAPER_TABLE4 = {"psnr": 17.73, "ssim": 0.8713}


# Heights of the relief (issue 13): from the photo alone, or measured with a surface model (DSM).
HEIGHT_MODES = (
    ("inflated", "Inflated", "Heights from the photo alone: each plant inflated into a dome (no DSM needed)"),
    (
        "calibrated",
        "Calibrated",
        "Photo domes scaled so each plant's top equals its height measured on the DSM",
    ),
    ("measured", "Measured", "The mesh follows the canopy height model: DSM minus ground, in metres"),
)
DEFAULT_HEIGHT_MODE = "inflated"
# Ground from one flight: blocks of this side (metres) for the trend (see cliff_terrain.measure.ground).
DEFAULT_GROUND_BLOCK_M = 5.0


def ids(choices):
    """The identifiers of a tuple of ``(identifier, label, description)`` choices."""
    return tuple(choice[0] for choice in choices)


# The plot table's traits a relief can be coloured by in Blender: (key, label, unit of the colour bar).
PLOT_TRAITS = (
    ("height_p90_m", "Canopy Height p90", "m"),
    ("height_p50_m", "Canopy Height p50", "m"),
    ("cover", "Cover", "%"),
)
