"""The relief objects the operators make, and the removal of what a failed build made.

Every new datablock goes into a ``created`` list as soon as it exists, so that
:func:`remove_datablocks` can leave the scene as it was when a later step fails.
:func:`remove_collection` removes a collection made earlier (the view rig, a season) with the data
only its objects used.
"""

import bpy

from .material import relief_material

# What an operator may create, each with the collection that removes it.
_COLLECTIONS = (
    ("objects", bpy.types.Object),
    ("meshes", bpy.types.Mesh),
    ("materials", bpy.types.Material),
    ("images", bpy.types.Image),
)


def textured_object(name, mesh, image, collection, *, created, extension="REPEAT"):
    """Give `mesh` a relief material showing `image` and link a new object `name` into `collection`.

    The material and the object are appended to `created`; the object is returned. `extension`
    is the texture's (see :func:`relief_material`).
    """
    material = relief_material(name, image, extension=extension)
    created.append(material)
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    created.append(obj)
    collection.objects.link(obj)
    return obj


def remove_datablocks(datablocks):
    """Remove what a failed build made, newest first (an object before its mesh and material)."""
    while datablocks:
        block = datablocks.pop()
        for attribute, kind in _COLLECTIONS:
            if isinstance(block, kind):
                getattr(bpy.data, attribute).remove(block)
                break


# Object data a removed collection's objects may leave unused, each with the collection that removes it.
_OBJECT_DATA = (
    ("meshes", bpy.types.Mesh),
    ("curves", bpy.types.Curve),
    ("cameras", bpy.types.Camera),
    ("lights", bpy.types.Light),
)


def remove_collection(name):
    """Remove the collection `name`, if any, its objects, and the data and materials only they used."""
    collection = bpy.data.collections.get(name)
    if collection is None:
        return
    for obj in list(collection.objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is None or data.users > 0:
            continue
        if isinstance(data, bpy.types.Mesh):
            for material in data.materials:
                if material is not None and material.users <= 1:
                    bpy.data.materials.remove(material)
        for attribute, kind in _OBJECT_DATA:
            if isinstance(data, kind):
                getattr(bpy.data, attribute).remove(data)
                break
    bpy.data.collections.remove(collection)
