"""The Render Views and Evaluate operators: figures and the paper's Table 4 metrics of the active relief.

Both work on the active object when it is a relief built by Cliff Terrain (it carries the
``cliff_terrain`` record: the photo, the grid size). They add the view rig (collection ``Cliff Terrain
Views``: top, side and perspective cameras and the calibrated sun; the scene's world becomes the
calibrated sky) and leave it, so the views can be rendered again by hand; the scene's camera and
render settings are put back as they were. Clicked in the sidebar, they run as a background job
(``render_job``: the window keeps answering, Esc cancels); from scripts they render in place.

Error policy as in the build operator: a bad photo or setting is reported as an ERROR and the
operator returns CANCELLED; anything else is a bug, its traceback goes to the console.
"""

import os
import tempfile
import time
import traceback
from pathlib import Path

import bpy
from bpy.props import EnumProperty, IntProperty

from ..cliff_terrain import settings as core_settings
from ..cliff_terrain.evaluate.views import metrics_summary, view_resolution
from ..scene import render_settings, rig, views
from ..scene.record import Record, is_relief
from . import render_job


def active_relief(context):
    """The active object if it is a relief built by Cliff Terrain, else None."""
    obj = context.active_object
    return obj if is_relief(obj) else None


class _ViewSettings:
    """Settings shared by both operators (a mixin: Blender collects annotations from bases)."""

    engine: EnumProperty(
        name="Engine",
        description="Engine of the lit views",
        items=core_settings.ENGINES,
        default=core_settings.DEFAULT_ENGINE,
    )
    resolution: IntProperty(
        name="Resolution",
        description="Longest side of each view in pixels (0 = the relief's grid, one pixel per cell)",
        min=0,
        max=core_settings.MAX_RESOLUTION,
        default=0,
    )
    samples: IntProperty(
        name="Samples",
        description="Samples per pixel of the lit views",
        min=1,
        max=core_settings.MAX_SAMPLES,
        default=core_settings.DEFAULT_SAMPLES,
    )

    @classmethod
    def poll(cls, context):
        relief = active_relief(context)
        if relief is None:
            cls.poll_message_set("The active object must be a relief built by Cliff Terrain")
            return False
        if is_rotated(relief):
            # The views look down the world's axes and are compared with the photo pixel for pixel:
            # a relief turned by 0.5 rad scored 7.6 dB, reported as a fact.
            cls.poll_message_set(
                "Clear the relief's rotation (Alt R): its top view is compared with the photo"
            )
            return False
        return context.mode == "OBJECT"

    def run(self, context, out_dir, view_names):
        """Render `view_names` of the active relief into `out_dir` and compare its top views with the photo."""
        obj = active_relief(context)
        scene = context.scene
        source = Record.of(obj).source_file
        if not os.path.isfile(source):  # before minutes of rendering, not after them
            from ..cliff_terrain.errors import CliffTerrainError

            raise CliffTerrainError(
                f"the photo {source!r} the relief was built from is not there: the views are compared "
                "with it (put it back, or build the relief again)"
            )

        def warn(message):
            self.report({"WARNING"}, message)

        engine = render_settings.choose_engine(self.engine, log=warn)
        with render_settings.KeptRenderSettings(scene, log=warn):
            rows, cols = Record.of(obj).grid_shape
            resolution = view_resolution(self.resolution, rows, cols, name="Resolution")
            view_rig = rig.make_rig(context, obj, resolution=resolution)
            try:
                paths, seconds = views.render_views(
                    context, view_rig, out_dir, views=view_names, engine=engine, samples=self.samples
                )
                start = time.perf_counter()
                metrics = views.evaluate_relief(obj, view_rig, paths["xy"], paths["xy_flat"])
                seconds["metrics"] = time.perf_counter() - start
            except BaseException:
                rig.remove_rig(scene)  # a failed run leaves no cameras or sun of its own behind
                raise
        metrics.update(
            engine=engine,
            samples=self.samples,
            light=view_rig.light,
            side_view=view_rig.side,
            timings_s=seconds,
        )
        settings = scene.cliff_terrain
        # An infinite PSNR (a view identical to the photo) is stored as float32's largest value
        # (Blender clamps it); the panel shows it as identical (evaluation.psnr_text).
        settings.psnr = metrics["psnr_xy"]
        settings.ssim = metrics["ssim_xy"]
        return metrics

    def invoke(self, context, event):
        # Clicked in the UI: render in a background Blender, so the window keeps answering.
        return render_job.start(self, context, active_relief(context))

    def modal(self, context, event):
        return render_job.modal(self, context, event)

    def execute(self, context):
        from ..cliff_terrain import CliffTerrainError

        try:
            return self.run_operator(context)
        except (CliffTerrainError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except Exception as exc:
            traceback.print_exc()
            self.report({"ERROR"}, f"Cliff Terrain failed: {type(exc).__name__}: {exc}")
            return {"CANCELLED"}


class CLIFF_TERRAIN_OT_render_views(_ViewSettings, bpy.types.Operator):
    """Render the active relief's top (lit and flat), side, perspective and height views into the
    output folder, with metrics.json (PSNR and SSIM of the top views against the photo)"""

    bl_idname = "cliff_terrain.render_views"
    bl_label = "Render Views"
    bl_options = {"REGISTER", "UNDO"}

    def run_operator(self, context):
        obj = active_relief(context)
        # As the background job's: beside an unsaved file "//" is the temporary folder, not the
        # working directory (Blender's install folder on Windows, where nothing may be written).
        folder = render_job.output_folder(context.scene.cliff_terrain)
        out_dir = os.path.join(folder, bpy.path.clean_name(obj.name))
        os.makedirs(out_dir, exist_ok=True)  # views are replaced, as F12 replaces its result
        metrics = self.run(context, out_dir, tuple(views.VIEW_FILES))
        self.write_outputs(obj, Path(out_dir), metrics)
        self.report(
            {"INFO"}, f"Rendered {len(views.VIEW_FILES)} views into {out_dir}: {metrics_summary(metrics)}"
        )
        return {"FINISHED"}

    def write_outputs(self, obj, out, metrics):
        """What render_views.py writes beside the views (the maps, tables, annotated figures and
        metrics.json), from the relief rebuilt from its photo and settings (a core run without a
        mesh); only metrics.json, with a warning, when the photo has changed since the build."""
        from ..cliff_terrain.figures import writer

        metrics = dict(metrics)
        side, seconds = metrics.pop("side_view"), metrics.pop("timings_s")
        record = Record.of(obj)
        render = views.render_record(
            obj, engine=metrics.pop("engine"), samples=metrics.pop("samples"), light=metrics.pop("light")
        )
        # The relief is rebuilt without its mesh: the parameters and error bound are the build's.
        render["params"] = dict(record.params)
        render["max_error"] = float(record.max_error) or None
        render["max_error_rule"] = record.max_error_rule or None
        render["mesh"] = record.mesh or None
        render["mesh_rule"] = record.mesh_rule
        timings = {
            ("metrics" if name == "metrics" else f"render_{name}"): value for name, value in seconds.items()
        }
        relief, reason = relief_from_record(record)
        if relief is None:
            self.report({"WARNING"}, f"No annotated figures: {reason}")
            writer.write_metrics(out, metrics, side=side, render=render, timings=timings)
            return
        writer.write_outputs(relief, out, side=side, metrics=metrics, render=render, timings=timings)


def is_rotated(obj):
    """Whether `obj` is turned or tilted in the world (its scale and place do not count)."""
    m = obj.matrix_world.to_3x3()
    scale = max(abs(v) for v in m.to_scale()) or 1.0
    return any(abs(m[i][j]) > 1e-6 * scale for i in range(3) for j in range(3) if i != j)


def relief_from_record(record):
    """``(relief, None)``: the core's relief of a relief object, rebuilt (without a mesh) from the
    photo and settings its :class:`~scene.record.Record` holds; ``(None, reason)`` when that is not
    the relief shown."""
    import numpy as np

    from ..cliff_terrain import CliffTerrainError, build_relief
    from ..cliff_terrain.params import ReliefParams

    source = str(record.source_file)
    if not os.path.isfile(source):
        return None, f"the photo {source!r} is not there any more"
    try:
        params = ReliefParams.from_properties(record.file_params())
        relief = build_relief(source, params, mesh=None)
    except (CliffTerrainError, OSError) as exc:
        return None, f"the photo {source!r} no longer builds: {exc}"
    same = relief.heights.shape == record.grid_shape and np.isclose(
        relief.max_height, float(record.max_height), rtol=1e-5
    )
    if same and record.mask_digest:  # reliefs built by earlier versions lack it
        same = relief.mask_digest == record.mask_digest
    if not same:
        return None, f"the photo {source!r} has changed since the relief was built"
    return relief, None


class CLIFF_TERRAIN_OT_evaluate(_ViewSettings, bpy.types.Operator):
    """Render the active relief's top views and compare them with the photo (PSNR and SSIM, as the
    paper's Table 4); the result is shown in the panel"""

    bl_idname = "cliff_terrain.evaluate"
    bl_label = "Evaluate"
    bl_options = {"REGISTER", "UNDO"}

    def run_operator(self, context):
        with tempfile.TemporaryDirectory(prefix="cliff_terrain_evaluate_") as out_dir:
            metrics = self.run(context, out_dir, ("xy_flat", "xy"))
        self.report({"INFO"}, metrics_summary(metrics))
        return {"FINISHED"}


CLASSES = (CLIFF_TERRAIN_OT_render_views, CLIFF_TERRAIN_OT_evaluate)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
