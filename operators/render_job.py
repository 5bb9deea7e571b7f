"""Render Views and Evaluate as a background job, so the window keeps answering while Cycles renders.

Clicked in the sidebar (``invoke``), either operator saves a copy of the file, starts
``blender -b COPY -P render_job_child.py`` (the same operator, run on the copy), and follows it
from a modal timer: the status bar and progress bar count the views rendered, **Esc** stops the
job, and when it ends the results come back (PSNR and SSIM in the panel, the rendered views listed
in the panel, with a button that opens each in an Image Editor). Run from a script or in background
mode (``execute``), the operators still render in place, blocking, as before.

The child is the Blender that runs this one (``bpy.app.binary_path``) with the user's preferences,
so an installed Cliff Terrain is there too; otherwise the child registers the add-on from this
folder, as ``render_views.py`` does.
"""

import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time

import bpy
from bpy.props import StringProperty

from ..cliff_terrain.figures.writer import RENDERS
from ..scene.record import absolute_paths

ADDON_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHILD_SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "render_job_child.py")
# What the child prints before each view, and the views each operator renders.
PROGRESS_TAG = "CLIFF_TERRAIN_VIEW"
VIEW_COUNTS = {"render_views": 5, "evaluate": 2}
TIMER_S = 0.25
# The jobs running now (what the GUI test looks at).
JOBS = []


def job_kind(operator):
    """Which job `operator` runs, "render_views" or "evaluate" (its bl_idname is CLIFF_TERRAIN_OT_...)."""
    return "render_views" if operator.bl_idname.lower().endswith("render_views") else "evaluate"


def can_run_in_background():
    """A Blender executable to start (not the bpy Python module, not background mode)."""
    binary = bpy.app.binary_path
    return not bpy.app.background and bool(binary) and os.path.isfile(binary)


def output_folder(settings):
    """The absolute folder Render Views writes into (beside an unsaved file: the temporary folder)."""
    folder = settings.output_dir
    if folder.startswith("//") and not bpy.data.filepath:
        return os.path.join(tempfile.gettempdir(), folder[2:] or "cliff_terrain_renders")
    return bpy.path.abspath(folder) or os.path.abspath(".")


class Job:
    """One child Blender rendering the views of relief `obj`."""

    def __init__(self, operator, context, obj):
        self.kind = job_kind(operator)
        self.total = VIEW_COUNTS.get(self.kind, 1)
        self.done = 0
        self.lines = queue.Queue()
        self.tail = []
        self.folder = tempfile.mkdtemp(prefix="cliff_terrain_job_")
        copy = os.path.join(self.folder, "scene.blend")
        # A copy: the user's file (and its name, its unsaved state) stays as it is; the records'
        # paths relative to the file are written absolute into it (the copy lies elsewhere).
        with absolute_paths():
            bpy.ops.wm.save_as_mainfile(filepath=copy, copy=True, check_existing=False)
        settings = context.scene.cliff_terrain
        self.out_parent = output_folder(settings)
        self.out_dir = os.path.join(self.out_parent, bpy.path.clean_name(obj.name))
        self.result = os.path.join(self.folder, "result.json")
        spec = {
            "operator": self.kind,
            "object": obj.name,
            "scene": context.scene.name,
            "out_parent": self.out_parent,
            "engine": operator.engine,
            "resolution": operator.resolution,
            "samples": operator.samples,
            "package": __package__.rpartition(".")[0],
            "addon_dir": ADDON_DIR,
            "result": self.result,
            "tag": PROGRESS_TAG,
        }
        spec_path = os.path.join(self.folder, "job.json")
        with open(spec_path, "w", encoding="utf-8") as stream:
            json.dump(spec, stream)
        command = [
            bpy.app.binary_path,
            # The child finds Python modules where this Blender does (PYTHONPATH when it honours it).
            *([] if sys.flags.ignore_environment else ["--python-use-system-env"]),
            "-b",
            copy,
            "--python-exit-code",
            "1",
            "--python",
            CHILD_SCRIPT,
            "--",
            spec_path,
        ]
        # The child's temporary files go into the job's folder, removed even when Esc kills it.
        env = dict(os.environ, TMPDIR=self.folder, TEMP=self.folder, TMP=self.folder)
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1, env=env
        )
        # A thread reads the child's output: the timer must never wait for it.
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        self.started = time.monotonic()

    def _read(self):
        for line in self.process.stdout:
            self.lines.put(line.rstrip("\n"))

    def poll(self):
        """Progress so far: (finished, fraction, current view name or None)."""
        view = None
        while True:
            try:
                line = self.lines.get_nowait()
            except queue.Empty:
                break
            if line.startswith(PROGRESS_TAG):
                self.done += 1
                view = line.split()[1] if len(line.split()) > 1 else None
            else:
                self.tail = [*self.tail[-19:], line]
        finished = self.process.poll() is not None
        fraction = min(1.0, max(0.0, (self.done - 1) / self.total)) if self.done else 0.0
        return finished, fraction, view

    def cancel(self):
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.cleanup()

    def outcome(self):
        """(metrics dict, None) on success, else (None, an error message from the child's output)."""
        if self.process.returncode == 0 and os.path.isfile(self.result):
            with open(self.result, encoding="utf-8") as stream:
                return json.load(stream), None
        errors = [line for line in self.tail if "Error" in line or "error" in line]
        message = errors[-1] if errors else (self.tail[-1] if self.tail else "no output")
        return None, f"the background render failed (exit status {self.process.returncode}): {message}"

    def cleanup(self):
        shutil.rmtree(self.folder, ignore_errors=True)


def start(operator, context, obj):
    """Start the job of `operator` (invoke); falls back to rendering in place without a Blender binary."""
    if not can_run_in_background():
        return operator.execute(context)
    try:
        operator._job = Job(operator, context, obj)
    except (OSError, RuntimeError) as exc:
        operator.report({"ERROR"}, f"Cannot start the background render: {exc}")
        return {"CANCELLED"}
    JOBS.append(operator._job)
    wm = context.window_manager
    operator._timer = wm.event_timer_add(TIMER_S, window=context.window)
    wm.modal_handler_add(operator)
    wm.progress_begin(0, 100)
    _status(
        context, f"Cliff Terrain: starting Blender in the background ({operator.bl_label}, Esc to cancel)"
    )
    return {"RUNNING_MODAL"}


def modal(operator, context, event):
    job = operator._job
    if event.type == "ESC" and event.value == "PRESS":
        job.cancel()
        _end(operator, context)
        operator.report({"WARNING"}, f"{operator.bl_label} cancelled")
        return {"CANCELLED"}
    if event.type != "TIMER":
        return {"PASS_THROUGH"}  # the window keeps answering
    finished, fraction, view = job.poll()
    context.window_manager.progress_update(int(100 * fraction))
    if view is not None:
        _status(context, f"Cliff Terrain: rendering {view} ({job.done}/{job.total}), Esc to cancel")
    if not finished:
        return {"PASS_THROUGH"}
    metrics, error = job.outcome()
    print(f"Cliff Terrain: {operator.bl_label} job ended with status {job.process.returncode}", flush=True)
    job.cleanup()
    _end(operator, context)
    if error is not None:
        print("\n".join(["Cliff Terrain: the background render's last lines:", *job.tail]), flush=True)
        operator.report({"ERROR"}, error)
        return {"CANCELLED"}
    settings = context.scene.cliff_terrain
    settings.psnr = metrics.get("psnr", 0.0)
    settings.ssim = metrics.get("ssim", 0.0)
    seconds = time.monotonic() - job.started
    if job.kind == "render_views":
        settings.last_views = job.out_dir
        opened = open_in_image_editor(context, os.path.join(job.out_dir, "xy.png"), only_existing=True)
        where = " (the lit top view is in the Image Editor)" if opened else " (listed in the panel)"
        operator.report({"INFO"}, f"Rendered the views into {job.out_dir} in {seconds:.0f} s{where}")
    else:
        operator.report({"INFO"}, f"PSNR {settings.psnr:.2f} dB, SSIM {settings.ssim:.4f} ({seconds:.0f} s)")
    for area in context.screen.areas if context.screen else ():
        area.tag_redraw()
    return {"FINISHED"}


def _end(operator, context):
    if operator._job in JOBS:
        JOBS.remove(operator._job)
    wm = context.window_manager
    wm.event_timer_remove(operator._timer)
    wm.progress_end()
    _status(context, None)


def _status(context, text):
    if context.workspace is not None:
        context.workspace.status_text_set(text)


def rendered_views(folder):
    """The PNG files of a Render Views folder, in the order the views are listed."""
    if not folder or not os.path.isdir(folder):
        return []
    order = list(RENDERS)
    names = [name for name in os.listdir(folder) if name.lower().endswith(".png")]
    return sorted(names, key=lambda name: (order.index(name) if name in order else len(order), name))


def open_in_image_editor(context, path, *, only_existing=False):
    """Show image `path` in an Image Editor: an open one, else (unless `only_existing`) a new window."""
    if not os.path.isfile(path):
        return False
    image = bpy.data.images.load(path, check_existing=True)
    image.reload()  # the file was just rendered again
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = image
                area.tag_redraw()
                return True
    if only_existing:
        return False
    known = set(context.window_manager.windows[:])
    bpy.ops.wm.window_new()
    new = [window for window in context.window_manager.windows if window not in known]
    if not new:
        return False
    area = new[0].screen.areas[0]
    area.type = "IMAGE_EDITOR"
    area.spaces.active.image = image
    return True


class CLIFF_TERRAIN_OT_open_view(bpy.types.Operator):
    """Open a rendered view in an Image Editor"""

    bl_idname = "cliff_terrain.open_view"
    bl_label = "Open View"
    bl_options = {"REGISTER"}

    filepath: StringProperty(name="File", subtype="FILE_PATH")

    def execute(self, context):
        if not open_in_image_editor(context, self.filepath):
            self.report({"ERROR"}, f"Cannot open {self.filepath}")
            return {"CANCELLED"}
        return {"FINISHED"}


CLASSES = (CLIFF_TERRAIN_OT_open_view,)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
