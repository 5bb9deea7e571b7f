"""The child of a Render Views / Evaluate job (see render_job.py): run inside ``blender -b COPY -P``.

Runs the operator on the relief of the saved copy, prints a progress line before each view, and
writes PSNR and SSIM to the job's result file. Any error ends Blender with status 1
(``--python-exit-code 1``) after printing it.
"""

import importlib
import importlib.util
import json
import os
import sys

import bpy

spec_path = sys.argv[sys.argv.index("--") + 1]
with open(spec_path, encoding="utf-8") as stream:
    job = json.load(stream)

# The installed extension is registered from the user's preferences; a copy loaded some other way
# (render_views.py, a development folder) is registered from its folder under the same name.
package = job["package"]
if not hasattr(bpy.types.Scene, "cliff_terrain"):
    if package not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            package,
            os.path.join(job["addon_dir"], "__init__.py"),
            submodule_search_locations=[job["addon_dir"]],
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[package] = module
        spec.loader.exec_module(module)
    sys.modules[package].register()

views = importlib.import_module(f"{package}.scene.views")
render_view = views.render_view


def announced(context, rig, view, path, **kwargs):
    print(f"{job['tag']} {view}", flush=True)
    return render_view(context, rig, view, path, **kwargs)


views.render_view = announced  # render_views() looks it up in its module at each call

scene = bpy.data.scenes[job["scene"]]
window_scene = bpy.context.scene
if window_scene != scene and bpy.context.window is not None:
    bpy.context.window.scene = scene
obj = bpy.data.objects[job["object"]]
view_layer = bpy.context.view_layer
for other in view_layer.objects.selected:
    other.select_set(False)
view_layer.objects.active = obj
obj.select_set(True)
settings = scene.cliff_terrain
settings.output_dir = job["out_parent"]
operator = (
    bpy.ops.cliff_terrain.render_views
    if job["operator"].endswith("render_views")
    else bpy.ops.cliff_terrain.evaluate
)
operator(engine=job["engine"], resolution=job["resolution"], samples=job["samples"])
with open(job["result"], "w", encoding="utf-8") as stream:
    json.dump({"psnr": settings.psnr, "ssim": settings.ssim}, stream)
