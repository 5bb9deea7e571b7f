"""Colour by: a relief shows its photo, its height or a plot trait (viridis, the core's one height map).

The colour is a point colour attribute (``COLOUR_ATTRIBUTE``) that the relief's material mixes over
the photo (its "Colour By" node: factor 0 = photo, 1 = the attribute), so Material Preview and
renders show it; Solid shading shows it through its Attribute colour mode, which the switch sets in
every 3D view of the window. The range the colours span, and its unit, are stored on the object
(``LEGEND_KEY``) for the viewport's colour bar.
"""

import bpy
import numpy as np

from ..cliff_terrain.settings import PLOT_TRAITS
from .mesh_data import positions
from .record import Record, is_relief

COLOUR_ATTRIBUTE = "Cliff Terrain Colour"
MIX_NODE = "Cliff Terrain Colour By"
ATTRIBUTE_NODE = "Cliff Terrain Colour Attribute"
LEGEND_KEY = "cliff_terrain_legend"  # custom property: {mode, title, low, high, unit}
# Vertices outside every plot, coloured by a plot trait: a neutral grey.
OUTSIDE_PLOTS = (0.35, 0.35, 0.35)


def reliefs(scene):
    """The scene's relief objects (those with a record, :mod:`.record`)."""
    return [obj for obj in scene.objects if is_relief(obj)]


def measured_grids():
    """{relief name: a plot grid over it with a plot table (Measure Plots)}, in one pass over the objects."""
    from .plot_grid_object import GRID_KEY, TABLE_KEY, grid_relief

    grids = {}
    for obj in bpy.data.objects:
        if GRID_KEY in obj and obj.get(TABLE_KEY) and (relief := grid_relief(obj)) is not None:
            grids[relief.name] = obj
    return grids


def measured_grid(relief):
    """A plot grid over `relief` with a plot table (Measure Plots), or None."""
    return measured_grids().get(relief.name)


def ensure_colour_nodes(material):
    """Add the Colour By nodes to a relief material (once): an attribute mixed over the Base Color."""
    tree = material.node_tree
    if tree is None or MIX_NODE in tree.nodes:
        return
    bsdf = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
    if bsdf is None:
        return
    base = bsdf.inputs["Base Color"]
    attribute = tree.nodes.new("ShaderNodeVertexColor")
    attribute.name = attribute.label = ATTRIBUTE_NODE
    attribute.layer_name = COLOUR_ATTRIBUTE
    mix = tree.nodes.new("ShaderNodeMix")
    mix.name = mix.label = MIX_NODE
    mix.data_type = "RGBA"
    _socket(mix.inputs, "Factor_Float").default_value = 0.0
    if base.links:
        tree.links.new(base.links[0].from_socket, _socket(mix.inputs, "A_Color"))
    tree.links.new(attribute.outputs["Color"], _socket(mix.inputs, "B_Color"))
    tree.links.new(_socket(mix.outputs, "Result_Color"), base)
    attribute.location = (bsdf.location.x - 450, bsdf.location.y - 350)
    mix.location = (bsdf.location.x - 200, bsdf.location.y - 150)


def photo_where_transparent(material):
    """The Colour By nodes mix by the colour attribute's alpha: its colour where alpha is 1, the photo
    where it is 0 (a season's frames colour the plots and keep the photo around them)."""
    ensure_colour_nodes(material)
    tree = material.node_tree
    mix, attribute = tree.nodes.get(MIX_NODE), tree.nodes.get(ATTRIBUTE_NODE)
    if mix is not None and attribute is not None:
        tree.links.new(attribute.outputs["Alpha"], _socket(mix.inputs, "Factor_Float"))


def _socket(sockets, identifier):
    return next(s for s in sockets if s.identifier == identifier)


def height_legend(relief):
    """(t per vertex in [0, 1], legend) of colouring `relief` by its height (0 to its highest point)."""
    record = Record.of(relief)
    top = float(record.max_height)
    z = positions(relief.data)[:, 2] / record.blender_units_per_unit
    t = np.clip(z / top, 0.0, 1.0) if top > 0 else np.zeros_like(z)
    return t, {"mode": "HEIGHT", "title": "Height", "low": 0.0, "high": top, "unit": record.units}


def trait_legend(relief, grid, settings, trait):
    """(t per vertex in [0, 1], NaN outside the plots; legend) of colouring `relief` by a plot trait."""
    from ..cliff_terrain.measure.field_plots import rasterize_plots
    from .plot_grid_object import TABLE_KEY, grid_plots
    from .probe import grid_cells

    record = Record.of(relief)
    plots, frame = grid_plots(grid, settings)
    rows, cols = record.grid_shape
    size = float(record.pixel_size)  # metres: plots need a ground size
    # The relief's processing grid on the map: its local (0, 0) is the bottom-left corner.
    transform = np.array([[size, 0.0, frame.offset[0]], [0.0, -size, frame.offset[1] + rows * size]])
    labels = rasterize_plots(plots, transform=transform, shape=(rows, cols))
    by_number = {row["plot"]: row for row in (dict(r) for r in grid[TABLE_KEY])}
    values = np.full(len(plots) + 1, np.nan)
    for k, attributes in enumerate(plots.attributes, start=1):
        row = by_number.get(attributes["plot"])
        if row is not None and row.get(trait) is not None:
            values[k] = float(row[trait])
    row, col = grid_cells(record, positions(relief.data)[:, :2])
    per_vertex = values[labels[row, col]]
    finite = values[np.isfinite(values)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    span = high - low
    t = (per_vertex - low) / span if span > 0 else np.where(np.isnan(per_vertex), np.nan, 0.5)
    label, unit = next((lab, u) for key, lab, u in PLOT_TRAITS if key == trait)
    if unit == "%":
        low, high = 100.0 * low, 100.0 * high
    return t, {"mode": "PLOT_TRAIT", "title": label, "low": low, "high": high, "unit": unit}


def index_legend(relief, index):
    """(t per vertex in [0, 1], NaN without data; legend) of colouring `relief` by a vegetation index
    of its photo's bands (:mod:`cliff_terrain.photo_heights.indices`), from its 2nd to 98th percentile."""
    from ..cliff_terrain.io.raster.bands import read_bands
    from ..cliff_terrain.photo_heights.indices import index_maps
    from .probe import grid_cells

    record = Record.of(relief)
    bands = read_bands(record.source_file, names=record.bands or None)
    values = index_maps(bands, (index,), shape=record.grid_shape)[index]
    row, col = grid_cells(record, positions(relief.data)[:, :2])
    per_vertex = values[row, col].astype(np.float64)
    finite = values[np.isfinite(values)]
    low, high = (float(v) for v in np.percentile(finite, (2, 98))) if finite.size else (0.0, 1.0)
    span = high - low
    t = (
        np.clip((per_vertex - low) / span, 0.0, 1.0)
        if span > 0
        else np.where(np.isnan(per_vertex), np.nan, 0.5)
    )
    return t, {"mode": "INDEX", "title": index, "low": low, "high": high, "unit": ""}


def set_vertex_colours(mesh, t, *, name=COLOUR_ATTRIBUTE, nan_alpha=1.0):
    """Write viridis colours of `t` (in [0, 1]; NaN: grey, of alpha `nan_alpha`) as the mesh's active
    point colour attribute `name`, and return it (active for display, so Solid's Attribute colour
    shows it). :func:`photo_where_transparent` makes the material show the photo where alpha is 0."""
    from ..cliff_terrain.figures.legends import height_colours

    t = np.asarray(t, dtype=np.float64)
    rgba = np.ones((len(t), 4), dtype=np.float32)
    rgba[:, :3] = height_colours(np.nan_to_num(t))
    rgba[np.isnan(t), :3] = OUTSIDE_PLOTS
    rgba[np.isnan(t), 3] = nan_alpha
    attribute = mesh.color_attributes.get(name)
    if attribute is None:
        attribute = mesh.color_attributes.new(name, "BYTE_COLOR", "POINT")
    attribute.data.foreach_set("color_srgb", rgba.ravel())
    mesh.color_attributes.active_color = attribute
    return attribute


def colour_relief(relief, mode, *, settings=None, trait="height_p90_m", index="NDVI"):
    """Colour one relief by `mode` (``PHOTO``, ``HEIGHT``, ``PLOT_TRAIT`` or ``INDEX``); returns the
    mode it shows.

    A relief with no measured plot grid stays on its photo when asked for a plot trait, and one whose
    bands do not give `index` (its record's ``indices``) when asked for an index.
    """
    material = relief.active_material
    if material is not None:
        ensure_colour_nodes(material)
    legend = None
    if mode != "PHOTO" and (problem := Record.of(relief).frame_error(relief)):
        print(f"Cliff Terrain: {problem}; it shows its photo")  # an update callback reports nowhere else
        mode = "PHOTO"
    if mode == "HEIGHT":
        t, legend = height_legend(relief)
    elif mode == "PLOT_TRAIT":
        grid = measured_grid(relief)
        if grid is not None:
            t, legend = trait_legend(relief, grid, settings, trait)
    elif mode == "INDEX" and index in Record.of(relief).indices:
        t, legend = index_legend(relief, index)
    if legend is not None:
        set_vertex_colours(relief.data, t)
        relief[LEGEND_KEY] = legend
    elif LEGEND_KEY in relief:
        del relief[LEGEND_KEY]
    mix = material.node_tree.nodes.get(MIX_NODE) if material is not None and material.node_tree else None
    if mix is not None:
        _socket(mix.inputs, "Factor_Float").default_value = 0.0 if legend is None else 1.0
    relief.data.update()
    return "PHOTO" if legend is None else legend["mode"]


def show_colours_in_solid(screen, attribute):
    """Solid shading of every 3D view shows the colour attribute (True) or the photo (False)."""
    if screen is None:
        return
    for area in screen.areas:
        if area.type == "VIEW_3D":
            shading = area.spaces.active.shading
            if shading.type == "SOLID":
                shading.color_type = "VERTEX" if attribute else "TEXTURE"
            area.tag_redraw()
