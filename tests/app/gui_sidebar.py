"""The Blender side of the sidebar's GUI test: runs inside a real Blender window (started by
``gui_driver.py`` under Xvfb) and never blocks it.

    blender -p 0 0 W H --python tests/app/gui_sidebar.py -- --work DIR --photo PHOTO [--source REPO]

A timer walks through the test one phase at a time and writes what it needs from the outside
world into ``DIR/state.json``; the driver (a separate process: a blocking timer would stop the
window from handling its clicks) answers with xdotool and xwd:

1. ``category``: the sidebar is open; the driver Ctrl+scrolls over it until the "Cliff Terrain"
   tab is active (``Region.active_panel_category`` is read-only in Blender 4.3).
2. ``shot``: the driver saves screenshots; two of the sidebar, with the photo set and unset, show
   where the Build Relief button is (the only full-width control that changes when it greys out).
3. ``click``: the driver clicks it; the build runs as a user's would.
4. Checks from inside Blender: the relief exists at the 3D cursor, selected and active; the 3D view
   frames it; Solid shading shows its texture; then a final screenshot (the README's sidebar.png)
   must show the photo's colours in the 3D view.

The verdict goes to ``DIR/result.json``; Blender then quits.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import math
import os
import sys
import time
import traceback

import bpy

CATEGORY = "Cliff Terrain"
# A UI unit (a row of widgets) in pixels at resolution scale 1; the Build row is 1.4 of it.
UNIT = 20
TIMEOUT_S = 420


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(prog="gui_sidebar.py")
    parser.add_argument("--work", required=True, help="folder shared with the driver")
    parser.add_argument("--photo", required=True)
    parser.add_argument("--source", help="register the add-on from this source folder (no installed zip)")
    parser.add_argument("--max-size", type=int, default=400)
    parser.add_argument(
        "--ortho", help="a georeferenced orthophoto with dsm.tif beside it: the plot grid part"
    )
    return parser.parse_args(argv)


ARGS = parse_args()
STATE = os.path.join(ARGS.work, "state.json")
RESULT = os.path.join(ARGS.work, "result.json")


class Test:
    def __init__(self):
        self.phase = "start"
        self.seq = 0
        self.started = time.monotonic()
        self.checks = {}
        self.notes = []
        self.waiting_for = None

    # ---- talking to the driver ---------------------------------------------------------------

    def ask(self, phase, **fields):
        """Publish a request for the driver (a new sequence number each time)."""
        self.seq += 1
        self.phase = phase
        state = {"seq": self.seq, "phase": phase, **fields}
        tmp = STATE + ".tmp"
        with open(tmp, "w") as stream:
            json.dump(state, stream)
        os.replace(tmp, STATE)
        self.waiting_for = fields.get("done")

    def answered(self):
        return self.waiting_for is None or os.path.exists(self.waiting_for)

    def finish(self, error=None):
        passed = error is None and all(self.checks.values())
        checks = {name: bool(value) for name, value in self.checks.items()}  # numpy bools too
        verdict = {"passed": passed, "checks": checks, "notes": self.notes, "error": error}
        # Serialised first, written whole: the driver never reads half a verdict.
        text = json.dumps(verdict, indent=2, default=repr)
        with open(RESULT + ".tmp", "w") as stream:
            stream.write(text)
        os.replace(RESULT + ".tmp", RESULT)
        self.ask("done", passed=passed)
        bpy.app.timers.register(quit_blender, first_interval=0.5)

    # ---- the window --------------------------------------------------------------------------

    def view3d(self):
        window = bpy.context.window_manager.windows[0]
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                regions = {r.type: r for r in area.regions}
                return window, area, regions["WINDOW"], regions["UI"]
        raise RuntimeError("no 3D view in the window")

    def to_screen(self, window, x, y):
        """Window pixel (origin bottom-left) to X screen pixel (origin top-left); the window is at 0, 0."""
        return int(round(x)), int(round(window.height - 1 - y))

    # ---- the phases --------------------------------------------------------------------------

    def step(self):
        if time.monotonic() - self.started > TIMEOUT_S:
            self.finish(f"timed out in phase {self.phase!r}")
            return None
        if not self.answered():
            return 0.2
        return getattr(self, f"phase_{self.phase}")()

    def phase_start(self):
        ensure_addon()
        window, area, region, ui = self.view3d()
        scene = bpy.context.scene
        settings = scene.cliff_terrain
        settings.filepath = ARGS.photo
        settings.max_size = ARGS.max_size
        area.spaces.active.show_region_ui = True
        self.checks["window_is_the_screen"] = window.x == 0 and window.width >= 800
        self.ask("category", point=self.to_screen(window, ui.x + ui.width - 6, ui.y + ui.height / 2))
        self.category_tries = 0
        return 0.5

    def phase_category(self):
        _, _, _, ui = self.view3d()
        if ui.active_panel_category == CATEGORY:
            self.notes.append(f"sidebar tab {CATEGORY!r} active after {self.category_tries} scroll steps")
            # The category changes before the region redraws: shoot after a redraw.
            self.redraw()
            self.delay_then("shoot_enabled")
            return 1.0
        self.category_tries += 1
        if self.category_tries > 40:
            self.finish(f"the sidebar never showed the {CATEGORY!r} tab (last {ui.active_panel_category!r})")
            return None
        window, _, _, ui = self.view3d()
        self.ask("category", point=self.to_screen(window, ui.x + ui.width - 6, ui.y + ui.height / 2))
        return 0.5

    def shoot(self, name):
        path = os.path.join(ARGS.work, f"{name}.png")
        self.shot_name = name
        self.ask("shot", path=path, done=path + ".done")
        self.phase = f"shot_{name}"

    def phase_shoot_enabled(self):
        self.shoot("enabled")
        return 0.3

    def phase_shot_enabled(self):
        # The same sidebar with the Build button greyed out (no photo).
        bpy.context.scene.cliff_terrain.filepath = ""
        self.redraw()
        self.delay_then("shoot_disabled")
        return 1.0

    def phase_shoot_disabled(self):
        self.shoot("disabled")
        return 0.3

    def phase_shot_disabled(self):
        bpy.context.scene.cliff_terrain.filepath = ARGS.photo
        self.redraw()
        window, _, _, ui = self.view3d()
        button = find_button(
            os.path.join(ARGS.work, "enabled.png"), os.path.join(ARGS.work, "disabled.png"), window, ui
        )
        if button is None:
            self.finish("could not find the Build Relief button in the sidebar")
            return None
        x, y, height = button
        self.notes.append(f"Build Relief button at screen ({x}, {y}), {height} px high")
        self.checks["build_button_found"] = True
        self.objects_before = set(bpy.data.objects.keys())
        self.cursor = tuple(bpy.context.scene.cursor.location)
        self.delay_then("click", point=(x, y))
        return 0.5

    def phase_click(self):
        self.ask("click", point=self.click_point)
        self.phase = "wait_relief"
        self.clicked = time.monotonic()
        return 0.5

    def phase_wait_relief(self):
        new = [
            obj for obj in bpy.data.objects if obj.name not in self.objects_before and "cliff_terrain" in obj
        ]
        if not new:
            if time.monotonic() - self.clicked > 120:
                self.finish("clicking Build Relief made no relief in 120 s")
                return None
            return 0.5
        self.relief = new[0]
        self.notes.append(f"relief {self.relief.name!r} after {time.monotonic() - self.clicked:.1f} s")
        self.delay_then("check")
        return 1.0

    def phase_check(self):
        obj = self.relief
        context = bpy.context
        window, area, region, _ = self.view3d()
        space = area.spaces.active
        self.checks["relief_at_cursor"] = all(
            math.isclose(a, b, abs_tol=1e-6) for a, b in zip(obj.location, self.cursor, strict=True)
        )
        self.checks["relief_selected_and_active"] = (
            obj.select_get() and context.view_layer.objects.active == obj
        )
        self.checks["solid_shading_shows_texture"] = (
            space.shading.type != "SOLID" or space.shading.color_type == "TEXTURE"
        )
        image = relief_image(obj)
        self.checks["material_shows_the_photo"] = image is not None and os.path.samefile(
            bpy.path.abspath(image.filepath), ARGS.photo
        )
        inside, share, offset = framing(obj, area, region, space.region_3d)
        self.notes.append(
            f"framing: corners inside the uncovered view {inside}, relief spans {share:.0%} of it, "
            f"its centre {offset:.1%} of the view's width from the middle"
        )
        self.checks["view_frames_relief"] = inside and share >= 0.5 and offset <= 0.1
        self.shoot("sidebar")
        return 0.3

    def phase_shot_sidebar(self):
        window, area, region, _ = self.view3d()
        before = colourful_share(os.path.join(ARGS.work, "enabled.png"), window, region)
        after = colourful_share(os.path.join(ARGS.work, "sidebar.png"), window, region)
        self.notes.append(
            f"colourful pixels (chroma > 8) in the 3D view: {before:.1%} before the build, {after:.1%} after"
        )
        # A grey slab adds only its orange outline; the photo's soil and leaves add far more.
        self.checks["screenshot_shows_the_photo"] = after >= 0.05 and after >= 4 * before
        self.phase = "job_start"
        return 0.5

    # ---- Render Views as a background job: the window keeps answering; Esc cancels Evaluate ----

    def invoke(self, idname):
        window, area, region, _ = self.view3d()
        category, name = idname.split(".")
        with bpy.context.temp_override(window=window, area=area, region=region):
            return getattr(getattr(bpy.ops, category), name)("INVOKE_DEFAULT")

    def phase_job_start(self):
        self.job_module = importlib.import_module(f"{addon_package()}.operators.render_job")
        settings = bpy.context.scene.cliff_terrain
        settings.output_dir = os.path.join(ARGS.work, "views")
        settings.psnr = settings.ssim = 0.0
        result = self.invoke("cliff_terrain.render_views")
        self.checks["render_views_runs_as_a_job"] = (
            result == {"RUNNING_MODAL"} and len(self.job_module.JOBS) == 1
        )
        if not self.checks["render_views_runs_as_a_job"]:
            self.finish(f"Render Views returned {result}")
            return None
        self.job_started = self.last_tick = time.monotonic()
        self.longest_gap = self.gap_at = 0.0
        self.job_shot = False
        self.phase = "job_wait"
        return 0.1

    def phase_job_wait(self):
        now = time.monotonic()
        if now - self.last_tick > self.longest_gap:
            self.longest_gap, self.gap_at = now - self.last_tick, self.last_tick - self.job_started
        self.last_tick = now
        if self.job_module.JOBS:
            if not self.job_shot and now - self.job_started > 8:
                # The window while the job renders (status bar: the view, its number, Esc to cancel).
                self.job_shot = True
                path = os.path.join(ARGS.work, "job.png")
                self.ask("shot", path=path, done=path + ".done")
                self.phase = "job_wait"
                return 0.1
            if now - self.job_started > 180:
                self.finish("Render Views did not finish in 180 s")
                return None
            return 0.1
        seconds = now - self.job_started
        settings = bpy.context.scene.cliff_terrain
        folder = bpy.path.abspath(settings.last_views)
        names = sorted(os.listdir(folder)) if folder and os.path.isdir(folder) else []
        self.notes.append(
            f"Render Views job: {seconds:.1f} s, the window's timer never waited more than "
            f"{self.longest_gap:.2f} s (from {self.gap_at:.1f} s); wrote {', '.join(names)}; PSNR {settings.psnr:.2f} dB"
        )
        # Rendering in place would stop the timer for the whole job; drawing the window on Mesa's
        # software renderer takes about a second, and saving the copy a little more.
        self.checks["window_answers_during_the_job"] = self.longest_gap < 0.25 * seconds
        expected = {"xy.png", "xy_flat.png", "xz.png", "view3d.png", "mesh.png", "metrics.json"}
        # The figures render_views.py draws too, from the relief rebuilt in the job's Blender.
        expected |= {"mask.png", "height.tif", "xy_annotated.png", "xz_annotated.png", "summary.png"}
        self.checks["job_results_come_back"] = expected <= set(names) and settings.psnr > 15.0
        # Evaluate, cancelled with Esc while it renders.
        settings.psnr = settings.ssim = 0.0
        result = self.invoke("cliff_terrain.evaluate")
        if result != {"RUNNING_MODAL"}:
            self.finish(f"Evaluate returned {result}")
            return None
        self.cancel_job = self.job_module.JOBS[0]
        self.job_started = time.monotonic()
        self.phase = "cancel_press"
        return 2.0

    def phase_cancel_press(self):
        window, area, region, _ = self.view3d()
        self.ask(
            "key", key="Escape", point=self.to_screen(window, region.x + region.width / 2, region.y + 40)
        )
        self.phase = "cancel_wait"
        return 0.2

    def phase_cancel_wait(self):
        seconds = time.monotonic() - self.job_started
        if self.job_module.JOBS and seconds < 30:
            return 0.2
        process_ended = self.cancel_job.process.poll() is not None
        self.notes.append(
            f"Esc ended the Evaluate job after {seconds:.1f} s; its Blender exited: {process_ended}"
        )
        self.checks["esc_cancels_the_job"] = (
            not self.job_module.JOBS and process_ended and bpy.context.scene.cliff_terrain.psnr == 0.0
        )
        # A view listed in the panel opens in an Image Editor (a new window when none is open).
        folder = bpy.path.abspath(bpy.context.scene.cliff_terrain.last_views)
        path = os.path.join(folder, "xy.png")
        window, area, region, _ = self.view3d()
        with bpy.context.temp_override(window=window, area=area, region=region):
            result = bpy.ops.cliff_terrain.open_view(filepath=path)
        shown = [
            a.spaces.active.image
            for w in bpy.context.window_manager.windows
            for a in w.screen.areas
            if a.type == "IMAGE_EDITOR" and a.spaces.active.image is not None
        ]
        self.checks["view_opens_in_an_image_editor"] = result == {"FINISHED"} and any(
            os.path.samefile(bpy.path.abspath(image.filepath), path) for image in shown
        )
        self.phase = "probe_start"
        return 0.5

    # ---- Probe Height: click a plant, read its height ----------------------------------------

    def phase_probe_start(self):
        # The Image Editor window that Open View made would take the click: close it.
        for window in list(bpy.context.window_manager.windows)[1:]:
            with bpy.context.temp_override(window=window):
                bpy.ops.wm.window_close()
        self.redraw()
        self.delay_then("probe_click")
        return 1.0

    def phase_probe_click(self):
        probe = importlib.import_module(f"{addon_package()}.scene.probe")
        obj = self.relief
        bpy.context.view_layer.objects.active = obj
        obj.pop(probe.PROBE_KEY, None)
        relief = probe.relief_of(obj)
        # The plant pixel farthest from its region's edge: a dome's top, where a screen pixel's
        # difference in the click changes the height least.
        import numpy as np

        row, col = np.unravel_index(np.argmax(np.where(relief.mask, relief.distance, -1)), relief.mask.shape)
        self.target = (int(row), int(col))
        self.core = relief
        info = obj["cliff_terrain"]
        scale = info["blender_units_per_unit"]
        size = info["pixel_size"] * scale
        rows = relief.heights.shape[0]
        from bpy_extras.view3d_utils import location_3d_to_region_2d
        from mathutils import Vector

        local = Vector(
            ((col + 0.5) * size, (rows - 1 - row + 0.5) * size, float(relief.heights[row, col]) * scale)
        )
        window, area, region, _ = self.view3d()
        point = location_3d_to_region_2d(region, area.spaces.active.region_3d, obj.matrix_world @ local)
        if point is None:
            self.finish("the plant to probe is not in the 3D view")
            return None
        result = self.invoke("cliff_terrain.probe_height")
        self.checks["probe_is_a_modal_tool"] = result == {"RUNNING_MODAL"}
        self.ask("click", point=self.to_screen(window, region.x + point.x, region.y + point.y))
        self.clicked = time.monotonic()
        self.phase = "probe_wait"
        return 0.5

    def phase_probe_wait(self):
        obj = self.relief
        values = obj.get("cliff_terrain_probe")
        if values is None:
            if time.monotonic() - self.clicked > 60:
                self.finish("clicking the relief with Probe Height read nothing in 60 s")
                return None
            return 0.3
        values = values.to_dict()
        relief, (row, col) = self.core, self.target
        top = float(relief.heights.max())
        self.notes.append(
            f"probe: clicked pixel ({row}, {col}), read ({values['row']}, {values['col']}): height "
            f"{values['height']:.4g} {values['unit']} (raster there {relief.heights[row, col]:.4g}), "
            f"plant {values['region']} p90 {values.get('region_p90', float('nan')):.4g}"
        )
        self.checks["probe_reads_the_clicked_plant"] = (
            abs(values["row"] - row) <= 2
            and abs(values["col"] - col) <= 2
            and values["region"] == int(relief.labels[row, col])
            and abs(values["height"] - float(relief.heights[row, col])) <= 0.01 * top
        )
        self.checks["probe_values_are_the_raster_at_its_pixel"] = (
            abs(values["height"] - float(relief.heights[values["row"], values["col"]])) <= 1e-6 * top
        )
        _, area, _, _ = self.view3d()
        self.redraw()
        self.settle_then("probe_shoot")
        return 1.0

    def phase_probe_shoot(self):
        self.shoot("probe")
        return 0.3

    def phase_shot_probe(self):
        self.probe_was_running = probe_running()
        window, area, region, _ = self.view3d()
        self.ask(
            "key", key="Escape", point=self.to_screen(window, region.x + region.width / 2, region.y + 40)
        )
        self.phase = "colour_start"
        return 1.0

    # ---- Colour By Height, and its colour bar -------------------------------------------------

    def phase_colour_start(self):
        # Window.modal_operators exists from Blender 4.2 (the oldest we support).
        self.checks["esc_ends_the_probe"] = self.probe_was_running and not probe_running()
        bpy.context.scene.cliff_terrain.color_by = "HEIGHT"
        self.redraw()
        self.settle_then("colour_shoot")
        return 1.5

    def phase_colour_shoot(self):
        self.shoot("color_by_height")
        return 0.3

    def phase_shot_color_by_height(self):
        import numpy as np

        window, area, region, _ = self.view3d()
        before = view_pixels(os.path.join(ARGS.work, "sidebar.png"), window, region)
        after = view_pixels(os.path.join(ARGS.work, "color_by_height.png"), window, region)
        changed = float((np.abs(after - before).max(axis=-1) > 0.1).mean())
        # The colour bar: viridis' dark violet at its foot, its yellow at its head.
        inspect = importlib.import_module(f"{addon_package()}.operators.inspect")
        x0, y0, width, height = inspect.colour_bar_box(area, region, bpy.context.preferences)
        top = region.height  # view_pixels' rows run from the region's top
        foot = after[int(top - y0 - 0.1 * height), int(x0 + width / 2)] * 255
        head = after[int(top - y0 - 0.9 * height), int(x0 + width / 2)] * 255
        self.notes.append(
            f"Colour By Height: {changed:.0%} of the 3D view changed; colour bar foot {foot.round()}, head {head.round()}"
        )
        self.checks["colour_by_height_changes_the_view"] = changed >= 0.05
        self.checks["colour_bar_is_drawn"] = foot[2] > foot[1] + 30 and head[1] > head[2] + 60
        bpy.context.scene.cliff_terrain.color_by = "PHOTO"
        self.phase = "plots_start" if ARGS.ortho else "end"
        if not ARGS.ortho:
            self.notes.append("no --ortho: the plot grid part was not run")
        return 0.5

    # ---- A plot grid over an orthophoto: added, fitted, measured, labelled --------------------

    def phase_plots_start(self):
        settings = bpy.context.scene.cliff_terrain
        settings.filepath = ARGS.ortho
        settings.dsm = os.path.join(os.path.dirname(ARGS.ortho), "dsm.tif")
        settings.height_source = "measured"
        settings.max_size = 250
        settings.two_sided = False
        before = set(bpy.data.objects.keys())
        window, area, region, _ = self.view3d()
        with bpy.context.temp_override(window=window, area=area, region=region):
            bpy.ops.cliff_terrain.build_relief("EXEC_DEFAULT")
        new = [obj for obj in bpy.data.objects if obj.name not in before and "cliff_terrain" in obj]
        if not new:
            self.finish("Build Relief made no relief of the orthophoto")
            return None
        ortho_relief = new[0]
        self.relief.hide_set(True)  # the photo's relief out of the way
        settings.plot_columns, settings.plot_rows = 4, 9
        settings.plot_width, settings.plot_length = 14.2, 4.8
        settings.plot_alley_across, settings.plot_alley_along = 3.8, 1.4
        with bpy.context.temp_override(window=window, area=area, region=region):
            bpy.ops.cliff_terrain.add_plot_grid("EXEC_DEFAULT")
            grid = bpy.context.view_layer.objects.active
            # Dragged roughly onto the plots (G), 1 m off: the plots' bottom-left corner read off the photo.
            plot_grid = importlib.import_module(f"{addon_package()}.scene.plot_grid_object")
            georaster = importlib.import_module(f"{addon_package()}.cliff_terrain.io.raster.geotiff")
            transform, _ = georaster.read_georeference(ARGS.ortho)
            corner = (
                transform[0, 2] + transform[0, 0] * 91 + 1.0,
                transform[1, 2] + transform[1, 1] * 377 - 0.8,
            )
            x, y = plot_grid.MapFrame(ortho_relief).to_world([corner])[0]
            grid.location = (x, y, grid.location.z)
            fitted = bpy.ops.cliff_terrain.fit_plot_grid("EXEC_DEFAULT")
            measured = bpy.ops.cliff_terrain.plot_table("EXEC_DEFAULT")
            bpy.ops.view3d.view_all()
        report = grid.get(plot_grid.FIT_KEY, {})
        table = grid.get(plot_grid.TABLE_KEY) or []
        self.notes.append(
            f"plot grid: fit {fitted}, angle {report.get('angle_deg', float('nan')):.2f} deg, "
            f"{report.get('plant_share_in_plots', 0):.0%} of plants in plots; {len(table)} plots measured"
        )
        self.checks["plot_grid_fitted_and_measured"] = (
            fitted == {"FINISHED"} and measured == {"FINISHED"} and len(table) == 36
        )
        settings.color_by = "PLOT_TRAIT"
        settings.show_plot_labels = False
        self.redraw()
        self.settle_then("plots_shoot_plain")
        return 1.5

    def phase_plots_shoot_plain(self):
        self.shoot("plots_plain")
        return 0.3

    def phase_shot_plots_plain(self):
        bpy.context.scene.cliff_terrain.show_plot_labels = True
        self.redraw()
        self.settle_then("plots_shoot")
        return 1.5

    def phase_plots_shoot(self):
        self.shoot("plots")
        return 0.3

    def phase_shot_plots(self):
        import numpy as np

        window, _, region, _ = self.view3d()
        plain = view_pixels(os.path.join(ARGS.work, "plots_plain.png"), window, region)
        labelled = view_pixels(os.path.join(ARGS.work, "plots.png"), window, region)
        changed = float((np.abs(labelled - plain).max(axis=-1) > 0.1).mean())
        self.notes.append(f"plot labels: {changed:.2%} of the 3D view changed")
        self.checks["plot_labels_are_drawn"] = changed > 0.001
        self.phase = "end"
        return 0.2

    def phase_end(self):
        self.finish()
        return None

    # ---- helpers -----------------------------------------------------------------------------

    def delay_then(self, phase, point=None):
        """Go to `phase` at the next tick (after the window has redrawn)."""
        if point is not None:
            self.click_point = point
        self.phase = phase
        self.waiting_for = None

    def settle_then(self, phase, redraws=3):
        """Go to `phase` after a few redraws, 0.7 s apart: Blender slides panels to their new places
        over several redraws when a panel grows (on Mesa's software renderer one takes 0.5 s)."""
        self.settle = (phase, redraws)
        self.phase = "settling"
        self.waiting_for = None

    def phase_settling(self):
        phase, left = self.settle
        self.redraw()
        if left <= 0:
            self.phase = phase
        else:
            self.settle = (phase, left - 1)
        return 0.7

    def redraw(self):
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                area.tag_redraw()


def probe_running():
    """True while Probe Height runs as a modal tool in the main window."""
    window = bpy.context.window_manager.windows[0]
    return any(op.bl_idname == "CLIFF_TERRAIN_OT_probe_height" for op in window.modal_operators)


def addon_package():
    """The add-on's package name: the installed extension's, or the one --source registers."""
    for name in list(sys.modules):
        if name.endswith(".operators.render_job"):
            return name.rpartition(".operators.")[0]
    raise RuntimeError("the Cliff Terrain add-on is not loaded")


def ensure_addon():
    """The add-on must be registered: installed (the zip, as users get it) or, with --source, from a
    source folder loaded the way render_views.py loads it."""
    if hasattr(bpy.types.Scene, "cliff_terrain"):
        return
    if not ARGS.source:
        raise RuntimeError("Cliff Terrain is not installed and enabled in this Blender (and no --source)")
    name = "cliff_terrain_addon"
    spec = importlib.util.spec_from_file_location(
        name, os.path.join(ARGS.source, "__init__.py"), submodule_search_locations=[ARGS.source]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    module.register()
    importlib.import_module(f"{name}.cliff_terrain")


def relief_image(obj):
    material = obj.active_material
    if material is None or material.node_tree is None:
        return None
    node = material.node_tree.nodes.active
    return node.image if node is not None and node.bl_idname == "ShaderNodeTexImage" else None


def framing(obj, area, region, rv3d):
    """How the 3D view shows the relief, in the part of the view that the toolbar and sidebar leave
    uncovered: (every bounding-box corner inside it, the share of its width or height the box spans,
    the distance of the box's projected middle from its middle as a share of its width)."""
    from bpy_extras.view3d_utils import location_3d_to_region_2d
    from mathutils import Vector

    space = area.spaces.active
    regions = {r.type: r for r in area.regions}
    overlap = bpy.context.preferences.system.use_region_overlap
    left = regions["TOOLS"].width if overlap and space.show_region_toolbar else 0
    right = region.width - (regions["UI"].width if overlap and space.show_region_ui else 0)
    corners = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
    points = [location_3d_to_region_2d(region, rv3d, c) for c in corners]
    if any(p is None for p in points):
        return False, 0.0, math.inf
    xs, ys = [p.x for p in points], [p.y for p in points]
    inside = min(xs) >= left and min(ys) >= 0 and max(xs) <= right and max(ys) <= region.height
    share = max((max(xs) - min(xs)) / (right - left), (max(ys) - min(ys)) / region.height)
    offset = abs(0.5 * (min(xs) + max(xs)) - 0.5 * (left + right)) / (right - left)
    return inside, share, offset


def load_pixels(path):
    """A PNG as a numpy (rows, cols, 3) float array, top row first."""
    import numpy as np

    image = bpy.data.images.load(path, check_existing=False)
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, dtype=np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1, :, :3]


def find_button(enabled_path, disabled_path, window, ui):
    """Screen centre (x, y) and height of the Build Relief button: the tallest band of rows that change
    across most of the sidebar's width when the button greys out (text that changes, such as the
    GSD note, changes only where its letters are)."""
    import numpy as np

    on, off = load_pixels(enabled_path), load_pixels(disabled_path)
    top = window.height - (ui.y + ui.height)
    left, right = int(ui.x + 0.05 * ui.width), int(ui.x + 0.85 * ui.width)  # short of the tab strip
    band = (slice(top, top + ui.height), slice(left, right))
    changed = np.abs(on[band] - off[band]).max(axis=-1) > 0.02
    wide = changed.mean(axis=1) > 0.6
    best, start = (0, 0), None
    for i, flag in enumerate([*wide, False]):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            best = max(best, (i - start, -start))  # the tallest; the topmost of equals
            start = None
    height, first = best[0], -best[1]
    scale = bpy.context.preferences.system.ui_scale
    if height < 0.9 * UNIT * scale:
        return None
    x = int(ui.x + ui.width * 0.45)
    return x, top + first + height // 2, height


def view_pixels(path, window, region):
    """The 3D view's pixels of a screenshot, (rows, cols, 3) in [0, 1], its top row first."""
    pixels = load_pixels(path)
    top = window.height - (region.y + region.height)
    return pixels[top : top + region.height, region.x : region.x + region.width]


def colourful_share(path, window, region):
    """Share of the 3D view's pixels in a screenshot with a chroma (max - min of R, G, B) over 8 of
    255: the photo's soil and leaves, not Blender's greys (chroma 0 to 2)."""
    pixels = load_pixels(path) * 255.0
    top = window.height - (region.y + region.height)
    view = pixels[top : top + region.height, region.x : region.x + region.width]
    return float(((view.max(axis=-1) - view.min(axis=-1)) > 8).mean())


def quit_blender():
    window = bpy.context.window_manager.windows[0]
    with bpy.context.temp_override(window=window):
        bpy.ops.wm.quit_blender()


TEST = Test()


def tick():
    try:
        return TEST.step()
    except Exception:
        TEST.finish(traceback.format_exc())
        return None


# No splash screen: on a fresh user folder it is the Quick Setup dialog, which swallows the clicks.
bpy.context.preferences.view.show_splash = False
# Windows exist once the event loop runs: start from a timer, never block in it.
bpy.app.timers.register(tick, first_interval=2.0)
