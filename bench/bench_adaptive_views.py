"""Benchmark: the lit and flat top views of the adaptive mesh at its default bound against the grid's.

For every shared photo of bench_adaptive_mesh.py (and the ODM pair with measured heights), in one
Blender process, grid and adaptive alternating: the relief as ``render_views.py --samples 8`` builds
it, its flat and lit top views only (the views ``metrics.json`` scores against the photo), their
PSNR and SSIM, the faces and the ``scene.blend`` render_views.py would save.

    python bench/bench_adaptive_views.py [--only NAME] [--samples 8]

`main(argv=None)` returns the rows as a dict.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_adaptive_mesh import MEASURED, PHOTOS, SHARED  # noqa: E402


def view_row(path, mesh, tmp, *, samples, **settings):
    """One relief's top views against its photo, as render_views.py makes and scores them."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    from cliff_terrain_addon import cliff_terrain as core
    from cliff_terrain_addon.cliff_terrain.evaluate import views as evaluation
    from cliff_terrain_addon.scene import rig, views
    from cliff_terrain_addon.scene.relief_object import build_relief_object as build_object

    relief = core.build_relief(str(path), mesh=mesh, **settings)
    rows, cols = relief.mesh.grid_shape
    obj = build_object(bpy.context, relief, str(path), relief.params, created=[])
    resolution = evaluation.view_resolution(None, rows, cols, name="--resolution")
    view_rig = rig.make_rig(
        bpy.context, obj, resolution=resolution, photo_shape=(relief.metadata.height, relief.metadata.width)
    )
    out = Path(tmp) / mesh
    out.mkdir(exist_ok=True)
    paths, _ = views.render_views(
        bpy.context, view_rig, str(out), views=("xy_flat", "xy"), samples=samples, quiet=True
    )
    metrics = views.evaluate_relief(obj, view_rig, paths["xy"], paths["xy_flat"], source=str(path))
    views.set_top_view(bpy.context, view_rig, "CYCLES", samples=samples)
    blend = out / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    return {
        "faces": len(obj.data.polygons),
        "blend_mb": blend.stat().st_size / 1e6,
        "lit_psnr": metrics["psnr_xy"],
        "lit_ssim": metrics["ssim_xy"],
        "flat_psnr": metrics["psnr_xy_flat"],
        "max_error": relief.max_error,
        "max_error_rule": relief.max_error_rule,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help="photos whose path contains this text")
    parser.add_argument("--samples", type=int, default=8)
    args = parser.parse_args(argv)

    import _loader

    bpy, addon, _core = _loader.start_blender(usage="python bench/bench_adaptive_views.py")
    cases = [(p, {}) for p in PHOTOS] + [(MEASURED[0], dict(MEASURED[1]))]
    out_rows = []
    with tempfile.TemporaryDirectory(prefix="cliff_terrain_views_") as tmp:
        for rel, settings in cases:
            if args.only and args.only not in rel:
                continue
            if "dsm" in settings:
                settings["dsm"] = str(SHARED / settings["dsm"])
            row = {"photo": rel + (" + DSM (measured)" if settings else "")}
            for mesh in ("grid", "adaptive"):
                row[mesh] = view_row(SHARED / rel, mesh, tmp, samples=args.samples, **settings)
            g, a = row["grid"], row["adaptive"]
            print(
                f"{row['photo']}: lit PSNR {g['lit_psnr']:.2f} -> {a['lit_psnr']:.2f} dB "
                f"({a['lit_psnr'] - g['lit_psnr']:+.2f}), SSIM {g['lit_ssim']:.3f} -> {a['lit_ssim']:.3f}; "
                f"flat {g['flat_psnr']:.2f} / {a['flat_psnr']:.2f} dB; faces {g['faces']} / {a['faces']} "
                f"({g['faces'] / a['faces']:.1f}x); scene.blend {g['blend_mb']:.1f} -> {a['blend_mb']:.1f} MB "
                f"({g['blend_mb'] / a['blend_mb']:.1f}x); bound {a['max_error']:.4g} ({a['max_error_rule']})",
                flush=True,
            )
            out_rows.append(row)
    addon.unregister()
    return {"blender": bpy.app.version_string, "photos": out_rows}


if __name__ == "__main__":
    main()
