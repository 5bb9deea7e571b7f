"""The figures of a relief object: render its views into PNG files and compare the top views
with the photo. Used by the Render Views and Evaluate operators and by ``render_views.py``.

The rig (cameras, light) is in ``rig``, the materials in ``render_materials``, the settings in
``render_settings``; the comparison itself (numpy only) is :mod:`cliff_terrain.evaluate.views`.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time

import bpy
import numpy as np

from ..cliff_terrain.evaluate.views import (
    compare_top_views,
    read_png,
    reference_image,
    resize_nearest,
    slope_degrees,
)
from ..cliff_terrain.figures import writer
from .mesh_data import positions
from .record import Record
from .render_materials import add_height_colours, flat_material, height_material, make_matte, relief_image
from .render_settings import FLAT_SAMPLES, SAMPLES, configure, gpu_available

# Views in the order they are rendered (Cycles keeps its scene data between them), and their files.
RENDER_ORDER = ("xy_flat", "xy", "xz", "view3d", "mesh")
VIEW_FILES = {view: writer.VIEW_FILES[view] for view in RENDER_ORDER}


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
    # The side view draws heights stretched by its vertical exaggeration (about height 0, the origin).
    scale_z = rig.obj.scale.z
    if view == "xz":
        rig.obj.scale.z = scale_z * rig.side.get("exaggeration", 1.0)
    try:
        return render_to(scene, path, quiet=quiet)
    finally:
        view_layer.material_override = previous
        rig.obj.scale.z = scale_z


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


def front_corner_heights(obj, grid_shape, n_front_faces=None):
    """Heights (z) of the relief's front grid, (rows + 1, cols + 1), in Blender units.

    A grid mesh's front vertices come first, row by row from the photo's top corner (see
    cliff_terrain.mesh.grid). An adaptive mesh's front faces (`n_front_faces` of them, by default
    its record's ``front_faces``) are sampled at the pixel corners, split into triangles as
    Blender draws them (cliff_terrain.mesh.quads).
    """
    rows, cols = grid_shape
    n = (rows + 1) * (cols + 1)
    mesh = obj.data
    co = positions(mesh)
    # A grid's first vertex is the top-left corner of the photo; an adaptive mesh's, a pixel centre.
    is_grid = len(co) >= n and co[0, 0] == co[:, 0].min() and co[0, 1] == co[:, 1].max()
    if not is_grid:
        from ..cliff_terrain.mesh.quads import fan_triangles
        from ..cliff_terrain.mesh.tin_sample import sample_front

        if n_front_faces is None:
            record = Record.of(obj)
            n_front_faces = record.front_faces if record is not None else None
        if n_front_faces is None:
            raise ValueError(
                f"{obj.name!r} is not a {rows} x {cols} grid and says nothing of its front faces"
            )
        sizes = np.empty(len(mesh.polygons), dtype=np.int32)
        mesh.polygons.foreach_get("loop_total", sizes)
        sizes = sizes[: int(n_front_faces)]
        corners = np.empty(len(mesh.loops), dtype=np.int32)
        mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
        triangles = fan_triangles(sizes, corners[: int(sizes.sum())])
        return sample_front(co, triangles, grid_shape)[::2, ::2]
    return co[:n, 2].reshape(rows + 1, cols + 1).astype(np.float64)


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
    record = Record.of(obj)
    size = rig.sizes["xy"]
    bands = record.bands or None  # a multispectral photo's, when its file names none
    reference, description = reference_image(source or record.source_file, size, bands=bands)
    grid = record.grid_shape
    width = rig.bounds.size[0]
    slope = slope_degrees(front_corner_heights(obj, grid), width / grid[1])
    metrics = compare_top_views(
        reference, read_png(lit_path), read_png(flat_path), resize_nearest(slope, size)
    )
    metrics["reference"] = description
    metrics["render_size"] = list(size)
    return metrics


def render_record(obj, *, engine, samples, light):
    """What ``metrics.json`` records of the Blender side of a run (``figures.writer.write_metrics``):
    the relief object's mesh, the engine, samples and light of the views, the versions."""
    from ..cliff_terrain import __version__

    return {
        "vertices": len(obj.data.vertices),
        "faces": len(obj.data.polygons),
        "engine": engine,
        "samples": samples,
        "flat_view": f"Cycles, texture as emission, {FLAT_SAMPLES} samples, 1-pixel box filter",
        "light": light,
        "versions": {"cliff_terrain": __version__, "blender": bpy.app.version_string},
    }
