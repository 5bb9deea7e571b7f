"""Every choice, default and limit of Cliff Terrain, in one place.

The core, the Blender operator properties, the sidebar, ``render_views.py`` and the ``cliff-terrain``
command all take their settings from here. This module is cheap to import: it needs no bpy, SciPy,
OpenCV or even numpy, so argument parsers can use it before anything heavy is loaded.

Each choice is a tuple of ``(identifier, label, description)``; ``ids(CHOICES)`` gives the identifiers.
Each setting of a relief build is declared once, as a :class:`Parameter` of :data:`PARAMETERS`: its
label, help, unit, default, limits and choices. The command-line options
(:meth:`cliff_terrain.params.ReliefParams.add_arguments`), the sidebar's properties
(``operators/properties.py``) and the docs' table of parameters (``tools/parameter_table.py``) are
made from it.
"""

from __future__ import annotations

from dataclasses import dataclass

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
# "auto" measured better than "circular" on every shared photo in the vegetation mode (docs/concepts/method.md).
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
        "The adaptive mesh from 1.5 MP up, where it builds faster; the grid below (see docs/concepts/adaptive-mesh.md); the build says which",
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
# bench/bench_adaptive_mesh.py --auto (docs/concepts/adaptive-mesh.md, "`mesh="auto"`, the default"): below about 1.5 MP the
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


# Where the relief's heights come from (issue 13): the photo alone, or a surface model (DSM). The one
# name of this setting everywhere (keyword, option, property, record) is ``height_source``.
HEIGHT_SOURCES = (
    ("inflated", "Inflated", "Heights from the photo alone: each plant inflated into a dome (no DSM needed)"),
    (
        "calibrated",
        "Calibrated",
        "Photo domes scaled so each plant's top equals its height measured on the DSM",
    ),
    ("measured", "Measured", "The mesh follows the canopy height model: DSM minus ground, in metres"),
)
DEFAULT_HEIGHT_SOURCE = "inflated"
# Ground from one flight: blocks of this side (metres) for the trend (see cliff_terrain.measure.ground).
DEFAULT_GROUND_BLOCK_M = 5.0
# The single-flight ground: "auto", then the candidates simplest first (ties go to the simpler one).
GROUND_METHODS = (
    (
        "auto",
        "Auto",
        "The candidate that predicts held-out bare soil best (refused when none does)",
    ),
    ("baseline", "Baseline", "The DSM's 2nd percentile in blocks"),
    ("smooth", "Smooth", "The baseline lifted onto the bare soil"),
    ("detailed", "Detailed", "The smooth ground with the soil's ridges and furrows"),
)


def ids(choices):
    """The identifiers of a tuple of ``(identifier, label, description)`` choices."""
    return tuple(choice[0] for choice in choices)


# The plot table's traits a relief can be coloured by in Blender: (key, label, unit of the colour bar).
PLOT_TRAITS = (
    ("height_p90_m", "Canopy Height p90", "m"),
    ("height_p50_m", "Canopy Height p50", "m"),
    ("cover", "Cover", "%"),
)


# ---- The settings of a relief build, each declared once ----

# Units of a parameter's number; "relief": the relief's own (metres with a GSD, else processing pixels).
UNITS = {"px": "pixels", "m": "metres", "m/px": "metres per pixel", "relief": "m with a GSD, else px"}


@dataclass(frozen=True)
class Parameter:
    """One setting of :func:`cliff_terrain.build.build_relief`, as every interface shows it.

    Parameters
    ----------
    name : str
        The keyword of ``build_relief``, the field of :class:`cliff_terrain.params.ReliefParams`,
        the sidebar's property and the key of a relief's recorded settings.
    label : str
        The sidebar's label.
    help : str
        What it does, as a phrase (lower case, no full stop): the option's help, the property's
        description, the docs' table.
    kind : {"int", "float", "bool", "choice", "path", "names"}
        Its type (``"names"``: comma-separated names).
    default : object
        The default of ``build_relief``; None: not given (see `unset`).
    unit : str, optional
        A key of :data:`UNITS`, or "" for none.
    minimum, maximum : float, optional
        Limits (None: none); `exclusive_minimum` makes the minimum open (> rather than >=).
    choices : tuple of (identifier, label, description), optional
        The values of a ``"choice"``.
    unset : str, optional
        What "not given" (None, the sidebar's 0 or empty path) stands for.
    allow_none : bool, optional
        None is a value even with a default (``mesh=None``: no mesh); a None default always is.
    option : str, optional
        The command-line option (default: ``--`` and the name with hyphens); for a ``"bool"``
        whose default is True, the option that turns it off, with `option_help`.
    metavar : str, optional
        The option's value in ``--help`` (paths and names).
    relief_option : bool, optional
        Among the options of ``cliff-terrain relief`` and ``render_views.py`` (else only a command
        that needs it adds it, e.g. ``cliff-terrain heights --ground``).
    sidebar : bool, optional
        A property of the Blender sidebar (and of the Build Relief operator).
    soft_maximum, sidebar_minimum : float, optional
        The sidebar slider's end, and its hard minimum where the core's is open.
    precision, step : optional
        The sidebar's digits and step (Blender's units: step 1 = 0.01).
    see : str, optional
        A Markdown link to the docs' page that explains it.

    Examples
    --------
    >>> max_size = PARAMETERS["max_size"]
    >>> max_size.flag, max_size.limits, max_size.default
    ('--max-size', '16 to 16384', 1000)
    """

    name: str
    label: str
    help: str
    kind: str
    default: object = None
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    choices: tuple = ()
    unset: str = ""
    allow_none: bool = False
    option: str = ""
    option_help: str = ""
    metavar: str | None = None
    relief_option: bool = True
    sidebar: bool = True
    soft_maximum: float | None = None
    sidebar_minimum: float | None = None
    precision: int | None = None
    step: float | None = None
    see: str = ""

    @property
    def flag(self):
        """The command-line option, e.g. ``--max-size``."""
        return self.option or "--" + self.name.replace("_", "-")

    @property
    def limits(self):
        """The limits as text (``"16 to 16384"``, ``"> 0"``), or ""."""
        if self.minimum is not None and self.maximum is not None:
            return f"{self.minimum:g} to {self.maximum:g}"
        if self.minimum is not None:
            return f"{'>' if self.exclusive_minimum else '>='} {self.minimum:g}"
        return "" if self.maximum is None else f"<= {self.maximum:g}"

    def choice_help(self):
        """The choices and what each does, e.g. ``"grid: one vertex ...; adaptive: ..."``."""
        return "; ".join(f"{key}: {text[0].lower()}{text[1:]}" for key, _, text in self.choices)


PARAMETERS = {
    p.name: p
    for p in (
        Parameter(
            "max_size",
            "Max Size",
            "longest side of the processing grid (the mesh's; the texture is the full photo)",
            "int",
            DEFAULT_MAX_SIZE,
            unit="px",
            minimum=MIN_SIZE,
            maximum=MAX_SIZE,
        ),
        Parameter(
            "segmentation",
            "Segmentation",
            "how the regions that rise are found",
            "choice",
            DEFAULT_SEGMENTATION,
            choices=SEGMENTATIONS,
            see="[Plants and soil](concepts/plants-soil.md)",
        ),
        Parameter(
            "profile",
            "Profile",
            "shape of each raised region",
            "choice",
            DEFAULT_PROFILE,
            choices=PROFILES,
            see="[Closed canopy](concepts/method.md#closed-canopy-a-plateau-not-a-hill)",
        ),
        Parameter(
            "exaggeration",
            "Exaggeration",
            "multiplies every height",
            "float",
            DEFAULT_EXAGGERATION,
            minimum=MIN_EXAGGERATION,
            exclusive_minimum=True,
            sidebar_minimum=0.01,  # the core takes any value > 0; the sidebar offers from 0.01
            soft_maximum=10.0,
        ),
        Parameter(
            "max_height",
            "Canopy Height",
            "where the plateau profile levels closed canopy off, and a cap for the other profiles "
            "(before the exaggeration)",
            "float",
            DEFAULT_MAX_HEIGHT,
            unit="relief",
            minimum=0.0,
            exclusive_minimum=True,
            unset="estimated from the photo: the radius of a typical isolated plant",
            soft_maximum=100.0,
            precision=3,
        ),
        Parameter(
            "gsd",
            "GSD (m/px)",
            "ground sampling distance of the original photo",
            "float",
            None,
            unit="m/px",
            minimum=0.0,
            exclusive_minimum=True,
            unset="from the GeoTIFF or the DJI metadata when present, else the relief is built in "
            "processing pixels (in Blender: normalised, longest side 10 units)",
            soft_maximum=1.0,
            precision=4,
            step=0.1,
        ),
        Parameter(
            "two_sided",
            "Closed Solid",
            "close the relief with side walls and a flat base (textured darker), so it can be viewed "
            "from any side or printed",
            "bool",
            True,
            option="--one-sided",
            option_help="the relief surface only (no walls and base)",
        ),
        Parameter(
            "mesh",
            "Mesh",
            "how the relief's surface is meshed",
            "choice",
            DEFAULT_MESH,
            choices=MESHES,
            allow_none=True,
            see="[Adaptive mesh](concepts/adaptive-mesh.md#adaptive-mesh-and-big-orthomosaics)",
        ),
        Parameter(
            "max_error",
            "Max Error",
            "adaptive mesh: the largest vertical distance between the mesh and any pixel's height",
            "float",
            None,
            unit="relief",
            minimum=0.0,
            exclusive_minimum=True,
            unset="half a pixel for heights from the photo, the DSM's noise (at least 1 cm) for measured ones",
            soft_maximum=1.0,
            precision=4,
            step=0.1,
            see="[The rules](concepts/adaptive-mesh.md#the-default-bound-no-detail-finer-than-the-data)",
        ),
        Parameter(
            "dsm",
            "Surface Model",
            "digital surface model GeoTIFF (DSM, metres) of the orthophoto: the canopy is measured on it; the relief follows it when the height source is measured or calibrated (the command line's default with a DSM is measured)",
            "path",
            unset="heights from the photo alone",
            metavar="DSM",
            see="[Measured crop height](concepts/ground.md#measured-crop-height-surface-models)",
        ),
        Parameter(
            "dtm",
            "Ground Model",
            "digital terrain model GeoTIFF (DTM, metres) of the orthophoto, with a surface model",
            "path",
            unset="the ground is estimated from the surface model at the soil pixels",
            metavar="DTM",
            see="[The ground](concepts/ground.md)",
        ),
        Parameter(
            "height_source",
            "Height Source",
            "where the relief's heights come from (calibrated and measured need a surface model)",
            "choice",
            DEFAULT_HEIGHT_SOURCE,
            choices=HEIGHT_SOURCES,
            see="[Measured crop height](concepts/ground.md#measured-crop-height-surface-models)",
        ),
        Parameter(
            "ground_block",
            "Ground Block",
            "block size of the estimated ground's lowest surface and of its held-out check (with a "
            "surface model and no terrain model)",
            "float",
            None,
            unit="m",
            minimum=0.0,
            exclusive_minimum=True,
            unset=f"{DEFAULT_GROUND_BLOCK_M:g} m",
            option="--block",
            metavar="METRES",
            relief_option=False,
            sidebar=False,
            see="[The single-flight ground](concepts/ground.md#the-single-flight-ground-geometry-first-checked-on-held-out-soil)",
        ),
        Parameter(
            "ground_method",
            "Ground",
            "the estimated ground (with a surface model and no terrain model)",
            "choice",
            None,
            choices=GROUND_METHODS,
            unset="auto",
            option="--ground",
            relief_option=False,
            sidebar=False,
            see="[The single-flight ground](concepts/ground.md#the-single-flight-ground-geometry-first-checked-on-held-out-soil)",
        ),
        Parameter(
            "bands",
            "Bands",
            "a multispectral photo's band names when its file does not name them, e.g. B,G,R,RE,NIR",
            "names",
            unset="the file's own",
            metavar="NAMES",
            sidebar=False,
            see="[Multispectral indices](concepts/multispectral.md)",
        ),
    )
}
"""Every setting of a relief build by name, in the order of :class:`cliff_terrain.params.ReliefParams`."""
