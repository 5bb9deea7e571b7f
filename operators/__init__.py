"""Blender operators of Cliff Terrain and what they share: scene settings, mesh and material builders.

``mesh_data`` and ``material`` hold no classes to register; the render script reuses them.
"""

from . import build, properties, render

# The settings first: the build operator and the panel read them.
_MODULES = (properties, build, render)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
