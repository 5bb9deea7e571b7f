"""Plot grid operators: Add Plot Grid over the active relief, Fit to Field, Export Plots, and the labels overlay.

The grid's layout is the scene settings' (``plot_columns`` ... ``plot_start``; an edit rebuilds the
active grid at once); its placement is the grid object's own matrix, moved with G, R and S. The core
does the work: :mod:`cliff_terrain.measure.plot_grid` numbers and writes the plots, :mod:`cliff_terrain.measure.plot_fit`
snaps the grid to the crop of the relief's orthophoto.
"""

import bpy

from ..cliff_terrain.io.raster.crs import crs_text
from ..scene.record import Record, is_relief
from .file_operator import FileOperator
from .properties import show_grid_settings
from .reports import report_failure


def _relief_of(context):
    obj = context.active_object
    return obj if is_relief(obj) else None


class _OnAGrid:
    """Runs on the active plot grid: greyed out, with the reason, when none is active."""

    @classmethod
    def poll(cls, context):
        from ..scene.plot_grid_object import GRID_KEY, active_grid, grid_relief

        grid = active_grid(context)
        if grid is None:
            cls.poll_message_set("Select a plot grid (Add Plot Grid)")
            return False
        if grid_relief(grid) is None:
            cls.poll_message_set(f"The relief {grid[GRID_KEY]!r} of this plot grid is gone")
            return False
        return True


class CLIFF_TERRAIN_OT_add_plot_grid(bpy.types.Operator):
    """Put a plot grid (the sidebar's columns, rows, plot size and alleys) over the active relief; move,
    rotate and scale it with G, R and S"""

    bl_idname = "cliff_terrain.add_plot_grid"
    bl_label = "Add Plot Grid"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        relief = _relief_of(context)
        if relief is None:
            cls.poll_message_set("Select a relief built from a georeferenced orthophoto")
            return False
        if not Record.of(relief).metres:
            cls.poll_message_set(
                "The active relief has no ground size (build it from a georeferenced orthophoto)"
            )
            return False
        return True

    def execute(self, context):
        from ..scene.datablocks import remove_datablocks
        from ..scene.plot_grid_object import new_grid

        created = []
        try:
            grid = new_grid(context, context.active_object, context.scene.cliff_terrain, created=created)
        except Exception as exc:
            remove_datablocks(created)
            return report_failure(self, exc)
        for other in context.view_layer.objects.selected:
            other.select_set(False)
        grid.select_set(True)
        context.view_layer.objects.active = grid
        settings = context.scene.cliff_terrain
        self.report(
            {"INFO"},
            f"{settings.plot_columns * settings.plot_rows} plots over {grid.get('cliff_terrain_plot_grid')}",
        )
        return {"FINISHED"}


class CLIFF_TERRAIN_OT_fit_plot_grid(_OnAGrid, bpy.types.Operator):
    """Snap the active plot grid to the crop rows and alleys of its relief's orthophoto (direction,
    pitch and position), starting from where it is"""

    bl_idname = "cliff_terrain.fit_plot_grid"
    bl_label = "Fit to Field"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from ..cliff_terrain.io.raster.geotiff import read_orthophoto
        from ..cliff_terrain.measure.canopy import plant_mask
        from ..cliff_terrain.measure.plot_fit import CONFIDENT, MIN_COVER, fit_grid
        from ..cliff_terrain.measure.plot_grid import Placement
        from ..scene.plot_grid_object import FIT_KEY, grid_map_corners, layout_of, mark_fit, move_grid

        grid = context.active_object
        settings = context.scene.cliff_terrain
        # The fields show this grid's own layout: the fitted alleys below change it, not another's.
        show_grid_settings(grid, settings)
        try:
            layout = layout_of(settings)
            frame, corners = grid_map_corners(grid, layout)
            ortho = read_orthophoto(frame.source)
            if ortho.crs != frame.crs:
                from ..cliff_terrain.errors import GeoreferenceError

                raise GeoreferenceError(
                    f"{frame.source!r} is in {crs_text(ortho.crs)}, the relief in {crs_text(frame.crs)}"
                )
            plants = plant_mask(ortho.data, valid=ortho.valid)
            fit = fit_grid(plants, ortho.transform, layout, placement=Placement(corners), valid=ortho.valid)
        except Exception as exc:
            return report_failure(self, exc)
        move_grid(grid, frame, fit.placement)
        # The fitted pitches become the alleys (which rebuilds the mesh through the settings' update).
        settings.plot_alley_across = max(0.0, fit.report["column_pitch_m"] - settings.plot_width)
        settings.plot_alley_along = max(0.0, fit.report["row_pitch_m"] - settings.plot_length)
        grid[FIT_KEY] = {k: v for k, v in fit.report.items() if isinstance(v, int | float)}
        import numpy as np

        # Per plot (the faces' order): the grid's confidence, none for a plot without crop of its own.
        confidence = np.where(fit.plot_cover >= MIN_COVER, fit.report["confidence"], 0.0)
        mark_fit(grid, confidence, confidence < CONFIDENT)
        self.report(
            {"INFO"},
            f"Fitted: angle {fit.report['angle_deg']:.2f} deg, {fit.report['plant_share_in_plots']:.0%} of the "
            f"plants in plots, moved {fit.report['moved_m']:.2f} m, confidence {fit.report['confidence']:.2f}; "
            f"{int((confidence < CONFIDENT).sum())} plots flagged (red)",
        )
        return {"FINISHED"}


class CLIFF_TERRAIN_OT_plot_table(_OnAGrid, bpy.types.Operator):
    """Measure every plot of the active grid on its relief: plant cover, and with a surface model the
    canopy height p50/p90 and the p90's standard error (shown in the Plots panel)"""

    bl_idname = "cliff_terrain.plot_table"
    bl_label = "Measure Plots"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from ..cliff_terrain.measure.canopy import relief_plot_rows
        from ..scene.plot_grid_object import TABLE_KEY, grid_plots, grid_relief
        from ..scene.probe import relief_of

        grid = context.active_object
        try:
            plots, frame = grid_plots(grid, context.scene.cliff_terrain)
            # The relief as it was built (its recorded settings), without a mesh: Probe Height's copy.
            relief = relief_of(grid_relief(grid))
            rows = relief_plot_rows(relief, plots, source=frame.source)
        except Exception as exc:
            return report_failure(self, exc)
        keys = ("column", "row", "cover", "height_p50_m", "height_p90_m", "height_p90_err_m")
        # The table's `plot` is the index in the set; the plot's own number is its attribute. The
        # height's standard error is NaN without a surface model (no heights to be unsure of).
        nan = float("nan")
        grid[TABLE_KEY] = [{"plot": row["plot_attr"], **{k: row.get(k, nan) for k in keys}} for row in rows]
        measured = [row for row in rows if row["height_p90_m"] == row["height_p90_m"]]  # not NaN
        heights = f", {len(measured)} with heights" if measured else " (no surface model: cover only)"
        self.report({"INFO"}, f"{len(rows)} plots measured{heights}")
        return {"FINISHED"}


class CLIFF_TERRAIN_OT_export_plots(_OnAGrid, FileOperator, bpy.types.Operator):
    """Write the active plot grid's plots (numbered, in the relief's CRS) as GeoJSON, or as a Shapefile
    when the name ends in .shp"""

    bl_idname = "cliff_terrain.export_plots"
    bl_label = "Export Plots"
    bl_options = {"REGISTER"}
    path_property = "filepath"

    filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH")
    filter_glob: bpy.props.StringProperty(default="*.geojson;*.json;*.shp", options={"HIDDEN"})

    def execute(self, context):
        from pathlib import Path

        from ..cliff_terrain.io.vector.plot_files import write_plots
        from ..scene.plot_grid_object import grid_plots

        path = Path(bpy.path.abspath(self.filepath))
        if not path.suffix:  # a name typed without one: GeoJSON, as the file browser offers
            path = path.with_suffix(".geojson")
        elif path.suffix.lower() not in (".geojson", ".json", ".shp"):
            # GeoJSON text under .gpkg is a file QGIS will not open.
            self.report(
                {"ERROR"},
                f"Export Plots writes GeoJSON (.geojson) or a Shapefile (.shp), not {path.suffix!r}",
            )
            return {"CANCELLED"}
        try:
            plots, frame = grid_plots(context.active_object, context.scene.cliff_terrain)
            written = write_plots(plots, path, crs=frame.crs)
        except OSError as exc:
            self.report({"ERROR"}, f"cannot write {str(path)!r}: {exc}")
            return {"CANCELLED"}
        except Exception as exc:
            return report_failure(self, exc)
        self.report({"INFO"}, f"{len(plots)} plots in {crs_text(frame.crs)} written to {written[0]}")
        return {"FINISHED"}


_LABELS = {"handle": None}


def draw_labels():
    """The labels overlay (POST_PIXEL): each plot's number where the plots are at least 24 px on screen."""
    context = bpy.context
    settings = getattr(context.scene, "cliff_terrain", None)
    region, rv3d = context.region, context.region_data
    if settings is None or not settings.show_plot_labels or rv3d is None:
        return
    import blf
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    from ..scene.plot_grid_object import GRID_KEY, label_positions

    for grid in context.visible_objects:
        if GRID_KEY not in grid:
            continue
        try:
            labels = label_positions(grid, settings)
        except Exception:  # a grid whose relief is gone: nothing to label
            continue
        if len(labels) > 1:
            a = location_3d_to_region_2d(region, rv3d, labels[0][1])
            b = location_3d_to_region_2d(region, rv3d, labels[1][1])
            if a is None or b is None or (a - b).length < 24:
                continue  # at a distance the numbers would only clutter
        blf.size(0, 12)
        blf.color(0, 1.0, 0.95, 0.6, 1.0)
        for text, position in labels:
            point = location_3d_to_region_2d(region, rv3d, position)
            if point is not None:
                width, height = blf.dimensions(0, text)
                blf.position(0, point.x - width / 2, point.y - height / 2, 0)
                blf.draw(0, text)


CLASSES = (
    CLIFF_TERRAIN_OT_add_plot_grid,
    CLIFF_TERRAIN_OT_fit_plot_grid,
    CLIFF_TERRAIN_OT_plot_table,
    CLIFF_TERRAIN_OT_export_plots,
)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    if not bpy.app.background:
        _LABELS["handle"] = bpy.types.SpaceView3D.draw_handler_add(draw_labels, (), "WINDOW", "POST_PIXEL")


def unregister():
    if _LABELS["handle"] is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_LABELS["handle"], "WINDOW")
        _LABELS["handle"] = None
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
