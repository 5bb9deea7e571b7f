"""A season of flights as an animation: one relief per date in one scene, shown one date per frame.

Reads what ``cliff-terrain season`` wrote (``season.json`` and the cached height grids, through
:mod:`cliff_terrain.season.reader`); it never runs Dask. Each date's relief is placed by its
georeference (map coordinates less a common origin, so the dates line up), textured with its
photo, and visible on its own frame only; the timeline has a marker per date, which Blender's
render stamp writes into every frame as the date label. Plot outlines are optional. Used by the
Season Animation operator and ``render_season.py``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from ..cliff_terrain.errors import CliffTerrainError
from ..cliff_terrain.measure.field_plots import rasterize_plots
from ..cliff_terrain.mesh.grid import grid_mesh
from .colour_by import photo_where_transparent, set_vertex_colours
from .datablocks import remove_collection
from .material import load_photo, relief_material
from .mesh_data import mesh_from_arrays
from .render_settings import engine_id, gpu_available, set_colour_management

COLLECTION = "Cliff Terrain Season"
# The scene the season is built in: its own, so that the user's scene keeps its timeline markers,
# frame range, camera and render settings (they were all replaced).
SEASON_SCENE = "Cliff Terrain Season"
CAMERA = "Season Camera"
VIDEO_SCENE = "Cliff Terrain Season Video"
FRAMES_DIR = "frames"
VIDEO_NAME = "season.mp4"
# Looking north from the south, this far above the horizon: the reliefs read as reliefs.
ELEVATION_DEG = 55.0
OUTLINE_RGBA = (1.0, 0.85, 0.1, 1.0)


@dataclass
class SeasonScene:
    """What :func:`build_season_scene` made."""

    scene: bpy.types.Scene
    reliefs: list  # one object per date, in date order
    dates: list  # ISO dates, in frame order (frame 1 is the first)
    camera: bpy.types.Object
    outlines: bpy.types.Object | None
    origin: tuple  # map (x, y) at the scene's (0, 0)
    failed: list = field(default_factory=list)


def build_season_scene(
    context,
    season,
    *,
    plots=None,
    colours=None,
    colour_plots=None,
    size=(1280, 720),
    engine="WORKBENCH",
    progress=None,
):
    """Build the season's animation in a scene of its own, ``Cliff Terrain Season`` (replacing an
    earlier season's), shown in the context's window: the user's scene is left as it was.

    Parameters
    ----------
    context : bpy.types.Context
    season : cliff_terrain.season.reader.SeasonOutputs
    plots : cliff_terrain.io.vector.plot_polygons.PlotSet, optional
        Plot outlines to draw (in the season's CRS).
    colours : cliff_terrain.season.reader.PlotColours, optional
        Colour each date's relief inside each plot by its value (viridis, one scale for the season);
        outside the plots, and in a plot without a value, the photo stays. The scale is stamped on
        every frame.
    colour_plots : cliff_terrain.measure.field_plots.PlotSet, optional
        The plots `colours` refers to (default `plots`).
    size : (int, int)
        Frame (cols, rows) in pixels.
    engine : {"WORKBENCH", "CYCLES"}
        Workbench needs EGL in background mode; Cycles is taken when it is missing.
    progress : callable, optional
        ``progress(fraction, stage)`` as each date's relief is made.

    Returns
    -------
    SeasonScene
    """
    remove_season()
    scene = bpy.data.scenes.get(SEASON_SCENE) or bpy.data.scenes.new(SEASON_SCENE)
    window = getattr(context, "window", None)
    if window is not None:  # headless there is none: the scene is rendered by name
        window.scene = scene
    collection = bpy.data.collections.new(COLLECTION)
    scene.collection.children.link(collection)

    # Every date's grid in map coordinates; their common centre becomes the scene's origin
    # (UTM coordinates are millions of metres: float32 vertices would lose centimetres).
    corners = np.concatenate([_grid_corners(d.transform, d.heights.shape) for d in season.dates])
    origin = tuple(float(v) for v in (corners.min(axis=0) + corners.max(axis=0)) / 2)
    colour_plots = colour_plots if colour_plots is not None else plots
    if colours is not None and engine == "WORKBENCH":
        engine = "CYCLES"  # Workbench draws no material nodes: the colours mix in the material
    if colours is not None and colour_plots is None:
        raise CliffTerrainError("`colours` needs the plots (`colour_plots` or `plots`), got None")
    reliefs = []
    for i, date in enumerate(season.dates):
        obj = _relief_object(collection, date, origin)
        if colours is not None:
            _colour_plots(obj, date, colour_plots, colours.normalised(i))
        reliefs.append(obj)
        if progress is not None:
            progress((i + 1) / len(season.dates), "making the dates' reliefs")
    n = len(reliefs)
    scene.frame_start, scene.frame_end = 1, n
    for marker in list(scene.timeline_markers):
        scene.timeline_markers.remove(marker)
    for i, (obj, date) in enumerate(zip(reliefs, season.dates, strict=True)):
        scene.timeline_markers.new(date.date, frame=i + 1)
        _visible_on_frame_only(obj, i + 1, n)
    top = max(float(np.nanmax(d.heights)) for d in season.dates)
    camera = _camera(collection, corners - origin, top, size)
    # Outlines about one frame pixel thick, whatever the field's size on the frame.
    thickness = camera.data.ortho_scale / size[0]
    outlines = _outlines(collection, plots, origin, thickness) if plots is not None else None
    scene.camera = camera
    _render_settings(scene, engine, size, legend=None if colours is None else colours.legend())
    scene.frame_set(1)
    return SeasonScene(
        scene=scene,
        reliefs=reliefs,
        dates=[d.date for d in season.dates],
        camera=camera,
        outlines=outlines,
        origin=origin,
        failed=list(season.failed),
    )


def remove_season():
    """Remove a season collection (objects, meshes, materials, camera) made earlier, if any (its
    scene stays, emptied, and takes the next season)."""
    remove_collection(COLLECTION)


def render_season(season_scene, out_dir, *, hold=12, fps=12, video=True, log=print, progress=None):
    """Render one PNG per date into ``OUT/frames/`` and, with `video`, ``OUT/season.mp4``.

    The frames come from Blender's animation render, each stamped with its date (the timeline
    marker); the video is Blender's own FFmpeg output of those frames, each held `hold` frames
    at `fps`. `progress` (``progress(fraction, stage)``) is told as each frame is rendered.

    Returns
    -------
    dict
        ``frames`` (paths in date order) and ``video`` (path or None).
    """
    scene = season_scene.scene
    frames_dir = Path(out_dir) / FRAMES_DIR
    frames_dir.mkdir(parents=True, exist_ok=True)
    for old in frames_dir.glob("*.png"):
        old.unlink()
    scene.render.filepath = str(frames_dir / "date_")
    scene.render.use_file_extension = True
    count = scene.frame_end - scene.frame_start + 1
    done = []

    def rendered(rendered_scene, *_):  # render_post: after each frame of the animation
        if progress is not None and rendered_scene == scene:
            done.append(rendered_scene.frame_current)
            progress(min(len(done) / count, 1.0), "rendering the dates")

    if progress is not None:
        # The stage first, here: a stage change redraws the window, which a render handler must not.
        progress(0.0, "rendering the dates")
    bpy.app.handlers.render_post.append(rendered)
    try:
        bpy.ops.render.render(animation=True, scene=scene.name)
    finally:
        bpy.app.handlers.render_post.remove(rendered)
    frames = [str(frames_dir / f"date_{i:04d}.png") for i in range(scene.frame_start, scene.frame_end + 1)]
    missing = [f for f in frames if not os.path.isfile(f)]
    if missing:
        raise RuntimeError(f"Blender wrote no frame {missing[0]}")
    log(f"rendered {len(frames)} frames into {frames_dir}")
    path = None
    if video:
        path = _video(scene, frames, Path(out_dir) / VIDEO_NAME, hold=hold, fps=fps)
        log(f"wrote {path}")
    return {"frames": frames, "video": path}


# ---- the pieces ----


def _grid_corners(transform, shape):
    rows, cols = shape
    pixel = np.array([[0, 0, 1], [cols, 0, 1], [0, rows, 1], [cols, rows, 1]], dtype=np.float64)
    return pixel @ np.asarray(transform, dtype=np.float64).T


def _relief_object(collection, date, origin):
    """The date's relief: the grid mesh (x = column, y = rows - row, z = height) placed on the map."""
    heights = np.nan_to_num(date.heights, nan=0.0)
    mesh_arrays = grid_mesh(heights, pixel_size=1.0, two_sided=False)
    mesh = mesh_from_arrays(f"Season {date.date}", mesh_arrays)
    image, _ = load_photo(date.image)
    mesh.materials.append(relief_material(f"Season {date.date}", image))
    obj = bpy.data.objects.new(f"Season {date.date}", mesh)
    collection.objects.link(obj)
    # Grid vertex (x, y) = (col, rows - row); the map has (X, Y) = t @ (col, row, 1).
    t = np.asarray(date.transform, dtype=np.float64)
    rows = heights.shape[0]
    obj.matrix_world = Matrix(
        (
            (t[0, 0], -t[0, 1], 0.0, t[0, 1] * rows + t[0, 2] - origin[0]),
            (t[1, 0], -t[1, 1], 0.0, t[1, 1] * rows + t[1, 2] - origin[1]),
            (0.0, 0.0, 1.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        )
    )
    obj["cliff_terrain_season"] = {"date": date.date, "image": date.image, "height_mode": date.height_mode}
    return obj


def _colour_plots(obj, date, plots, t):
    """Colour the relief's vertices inside plot k by `t[k]` (viridis); elsewhere, and where `t` is
    NaN, alpha 0 so the material shows the photo."""
    rows, cols = date.heights.shape
    # The grid's vertices are its pixel corners: the corner lattice is a grid of (rows + 1, cols + 1)
    # pixels half a pixel up and left, whose pixel centres are the vertices, in grid_mesh's order.
    t_map = np.vstack([np.asarray(date.transform, dtype=np.float64), [0.0, 0.0, 1.0]])
    corners = t_map @ np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    labels = rasterize_plots(plots, transform=corners, shape=(rows + 1, cols + 1)).ravel()
    per_plot = np.concatenate([[np.nan], np.asarray(t, dtype=np.float64)])
    set_vertex_colours(obj.data, per_plot[labels], nan_alpha=0.0)
    photo_where_transparent(obj.active_material)


def _visible_on_frame_only(obj, frame, n_frames):
    """Keyframe the object's visibility: shown (viewport and render) on `frame` only."""
    for f in range(1, n_frames + 1):
        hidden = f != frame
        obj.hide_render = hidden
        obj.hide_viewport = hidden
        obj.keyframe_insert("hide_render", frame=f)
        obj.keyframe_insert("hide_viewport", frame=f)


def _outlines(collection, plots, origin, thickness):
    """The plots' rings as one curve object, `thickness` wide, just above the ground."""
    curve = bpy.data.curves.new("Season plots", type="CURVE")
    curve.dimensions = "3D"
    curve.bevel_depth = 0.6 * thickness
    curve.bevel_resolution = 1
    for rings in plots.polygons:
        for ring in rings:
            ring = np.asarray(ring, dtype=np.float64)
            if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
                ring = ring[:-1]
            spline = curve.splines.new("POLY")
            spline.points.add(len(ring) - 1)
            co = np.zeros((len(ring), 4), dtype=np.float32)
            co[:, 0] = ring[:, 0] - origin[0]
            co[:, 1] = ring[:, 1] - origin[1]
            co[:, 2] = 0.05
            co[:, 3] = 1.0
            spline.points.foreach_set("co", co.ravel())
            spline.use_cyclic_u = True
    material = bpy.data.materials.new("Season plots")
    material.diffuse_color = OUTLINE_RGBA
    curve.materials.append(material)
    obj = bpy.data.objects.new("Season plots", curve)
    collection.objects.link(obj)
    return obj


def _camera(collection, corners, top, size):
    """An orthographic camera looking north, ELEVATION_DEG above the horizon, framing every date."""
    data = bpy.data.cameras.new(CAMERA)
    data.type = "ORTHO"
    camera = bpy.data.objects.new(CAMERA, data)
    collection.objects.link(camera)
    (x0, y0), (x1, y1) = corners.min(axis=0), corners.max(axis=0)
    e = math.radians(ELEVATION_DEG)
    width = x1 - x0
    # On the frame, the field's depth shrinks by sin(e) and its heights show by cos(e).
    depth = (y1 - y0) * math.sin(e) + top * math.cos(e)
    aspect = size[0] / size[1]
    data.ortho_scale = 1.08 * max(width, depth * aspect)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, top / 2])
    direction = np.array([0.0, math.cos(e), -math.sin(e)])  # from the camera towards the field
    distance = 2.0 * max(width, y1 - y0) + top
    camera.location = tuple(centre - direction * distance)
    camera.rotation_euler = (math.pi / 2 - e, 0.0, 0.0)
    data.clip_end = 4.0 * distance
    return camera


def _render_settings(scene, engine, size, *, legend=None):
    render = scene.render
    if engine == "WORKBENCH" and not gpu_available():
        engine = "CYCLES"  # Workbench draws through EGL, which this machine lacks
    render.engine = engine_id(engine)
    render.resolution_x, render.resolution_y = size
    render.resolution_percentage = 100
    render.film_transparent = False
    render.image_settings.file_format = "PNG"
    render.image_settings.color_mode = "RGB"
    set_colour_management(scene)
    if scene.world is None:
        scene.world = bpy.data.worlds.new("Season world")
    scene.world.color = (0.8, 0.8, 0.8)
    if engine == "WORKBENCH":
        shading = scene.display.shading
        shading.light = "STUDIO"
        shading.color_type = "TEXTURE"
        shading.show_shadows = False
        shading.show_cavity = False
        shading.show_specular_highlight = False
        scene.display.render_aa = "8"
    else:
        scene.cycles.samples = 16
        scene.cycles.use_denoising = False
        sun = bpy.data.lights.new("Season sun", "SUN")
        sun.energy = 3.0
        light = bpy.data.objects.new("Season sun", sun)
        bpy.data.collections[COLLECTION].objects.link(light)
        light.rotation_euler = (math.radians(40), 0.0, math.radians(30))
    # The date label: Blender's stamp writes the frame's timeline marker (the date) into the image.
    render.use_stamp = True
    for name in render.bl_rna.properties.keys():
        if name.startswith("use_stamp_"):
            setattr(render, name, name == "use_stamp_marker")
    if legend:  # the colour scale, on every frame beside the date
        render.use_stamp_note = True
        render.stamp_note_text = legend
    render.stamp_font_size = max(16, size[1] // 16)
    render.stamp_foreground = (1.0, 1.0, 1.0, 1.0)
    render.stamp_background = (0.0, 0.0, 0.0, 0.8)


def _video(scene, frames, path, *, hold, fps):
    """Blender's FFmpeg output of `frames`, each held `hold` frames, from a sequencer scene."""
    video = bpy.data.scenes.get(VIDEO_SCENE) or bpy.data.scenes.new(VIDEO_SCENE)
    editor = video.sequence_editor or video.sequence_editor_create()
    strips = editor.strips if hasattr(editor, "strips") else editor.sequences  # "sequences" before 5.0
    for strip in list(strips):
        strips.remove(strip)
    for i, frame in enumerate(frames):
        strip = strips.new_image(f"date {i + 1}", frame, 1, 1 + i * hold)
        # "duration" from Blender 5.1 ("frame_final_duration" is deprecated there).
        if hasattr(strip, "duration"):
            strip.duration = hold
        else:
            strip.frame_final_duration = hold
    render = video.render
    render.resolution_x, render.resolution_y = scene.render.resolution_x, scene.render.resolution_y
    render.resolution_percentage = 100
    render.fps = fps
    video.frame_start, video.frame_end = 1, len(frames) * hold
    render.use_sequencer = True
    render.use_compositing = False
    render.use_stamp = False
    settings = render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0 sorts formats by media type
        settings.media_type = "VIDEO"
    settings.file_format = "FFMPEG"
    render.ffmpeg.format = "MPEG4"
    render.ffmpeg.codec = "H264"
    render.ffmpeg.constant_rate_factor = "HIGH"
    set_colour_management(video)
    path = Path(path)
    if path.exists():
        path.unlink()
    render.filepath = str(path)
    render.use_file_extension = False
    try:
        bpy.ops.render.render(animation=True, scene=video.name)
    finally:
        bpy.data.scenes.remove(video)
    if not path.is_file():
        raise RuntimeError(f"Blender wrote no video at {path}")
    return str(path)
