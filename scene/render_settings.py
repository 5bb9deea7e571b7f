"""Render settings of the views: engine, frame, samples, colour management, and putting them back.

* **Colour management**: the "Standard" view transform, no look, exposure 0, gamma 1 and no dither,
  so a rendered pixel holds the texture's sRGB value.
* **The flat top view (xy_flat) is always a Cycles render** (16 samples, a 1-pixel box filter):
  Workbench and EEVEE sample the full-resolution texture without mip-mapping in background mode
  and alias (36.6 dB on a 3600 x 2700 photo rendered at 1000 x 750; 47 dB against Cycles' 56 dB
  with 16 anti-aliasing samples on the 12 MP photo, at twice the time).
"""

from __future__ import annotations

import ctypes.util
import sys

import bpy

from ..cliff_terrain.settings import DEFAULT_SAMPLES, ids
from ..cliff_terrain.settings import ENGINES as _ENGINE_CHOICES

ENGINES = ids(_ENGINE_CHOICES)
SAMPLES = DEFAULT_SAMPLES  # of the lit views
FLAT_SAMPLES = 16  # of the flat top view, whatever the lit views take


def engine_id(engine):
    """Blender's identifier of `engine` ("CYCLES", "WORKBENCH" or "EEVEE") in this Blender.

    EEVEE is ``BLENDER_EEVEE_NEXT`` in Blender 4.2-4.5 and ``BLENDER_EEVEE`` from 5.0.
    """
    if engine == "CYCLES":
        return "CYCLES"
    if engine == "WORKBENCH":
        return "BLENDER_WORKBENCH"
    if engine == "EEVEE":
        items = bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items.keys()
        eevee = [item for item in items if item.startswith("BLENDER_EEVEE")]
        return eevee[0] if eevee else "BLENDER_EEVEE"
    raise ValueError(f"`engine` must be one of {', '.join(ENGINES)}, got {engine!r}")


def gpu_available():
    """Whether Workbench and EEVEE can render here.

    Without a window (background mode) on Linux, Blender draws through EGL (libEGL with a Mesa
    driver); a machine without it can render only with Cycles.
    """
    if not bpy.app.background or not sys.platform.startswith("linux"):
        return True
    return ctypes.util.find_library("EGL") is not None


def choose_engine(engine, *, log=print):
    """The engine to render the lit views with: `engine`, or Cycles when it needs a GPU and has none."""
    if engine != "CYCLES" and not gpu_available():
        log(f"{engine} needs EGL (libegl-mesa0, libgl1-mesa-dri) to render without a display: using CYCLES")
        return "CYCLES"
    return engine


def set_colour_management(scene):
    """Output = the texture's sRGB values: Standard view, no look, exposure 0, gamma 1, no dither."""
    scene.display_settings.display_device = "sRGB"
    view = scene.view_settings
    view.view_transform = "Standard"
    view.look = "None"
    view.exposure = 0.0
    view.gamma = 1.0
    view.use_curve_mapping = False
    scene.render.dither_intensity = 0.0


def configure(scene, engine, *, size, samples=SAMPLES, transparent=False, aspect=(1.0, 1.0)):
    """Render settings of one view: `engine` ("CYCLES", "WORKBENCH", "EEVEE"), frame `size` (cols, rows),
    pixel `aspect` (x, y)."""
    render = scene.render
    render.engine = engine_id(engine)
    render.resolution_x, render.resolution_y = size
    render.resolution_percentage = 100
    render.pixel_aspect_x, render.pixel_aspect_y = aspect
    render.use_border = False
    render.film_transparent = transparent
    render.use_persistent_data = True  # the scene is synchronised once for all Cycles views
    render.use_compositing = False
    render.use_sequencer = False
    # Workbench and EEVEE anti-aliasing filter: one pixel wide.
    render.filter_size = 1.0
    settings = render.image_settings
    settings.file_format = "PNG"
    settings.color_mode = "RGBA" if transparent else "RGB"
    settings.color_depth = "8"
    settings.compression = 15
    set_colour_management(scene)
    if engine == "CYCLES":
        cycles = scene.cycles
        cycles.samples = samples
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.seed = 0
        cycles.use_animated_seed = False
        # Direct light only: the calibration (level ground at its albedo) holds exactly.
        for name in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces"):
            setattr(cycles, name, 0)
        # A one-pixel box: samples spread evenly over the pixel and nothing from its neighbours.
        cycles.pixel_filter_type = "BOX"
        cycles.filter_width = 1.0
    elif engine == "WORKBENCH":
        # Workbench has no calibrated light: the texture as it is, with cavity shading on ridges and
        # valleys (its studio light darkens every colour; its shadows streak level ground).
        display = scene.display
        display.render_aa = "8"
        shading = display.shading
        shading.light = "FLAT"
        shading.color_type = "TEXTURE"
        shading.show_specular_highlight = False
        shading.show_object_outline = False
        shading.show_shadows = False
        shading.show_cavity = True
        shading.cavity_type = "WORLD"
    else:
        scene.eevee.taa_render_samples = samples


# Render settings a Render Views or Evaluate operator changes and puts back afterwards.
_STATE = (
    ("render", ("engine", "resolution_x", "resolution_y", "resolution_percentage", "film_transparent")),
    ("render", ("pixel_aspect_x", "pixel_aspect_y")),
    ("render", ("use_persistent_data", "use_compositing", "use_sequencer", "filter_size", "filepath")),
    ("render", ("dither_intensity", "use_border", "use_file_extension")),
    ("render.image_settings", ("file_format", "color_mode", "color_depth", "compression")),
    ("view_settings", ("view_transform", "look", "exposure", "gamma", "use_curve_mapping")),
    ("display_settings", ("display_device",)),
    ("cycles", ("samples", "use_adaptive_sampling", "use_denoising", "seed", "use_animated_seed")),
    ("cycles", ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces")),
    ("cycles", ("pixel_filter_type", "filter_width")),
    ("display", ("render_aa",)),
    ("display.shading", ("light", "color_type", "show_specular_highlight", "show_cavity", "cavity_type")),
    ("display.shading", ("show_object_outline", "show_shadows", "shadow_intensity")),
    ("eevee", ("taa_render_samples",)),
)


class KeptRenderSettings:
    """Context manager: the scene's camera, world and render settings are as before when it exits
    (the rig's sky replaces the world while the views render: the user's HDRI comes back).

        A setting that cannot be put back (a value another add-on's engine no longer accepts) is
        listed in `not_restored` as ``"path.name"`` and passed to `log` in one message.
    """

    def __init__(self, scene, *, log=None):
        self.scene = scene
        self.log = log
        self.not_restored = []

    def _owner(self, path):
        owner = self.scene
        for part in path.split("."):
            owner = getattr(owner, part, None)
            if owner is None:
                return None
        return owner

    def __enter__(self):
        self.camera = self.scene.camera
        self.world = self.scene.world
        self.values = []
        for path, names in _STATE:
            owner = self._owner(path)
            if owner is None:
                continue
            for name in names:
                if hasattr(owner, name):
                    value = getattr(owner, name)
                    if hasattr(value, "__len__") and not isinstance(value, str):
                        value = tuple(value)
                    self.values.append((path, owner, name, value))
        return self

    def __exit__(self, *exc):
        for path, owner, name, value in self.values:
            try:
                setattr(owner, name, value)
            except (AttributeError, TypeError, ValueError):
                self.not_restored.append(f"{path}.{name}")
        if self.not_restored and self.log is not None:
            self.log(f"render settings not put back: {', '.join(self.not_restored)}")
        if self.camera is None or self.camera.name in bpy.data.objects:
            self.scene.camera = self.camera
        if self.world is None or self.world.name in bpy.data.worlds:
            self.scene.world = self.world
        return False
