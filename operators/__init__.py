"""Blender operators of Cliff Terrain: the scene settings, Build Relief, Render Views, Evaluate, the
plot grid and inspecting (Probe Height, the colour bar).

What they put into the scene (mesh, materials, cameras, light, render settings) is in ``scene/``.
"""

from . import build, inspect, mosaic, plots, properties, render, render_job, season_animation

# The settings first: the build operator and the panel read them.
_MODULES = (properties, build, render, render_job, season_animation, mosaic, plots, inspect)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
