"""The Build Relief operator: photo -> core pipeline -> a new textured relief object.

Error policy: a :class:`CliffTerrainError` (bad photo or setting) is reported as an ERROR with the
core's message and the operator returns CANCELLED. Any other exception is a bug: its traceback goes
to the console, it is reported as an ERROR naming the exception, and the operator returns CANCELLED
(Blender turns the ERROR report into a RuntimeError for scripts, so nothing fails silently). Either
way every datablock the build made (object, mesh, material, image) is removed first: the scene is
left as it was.

The new object (:func:`scene.relief_object.build_relief_object`, with its record,
:mod:`scene.record`) is named after the photo, placed at the 3D cursor, selected and made active;
in a window, every 3D view frames it and Solid shading shows its texture
(:func:`scene.viewport.show_relief`). User objects are never modified. The core runs in a worker
thread while this one makes the Blender mesh (:func:`build_beside_the_mesh`).
"""

import dataclasses
import queue
from concurrent.futures import ThreadPoolExecutor

import bpy

from ..scene.datablocks import remove_datablocks
from ..scene.mesh_data import allocate_mesh, checked_topology, fill_topology
from ..scene.record import Record, record_figures
from ..scene.relief_object import build_relief_object, relief_name
from ..scene.viewport import show_relief
from .progress import Progress
from .properties import PARAMETER_NAMES, ReliefParameters
from .reports import cancel_build

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
        # A path relative to the .blend (``//``) is recorded and loaded as given: a project folder
        # moved or copied to a colleague still finds its photo and surface model.
        stored = self.filepath if self.filepath.startswith("//") else path
        created = []
        try:
            params = self.relief_params()
            with Progress(context) as progress:

                def on_progress(fraction, stage):
                    progress(PIPELINE_SHARE * fraction, stage)

                relief, mesh, figures = build_beside_the_mesh(
                    build_relief, path, params, on_progress, created
                )
                progress(PIPELINE_SHARE, "building the mesh")
                obj = build_relief_object(
                    context, relief, stored, params, created=created, mesh=mesh, figures=figures
                )
                keep_relative_paths(obj, self)
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
        record = Record.of(obj)
        self.report(
            {"INFO"},
            f"Built {obj.name}: {len(obj.data.vertices)} vertices, {record.regions} regions, "
            + ("sizes in metres" if record.metres else "relative units (longest side = 10)")
            + f"; {record.mesh} mesh"
            + ("" if record.mesh_rule == "given" else f" ({record.mesh_rule})")
            + (
                f", max error {record.max_error:.3g} {record.units}: {record.max_error_rule}"
                if record.max_error
                else ""
            ),
        )
        return {"FINISHED"}


def keep_relative_paths(obj, properties):
    """Record the relief's path parameters (its surface and terrain models) as the user gave them
    when they are relative to the .blend; the build itself read them resolved."""
    from ..cliff_terrain import settings
    from ..scene.record import KEY

    params = obj[KEY]["params"]
    for name, parameter in settings.PARAMETERS.items():
        given = getattr(properties, name, "") if parameter.kind == "path" else ""
        if isinstance(given, str) and given.startswith("//") and name in params:
            params[name] = given


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
    works out the key figures of the object's record (`figures`, for
    :func:`scene.record.write_record`; ``pydelatin`` holds the GIL, but the figures' array steps run
    without it); `mesh` is then None. For the grid, `figures` is None: the record works them out.
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


CLASSES = (CLIFF_TERRAIN_OT_build_relief,)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
