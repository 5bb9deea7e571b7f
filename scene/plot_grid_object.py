"""The plot grid object: a mesh of plot quads over a relief, moved, rotated and scaled with Blender's own
tools, and its map frame (Blender world <-> the relief's map coordinates).

The mesh holds the grid in its own frame: u (across the columns) along local x, v (along them) along
local y, from the grid's (0, 0) corner, in Blender units. The object's matrix is the placement. Each
face carries its plot's ``column`` and ``row`` (0-based in the grid's frame) as integer attributes;
after Fit to Field also ``fit_confidence`` (float), ``fit_flag`` (1: the fit is unsure of this plot)
and the colour attribute ``fit_colour`` (the grid's yellow, red where flagged), until the layout is
edited.
"""

import functools

import bpy
import numpy as np
from mathutils import Vector

from .record import Record

GRID_KEY = "cliff_terrain_plot_grid"  # custom property: the name of the relief the grid belongs to
# Custom properties: an id the relief carries, and the grid the id of its relief. The name alone broke
# Fit, Measure and Export once the user renamed the relief in the Outliner; an ID pointer counted as
# a user, so a relief deleted in the viewport lived on hidden (measured, saved with the file).
RELIEF_ID_KEY = "cliff_terrain_id"
RELIEF_KEY = "cliff_terrain_relief"
FIT_KEY = "cliff_terrain_fit"  # custom property: the last fit's report
TABLE_KEY = "cliff_terrain_plot_table"  # custom property: the last Measure Plots' rows
GRID_RGBA = (1.0, 0.85, 0.1, 1.0)
FLAGGED_RGBA = (0.9, 0.1, 0.1, 1.0)  # plots the last fit is unsure of


def active_grid(context):
    """The active object when it is a plot grid, else None."""
    obj = getattr(context, "active_object", None)
    return obj if obj is not None and GRID_KEY in obj else None


def grid_relief(grid):
    """The relief object a grid was added over (None when it is gone, deleted or in no scene): the one
    carrying the grid's relief id, renamed or not, or for a grid from an earlier version the object
    of its recorded name."""
    key, name = grid.get(RELIEF_KEY), grid.get(GRID_KEY, "")
    if isinstance(key, str):
        found = [obj for obj in bpy.data.objects if obj.get(RELIEF_ID_KEY) == key and obj.users_scene]
        # A relief duplicated (Shift D) carries the same id: the one of the recorded name first.
        return next((obj for obj in found if obj.name == name), found[0] if found else None)
    relief = bpy.data.objects.get(name)
    return relief if relief is not None and relief.users_scene else None


# Custom property: the layout the grid was drawn with (its sidebar fields). Each grid keeps its own:
# read from the scene's fields, a grid drew 32 plots and exported 4 once another grid was edited.
LAYOUT_KEY = "cliff_terrain_layout"
LAYOUT_FIELDS = (
    "plot_columns",
    "plot_rows",
    "plot_width",
    "plot_length",
    "plot_alley_across",
    "plot_alley_along",
    "plot_numbering",
    "plot_start",
)


def grid_settings(grid, settings):
    """The grid's own layout fields (what it was drawn with), as attributes like the scene's
    `settings`. A grid from an earlier version kept none: its layout is read off its mesh (the
    numbering, which the mesh does not hold, is the scene's)."""
    from types import SimpleNamespace

    own = grid.get(LAYOUT_KEY)
    own = own.to_dict() if hasattr(own, "to_dict") else (own or _layout_from_mesh(grid))
    return SimpleNamespace(**{name: own.get(name, getattr(settings, name)) for name in LAYOUT_FIELDS})


def _layout_from_mesh(grid):
    """The layout fields of a grid's mesh as :func:`update_grid_mesh` made it (four vertices a plot,
    the plots in (row, column) order with ``column`` and ``row`` face attributes), or {}."""
    mesh = getattr(grid, "data", None)
    n = len(mesh.polygons) if mesh is not None else 0
    if (
        not n
        or len(mesh.vertices) != 4 * n
        or "column" not in mesh.attributes
        or "row" not in mesh.attributes
    ):
        return {}
    columns, rows = np.zeros(n, np.int32), np.zeros(n, np.int32)
    mesh.attributes["column"].data.foreach_get("value", columns)
    mesh.attributes["row"].data.foreach_get("value", rows)
    xyz = np.zeros(3 * 4 * n, np.float32)
    mesh.vertices.foreach_get("co", xyz)
    corners = xyz.reshape(n, 4, 3).astype(np.float64) / float(grid.get("cliff_terrain_scale", 1.0))
    layout = {
        "plot_columns": int(columns.max()) + 1,
        "plot_rows": int(rows.max()) + 1,
        "plot_width": float(corners[0, 1, 0] - corners[0, 0, 0]),
        "plot_length": float(corners[0, 2, 1] - corners[0, 1, 1]),
    }
    if layout["plot_columns"] > 1:  # the next plot along the row, less the plot
        pitch = corners[(rows == 0) & (columns == 1)][0, 0, 0] - corners[0, 0, 0]
        layout["plot_alley_across"] = float(pitch - layout["plot_width"])
    if layout["plot_rows"] > 1:
        pitch = corners[(rows == 1) & (columns == 0)][0, 0, 1] - corners[0, 0, 1]
        layout["plot_alley_along"] = float(pitch - layout["plot_length"])
    return layout


def keep_layout(grid, settings):
    """Record the scene's layout fields as the grid's own (:func:`grid_settings`)."""
    grid[LAYOUT_KEY] = {name: getattr(settings, name) for name in LAYOUT_FIELDS}


def layout_of(settings):
    """The core layout of grid settings (the scene's, or a grid's own: :func:`grid_settings`)."""
    from ..cliff_terrain.measure.plot_grid import grid_layout

    return grid_layout(
        settings.plot_columns,
        settings.plot_rows,
        plot_size=(settings.plot_width, settings.plot_length),
        alleys=(settings.plot_alley_across, settings.plot_alley_along),
    )


def _georeference(path):
    """The photo's georeference, read once per version of the file: the labels overlay asks at
    every redraw of every 3D view (it read the GeoTIFF's header 20 times in 20 redraws)."""
    import os

    try:
        stamp = os.stat(path).st_mtime_ns
    except OSError:
        stamp = None  # read_georeference says what is wrong with the path
    return _georeference_of(path, stamp)


@functools.lru_cache(maxsize=8)
def _georeference_of(path, stamp):
    from ..cliff_terrain.io.raster.geotiff import read_georeference

    return read_georeference(path)


class MapFrame:
    """Blender world (x, y) <-> map (x, y) of a relief built from a georeferenced orthophoto."""

    def __init__(self, relief):
        record = Record.of(relief)
        if record is None:
            raise ValueError(f"{relief.name!r} is not a Cliff Terrain relief")
        if problem := record.frame_error(relief):
            from ..cliff_terrain.errors import CliffTerrainError

            raise CliffTerrainError(problem)
        self.scale = record.blender_units_per_unit
        if not record.metres:
            from ..cliff_terrain.errors import CliffTerrainError

            raise CliffTerrainError(
                f"{relief.name!r} has no ground size: plots need a relief built from a georeferenced orthophoto"
            )
        if record.map_offset is not None:
            self.offset = np.array(record.map_offset, dtype=np.float64)
            from ..cliff_terrain.io.raster.crs import crs_from_record

            self.crs = crs_from_record(record.crs, source=relief.name)
        else:
            transform, self.crs = _georeference(record.source_file)
            # The mesh's local (0, 0) is the photo's bottom-left corner.
            self.offset = transform[:2, :2] @ [0.0, float(record.image_height)] + transform[:2, 2]
        self.matrix = np.array(relief.matrix_world, dtype=np.float64)
        self.inverse = np.linalg.inv(self.matrix)
        self.source = record.source_file

    def to_map(self, world_xy):
        world = np.asarray(world_xy, dtype=np.float64).reshape(-1, 2)
        homogeneous = np.column_stack([world, np.zeros(len(world)), np.ones(len(world))])
        local = homogeneous @ self.inverse.T
        return local[:, :2] / self.scale + self.offset

    def to_world(self, map_xy):
        local = (np.asarray(map_xy, dtype=np.float64).reshape(-1, 2) - self.offset) * self.scale
        homogeneous = np.column_stack([local, np.zeros(len(local)), np.ones(len(local))])
        return (homogeneous @ self.matrix.T)[:, :2]


def grid_mesh_arrays(layout, scale):
    """Vertices (4 per plot, z 0) and the plots' (column, row), in the grid's frame, in (row, column) order."""
    columns, rows = np.meshgrid(np.arange(layout.columns), np.arange(layout.rows))
    columns, rows = columns.ravel(), rows.ravel()
    u0 = layout.column_offsets[columns]
    v0 = layout.row_offsets[rows]
    u = np.stack([u0, u0 + layout.width, u0 + layout.width, u0], axis=1)
    v = np.stack([v0, v0, v0 + layout.length, v0 + layout.length], axis=1)
    vertices = np.zeros((u.size, 3), dtype=np.float32)
    vertices[:, 0] = u.ravel() * scale
    vertices[:, 1] = v.ravel() * scale
    return vertices, columns.astype(np.int32), rows.astype(np.int32)


def update_grid_mesh(grid, settings):
    """Replace the grid's mesh with the settings' layout (one bulk write per array), and keep the
    layout as the grid's own."""
    frame_scale = float(grid.get("cliff_terrain_scale", 1.0))
    layout = layout_of(settings)
    keep_layout(grid, settings)
    vertices, columns, rows = grid_mesh_arrays(layout, frame_scale)
    mesh = grid.data
    mesh.clear_geometry()
    n = len(columns)
    mesh.vertices.add(4 * n)
    mesh.vertices.foreach_set("co", vertices.ravel())
    mesh.loops.add(4 * n)
    mesh.loops.foreach_set("vertex_index", np.arange(4 * n, dtype=np.int32))
    mesh.polygons.add(n)
    mesh.polygons.foreach_set("loop_start", np.arange(0, 4 * n, 4, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(n, 4, dtype=np.int32))
    for name, values in (("column", columns), ("row", rows)):
        attribute = mesh.attributes.get(name) or mesh.attributes.new(name, "INT", "FACE")
        attribute.data.foreach_set("value", values)
    mesh.update(calc_edges=True)
    mesh.validate()
    # The last fit's figures and red wire describe the plots as they were (Fit to Field writes its
    # own after its alleys rebuild the mesh).
    if FIT_KEY in grid:
        del grid[FIT_KEY]
    grid.color = GRID_RGBA
    if TABLE_KEY in grid:  # measured on the plots as they were
        del grid[TABLE_KEY]
    return layout


def new_grid(context, relief, settings, *, created):
    """A grid object over `relief`, centred on it, at 5 cm above its highest point (wireframe display)."""
    frame = MapFrame(relief)
    mesh = bpy.data.meshes.new(f"{relief.name} plots")
    created.append(mesh)
    grid = bpy.data.objects.new(f"{relief.name} plots", mesh)
    created.append(grid)
    if not isinstance(relief.get(RELIEF_ID_KEY), str):
        import uuid

        relief[RELIEF_ID_KEY] = uuid.uuid4().hex
    grid[GRID_KEY] = relief.name
    grid[RELIEF_KEY] = relief[RELIEF_ID_KEY]
    grid["cliff_terrain_scale"] = frame.scale
    layout = update_grid_mesh(grid, settings)
    across, along = layout.extent
    # Centred on the relief's footprint, above its top (its bounding box's 8 corners).
    bounds = np.array([relief.matrix_world @ Vector(c) for c in relief.bound_box])
    centre = bounds[:, :2].mean(axis=0)
    top = float(bounds[:, 2].max())
    grid.location = (
        centre[0] - 0.5 * across * frame.scale,
        centre[1] - 0.5 * along * frame.scale,
        top + 0.05 * frame.scale,
    )
    grid.display_type = "WIRE"
    grid.show_in_front = True
    grid.color = GRID_RGBA
    (context.collection or context.scene.collection).objects.link(grid)
    return grid


def grid_map_corners(grid, layout):
    """Map (x, y) of the grid's corners (u, v) = (0, 0), (U, 0), (U, V), (0, V) as placed by the user."""
    relief = grid_relief(grid)
    if relief is None:
        from ..cliff_terrain.errors import CliffTerrainError

        raise CliffTerrainError(f"the relief {grid.get(GRID_KEY)!r} of the plot grid {grid.name!r} is gone")
    frame = MapFrame(relief)
    across, along = layout.extent
    scale = float(grid.get("cliff_terrain_scale", 1.0))
    local = np.array(
        [
            [0, 0, 0, 1],
            [across * scale, 0, 0, 1],
            [across * scale, along * scale, 0, 1],
            [0, along * scale, 0, 1],
        ]
    )
    world = local @ np.array(grid.matrix_world, dtype=np.float64).T
    return frame, frame.to_map(world[:, :2])


def move_grid(grid, frame, placement):
    """Move and rotate the grid so that its (0, 0) corner and u direction are the placement's."""
    corners = frame.to_world(placement.corners)
    u = corners[1] - corners[0]
    z = grid.location.z
    grid.rotation_mode = "XYZ"
    grid.rotation_euler = (0.0, 0.0, float(np.arctan2(u[1], u[0])))
    grid.scale = (1.0, 1.0, 1.0)
    grid.location = (float(corners[0][0]), float(corners[0][1]), z)


def grid_plots(grid, settings):
    """The grid as numbered plots in the relief's CRS (:class:`cliff_terrain.io.vector.plot_polygons.PlotSet`), and the frame."""
    from ..cliff_terrain.measure.plot_grid import Placement, plots_from

    own = grid_settings(grid, settings)
    layout = layout_of(own)
    frame, corners = grid_map_corners(grid, layout)
    plots = plots_from(
        layout, Placement(corners), numbering=own.plot_numbering, start=own.plot_start, crs=frame.crs
    )
    return plots, frame


def label_positions(grid, settings):
    """(text, world (x, y, z)) of every plot's number at its centre, for the labels overlay."""
    plots, frame = grid_plots(grid, settings)
    centres = np.array([rings[0][:4].mean(axis=0) for rings in plots.polygons])
    world = frame.to_world(centres)
    z = float(grid.matrix_world.translation.z)
    return [
        (str(a["plot"]), (float(x), float(y), z)) for a, (x, y) in zip(plots.attributes, world, strict=True)
    ]


def mark_fit(grid, confidence, flagged):
    """Write the last fit's per-plot `confidence` and `flagged` (grid (row, column) order, as the
    faces) onto the grid's faces, with a colour attribute that shows the flagged plots in red."""
    mesh = grid.data
    n = len(mesh.polygons)
    confidence = np.asarray(confidence, dtype=np.float32).reshape(n)
    flagged = np.asarray(flagged, dtype=bool).reshape(n)
    for name, kind, values in (
        ("fit_confidence", "FLOAT", confidence),
        ("fit_flag", "INT", flagged.astype(np.int32)),
    ):
        attribute = mesh.attributes.get(name) or mesh.attributes.new(name, kind, "FACE")
        attribute.data.foreach_set("value", values)
    # Colour attributes live on points or face corners: each plot's four corners (the mesh's loops
    # are face after face, four each).
    colour = mesh.color_attributes.get("fit_colour") or mesh.color_attributes.new(
        "fit_colour", "FLOAT_COLOR", "CORNER"
    )
    rgba = np.where(flagged[:, None], FLAGGED_RGBA, GRID_RGBA).astype(np.float32)
    colour.data.foreach_set("color", np.repeat(rgba, 4, axis=0).ravel())
    mesh.color_attributes.active_color = colour
    # The wire shows the object's colour: red when the fit is unsure of any plot.
    grid.color = FLAGGED_RGBA if flagged.any() else GRID_RGBA
    mesh.update()
