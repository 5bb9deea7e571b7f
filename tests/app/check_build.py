"""Run inside a real Blender (``blender -b --python-exit-code 1 --python check_build.py -- PHOTO OUT.json``)
with the extension installed from its zip: Build Relief builds a textured relief from the photo using
the zip's own libraries. Any failed check raises, so Blender exits non-zero."""

import json
import os
import sys

import bpy

# The core's libraries: the zip's wheels, installed for this Blender's Python (numpy is Blender's).
import cv2
import numpy
import scipy
import skimage

photo, out_path = sys.argv[sys.argv.index("--") + 1 :][:2]
module = "bl_ext.user_default.cliff_terrain"
assert module in bpy.context.preferences.addons, (
    f"the extension is not enabled: {list(bpy.context.preferences.addons.keys())}"
)
assert hasattr(bpy.types.Scene, "cliff_terrain"), "the extension's settings are not registered"

result = bpy.ops.cliff_terrain.build_relief(filepath=photo, max_size=400)
assert result == {"FINISHED"}, result
obj = bpy.context.active_object
stem = os.path.splitext(os.path.basename(photo))[0]
assert obj is not None and obj.name.startswith(stem), obj
mesh = obj.data
record = obj["cliff_terrain"]
# The default mesh is "auto": the grid (a vertex per pixel corner) or the adaptive TIN within its
# bound; either covers the whole processing grid of the photo (400 px on its longest side).
assert record["grid_rows"] * record["grid_cols"] > 400 * 100, (record["grid_rows"], record["grid_cols"])
assert record["mesh"] in ("grid", "adaptive") and record["mesh_rule"], (record["mesh"], record["mesh_rule"])
if record["mesh"] == "grid":
    assert len(mesh.vertices) > record["grid_rows"] * record["grid_cols"], len(mesh.vertices)
else:
    assert record["max_error"] > 0 and record["max_error_rule"], (
        record["max_error"],
        record["max_error_rule"],
    )
assert len(mesh.polygons) > 1000 and len(mesh.vertices) > 1000, (len(mesh.vertices), len(mesh.polygons))
co = numpy.empty(len(mesh.vertices) * 3, dtype=numpy.float32)
mesh.vertices.foreach_get("co", co)
heights = co[2::3]
assert heights.max() > heights.min(), "the relief is flat"
images = [
    node.image for node in obj.active_material.node_tree.nodes if node.type == "TEX_IMAGE" and node.image
]
assert images and os.path.samefile(bpy.path.abspath(images[0].filepath), photo), images
assert "cliff_terrain" in obj, "no custom property with the build settings"

user = os.environ["BLENDER_USER_RESOURCES"]
libraries = {m.__name__: (m.__version__, m.__file__) for m in (numpy, cv2, scipy, skimage)}
for name in ("cv2", "scipy", "skimage"):
    assert libraries[name][1].startswith(user), (name, libraries[name])
report = {
    "blender": bpy.app.version_string,
    "python": sys.version.split()[0],
    "libraries": {name: version for name, (version, _) in libraries.items()},
    "object": obj.name,
    "vertices": len(mesh.vertices),
    "faces": len(mesh.polygons),
    "mesh": record["mesh"],
    "height_range": [float(heights.min()), float(heights.max())],
}
with open(out_path, "w") as file:
    json.dump(report, file, indent=1)
print("check_build: ok", report)
