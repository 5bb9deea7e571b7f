"""Figures of a relief object: cameras that frame it, a calibrated light, render settings, and the
comparison of the top views with the photo. Used by the Render Views and Evaluate operators and by
``render_views.py``.

Choices, each measured (figures in the report of issue 4):

* **Top views are pixel-aligned with the photo**: an orthographic camera over the middle of the relief,
  ``ortho_scale`` = its longer side, a resolution with the relief's aspect, the "Standard" view
  transform, no look, exposure 0, gamma 1 and no dither. The mesh has vertices at pixel corners, so
  pixel (r, c) of the render covers pixel (r, c) of the photo resized to the render resolution.
* **The flat top view (xy_flat) is always a Cycles render** of the texture as emission (nearest-texel
  lookups, a 1-pixel box filter, 16 samples): the mean of the samples is the photo averaged over
  each output pixel. Workbench and EEVEE sample the full-resolution texture without mip-mapping in
  background mode and alias (36.6 dB on a 3600 x 2700 photo rendered at 1000 x 750; 47 dB against
  Cycles' 56 dB with 16 anti-aliasing samples on the 12 MP photo, at twice the time).
* **The reference is the photo area-averaged in linear light** (OpenCV ``INTER_AREA`` between sRGB
  decoding and encoding), as a renderer averages texels: averaging the sRGB code values instead makes
  every high-contrast edge darker than any render of it (8 dB on the soybean orthophotos' black
  no-data borders). At the photo's own size the reference is the photo itself.
* **The lit views use a sun and a uniform white sky calibrated so level ground renders at its albedo**:
  ``sun_strength * sin(elevation) / pi + ambient = 1`` for a matte (Lambertian) surface, with direct
  light only (no bounces); a fully level relief renders exactly as the flat view. The material's
  specular layer is switched off for the render (the photo already holds the real light; a 4 % white
  reflection greys every dark pixel). The sun comes from the north-west (the upper left of the image,
  the cartographic convention that keeps relief from reading inverted) at 70 degrees with 40 % sky
  light. On the densest canopy of the shared photos (mature broccoli, 42 % of it sloped over 15
  degrees) this keeps PSNR above 20 dB and SSIM above 0.90 while slopes differ from the flat view by
  about 25 grey levels against 2 on level ground; lower suns (45-60 degrees) or less sky light
  (35 %) fall under 20 dB there.
"""

from __future__ import annotations

import ctypes.util
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field

import bpy
import numpy as np
from mathutils import Vector

from .material import empty_node_tree

# Views in the order they are rendered (Cycles keeps its scene data between them).
VIEW_FILES = {
    "xy_flat": "xy_flat.png",
    "xy": "xy.png",
    "xz": "xz.png",
    "view3d": "view3d.png",
    "mesh": "mesh.png",
}
ENGINES = ("CYCLES", "WORKBENCH", "EEVEE")

# The light: where the sun comes from (compass degrees, 0 = north = the image's top, 90 = east) and
# how high, and the share of the sky light on level ground.
SUN_AZIMUTH = 315.0
SUN_ELEVATION = 70.0
AMBIENT = 0.4
# The sun's angular diameter: shadows as soft as real ones.
SUN_ANGLE = math.radians(0.53)
# Samples per pixel of the lit Cycles views; fewer leave the sky-light shadows noisy (SSIM drops by
# about 0.01 at 8 on dense canopies).
SAMPLES = 16
FLAT_SAMPLES = 16
# The perspective view: from the south-west, 35 degrees above the horizon, 4:3 frame.
VIEW3D_AZIMUTH = 225.0
VIEW3D_ELEVATION = 35.0
VIEW3D_LENS_MM = 50.0
VIEW3D_ASPECT = 4 / 3
# Frame margin of the side and perspective views (share of the frame).
MARGIN = 0.04
# Slopes (degrees) that count as sloped and as level when measuring how much the shading shows.
SLOPED_DEG = 15.0
LEVEL_DEG = 2.0

# Longest side of a rendered view.
MAX_RESOLUTION = 16384
# The top views are compared with the photo by SSIM, whose 7x7 window needs 7 pixels on each side;
# by default a tiny or thin photo's views are enlarged until their shorter side has MIN_VIEW_SIDE
# pixels (a 2x2 photo would otherwise render 2x2 views that cannot be compared).
SSIM_MIN_SIDE = 7
MIN_VIEW_SIDE = 16
RIG_COLLECTION = "Cliff Terrain Views"
WORLD_NAME = "Cliff Terrain Sky"
HEIGHT_ATTRIBUTE = "Cliff Terrain Height"
# Rec. 709 luma of sRGB values (the shading measure compares brightness, not hue).
LUMA = np.array([0.2126, 0.7152, 0.0722])


# --------------------------------------------------------------------------------------------
# Engines
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# Cameras and light
# --------------------------------------------------------------------------------------------


@dataclass
class Bounds:
    """World-space box of the relief."""

    xmin: float
    xmax: float
    ymin: float
    ymax: float
    zmin: float
    zmax: float

    @property
    def size(self):
        return self.xmax - self.xmin, self.ymax - self.ymin, self.zmax - self.zmin

    @property
    def centre(self):
        return Vector(((self.xmin + self.xmax) / 2, (self.ymin + self.ymax) / 2, (self.zmin + self.zmax) / 2))

    def corners(self):
        return [
            Vector((x, y, z))
            for x in (self.xmin, self.xmax)
            for y in (self.ymin, self.ymax)
            for z in (self.zmin, self.zmax)
        ]


def relief_bounds(obj):
    """The box around `obj` in world space (the relief is not rotated: x, y stay the photo's axes)."""
    points = np.array([tuple(obj.matrix_world @ Vector(corner)) for corner in obj.bound_box])
    lo, hi = points.min(axis=0), points.max(axis=0)
    return Bounds(*(float(v) for v in (lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])))


def frame_size(width, height, longest):
    """Pixels (columns, rows) with the aspect `width` : `height` and the longer side `longest`."""
    if width >= height:
        return longest, max(1, round(longest * height / width))
    return max(1, round(longest * width / height)), longest


@dataclass
class ViewRig:
    """The cameras and light of one relief, and the frame size of each view."""

    obj: object
    bounds: Bounds
    cameras: dict  # view name -> camera object
    sizes: dict  # view name -> (columns, rows)
    sun: object
    world: object
    light: dict = field(default_factory=dict)
    aspects: dict = field(default_factory=dict)  # view name -> (pixel_aspect_x, pixel_aspect_y)


def make_rig(
    context,
    obj,
    *,
    resolution,
    sun_azimuth=SUN_AZIMUTH,
    sun_elevation=SUN_ELEVATION,
    ambient=AMBIENT,
):
    """Cameras for every view and the calibrated sun and sky, in the collection ``Cliff Terrain Views``.

    A rig left by an earlier call is replaced. The scene's world becomes the rig's sky.

    Parameters
    ----------
    context : bpy.types.Context
    obj : bpy.types.Object
        The relief.
    resolution : int
        Longest side of each view in pixels.
    sun_azimuth, sun_elevation : float, optional
        Where the sun comes from, in degrees (azimuth clockwise from north = the image's top).
    ambient : float, optional
        Share of the sky light on level ground, in [0, 1); the sun gives the rest.

    Returns
    -------
    ViewRig
    """
    if not 0.0 <= ambient < 1.0:
        raise ValueError(f"`ambient` must be in [0, 1), got {ambient}")
    if not 0.0 < sun_elevation <= 90.0:
        raise ValueError(f"`sun_elevation` must be in (0, 90] degrees, got {sun_elevation}")
    scene = context.scene
    remove_rig(scene)
    collection = bpy.data.collections.new(RIG_COLLECTION)
    scene.collection.children.link(collection)
    bounds = relief_bounds(obj)
    width, depth, height = bounds.size
    centre = bounds.centre
    longest = max(width, depth)
    pad = 0.1 * longest + 1e-3

    cameras, sizes = {}, {}

    # Top: looking down -z, image up = +y = the photo's top row.
    top = _camera(collection, "Cliff Terrain Top", "ORTHO")
    top.data.ortho_scale = longest
    top.location = (centre.x, centre.y, bounds.zmax + pad)
    top.rotation_euler = (0.0, 0.0, 0.0)
    top.data.clip_start = pad / 2
    top.data.clip_end = height + 2 * pad
    sizes["xy"] = sizes["xy_flat"] = frame_size(width, depth, resolution)
    # A rounded frame size cannot hold the relief's aspect exactly (284 x 261 at 128 pixels is
    # 128 x 117.6): pixels a hair off square make the frame span the relief exactly in both
    # directions, as the reference's independent row and column scales do.
    cols, rows = sizes["xy"]
    ratio = (width * rows) / (depth * cols)
    top_aspect = (ratio, 1.0) if ratio >= 1.0 else (1.0, 1.0 / ratio)
    cameras["xy"] = cameras["xy_flat"] = top

    # Side: from the south (the image's bottom edge) looking north, x to the right, z up.
    side = _camera(collection, "Cliff Terrain Side", "ORTHO")
    frame_w, frame_h = width / (1 - 2 * MARGIN), max(height, 1e-6 * longest) / (1 - 2 * MARGIN)
    side.data.ortho_scale = max(frame_w, frame_h)
    side.location = (centre.x, bounds.ymin - pad, centre.z)
    side.rotation_euler = (math.pi / 2, 0.0, 0.0)
    side.data.clip_start = pad / 2
    side.data.clip_end = depth + 2 * pad
    cols, rows = frame_size(frame_w, frame_h, resolution)
    sizes["xz"] = (cols, max(rows, 16))
    cameras["xz"] = side

    # Perspective: the whole relief, seen from VIEW3D_AZIMUTH and VIEW3D_ELEVATION.
    persp = _camera(collection, "Cliff Terrain Perspective", "PERSP")
    persp.data.lens = VIEW3D_LENS_MM
    persp.data.sensor_fit = "HORIZONTAL"
    sizes["view3d"] = sizes["mesh"] = frame_size(VIEW3D_ASPECT, 1.0, resolution)
    _aim_perspective(persp, bounds, sizes["view3d"])
    cameras["view3d"] = cameras["mesh"] = persp

    sun, world, light = _light(scene, collection, sun_azimuth, sun_elevation, ambient)
    return ViewRig(
        obj=obj,
        bounds=bounds,
        cameras=cameras,
        sizes=sizes,
        sun=sun,
        world=world,
        light=light,
        aspects={"xy": top_aspect, "xy_flat": top_aspect},
    )


def remove_rig(scene):
    """Remove the cameras and sun of an earlier rig (the collection ``Cliff Terrain Views``)."""
    collection = bpy.data.collections.get(RIG_COLLECTION)
    if collection is None:
        return
    for obj in list(collection.objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            if isinstance(data, bpy.types.Camera):
                bpy.data.cameras.remove(data)
            elif isinstance(data, bpy.types.Light):
                bpy.data.lights.remove(data)
    bpy.data.collections.remove(collection)


def _camera(collection, name, kind):
    data = bpy.data.cameras.new(name)
    data.type = kind
    data.sensor_fit = "AUTO"
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    return obj


def _direction(azimuth_deg, elevation_deg):
    """Unit vector towards a compass azimuth (0 = +y, 90 = +x) at an elevation above the horizon."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return Vector((math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)))


def _aim_perspective(camera, bounds, size):
    """Place `camera` so the whole box fills its frame (with MARGIN), looking at the box's centre."""
    view_dir = -_direction(VIEW3D_AZIMUTH, VIEW3D_ELEVATION)
    rotation = view_dir.to_track_quat("-Z", "Y")
    camera.rotation_euler = rotation.to_euler()
    right = rotation @ Vector((1.0, 0.0, 0.0))
    up = rotation @ Vector((0.0, 1.0, 0.0))
    cols, rows = size
    half_w = camera.data.sensor_width / (2 * camera.data.lens)  # tangent of half the field of view
    half_h = half_w * rows / cols
    centre = bounds.centre
    corners = [(q.dot(right), q.dot(up), q.dot(view_dir)) for q in (c - centre for c in bounds.corners())]

    def extents(distance):
        """Tangent-space box of the corners seen from centre - view_dir * distance."""
        u = [x / (z + distance) for x, _, z in corners]
        v = [y / (z + distance) for _, y, z in corners]
        return min(u), max(u), min(v), max(v)

    def fits(distance):
        u0, u1, v0, v1 = extents(distance)
        return u1 - u0 <= 2 * half_w * (1 - 2 * MARGIN) and v1 - v0 <= 2 * half_h * (1 - 2 * MARGIN)

    # Symmetric fit first (every corner within the margin around the centre: it always fits) ...
    far = max(
        max(abs(x) / (half_w * (1 - 2 * MARGIN)) - z, abs(y) / (half_h * (1 - 2 * MARGIN)) - z)
        for x, y, z in corners
    )
    near = max(-z for _, _, z in corners) + 1e-6 * max(bounds.size)
    # ... then the nearest camera whose view, shifted to centre the relief, still holds it all:
    # perspective makes the near side look larger, so centring on the box's middle wastes the top.
    for _ in range(40):
        middle = 0.5 * (near + far)
        near, far = (near, middle) if fits(middle) else (middle, far)
    distance = far
    u0, u1, v0, v1 = extents(distance)
    # Lens shift is in units of the (horizontal) sensor width; the tangent frame is 2 * half_w wide.
    camera.data.shift_x = 0.5 * (u0 + u1) / (2 * half_w)
    camera.data.shift_y = 0.5 * (v0 + v1) / (2 * half_w)
    camera.location = centre - view_dir * distance
    span = max(bounds.size)
    camera.data.clip_start = max(distance - span, distance * 1e-3)
    camera.data.clip_end = distance + span


def _light(scene, collection, azimuth, elevation, ambient):
    """The calibrated sun and sky: level matte ground renders at its albedo."""
    sun_strength = (1.0 - ambient) * math.pi / math.sin(math.radians(elevation))
    data = bpy.data.lights.new("Cliff Terrain Sun", "SUN")
    data.energy = sun_strength
    data.angle = SUN_ANGLE
    data.color = (1.0, 1.0, 1.0)
    sun = bpy.data.objects.new("Cliff Terrain Sun", data)
    collection.objects.link(sun)
    sun.rotation_euler = (-_direction(azimuth, elevation)).to_track_quat("-Z", "Y").to_euler()

    world = bpy.data.worlds.get(WORLD_NAME) or bpy.data.worlds.new(WORLD_NAME)
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True  # always on (and deprecated) from Blender 5.0
    nodes = world.node_tree.nodes
    background = next((n for n in nodes if n.bl_idname == "ShaderNodeBackground"), None)
    if background is None:
        background = nodes.new("ShaderNodeBackground")
        output = next((n for n in nodes if n.bl_idname == "ShaderNodeOutputWorld"), None)
        output = output or nodes.new("ShaderNodeOutputWorld")
        world.node_tree.links.new(background.outputs["Background"], output.inputs["Surface"])
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    background.inputs["Strength"].default_value = ambient
    # Workbench shows this through transparent (no-data) texels: black, as the core fills them.
    world.color = (0.0, 0.0, 0.0)
    scene.world = world
    light = {
        "sun_azimuth_deg": azimuth,
        "sun_elevation_deg": elevation,
        "ambient": ambient,
        "sun_strength": sun_strength,
        "calibration": "sun_strength * sin(elevation) / pi + ambient = 1 (level matte ground at its albedo)",
    }
    return sun, world, light


# --------------------------------------------------------------------------------------------
# Materials for the renders
# --------------------------------------------------------------------------------------------


def relief_image(obj):
    """The photo a relief's material shows (its Image Texture node's image), or None."""
    material = obj.active_material
    if material is None or material.node_tree is None:
        return None
    for node in material.node_tree.nodes:
        if node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
            return node.image
    return None


def make_matte(material):
    """Switch off the specular layer of every Principled BSDF of `material` (a photo is already lit)."""
    if material is None or material.node_tree is None:
        return
    for node in material.node_tree.nodes:
        if node.bl_idname == "ShaderNodeBsdfPrincipled":
            for name in ("Specular IOR Level", "Specular"):
                socket = node.inputs.get(name)
                if socket is not None:
                    socket.default_value = 0.0
                    break


def flat_material(image, uv_name="UVMap"):
    """A material that emits the photo as it is: the flat top view (no shading at all)."""
    material = bpy.data.materials.get("Cliff Terrain Flat") or bpy.data.materials.new("Cliff Terrain Flat")
    tree = empty_node_tree(material)
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = uv_name
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.extension = "REPEAT"
    # Nearest texels: the 1-pixel box filter then averages the photo over each output pixel, as
    # an area resize does; bilinear lookups would blur it a little more.
    tex.interpolation = "Closest"
    emit = tree.nodes.new("ShaderNodeEmission")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], emit.inputs["Color"])
    tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    # Not a light: Cycles would otherwise build a light distribution over every triangle of the
    # relief before each render (about 5 s for 1.5 M triangles).
    material.cycles.emission_sampling = "NONE"
    return material


def height_material():
    """A matte material coloured by the height colour attribute (the mesh view rendered by Cycles)."""
    material = bpy.data.materials.get("Cliff Terrain Height") or bpy.data.materials.new(
        "Cliff Terrain Height"
    )
    tree = empty_node_tree(material)
    colour = tree.nodes.new("ShaderNodeVertexColor")
    colour.layer_name = HEIGHT_ATTRIBUTE
    bsdf = tree.nodes.new("ShaderNodeBsdfDiffuse")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(colour.outputs["Color"], bsdf.inputs["Color"])
    tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return material


# A colour map in the spirit of MATLAB's mesh plots (jet): low = dark blue, high = dark red.
_JET = np.array(
    [
        (0.0, 0.0, 0.0, 0.56),
        (0.11, 0.0, 0.0, 1.0),
        (0.36, 0.0, 1.0, 1.0),
        (0.61, 1.0, 1.0, 0.0),
        (0.86, 1.0, 0.0, 0.0),
        (1.0, 0.5, 0.0, 0.0),
    ]
)


def height_colours(t):
    """sRGB colours (n, 3) in [0, 1] of heights `t` scaled to [0, 1] (jet colour map)."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return np.stack([np.interp(t, _JET[:, 0], _JET[:, k]) for k in (1, 2, 3)], axis=-1)


def add_height_colours(mesh):
    """Colour every vertex of `mesh` by its height (z from 0 to the highest vertex) as a colour attribute.

    Returns the attribute (active for display, so Workbench's Attribute colour mode shows it).
    """
    n = len(mesh.vertices)
    z = np.empty(3 * n, dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", z)
    z = z[2::3]
    top = float(z.max(initial=0.0))
    t = z / top if top > 0 else np.zeros_like(z)
    rgba = np.ones((n, 4), dtype=np.float32)
    rgba[:, :3] = height_colours(t)
    attribute = mesh.color_attributes.get(HEIGHT_ATTRIBUTE)
    if attribute is not None:
        mesh.color_attributes.remove(attribute)
    attribute = mesh.color_attributes.new(HEIGHT_ATTRIBUTE, "BYTE_COLOR", "POINT")
    attribute.data.foreach_set("color_srgb", rgba.ravel())
    mesh.color_attributes.active_color = attribute
    return attribute


# --------------------------------------------------------------------------------------------
# Render settings and rendering
# --------------------------------------------------------------------------------------------


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


def render_to(scene, path, *, quiet=False):
    """Render the scene's camera into the PNG `path`.

    It is rendered into a temporary folder first, so Blender's ``#`` frame placeholders and ``//``
    prefixes in `path` mean nothing. `quiet` silences Blender's per-sample progress lines (printed
    to standard output in background mode) for the duration of the render.
    """
    folder = tempfile.mkdtemp(prefix="cliff_terrain_render_")
    try:
        scene.render.filepath = os.path.join(folder, "view.png")
        scene.render.use_file_extension = True
        with _silenced_stdout(quiet):
            bpy.ops.render.render(write_still=True)
        shutil.move(os.path.join(folder, "view.png"), path)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return path


class _silenced_stdout:
    """Point file descriptor 1 at the null device (Blender prints from C, past sys.stdout)."""

    def __init__(self, active):
        self.active = active

    def __enter__(self):
        if self.active:
            sys.stdout.flush()
            self.saved = os.dup(1)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.close(null)
        return self

    def __exit__(self, *exc):
        if self.active:
            os.dup2(self.saved, 1)
            os.close(self.saved)
        return False


def render_view(context, rig, view, path, *, engine="CYCLES", samples=SAMPLES, quiet=False):
    """Render one view of `rig` ("xy", "xy_flat", "xz", "view3d" or "mesh") into the PNG `path`.

    The flat top view is always made by Cycles (see the module notes); the mesh view by Workbench
    when a GPU context is available, else by Cycles.
    """
    scene = context.scene
    view_layer = context.view_layer
    scene.camera = rig.cameras[view]
    size = rig.sizes[view]
    aspect = rig.aspects.get(view, (1.0, 1.0))
    override = None
    if view == "xy_flat":
        image = relief_image(rig.obj)
        if image is None:
            raise RuntimeError(f"{rig.obj.name!r} has no image texture to render flat")
        override = flat_material(image)
        configure(scene, "CYCLES", size=size, samples=FLAT_SAMPLES, aspect=aspect)
    elif view == "mesh":
        add_height_colours(rig.obj.data)
        if gpu_available():
            configure(scene, "WORKBENCH", size=size, transparent=True)
            shading = scene.display.shading
            shading.light = "STUDIO"  # a plot, not a photo: shaded so the surface reads in 3D
            shading.color_type = "VERTEX"
        else:
            override = height_material()
            configure(scene, "CYCLES", size=size, samples=samples, transparent=True)
    else:
        make_matte(rig.obj.active_material)
        configure(scene, engine, size=size, samples=samples, transparent=view != "xy", aspect=aspect)
    previous = view_layer.material_override
    view_layer.material_override = override
    try:
        return render_to(scene, path, quiet=quiet)
    finally:
        view_layer.material_override = previous


def render_views(
    context, rig, out_dir, *, views=tuple(VIEW_FILES), engine="CYCLES", samples=SAMPLES, log=None, quiet=False
):
    """Render `views` of `rig` into `out_dir` (file names from VIEW_FILES).

    Returns
    -------
    paths : dict
        View name -> written path.
    seconds : dict
        View name -> render time in seconds.
    """
    paths, seconds = {}, {}
    for view in views:
        if log is not None:
            cols, rows = rig.sizes[view]
            log(f"rendering {view} ({cols} x {rows})")
        start = time.perf_counter()
        paths[view] = render_view(
            context,
            rig,
            view,
            os.path.join(out_dir, VIEW_FILES[view]),
            engine=engine,
            samples=samples,
            quiet=quiet,
        )
        seconds[view] = time.perf_counter() - start
    return paths, seconds


def set_top_view(context, rig, engine="CYCLES", *, samples=SAMPLES):
    """Leave the scene set up for the lit top view (so F12 on the saved scene gives xy.png again)."""
    scene = context.scene
    scene.camera = rig.cameras["xy"]
    make_matte(rig.obj.active_material)
    configure(scene, engine, size=rig.sizes["xy"], samples=samples, aspect=rig.aspects["xy"])
    scene.render.filepath = "//xy.png"


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
    """Context manager: the scene's camera and render settings are as before when it exits."""

    def __init__(self, scene):
        self.scene = scene

    def _owner(self, path):
        owner = self.scene
        for part in path.split("."):
            owner = getattr(owner, part, None)
            if owner is None:
                return None
        return owner

    def __enter__(self):
        self.camera = self.scene.camera
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
                    self.values.append((owner, name, value))
        return self

    def __exit__(self, *exc):
        for owner, name, value in self.values:
            try:
                setattr(owner, name, value)
            except (AttributeError, TypeError, ValueError):
                pass  # a setting another add-on's engine no longer accepts
        if self.camera is None or self.camera.name in bpy.data.objects:
            self.scene.camera = self.camera
        return False


# --------------------------------------------------------------------------------------------
# Evaluation of the top views (numpy only)
# --------------------------------------------------------------------------------------------


def front_corner_heights(obj, grid_shape):
    """Heights (z) of the relief's front grid, (rows + 1, cols + 1), in Blender units.

    The front vertices come first in the mesh, row by row from the photo's top (see
    cliff_terrain.mesh).
    """
    rows, cols = grid_shape
    n = (rows + 1) * (cols + 1)
    mesh = obj.data
    if len(mesh.vertices) < n:
        raise ValueError(f"{obj.name!r} has {len(mesh.vertices)} vertices, fewer than a {rows} x {cols} grid")
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", co)
    return co[2 : 3 * n : 3].reshape(rows + 1, cols + 1).astype(np.float64)


def slope_degrees(corner_heights, cell):
    """Slope of each grid cell in degrees from the heights at its corners (cell size `cell`)."""
    z = np.asarray(corner_heights, dtype=np.float64)
    dx = ((z[:-1, 1:] - z[:-1, :-1]) + (z[1:, 1:] - z[1:, :-1])) / (2 * cell)
    dy = ((z[:-1, :-1] - z[1:, :-1]) + (z[:-1, 1:] - z[1:, 1:])) / (2 * cell)
    return np.degrees(np.arctan(np.hypot(dx, dy)))


def resize_nearest(array, size):
    """`array` (rows, cols, ...) resampled to `size` = (cols', rows') by nearest pixel centres."""
    rows, cols = array.shape[:2]
    out_cols, out_rows = size
    r = np.minimum(((np.arange(out_rows) + 0.5) * rows / out_rows).astype(np.intp), rows - 1)
    c = np.minimum(((np.arange(out_cols) + 0.5) * cols / out_cols).astype(np.intp), cols - 1)
    return array[r[:, None], c[None, :]]


def shading_measure(lit, flat, slope):
    """How much the lit view's shading shows the relief.

    Mean absolute brightness difference (Rec. 709 luma, 8-bit grey levels) between the lit and the
    flat top views over sloped pixels (slope >= SLOPED_DEG) and over level ones (< LEVEL_DEG).

    Returns
    -------
    dict
        ``shading_sloped``, ``shading_level``, ``shading_contrast`` (their difference; None when
        nothing is sloped), ``sloped_fraction``.
    """
    diff = np.abs(lit[..., :3].astype(np.float64) @ LUMA - flat[..., :3].astype(np.float64) @ LUMA)
    sloped = slope >= SLOPED_DEG
    level = slope < LEVEL_DEG
    s = float(diff[sloped].mean()) if sloped.any() else None
    lv = float(diff[level].mean()) if level.any() else None
    return {
        "shading_sloped": s,
        "shading_level": lv,
        "shading_contrast": None if s is None or lv is None else s - lv,
        "sloped_fraction": float(sloped.mean()),
        "sloped_deg": SLOPED_DEG,
        "level_deg": LEVEL_DEG,
    }


def srgb_to_linear(rgb):
    """8-bit sRGB values to linear light, float32 in [0, 1] (the piecewise sRGB curve)."""
    c = np.arange(256, dtype=np.float64) / 255.0
    lut = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)
    return lut[rgb]


def linear_to_srgb(linear):
    """Linear light in [0, 1] to 8-bit sRGB values (rounded)."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.round(255.0 * srgb).astype(np.uint8)


def view_resolution(requested, rows, cols, *, name="resolution"):
    """Longest side of the views of a `rows` x `cols` grid: `requested`, or by default one view pixel
    per grid cell, enlarged (up to MAX_RESOLUTION) until the shorter side has MIN_VIEW_SIDE pixels.

    The shorter side is ``max(1, round(resolution * shorter / longer))``, as :func:`frame_size`
    makes it. A resolution that leaves it under SSIM_MIN_SIDE is refused with a CliffTerrainError
    naming the setting (`name`) and the resolution needed: the top views could not be compared
    with the photo. `requested` of None or 0 means the default.
    """
    from ..cliff_terrain import CliffTerrainError

    longest, shortest = max(rows, cols), min(rows, cols)
    if requested:
        resolution = int(requested)
    else:
        resolution = min(MAX_RESOLUTION, max(longest, -(-MIN_VIEW_SIDE * longest // shortest)))
    across = max(1, round(resolution * shortest / longest))
    if across < SSIM_MIN_SIDE:
        views = f"{across} pixel{'' if across == 1 else 's'} across the {cols} x {rows} grid"
        needed = -(-SSIM_MIN_SIDE * longest // shortest)
        if requested and needed <= MAX_RESOLUTION:
            raise CliffTerrainError(
                f"{name} {requested} makes the top views {views}; comparing them with the photo "
                f"needs at least {SSIM_MIN_SIDE}: use {name} {needed} or more"
            )
        raise CliffTerrainError(
            f"the photo is too thin to render: even {MAX_RESOLUTION} pixels long, the top views are "
            f"{views}; comparing them with the photo needs at least {SSIM_MIN_SIDE}"
        )
    return resolution


def reference_image(path, size):
    """The photo as the top views are compared with it, at the render size.

    The photo is read as the core reads it (EXIF orientation applied, transparent pixels black; a
    JPEG more than 4 times larger than the render is decoded reduced by 2, 4 or 8) and area-averaged
    (OpenCV INTER_AREA) to `size` in linear light, as a renderer averages texels: averaging the sRGB
    values instead makes every high-contrast edge darker than any render of it (up to 50 grey levels
    at a black no-data border, 8 dB on the soybean orthophotos).

    Parameters
    ----------
    path : str
    size : tuple of int
        (cols, rows) of the render.

    Returns
    -------
    reference : (rows, cols, 3) uint8 array
    description : str
        What the reference is, for metrics.json.
    """
    import cv2

    from ..cliff_terrain import load_image

    # (load_image's smallest max_size is 16: views of tiny photos are enlarged, not the photo.)
    rgb, meta = load_image(path, max_size=max(16, 4 * max(size)))
    how = "decoded at full resolution" if meta.reduction == 1 else f"decoded reduced by {meta.reduction}"
    if (rgb.shape[1], rgb.shape[0]) != tuple(size):
        rgb = linear_to_srgb(cv2.resize(srgb_to_linear(rgb), tuple(size), interpolation=cv2.INTER_AREA))
    return rgb, (
        f"the input photo {how}, area-resized (OpenCV INTER_AREA) in linear light to the render size "
        f"{size[0]}x{size[1]}"
    )


def read_png(path):
    """An 8-bit PNG as an array (rows, cols, channels)."""
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGBA" if "A" in image.mode else "RGB"))


def compare_top_views(reference, lit, flat, slope=None):
    """PSNR and SSIM of the lit and flat top views against `reference`, and the shading measure.

    Parameters
    ----------
    reference, lit, flat : (rows, cols, 3) uint8 arrays
    slope : (rows, cols) array, optional
        Slope in degrees of each rendered pixel.

    Returns
    -------
    dict
    """
    from ..cliff_terrain import psnr, ssim

    lit, flat = lit[..., :3], flat[..., :3]
    result = {
        "psnr_xy": psnr(reference, lit),
        "ssim_xy": ssim(reference, lit),
        "psnr_xy_flat": psnr(reference, flat),
        "ssim_xy_flat": ssim(reference, flat),
    }
    if slope is not None:
        result.update(shading_measure(lit, flat, slope))
    return result


def evaluate_relief(obj, rig, lit_path, flat_path, *, source=None):
    """Compare the rendered top views of relief `obj` with its photo (see :func:`compare_top_views`).

    Parameters
    ----------
    obj : bpy.types.Object
        A relief built by Cliff Terrain (its ``cliff_terrain`` record gives the photo and the grid).
    rig : ViewRig
    lit_path, flat_path : str
        The rendered lit and flat top views.
    source : str, optional
        The photo; default the one the relief was built from.

    Returns
    -------
    dict
        The metrics, plus ``reference`` (what the views were compared with) and ``render_size``.
    """
    record = obj["cliff_terrain"]
    size = rig.sizes["xy"]
    reference, description = reference_image(source or record["source"], size)
    grid = (int(record["grid_rows"]), int(record["grid_cols"]))
    width = rig.bounds.size[0]
    slope = slope_degrees(front_corner_heights(obj, grid), width / grid[1])
    metrics = compare_top_views(
        reference, read_png(lit_path), read_png(flat_path), resize_nearest(slope, size)
    )
    metrics["reference"] = description
    metrics["render_size"] = list(size)
    return metrics
