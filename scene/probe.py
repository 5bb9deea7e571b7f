"""Point at a relief and read its height: the relief's own rasters under a point of the scene.

A relief object keeps no height raster (its .blend stays the mesh's size). The first probe of a
relief (or Measure Plots) rebuilds it from its recorded photo and settings without a mesh, and
bit for bit the same relief (its ``mask_digest`` is checked), and keeps the last one in memory, so
the next clicks answer at once. A point is read from the pixel under it: the value the relief's
height raster (``height.tif``) holds there, whatever mesh shows it.
"""

import json

from mathutils import Vector

from .record import Record

PROBE_KEY = "cliff_terrain_probe"  # custom property of the relief: the last probe's values
# The last relief rebuilt for probing: (object name, its whole record) -> Relief. The whole record,
# not only the mask's digest: a relief rebuilt under the same name with another exaggeration or
# profile has the same mask and other heights. One at a time: a relief of a 4000-pixel grid holds
# about 1 GB of stages.
_RELIEFS = {}


def forget_reliefs():
    """Drop the cached relief (the add-on's unregister, and a newly opened file)."""
    _RELIEFS.clear()


def relief_of(obj):
    """The core :class:`~cliff_terrain.build.Relief` of a relief object, rebuilt once and cached."""
    from ..cliff_terrain.errors import CliffTerrainError

    record = Record.of(obj)
    key = (obj.name, json.dumps(record.as_properties(), sort_keys=True, default=str))
    if key in _RELIEFS:
        return _RELIEFS[key]
    from ..cliff_terrain.build import build_relief
    from ..cliff_terrain.params import ReliefParams

    params = ReliefParams.from_properties(record.file_params())
    relief = build_relief(record.source_file, params, mesh=None)
    if record.mask_digest and relief.mask_digest != record.mask_digest:
        raise CliffTerrainError(
            f"{record.source!r} no longer gives the relief {obj.name!r} was built from (the photo "
            "or Cliff Terrain changed): build it again to probe it"
        )
    _RELIEFS.clear()
    _RELIEFS[key] = relief
    return relief


def hit_from_above(obj, world_xy):
    """Local hit point on `obj` of a vertical ray down through world (x, y), or None."""
    bounds = [obj.matrix_world @ Vector(corner) for corner in obj.bound_box]
    top = max(c.z for c in bounds) + 1.0
    bottom = min(c.z for c in bounds) - 1.0
    return hit_along(obj, Vector((world_xy[0], world_xy[1], top)), Vector((0.0, 0.0, bottom - top)))


def hit_along(obj, origin, direction):
    """Local hit point on `obj` of a world-space ray (the first face it meets), or None."""
    inverse = obj.matrix_world.inverted()
    local_origin = inverse @ origin
    local_direction = (inverse.to_3x3() @ direction).normalized()
    hit, location, _normal, _face = obj.ray_cast(local_origin, local_direction)
    return location if hit else None


def pixel_of(record, local):
    """(row, col) of the relief's processing grid under a local point, or None outside the grid.

    `record`: the relief's :class:`~.record.Record`. The mesh's x grows with the column from 0, y
    with the rows upwards (the top row has the largest y); one processing pixel is ``pixel_size``
    core units, times ``blender_units_per_unit``.
    """
    size = record.blender_pixel
    rows, cols = record.grid_shape
    # A point on the grid's last edge (up to a millionth of a pixel out) belongs to the last pixel.
    tolerance = 1e-6 * size
    if not (
        -tolerance <= local.x <= cols * size + tolerance and -tolerance <= local.y <= rows * size + tolerance
    ):
        return None
    (row,), (col,) = grid_cells(record, [(local.x, local.y)])
    return int(row), int(col)


def grid_cells(record, local_xy):
    """(rows, cols) arrays of the processing-grid pixels under local (x, y) points, clipped to the grid
    (the mesh's frame: see :func:`pixel_of`)."""
    import numpy as np

    size = record.blender_pixel
    rows, cols = record.grid_shape
    # In the points' own precision (a mesh's float32 positions, a probe's float64 point): a vertex on
    # a pixel edge falls on the side its float32 quotient gives, as Color By has always read it.
    xy = np.asarray(local_xy).reshape(-1, 2) / size
    col = np.clip(np.floor(xy[:, 0]).astype(np.int64), 0, cols - 1)
    row = np.clip(rows - 1 - np.floor(xy[:, 1]).astype(np.int64), 0, rows - 1)
    return row, col


def probe(obj, local):
    """The relief's values at a local point of relief object `obj` (a dict; see ``PROBE_KEY``).

    Keys: ``height`` (the relief's height raster there, as the mesh shows it), ``ground`` (the
    ground's elevation with a surface model, else 0: the relief's base), ``unit`` (``"m"`` or
    ``"px"``), ``region`` (the plant's number, 0 on soil), the region's ``region_p50``,
    ``region_p90`` and ``region_area`` (in ``area_unit``), the ``row`` and ``col`` of the pixel, and
    with a surface model the measured ``canopy_height`` (and, with an estimated ground, its standard
    error ``ground_err``, which is the canopy height's too).
    """
    import numpy as np

    from ..cliff_terrain.errors import CliffTerrainError
    from ..cliff_terrain.measure.field_plots import region_figures

    record = Record.of(obj)
    if problem := record.frame_error(obj):
        raise CliffTerrainError(problem)
    pixel = pixel_of(record, local)
    if pixel is None:
        raise CliffTerrainError(f"the point is outside the relief {obj.name!r}")
    relief = relief_of(obj)
    row, col = pixel
    unit = relief.units
    values = {
        "height": float(relief.heights[row, col]),
        "ground": 0.0,
        "unit": unit,
        "row": row,
        "col": col,
        "exaggeration": float(relief.params.get("exaggeration") or 1.0),
    }
    canopy = relief.canopy
    if canopy is not None:
        # NaN where the surface model has no data.
        values["ground"] = float(canopy.ground[row, col])
        values["canopy_height"] = float(canopy.chm[row, col])
        if canopy.sigma is not None:  # an estimated ground: its standard error there
            values["ground_err"] = float(canopy.sigma[row, col])
    region = int(relief.labels[row, col])
    values["region"] = region
    if region:
        pixel_area = float(relief.pixel_size) ** 2
        (figure,) = region_figures(
            (relief.labels == region).astype(np.int32),
            1,
            mask=relief.mask,
            heights=relief.heights,
            pixel_area_m2=pixel_area,
        )
        values.update(
            region_p50=figure["height_p50_m"],
            region_p90=figure["height_p90_m"],
            region_area=figure["area_m2"],
        )
    values["area_unit"] = "m²" if unit == "m" else "px²"
    return values


def length_text(value, unit):
    """A height with its unit: cm under 1 m, m above; pixels as px."""
    if unit != "m":
        return f"{value:.3g} px"
    return f"{value * 100:.1f} cm" if abs(value) < 1.0 else f"{value:.3f} m"


def probe_lines(values):
    """The probe's values as short lines (the status bar joins them, the panel shows them)."""
    unit = values["unit"]
    lines = [f"Height {length_text(values['height'], unit)}"]
    if values.get("exaggeration", 1.0) != 1.0:
        lines[0] += f" (x{values['exaggeration']:g} exaggerated)"
    if "canopy_height" in values:
        ground, canopy = values["ground"], values["canopy_height"]
        if ground != ground or canopy != canopy:  # NaN: no surface model there
            lines.append("Ground: the surface model has no data here")
        else:
            err = values.get("ground_err")
            sure = "" if err is None or err != err else f" ± {length_text(err, 'm')}"
            lines.append(f"Ground {ground:.2f} m, canopy {length_text(canopy, 'm')}{sure}")
    else:
        lines.append(f"Ground {length_text(values['ground'], unit)} (the relief's base)")
    if values.get("region"):
        area = values["region_area"]
        area_text = f"{area:.3g} m²" if unit == "m" else f"{area:.0f} px²"
        # Two short lines: the sidebar is narrow.
        lines.append(f"Plant {values['region']}, area {area_text}")
        lines.append(
            f"Plant p50 {length_text(values['region_p50'], unit)}, p90 {length_text(values['region_p90'], unit)}"
        )
    else:
        lines.append("Soil (no plant)")
    return lines
