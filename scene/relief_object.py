"""The relief object of a build: its mesh, material and photo, linked to the active collection,
with its record (:mod:`.record`), placed at the 3D cursor, selected and made active.

Made by the Build Relief operator and by ``render_views.py`` alike. Sizes: metres when the ground
sampling distance is known (1 Blender unit = 1 m), otherwise "normalised units" (the longest side is
``NORMALISED_SIZE`` Blender units; the factor is the record's ``blender_units_per_unit``).
"""

from pathlib import Path

from .datablocks import textured_object
from .material import load_photo
from .mesh_data import mesh_from_arrays, set_positions
from .record import write_record

# Without a known ground sampling distance the relief is scaled so its longest side is this many
# Blender units ("normalised units"); with one, 1 Blender unit = 1 metre.
NORMALISED_SIZE = 10.0


def relief_scale(relief):
    """Blender units per core unit: 1 for metres, else the longest side becomes NORMALISED_SIZE."""
    if relief.units == "m":
        return 1.0
    rows, cols = relief.mesh.grid_shape
    return NORMALISED_SIZE / (max(rows, cols) * float(relief.pixel_size))


def relief_name(path):
    """Name of the relief object (and its mesh, material and image): the photo's file name."""
    return Path(path).stem or "relief"


def build_relief_object(context, relief, path, params, *, created, mesh=None, figures=None):
    """Make the relief's mesh, material and object, linked to the active collection.

    Every new datablock is appended to `created` as soon as it exists, so the caller can remove them
    all if a later step fails. `mesh`, if given, is the relief's mesh with its faces, edges and UVs
    filled (already in `created`) and only needs its vertices placed. `figures`, if given, are
    :func:`.record.record_figures` of the relief.
    """
    name = relief_name(path)
    scale = relief_scale(relief)
    if mesh is None:
        mesh = mesh_from_arrays(name, relief.mesh, scale=scale)
        created.append(mesh)
    else:
        set_positions(mesh, relief.mesh.vertices, scale=scale)
    image, image_created = load_photo(path, metadata=relief.metadata, fallback_rgb=relief.image, name=name)
    if image_created:
        created.append(image)
    obj = textured_object(name, mesh, image, context.collection or context.scene.collection, created=created)
    write_record(obj, relief, path, params, scale, figures=figures)
    obj.location = context.scene.cursor.location
    for other in context.view_layer.objects.selected:
        other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
    return obj
