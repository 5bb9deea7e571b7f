"""3D Viewport > Sidebar > Cliff Terrain: Build Relief, the key figures, Colour By and Probe Height always
visible; Photo & Models, Heights, Mesh, Plots, Figures and Season in collapsible sub-panels."""

import os

import bpy

from ..operators.render_job import rendered_views
from ..scene.probe import PROBE_KEY, probe_lines
from ..scene.record import Record

BUILD_OPERATOR = "cliff_terrain.build_relief"
SEASON_OPERATOR = "cliff_terrain.season_animation"
PROBE_OPERATOR = "cliff_terrain.probe_height"
# The render operators (their own poll greys them out without a relief object).
OPEN_VIEW_OPERATOR = "cliff_terrain.open_view"
RENDER_OPERATORS = (
    ("cliff_terrain.render_views", "RENDER_STILL"),
    ("cliff_terrain.evaluate", "GRAPH"),
)


def format_length(metres):
    """A length in cm under 1 m, else in m ("42 cm", "3.1 m")."""
    return f"{metres * 100:.3g} cm" if abs(metres) < 1.0 else f"{metres:.3g} m"


# What the core's ``gsd_source`` values mean, for the panel.
GSD_SOURCES = {
    "user": "set by hand",
    "geotiff": "from the GeoTIFF",
    "height_above_ground": "from the flight height and camera",
    "exif-xmp": "from the photo's camera and flight height (EXIF/XMP)",
}
# The photo's GSD per (path, modification time): the header is read once, not at every redraw.
_PHOTO_GSD = {}


def photo_gsd(path):
    """(metres per pixel, source) of the photo's own GSD, (None, None) when it has none, or None when
    the photo cannot be read (the Build button reports why)."""
    try:
        key = (path, os.path.getmtime(path))
    except OSError:
        return None
    if key not in _PHOTO_GSD:
        try:
            from ..cliff_terrain.io.photo import read_metadata

            meta = read_metadata(path)
            _PHOTO_GSD[key] = (meta.gsd_m_per_px, meta.gsd_source)
        except Exception:  # a bad photo: Build reports it properly; the panel just says nothing
            _PHOTO_GSD[key] = None
    return _PHOTO_GSD[key]


def gsd_note(layout, settings):
    """One plain line under the GSD field: where the ground size will come from."""
    if settings.gsd > 0.0:
        layout.label(text=f"GSD set by hand: {format_length(settings.gsd)}/px", icon="INFO")
        return
    path = bpy.path.abspath(settings.filepath) if settings.filepath else ""
    found = photo_gsd(path) if path and os.path.isfile(path) else None
    if found is None:
        layout.label(text="0 = GSD from the photo", icon="INFO")
    elif found[0] is None:
        layout.label(text="Photo has no GSD: relative units", icon="INFO")
    else:
        layout.label(text=f"GSD from photo: {format_length(found[0])}/px", icon="INFO")


def relief_size_lines(record):
    """The relief's size in one unit: cm/m with a GSD, else relative units (longest side = 10)."""
    height = float(record.max_height)
    if record.metres:
        gsd = float(record.gsd_m_per_px)
        source = GSD_SOURCES.get(record.gsd_source, "")
        lines = [f"Max height {format_length(height)}"]
        if gsd > 0:
            lines.append(f"GSD {format_length(gsd)}/px{f' ({source})' if source else ''}")
        return lines
    return [f"Max height {height * record.blender_units_per_unit:.3g}", "Relative units (longest side = 10)"]


def key_figure_lines(record):
    """Plants and cover, and the measured canopy height p50/p90 in cm after a build with a DSM; why
    the ground took its soil from the surface when the photo's colour was not trusted; and that the
    surface model does not see the soil between the plots when the ground's check found so."""
    lines = []
    if record.cover is not None:
        lines.append(f"Plants {record.regions}, cover {float(record.cover):.0%}")
    if record.canopy_p90_cm >= 0.0:
        lines.append(
            f"Canopy height p50 {float(record.canopy_p50_cm):.1f} cm, p90 {float(record.canopy_p90_cm):.1f} cm"
        )
    if record.soil_note:
        lines.append(f"Soil from the surface: {record.soil_note}")
    if record.ground_note:
        lines.append(f"Ground: {record.ground_note}")
    return lines


def relief_info(obj):
    """The build record of a relief object (:class:`scene.record.Record`), or None."""
    return Record.of(obj)


class CLIFF_TERRAIN_PT_sidebar(bpy.types.Panel):
    """Always visible: Build Relief, the active relief's key figures, Colour By and Probe Height.
    The settings are in the sub-panels below, each collapsible."""

    bl_idname = "CLIFF_TERRAIN_PT_sidebar"
    bl_label = "Cliff Terrain"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Cliff Terrain"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.cliff_terrain

        row = layout.row()
        row.scale_y = 1.4
        # Greyed out until the photo exists; the operator then takes its parameters from here.
        row.enabled = bool(settings.filepath) and os.path.isfile(bpy.path.abspath(settings.filepath))
        row.operator(BUILD_OPERATOR, text="Build Relief", icon="MESH_GRID")
        # A tiled GeoTIFF orthomosaic of any size: one adaptive-mesh object per tile.
        layout.operator("cliff_terrain.import_mosaic", icon="IMPORT")

        obj = context.active_object
        info = relief_info(obj)
        if info is not None:
            box = layout.box()
            box.label(text=f"{obj.name}", icon="OBJECT_DATA")
            box.label(text=f"Grid {info.grid_cols} x {info.grid_rows}, {info.regions} regions")
            for line in relief_size_lines(info):
                box.label(text=line)
            for line in key_figure_lines(info):
                box.label(text=line)
            if info.max_error:
                box.label(
                    text=f"Adaptive: {info.front_faces} front faces, max error {info.max_error:.3g} {info.units}"
                )
                if info.max_error_rule:
                    box.label(text=f"Bound: {info.max_error_rule}")
            if info.mesh_rule not in ("", "given"):  # "": a record from before the mesh was chosen
                box.label(text=f"Mesh: {info.mesh_rule}")

        # ---- Inspecting ----
        col = layout.column()
        col.prop(settings, "color_by")
        if settings.color_by == "PLOT_TRAIT":
            col.prop(settings, "color_trait")
        elif settings.color_by == "INDEX":
            col.prop(settings, "color_index")
        layout.operator(PROBE_OPERATOR, icon="EYEDROPPER")
        probe = obj.get(PROBE_KEY) if info is not None else None
        if probe:
            box = layout.box()
            for k, line in enumerate(probe_lines(probe)):
                box.label(text=line, icon="EYEDROPPER" if k == 0 else "BLANK1")


class _SubPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Cliff Terrain"
    bl_parent_id = "CLIFF_TERRAIN_PT_sidebar"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        self.draw_settings(layout, context.scene.cliff_terrain)


class CLIFF_TERRAIN_PT_photo(_SubPanel, bpy.types.Panel):
    """The photo, its surface and ground models, and how the plants are found."""

    bl_idname = "CLIFF_TERRAIN_PT_photo"
    bl_label = "Photo & Models"

    def draw_settings(self, layout, settings):
        col = layout.column()
        col.prop(settings, "filepath")
        col.prop(settings, "dsm")
        col.prop(settings, "dtm")
        col.separator()
        col.prop(settings, "segmentation")


class CLIFF_TERRAIN_PT_heights(_SubPanel, bpy.types.Panel):
    """Where the heights come from and their scale."""

    bl_idname = "CLIFF_TERRAIN_PT_heights"
    bl_label = "Heights"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_settings(self, layout, settings):
        col = layout.column()
        sub = col.row()
        sub.active = bool(settings.dsm)  # Calibrated and Measured need a surface model
        sub.prop(settings, "height_source")
        if not settings.dsm:
            col.label(text="Calibrated and Measured need a surface model", icon="INFO")
        col.prop(settings, "profile")
        # 0: estimated from the photo (the radius of a typical isolated plant).
        col.prop(
            settings,
            "max_height",
            text="Canopy Height (auto)" if settings.max_height == 0.0 else "Canopy Height",
        )
        col.prop(settings, "exaggeration")
        # 0 means "from the photo": say so, rather than let "0.0000" read as a ground size.
        col.prop(settings, "gsd", text="GSD Override" if settings.gsd == 0.0 else "GSD (m/px)")
        gsd_note(col, settings)


class CLIFF_TERRAIN_PT_mesh(_SubPanel, bpy.types.Panel):
    """The mesh: grid size, grid or adaptive triangles, closed solid."""

    bl_idname = "CLIFF_TERRAIN_PT_mesh"
    bl_label = "Mesh"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_settings(self, layout, settings):
        col = layout.column()
        col.prop(settings, "max_size")
        col.prop(settings, "mesh")
        sub = col.row()
        sub.active = settings.mesh != "grid"  # the grid has no error to bound
        sub.prop(settings, "max_error")
        col.prop(settings, "two_sided")


class CLIFF_TERRAIN_PT_figures(_SubPanel, bpy.types.Panel):
    """Render Views and Evaluate as background jobs, and the views they wrote."""

    bl_idname = "CLIFF_TERRAIN_PT_figures"
    bl_label = "Figures"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_settings(self, layout, settings):
        col = layout.column()
        col.prop(settings, "output_dir")
        for idname, icon in RENDER_OPERATORS:
            col.operator(idname, icon=icon)
        if settings.psnr or settings.ssim:
            box = layout.box()
            from ..cliff_terrain.evaluate.views import psnr_text  # numpy: not at Blender's start-up

            box.label(text=f"PSNR {psnr_text(settings.psnr)}", icon="INFO")
            box.label(text=f"SSIM {settings.ssim:.3f}")
        # The views the last Render Views job wrote: each opens in an Image Editor.
        names = rendered_views(bpy.path.abspath(settings.last_views)) if settings.last_views else []
        if names:
            box = layout.box()
            box.label(
                text=f"Views in {os.path.basename(os.path.normpath(settings.last_views))}", icon="IMAGE_DATA"
            )
            grid = box.grid_flow(columns=2, even_columns=True)
            for name in names:
                op = grid.operator(OPEN_VIEW_OPERATOR, text=os.path.splitext(name)[0], icon="IMAGE")
                op.filepath = os.path.join(bpy.path.abspath(settings.last_views), name)


class CLIFF_TERRAIN_PT_season(_SubPanel, bpy.types.Panel):
    """A season of flights: the folder ``cliff-terrain season`` wrote, as an animation."""

    bl_idname = "CLIFF_TERRAIN_PT_season"
    bl_label = "Season"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_settings(self, layout, settings):
        layout.operator(SEASON_OPERATOR, icon="RENDER_ANIMATION")


class CLIFF_TERRAIN_PT_plots(bpy.types.Panel):
    """The plot grid: layout, Add Plot Grid, Fit to Field, Export Plots and the last fit's figures."""

    bl_idname = "CLIFF_TERRAIN_PT_plots"
    bl_label = "Plots"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Cliff Terrain"
    bl_parent_id = "CLIFF_TERRAIN_PT_sidebar"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        from ..scene.plot_grid_object import FIT_KEY, GRID_KEY, TABLE_KEY, grid_relief, grid_settings

        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.cliff_terrain
        col = layout.column(align=True)
        for name in (
            "plot_columns",
            "plot_rows",
            "plot_width",
            "plot_length",
            "plot_alley_across",
            "plot_alley_along",
        ):
            col.prop(settings, name)
        col = layout.column()
        col.prop(settings, "plot_numbering")
        col.prop(settings, "plot_start")
        col.prop(settings, "show_plot_labels")
        # Each button greys itself out (its poll) with the reason as its tooltip.
        layout.operator("cliff_terrain.add_plot_grid", icon="MESH_GRID")
        row = layout.row(align=True)
        row.operator("cliff_terrain.fit_plot_grid", icon="SNAP_ON")
        row.operator("cliff_terrain.plot_table", icon="SPREADSHEET")
        layout.operator("cliff_terrain.export_plots", icon="EXPORT")
        grid = context.active_object
        if grid is not None and GRID_KEY in grid:
            box = layout.box()
            relief, own = grid_relief(grid), grid_settings(grid, settings)
            box.label(
                text=f"{own.plot_columns * own.plot_rows} plots over "
                + (relief.name if relief is not None else f"{grid[GRID_KEY]} (gone)"),
                icon="MESH_GRID",
            )
            for line in fit_lines(grid.get(FIT_KEY)):
                box.label(text=line)
            table = grid.get(TABLE_KEY)
            if table:
                cells = box.grid_flow(columns=3, even_columns=True, align=True)
                for line in plot_table_lines([dict(row) for row in table]):
                    for cell in line:
                        cells.label(text=cell)


def plot_table_lines(rows, limit=12):
    """The panel's plot table: a header, then plot, cover and canopy height p90 (cm) per plot, by number,
    with its standard error (the ground's, from its held-out check) when it has one: ``42 ± 3 cm``."""
    lines = [("Plot", "Cover", "p90")]
    for row in sorted(rows, key=lambda r: r["plot"])[:limit]:
        p90 = row.get("height_p90_m", float("nan"))
        err = row.get("height_p90_err_m", float("nan"))
        height = "-" if p90 != p90 else f"{p90 * 100:.0f} cm"
        if p90 == p90 and err == err and err > 0:
            height = f"{p90 * 100:.0f} ± {err * 100:.0f} cm"
        lines.append((str(row["plot"]), f"{row['cover']:.0%}", height))
    if len(rows) > limit:
        lines.append((f"+{len(rows) - limit}", "more", ""))
    return lines


def fit_lines(report):
    """The last fit's figures as panel lines (none before a fit)."""
    if not report:
        return []
    return [
        f"Angle {float(report['angle_deg']):.2f}°, pitch {float(report['column_pitch_m']):.3g} x "
        f"{float(report['row_pitch_m']):.3g} m",
        f"Plants in plots {float(report['plant_share_in_plots']):.0%}, confidence {float(report['confidence']):.2f}",
    ]


# The sub-panels in the order they show.
CLASSES = (
    CLIFF_TERRAIN_PT_sidebar,
    CLIFF_TERRAIN_PT_photo,
    CLIFF_TERRAIN_PT_heights,
    CLIFF_TERRAIN_PT_mesh,
    CLIFF_TERRAIN_PT_plots,
    CLIFF_TERRAIN_PT_figures,
    CLIFF_TERRAIN_PT_season,
)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
