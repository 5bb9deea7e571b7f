"""Settings of a relief build, stored once per scene as ``bpy.types.Scene.cliff_terrain``.

The build parameters are declared once (:class:`ReliefParameters`) and shared by the scene settings
and the build operator, so the panel, scripts and the Adjust Last Operation panel agree.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

# The core's choices, defaults and limits (a module that imports nothing: registering stays fast).
from ..cliff_terrain import settings
from ..cliff_terrain.relief import indices

# Names of the parameters passed to the core's build_relief (besides the image path).
PARAMETER_NAMES = (
    "segmentation",
    "profile",
    "max_size",
    "exaggeration",
    "max_height",
    "gsd",
    "two_sided",
    "mesh",
    "max_error",
    "dsm",
    "dtm",
    "heights",
)


class ReliefParameters:
    """The parameters of one relief build (a mixin: Blender collects annotations from bases)."""

    filepath: StringProperty(
        name="Photo",
        description="UAV photo to turn into a relief (JPEG, PNG or TIFF)",
        subtype="FILE_PATH",
    )
    segmentation: EnumProperty(
        name="Segmentation",
        description="How the regions that rise are found",
        items=settings.SEGMENTATIONS,
        default=settings.DEFAULT_SEGMENTATION,
    )
    profile: EnumProperty(
        name="Profile",
        description="Shape of each raised region",
        items=settings.PROFILES,
        default=settings.DEFAULT_PROFILE,
    )
    max_size: IntProperty(
        name="Max Size",
        description="Longest side of the processing grid in pixels (the mesh has about max size squared "
        "vertices; the texture always uses the full-resolution photo)",
        min=settings.MIN_SIZE,
        max=settings.MAX_SIZE,
        default=settings.DEFAULT_MAX_SIZE,
    )
    exaggeration: FloatProperty(
        name="Exaggeration",
        description="Multiplies every height",
        min=0.01,  # the core takes any value > 0; the panel offers from 0.01
        soft_max=10.0,
        default=settings.DEFAULT_EXAGGERATION,
    )
    max_height: FloatProperty(
        name="Canopy Height",
        description="Where the Plateau profile levels closed canopy off (a cap for the other profiles), "
        "in metres when the GSD is known, else in processing pixels. 0 = estimated from the photo "
        "(the radius of a typical isolated plant)",
        min=0.0,
        soft_max=100.0,
        default=0.0,
        precision=3,
    )
    gsd: FloatProperty(
        name="GSD (m/px)",
        description="Ground sampling distance of the original photo in metres per pixel. 0 = unknown: "
        "taken from the GeoTIFF or DJI metadata when present, otherwise the relief is built in "
        "normalised units (longest side 10 Blender units)",
        min=0.0,
        soft_max=1.0,
        default=0.0,
        precision=4,
        step=0.1,
    )
    two_sided: BoolProperty(
        name="Closed Solid",
        description="Close the relief with side walls and a flat base (textured darker), so it "
        "can be viewed from any side or printed",
        default=True,
    )

    mesh: EnumProperty(
        name="Mesh",
        description="How the relief's surface is meshed",
        items=settings.MESHES,
        default=settings.DEFAULT_MESH,
    )
    max_error: FloatProperty(
        name="Max Error",
        description="Adaptive mesh: largest vertical distance between the mesh and any pixel's height, "
        "in metres with a GSD, else in processing pixels. 0 = automatic: half a pixel for heights "
        "from the photo, the DSM's noise (at least 1 cm) for measured ones",
        min=0.0,
        soft_max=1.0,
        default=0.0,
        precision=4,
        step=0.1,
    )

    # Measured heights (a surface model of the same orthophoto); empty paths mean none.
    dsm: StringProperty(
        name="Surface Model",
        description="Digital surface model GeoTIFF (DSM, metres) of the orthophoto: heights are then "
        "measured. Empty = heights from the photo alone",
        subtype="FILE_PATH",
    )
    dtm: StringProperty(
        name="Ground Model",
        description="Digital terrain model GeoTIFF (DTM, metres). Empty = the ground is estimated from "
        "the surface model at the soil pixels",
        subtype="FILE_PATH",
    )
    heights: EnumProperty(
        name="Heights",
        description="Where the relief's heights come from (Calibrated and Measured need a surface model)",
        items=settings.HEIGHT_MODES,
        default=settings.DEFAULT_HEIGHT_MODE,
    )

    def relief_params(self):
        """The core's :class:`ReliefParams` of these properties (0 and empty paths mean "not given")."""
        from ..cliff_terrain.params import ReliefParams

        return ReliefParams.from_properties(self, path=bpy.path.abspath)


def _grid_changed(settings, context):
    """Rebuild the active plot grid from the new layout (its placement stays where the user put it)."""
    from ..scene.plot_grid import active_grid, update_grid_mesh

    grid = active_grid(context)
    if grid is not None:
        update_grid_mesh(grid, settings)


_COLOUR_MODES = (
    ("PHOTO", "Photo", "The photo, as taken", "IMAGE_RGB", 0),
    ("HEIGHT", "Height", "The relief's height, from 0 to its highest point (viridis)", "IPO_EASE_IN_OUT", 1),
)
_PLOT_TRAIT = (
    "PLOT_TRAIT",
    "Plot Trait",
    "A trait of the measured plots (Plots > Measure Plots)",
    "MESH_GRID",
    2,
)
_INDEX = (
    "INDEX",
    "Vegetation Index",
    "A vegetation index of the relief's multispectral bands (NDVI, NDRE ...)",
    "COLOR",
    3,
)
# Blender keeps no reference to dynamic enum items: they must outlive the call.
_ITEMS = {}


def _colour_items(settings, context):
    """Photo and Height; Plot Trait too once some relief has a measured plot grid, Vegetation Index
    once some relief's bands give one."""
    from ..scene.colour_by import measured_grids, reliefs
    from ..scene.record import Record

    scene = getattr(context, "scene", None)
    # Drawn at every redraw of the sidebar: one pass over the objects.
    objects = reliefs(scene) if scene is not None else []
    measured = scene is not None and not measured_grids().keys().isdisjoint(obj.name for obj in objects)
    indexed = any(Record.of(obj).indices for obj in objects)
    _ITEMS["colour"] = (*_COLOUR_MODES, *([_PLOT_TRAIT] if measured else []), *([_INDEX] if indexed else []))
    return _ITEMS["colour"]


def _colour_changed(settings, context):
    """Colour every relief of the scene as asked, and show it in the window's Solid views."""
    from ..scene.colour_by import colour_relief, reliefs, show_colours_in_solid

    shown = {
        colour_relief(
            obj, settings.color_by, settings=settings, trait=settings.color_trait, index=settings.color_index
        )
        for obj in reliefs(context.scene)
    }
    show_colours_in_solid(getattr(context, "screen", None), bool(shown - {"PHOTO"}))


class CliffTerrainSettings(ReliefParameters, bpy.types.PropertyGroup):
    """Cliff Terrain settings of a scene: build parameters, render folder and the last evaluation."""

    output_dir: StringProperty(
        name="Output Folder",
        description="Folder for rendered views and figures",
        subtype="DIR_PATH",
        default="//cliff_terrain_renders/",
    )
    # Results of the last Evaluate (shown in the panel, written by the evaluate operator).
    psnr: FloatProperty(name="PSNR (dB)", description="PSNR of the top view against the photo", default=0.0)
    ssim: FloatProperty(name="SSIM", description="SSIM of the top view against the photo", default=0.0)
    # Folder of the views the last Render Views job wrote (listed in the panel).
    last_views: StringProperty(
        name="Last Views", description="Folder of the last rendered views", subtype="DIR_PATH"
    )

    # ---- The plot grid (Add Plot Grid): edits rebuild the active grid object at once ----
    plot_columns: IntProperty(
        name="Columns",
        description="Plots across the columns",
        min=1,
        soft_max=200,
        default=4,
        update=_grid_changed,
    )
    plot_rows: IntProperty(
        name="Rows",
        description="Plots along the columns",
        min=1,
        soft_max=200,
        default=8,
        update=_grid_changed,
    )
    plot_width: FloatProperty(
        name="Plot Width", description="Metres across the columns", min=0.01, soft_max=50.0, default=1.5,
        unit="LENGTH", update=_grid_changed,
    )  # fmt: skip
    plot_length: FloatProperty(
        name="Plot Length", description="Metres along the columns", min=0.01, soft_max=50.0, default=5.0,
        unit="LENGTH", update=_grid_changed,
    )  # fmt: skip
    plot_alley_across: FloatProperty(
        name="Column Alley", description="Gap between columns, metres", min=0.0, soft_max=10.0, default=0.3,
        unit="LENGTH", update=_grid_changed,
    )  # fmt: skip
    plot_alley_along: FloatProperty(
        name="Row Alley", description="Gap between rows, metres", min=0.0, soft_max=10.0, default=1.0,
        unit="LENGTH", update=_grid_changed,
    )  # fmt: skip
    plot_numbering: EnumProperty(
        name="Numbering",
        description="How plots are numbered from the start corner",
        items=(
            ("serpentine", "Serpentine", "Along the rows, turning back at each row's end"),
            ("rows", "Rows", "Along each row, every row in the same direction"),
            ("columns", "Columns", "Along each column first"),
        ),
        default="serpentine",
    )
    plot_start: EnumProperty(
        name="Plot 1",
        description="The corner of plot 1 on the map (north up)",
        items=(
            ("top-left", "Top Left", ""),
            ("top-right", "Top Right", ""),
            ("bottom-left", "Bottom Left", ""),
            ("bottom-right", "Bottom Right", ""),
        ),
        default="top-left",
    )
    # ---- Inspecting: what the reliefs show ----
    color_by: EnumProperty(
        name="Color By",  # Blender's UI speaks American English
        description="What the reliefs show: the photo, their height, or a trait of the measured plots",
        items=_colour_items,
        update=_colour_changed,
    )
    color_trait: EnumProperty(
        name="Trait",
        description="The plot trait that Color By Plot Trait shows",
        items=[
            (key, label, f"{label} of each plot, from Measure Plots")
            for key, label, _ in settings.PLOT_TRAITS
        ],
        update=_colour_changed,
    )
    color_index: EnumProperty(
        name="Index",
        description="The vegetation index that Color By Vegetation Index shows (of the relief's own bands)",
        items=[(name, name, f"{name} = {d.formula} ({d.reference})") for name, d in indices.INDICES.items()],
        default="NDVI",
        update=_colour_changed,
    )
    show_plot_labels: BoolProperty(
        name="Plot Labels", description="Show each plot's number over the relief (when the plots are large enough on screen)",
        default=False,
    )  # fmt: skip


CLASSES = (CliffTerrainSettings,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.cliff_terrain = PointerProperty(type=CliffTerrainSettings)


def unregister():
    del bpy.types.Scene.cliff_terrain
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
