"""Settings of a relief build, stored once per scene as ``bpy.types.Scene.cliff_terrain``.

The build parameters are made from the core's declarations (``cliff_terrain.settings.PARAMETERS``:
label, help, unit, limits, choices) into one mixin (:class:`ReliefParameters`) shared by the scene
settings and the build operator, so the panel, scripts and the Adjust Last Operation panel agree.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

# The core's choices, defaults and limits (a module that imports nothing: registering stays fast).
from ..cliff_terrain import settings
from ..cliff_terrain.photo_heights import indices

# Names of the parameters passed to the core's build_relief (besides the image path): the
# declarations shown in the sidebar.
# Paths relative to the .blend ("//photos/a.tif") are kept as given; Blender 4.5+ warns on one unless
# the property says it takes them (4.2-4.4 have no such option and take them silently).
RELATIVE_PATHS = {"options": {"PATH_SUPPORTS_BLEND_RELATIVE"}} if bpy.app.version >= (4, 5, 0) else {}
PARAMETER_NAMES = tuple(name for name, p in settings.PARAMETERS.items() if p.sidebar)
# Blender's unit of a declared unit (the others, e.g. metres with a GSD else pixels, have none).
_UNITS = {"m": "LENGTH"}


def relief_property(parameter):
    """The bpy property of a declared build parameter (ID properties hold no None: 0 or an empty
    path stands for "not given", and the description says what it means)."""
    description = parameter.help[0].upper() + parameter.help[1:]
    if parameter.unit:
        description += f", in {settings.UNITS[parameter.unit]}"
    if parameter.unset:
        description += f". {'Empty' if parameter.kind == 'path' else '0'} = {parameter.unset}"
    common = {"name": parameter.label, "description": description}
    if parameter.kind == "choice":
        return EnumProperty(items=parameter.choices, default=parameter.default, **common)
    if parameter.kind == "bool":
        return BoolProperty(default=parameter.default, **common)
    if parameter.kind == "path":
        return StringProperty(subtype="FILE_PATH", **RELATIVE_PATHS, **common)
    limits = {}
    minimum = parameter.minimum if parameter.sidebar_minimum is None else parameter.sidebar_minimum
    if minimum is not None:
        limits["min"] = minimum
    if parameter.maximum is not None:
        limits["max"] = parameter.maximum
    if parameter.soft_maximum is not None:
        limits["soft_max"] = parameter.soft_maximum
    if parameter.kind == "int":
        return IntProperty(default=parameter.default, **limits, **common)
    for key in ("precision", "step"):
        if getattr(parameter, key) is not None:
            limits[key] = getattr(parameter, key)
    if parameter.unit in _UNITS:
        limits["unit"] = _UNITS[parameter.unit]
    return FloatProperty(default=parameter.default or 0.0, **limits, **common)


class ReliefParameters:
    """The parameters of one relief build (a mixin: Blender collects annotations from bases)."""

    filepath: StringProperty(
        name="Photo",
        description="UAV photo to turn into a relief (JPEG, PNG, TIFF, WebP or BMP)",
        subtype="FILE_PATH",
        **RELATIVE_PATHS,
    )

    def relief_params(self):
        """The core's :class:`ReliefParams` of these properties (0 and empty paths mean "not given")."""
        from ..cliff_terrain.params import ReliefParams

        return ReliefParams.from_properties(self, path=bpy.path.abspath)


ReliefParameters.__annotations__.update(
    {name: relief_property(settings.PARAMETERS[name]) for name in PARAMETER_NAMES}
)


# While the sidebar's fields take a selected grid's own layout, they rebuild nothing.
_SHOWING = {"grid": False}


def show_grid_settings(grid, settings):
    """Put `grid`'s own layout (what it was drawn with) into the sidebar's fields, rebuilding nothing:
    selecting a grid shows its layout, and an edit then changes that grid as shown."""
    from ..scene.plot_grid_object import LAYOUT_FIELDS, grid_settings

    own = grid_settings(grid, settings)
    _SHOWING["grid"] = True
    try:
        for name in LAYOUT_FIELDS:
            if getattr(settings, name) != getattr(own, name):
                setattr(settings, name, getattr(own, name))
    finally:
        _SHOWING["grid"] = False


def _layout_edit(name, *, rebuild=True):
    """The update of the layout field `name`: the active grid takes it, with the rest of its own
    layout (not the other fields as they stand: after an undo they may show another grid's)."""

    def update(settings, context):
        _grid_changed(settings, context, name, rebuild=rebuild)

    return update


def _grid_changed(settings, context, name, *, rebuild=True):
    """Rebuild the active plot grid with field `name` changed (its placement stays where the user put
    it); the numbering (``rebuild=False``) only renumbers it."""
    from ..scene.colour_by import colour_relief, measured_grids
    from ..scene.plot_grid_object import (
        TABLE_KEY,
        active_grid,
        grid_relief,
        grid_settings,
        keep_layout,
        update_grid_mesh,
    )

    grid = active_grid(context)
    if grid is None or _SHOWING["grid"]:
        return
    # Read before the table goes: once no grid has one, Plot Trait is no item and reads as "".
    showed_table = TABLE_KEY in grid and settings.color_by == "PLOT_TRAIT"
    own = grid_settings(grid, settings)
    setattr(own, name, getattr(settings, name))
    if rebuild:
        update_grid_mesh(grid, own)
    else:  # the same plots, other numbers (the table's are the old ones)
        keep_layout(grid, own)
        if TABLE_KEY in grid:
            del grid[TABLE_KEY]
    show_grid_settings(grid, settings)  # the other fields show this grid's own
    if showed_table:  # the relief showed the plots as they were, with their colour bar
        if not measured_grids():
            settings.color_by = "PHOTO"  # recolours every relief
        elif (relief := grid_relief(grid)) is not None:
            colour_relief(relief, "PHOTO", settings=settings)


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
        **RELATIVE_PATHS,
        default="//cliff_terrain_renders/",
    )
    # Results of the last Evaluate (shown in the panel, written by the evaluate operator).
    psnr: FloatProperty(name="PSNR (dB)", description="PSNR of the top view against the photo", default=0.0)
    ssim: FloatProperty(name="SSIM", description="SSIM of the top view against the photo", default=0.0)
    # Folder of the views the last Render Views job wrote (listed in the panel).
    last_views: StringProperty(
        name="Last Views",
        description="Folder of the last rendered views",
        subtype="DIR_PATH",
        **RELATIVE_PATHS,
    )

    # ---- The plot grid (Add Plot Grid): edits rebuild the active grid object at once ----
    plot_columns: IntProperty(
        name="Columns",
        description="Plots across the columns",
        min=1,
        soft_max=200,
        default=4,
        update=_layout_edit("plot_columns"),
    )
    plot_rows: IntProperty(
        name="Rows",
        description="Plots along the columns",
        min=1,
        soft_max=200,
        default=8,
        update=_layout_edit("plot_rows"),
    )
    plot_width: FloatProperty(
        name="Plot Width", description="Metres across the columns", min=0.01, soft_max=50.0, default=1.5,
        unit="LENGTH", update=_layout_edit("plot_width"),
    )  # fmt: skip
    plot_length: FloatProperty(
        name="Plot Length", description="Metres along the columns", min=0.01, soft_max=50.0, default=5.0,
        unit="LENGTH", update=_layout_edit("plot_length"),
    )  # fmt: skip
    plot_alley_across: FloatProperty(
        name="Column Alley", description="Gap between columns, metres", min=0.0, soft_max=10.0, default=0.3,
        unit="LENGTH", update=_layout_edit("plot_alley_across"),
    )  # fmt: skip
    plot_alley_along: FloatProperty(
        name="Row Alley", description="Gap between rows, metres", min=0.0, soft_max=10.0, default=1.0,
        unit="LENGTH", update=_layout_edit("plot_alley_along"),
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
        update=_layout_edit("plot_numbering", rebuild=False),
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
        update=_layout_edit("plot_start", rebuild=False),
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


# The owner of the subscription to the active object (selecting a grid shows its layout).
_OWNER = object()


def _active_changed():
    from ..scene.plot_grid_object import LAYOUT_KEY, active_grid

    context = bpy.context
    grid = active_grid(context)
    if grid is not None and LAYOUT_KEY in grid and getattr(context, "scene", None) is not None:
        show_grid_settings(grid, context.scene.cliff_terrain)


@bpy.app.handlers.persistent
def _after_undo(*_args):
    """After an undo or redo the fields show what the undo step kept, which may be another grid's."""
    _active_changed()


@bpy.app.handlers.persistent
def _subscribe(*_args):
    """Follow the active object (again after a file is opened: opening one drops subscriptions)."""
    bpy.msgbus.clear_by_owner(_OWNER)
    bpy.msgbus.subscribe_rna(
        key=(bpy.types.LayerObjects, "active"), owner=_OWNER, args=(), notify=_active_changed
    )


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.cliff_terrain = PointerProperty(type=CliffTerrainSettings)
    _subscribe()
    bpy.app.handlers.load_post.append(_subscribe)
    bpy.app.handlers.undo_post.append(_after_undo)
    bpy.app.handlers.redo_post.append(_after_undo)


def unregister():
    for handlers, handler in (
        (bpy.app.handlers.load_post, _subscribe),
        (bpy.app.handlers.undo_post, _after_undo),
        (bpy.app.handlers.redo_post, _after_undo),
    ):
        if handler in handlers:
            handlers.remove(handler)
    bpy.msgbus.clear_by_owner(_OWNER)
    del bpy.types.Scene.cliff_terrain
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
