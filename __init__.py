"""Cliff Terrain: turn one UAV crop photo into a textured 3D relief (a Blender extension).

Only registration lives here. The Blender side is in ``operators/`` (scene settings and operators),
``scene/`` (what they put into a scene: the numpy-to-Blender mesh, materials, the view rig and render
settings; no classes) and ``panels/`` (the 3D Viewport sidebar); the bpy-free core that does the image
work is ``cliff_terrain/``.
"""

from . import operators, panels

# Registered in this order, unregistered in reverse: the panel draws the operators' settings.
_PACKAGES = (operators, panels)


def register():
    for package in _PACKAGES:
        package.register()


def unregister():
    for package in reversed(_PACKAGES):
        package.unregister()
