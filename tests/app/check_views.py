"""Check what ``blender -b -P render_views.py -- PHOTO --out DIR`` wrote in a real Blender:
every view and map, and a top view that matches the photo (``python check_views.py PHOTO DIR``)."""

import json
import sys
from pathlib import Path

from PIL import Image

photo, out = Path(sys.argv[1]), Path(sys.argv[2])
metrics = json.loads((out / "metrics.json").read_text())
for name in (
    "xy.png",
    "xy_flat.png",
    "xz.png",
    "view3d.png",
    "mesh.png",
    "mask.png",
    "height.tif",
    "scene.blend",
):
    path = out / name
    assert path.is_file() and path.stat().st_size > 0, f"{name} is missing"
for name in ("xy.png", "xy_flat.png", "view3d.png"):
    with Image.open(out / name) as im:
        extrema = im.convert("L").getextrema()
        assert extrema[1] - extrema[0] > 20, f"{name} is blank: {extrema}"
# The flat top view is the photo's texture, pixel-aligned; the lit one keeps its colours.
assert metrics["psnr_xy_flat"] > 35 and metrics["ssim_xy_flat"] > 0.95, metrics
assert metrics["psnr_xy"] > 15 and metrics["ssim_xy"] > 0.5, metrics
assert metrics["regions"] > 0, metrics
print(
    f"check_views: ok, Blender {metrics.get('blender_version', '?')}: flat {metrics['psnr_xy_flat']:.2f} dB / "
    f"{metrics['ssim_xy_flat']:.4f}, lit {metrics['psnr_xy']:.2f} dB / {metrics['ssim_xy']:.4f}, "
    f"{metrics['regions']} regions"
)
