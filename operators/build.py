"""The Build Relief operator: photo -> core pipeline -> a new textured relief object.

Error policy: a :class:`CliffTerrainError` (bad photo or setting) is reported as an ERROR with the
core's message and the operator returns CANCELLED. Any other exception is a bug: its traceback goes
to the console, it is reported as an ERROR naming the exception, and the operator returns CANCELLED
(Blender turns the ERROR report into a RuntimeError for scripts, so nothing fails silently). Either
way every datablock the build made (object, mesh, material, image) is removed first: the scene is
left as it was.

The new object is named after the photo, placed at the 3D cursor, selected and made active; in a
window, every 3D view frames it and Solid shading shows its texture (:func:`show_relief`). User
objects are never modified. Sizes: metres when the ground sampling distance is known (1 Blender unit
= 1 m), otherwise "normalised units" (the longest side is 10 Blender units; the factor is recorded
as ``blender_units_per_unit`` in the object's ``cliff_terrain`` custom property).
"""

import dataclasses
import queue
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import bpy

from ..scene.datablocks import remove_datablocks, textured_object
from ..scene.material import load_photo
from ..scene.mesh_data import allocate_mesh, checked_topology, fill_topology, mesh_from_arrays, set_positions
from .properties import PARAMETER_NAMES, ReliefParameters
from .reports import report_failure

# Without a known ground sampling distance the relief is scaled so its longest side is this many
# Blender units ("normalised units"); with one, 1 Blender unit = 1 metre.
NORMALISED_SIZE = 10.0
# Share of the progress bar taken by the core pipeline; the rest is mesh and material.
PIPELINE_SHARE = 0.8


class CLIFF_TERRAIN_OT_build_relief(ReliefParameters, bpy.types.Operator):
    """Build a textured 3D relief of a UAV photo as a new object"""

    # Parameters not passed take the scene's Cliff Terrain settings, so
    # bpy.ops.cliff_terrain.build_relief(filepath=..., max_size=2000) uses the panel's other values.

    bl_idname = "cliff_terrain.build_relief"
    bl_label = "Build Relief"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT"

    def invoke(self, context, event):
        self.take_scene_settings(context)
        if not self.filepath:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def take_scene_settings(self, context):
        """Parameters not given explicitly take the scene's settings (what the panel shows)."""
        settings = context.scene.cliff_terrain
        for name in ("filepath", *PARAMETER_NAMES):
            # ghost=False: a value remembered from the operator's last run does not count as given.
            if not self.properties.is_property_set(name, ghost=False):
                setattr(self, name, getattr(settings, name))

    def execute(self, context):
        # Imported here, not at registration: the core pulls in SciPy, scikit-image and OpenCV,
        # which would slow every Blender start-up.
        try:
            from ..cliff_terrain import build_relief
        except ImportError as exc:
            self.report({"ERROR"}, f"Cliff Terrain cannot load its libraries: {exc}")
            return {"CANCELLED"}
        # Also here, not only in invoke: headless and from scripts Blender calls execute directly.
        self.take_scene_settings(context)
        path = bpy.path.abspath(self.filepath)
        created = []
        try:
            params = self.relief_params()
            with _Progress(context) as progress:

                def on_progress(fraction, stage):
                    progress(PIPELINE_SHARE * fraction, stage)

                relief, mesh, figures = build_beside_the_mesh(
                    build_relief, path, params, on_progress, created
                )
                progress(PIPELINE_SHARE, "building the mesh")
                obj = build_relief_object(
                    context, relief, path, params, created=created, mesh=mesh, figures=figures
                )
                progress(1.0, "done")
        except Exception as exc:
            return cancel_build(self, exc, created)
        except BaseException:
            remove_datablocks(created)
            raise
        show_relief(context, obj)
        settings = context.scene.cliff_terrain
        if settings.color_by != "PHOTO":  # a new relief shows what the others show
            from ..scene.colour_by import colour_relief

            colour_relief(
                obj,
                settings.color_by,
                settings=settings,
                trait=settings.color_trait,
                index=settings.color_index,
            )
        info = obj["cliff_terrain"]
        self.report(
            {"INFO"},
            f"Built {obj.name}: {len(obj.data.vertices)} vertices, {info['regions']} regions, "
            + ("sizes in metres" if info["units"] == "m" else "relative units (longest side = 10)")
            + f"; {info['mesh']} mesh"
            + ("" if info["mesh_rule"] == "given" else f" ({info['mesh_rule']})")
            + (
                f", max error {info['max_error']:.3g} {info['units']}: {info['max_error_rule']}"
                if info["max_error"]
                else ""
            ),
        )
        return {"FINISHED"}


def show_relief(context, obj):
    """Show a new relief in every 3D view of the window, as Blender's Add menu would and then some:
    each view frames it (View Selected, then fitted into the part of the view that the toolbar and
    sidebar do not cover), and Solid shading shows the photo (Texture colour) so the user does not
    meet a grey slab. Nothing to do without a window (background mode, scripts).
    """
    screen = context.screen
    if bpy.app.background or screen is None:
        return
    view_prefs = context.preferences.view
    smooth = view_prefs.smooth_view
    view_prefs.smooth_view = 0  # the view settles now, so it can be refined below
    try:
        for area in screen.areas:
            if area.type != "VIEW_3D":
                continue
            space = area.spaces.active
            if space.shading.type == "SOLID":
                space.shading.color_type = "TEXTURE"
            regions = {region.type: region for region in area.regions}
            region = regions.get("WINDOW")
            if region is None or space.region_3d is None:
                continue
            rv3d = space.region_3d
            distance = rv3d.view_distance
            # World units per pixel at the view's centre, from the matrices of the last redraw.
            per_pixel = _world_per_pixel(region, rv3d)
            with context.temp_override(area=area, region=region, space_data=space):
                bpy.ops.view3d.view_selected(use_all_regions=False)
            if context.preferences.system.use_region_overlap and per_pixel:
                _fit_visible_part(space, regions, region, rv3d, per_pixel * rv3d.view_distance / distance)
    finally:
        view_prefs.smooth_view = smooth


def _world_per_pixel(region, rv3d):
    from bpy_extras.view3d_utils import region_2d_to_location_3d

    centre = (region.width / 2, region.height / 2)
    a = region_2d_to_location_3d(region, rv3d, centre, rv3d.view_location)
    b = region_2d_to_location_3d(region, rv3d, (centre[0] + 100, centre[1]), rv3d.view_location)
    return (b - a).length / 100 if a is not None and b is not None else None


def _fit_visible_part(space, regions, region, rv3d, per_pixel):
    """Zoom out and pan so the framed relief sits in the view's uncovered middle: with region overlap,
    the toolbar and the sidebar are drawn over the 3D view's left and right edges."""
    from mathutils import Vector

    left = regions["TOOLS"].width if "TOOLS" in regions and space.show_region_toolbar else 0
    right = regions["UI"].width if "UI" in regions and space.show_region_ui else 0
    visible = region.width - left - right
    if visible < 0.3 * region.width:
        return
    factor = region.width / visible
    rv3d.view_distance *= factor
    # Move the view right, so the relief moves left into the middle of the uncovered part.
    shift = 0.5 * (right - left) * per_pixel * factor
    rv3d.view_location += (rv3d.view_rotation @ Vector((1.0, 0.0, 0.0))) * shift


def build_beside_the_mesh(build_relief, path, params, progress, created):
    """``(relief, mesh, figures)``: `build_relief` run in a worker thread while this thread makes the mesh.

    The worker computes the relief without a mesh (``mesh=None``); meanwhile this thread, the one
    Blender's calls need, allocates the Blender mesh (the grid's size comes from the photo's
    header) while the worker decodes the photo, and writes the faces, edges and UVs in once it
    computes the heights (long calls that release the GIL, which Blender's bulk writes hold; its
    progress tells when). The vertices are placed by the caller (:func:`build_relief_object`). The
    worker's `progress` is relayed to `progress` in this thread. The mesh goes into `created` as
    soon as it exists; an exception of either thread propagates once the worker has finished.

    An adaptive mesh's size is known only at its end, so there is nothing to allocate early: the
    relief is built in this thread without a mesh, then its mesh in this thread while a worker
    works out the key figures of the object's record (`figures`, for :func:`build_record`;
    ``pydelatin`` holds the GIL, but the figures' array steps run without it); `mesh` is then
    None. For the grid, `figures` is None: :func:`build_record` works them out.
    """
    from ..cliff_terrain.build import grid_shape, mesh_relief
    from ..cliff_terrain.mesh.adaptive import choose_mesh
    from ..cliff_terrain.mesh.grid import grid_sizes, grid_topology, place_vertices

    shape = grid_shape(path, max_size=params.max_size)
    kind, rule = choose_mesh(params.mesh, shape)  # what build_relief would choose ("auto")
    if kind != "grid":

        def until_the_mesh(fraction, stage):
            if stage != "done":  # the core is done without its mesh: "done" comes after it
                progress(fraction, stage)

        relief = build_relief(path, params, mesh=None, progress=None if progress is None else until_the_mesh)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="cliff_terrain") as pool:
            figures = pool.submit(record_figures, relief)
            relief = mesh_relief(
                relief, mesh=params.mesh, max_error=params.max_error, two_sided=params.two_sided
            )
        if progress is not None:
            progress(1.0, "done")
        return relief, None, figures.result()
    events = queue.SimpleQueue()
    stages = set()

    def relay(*, until=None):
        """Pass the worker's progress on: what has come, or all until stage `until` or its end."""
        while not events.empty() or (until is not None and until not in stages and not future.done()):
            try:
                event = events.get(timeout=0.05)
            except queue.Empty:
                continue
            stages.add(event[1])
            if progress is not None:
                progress(*event)

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="cliff_terrain") as pool:
        future = pool.submit(
            build_relief,
            path,
            params,
            mesh=None,
            progress=lambda fraction, stage: events.put((fraction, stage)),
        )
        try:
            mesh = allocate_mesh(relief_name(path), grid_sizes(shape, two_sided=params.two_sided))
            created.append(mesh)
            relay()
            topology = grid_topology(shape, two_sided=params.two_sided)
            checked = checked_topology(topology)
            relay(until="heights")
            fill_topology(mesh, checked)
        finally:
            relay(until="done")  # the worker's last stage, or its end by an exception (raised below)
            future.exception()
    relief = future.result()
    vertices = place_vertices(topology, relief.heights, pixel_size=relief.pixel_size)
    relief = dataclasses.replace(
        relief, mesh=vertices, mesh_kind=kind, mesh_rule=rule, params={**relief.params, "mesh": params.mesh}
    )
    return relief, mesh, None


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
    :func:`record_figures` of the relief.
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
    obj["cliff_terrain"] = build_record(relief, path, params, scale, figures=figures)
    obj.location = context.scene.cursor.location
    for other in context.view_layer.objects.selected:
        other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
    return obj


def build_record(relief, path, params, scale, *, figures=None):
    """What a relief object records about its build (its ``cliff_terrain`` custom property).

    `figures`: :func:`record_figures` of the relief, if already worked out.
    """
    from ..cliff_terrain import __version__
    from ..cliff_terrain.relief.indices import available_indices

    digest, figures = record_figures(relief) if figures is None else figures

    return {
        "version": __version__,
        "source": str(path),
        "units": relief.units,
        "blender_units_per_unit": scale,
        "size_mode": "metres" if relief.units == "m" else "normalised",
        "pixel_size": float(relief.pixel_size),
        "grid_rows": int(relief.mesh.grid_shape[0]),
        "grid_cols": int(relief.mesh.grid_shape[1]),
        "regions": int(relief.n_regions),
        # The photo's ground sampling distance (0 when unknown) and where it came from ("" when unknown).
        "gsd_m_per_px": float(relief.metadata.gsd_m_per_px or 0.0),
        "gsd_source": relief.metadata.gsd_source or "",
        # The adaptive mesh's bound (0 for the grid) and its front faces (triangles, or grid quads).
        "max_error": float(relief.max_error or 0.0),
        # Which rule chose the bound ("given", half a pixel, the DSM's noise; "" for the grid), and
        # the mesh made with why ("auto" resolved per build).
        "max_error_rule": relief.max_error_rule or "",
        "mesh": relief.mesh_kind or "",
        "mesh_rule": relief.mesh_rule,
        "front_faces": int(relief.mesh.n_front_faces),
        "max_height": relief.max_height,
        # Tells a rebuild of the relief from its photo (Render Views' figures) from another photo.
        "mask_digest": digest,
        # A multispectral photo's bands (as named by its file or by the build) and the vegetation
        # indices they allow (Color By offers them).
        "bands": list(relief.metadata.band_names or ()),
        "indices": list(available_indices(relief.metadata.band_names or ())),
        "image_width": int(relief.metadata.width),
        "image_height": int(relief.metadata.height),
        # The settings as the sidebar holds them (0 for "not given"), which a rebuild reads back.
        "params": _relief_params(params).to_properties(),
        **figures,
    }


def record_figures(relief):
    """``(mask_digest, key_figures)`` of a relief, for its record: they need no mesh."""
    return mask_digest(relief.mask), key_figures(relief)


def _relief_params(params):
    """`params` as a :class:`ReliefParams` (render_views.py passes a relief's recorded ``params``)."""
    from ..cliff_terrain.params import ReliefParams

    return params if isinstance(params, ReliefParams) else ReliefParams.from_properties(params)


def mask_digest(mask):
    """A short hash of a plant mask (the segmentation, which a rebuild reproduces bit for bit)."""
    import hashlib

    import numpy as np

    return hashlib.blake2b(np.packbits(mask, axis=None).tobytes(), digest_size=8).hexdigest()


def key_figures(relief):
    """Cover and, with a surface model, the canopy height p50/p90 (cm, -1 without) and the map offset.

    The mesh is built near the world origin; ``map_offset`` is the map (x, y) of its local (0, 0)
    (the grid's bottom-left corner) in EPSG ``crs``: add it to a vertex to get map coordinates.
    """
    from ..cliff_terrain.measure.key_figures import key_figures as core_figures

    # One definition of the figures (the core's), shown in the sidebar in centimetres.
    core = core_figures(relief)
    figures = {"cover": core["cover"], "canopy_p50_cm": -1.0, "canopy_p90_cm": -1.0}
    canopy = getattr(relief, "canopy", None)
    if canopy is not None:
        if core["canopy_height_p90_m"] is not None:
            figures.update(
                canopy_p50_cm=core["canopy_height_p50_m"] * 100.0,
                canopy_p90_cm=core["canopy_height_p90_m"] * 100.0,
            )
        rows = relief.heights.shape[0]  # the mesh's grid
        t = canopy.transform
        figures["map_offset"] = [float(t[0, 1] * rows + t[0, 2]), float(t[1, 1] * rows + t[1, 2])]
        from ..cliff_terrain.io.crs import crs_record

        figures["crs"] = crs_record(canopy.crs)  # an EPSG code, or a user-defined CRS's WKT
        figures["ground"] = canopy.ground_source
    return figures


def cancel_build(operator, exc, created):
    """Remove every datablock in `created`, report `exc` as the module's error policy says and
    return CANCELLED: a :class:`CliffTerrainError` with its message, anything else as a bug."""
    remove_datablocks(created)
    return report_failure(operator, exc)


class _Progress:
    """Progress bar and status-bar text while building (both may be missing in background mode)."""

    def __init__(self, context):
        self.wm = context.window_manager
        self.workspace = context.workspace

    def __enter__(self):
        self.wm.progress_begin(0, 100)
        return self

    def __call__(self, fraction, stage):
        self.wm.progress_update(int(round(100 * min(max(fraction, 0.0), 1.0))))
        if self.workspace is not None:
            self.workspace.status_text_set(f"Cliff Terrain: {stage} ({fraction:.0%})")
            # The window redraws only between operators: draw the status bar once per stage.
            if stage != getattr(self, "stage", None) and not bpy.app.background:
                self.stage = stage
                bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)

    def __exit__(self, *exc):
        self.wm.progress_end()
        if self.workspace is not None:
            self.workspace.status_text_set(None)
        return False


CLASSES = (CLIFF_TERRAIN_OT_build_relief,)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
