"""Benchmark: the adaptive mesh (a TIN within a vertical error) against the grid and Blender's Decimate.

For every shared photo, at the default `max_size` and the default maximum error:

* triangles of the adaptive front against the grid's (two per pixel), and the adaptive mesh's
  maximum vertical error measured at every pixel centre against the height raster;
* the whole Build Relief operator (``bpy.ops.cliff_terrain.build_relief``) with each mesh, and the
  size of the ``scene.blend`` each leaves (saved as render_views.py saves it);
* the peer, in the same run: Blender's Decimate modifier (collapse) applied to the grid relief's
  surface down to the same number of triangles; its time and its maximum vertical error at the
  pixel centres (the decimated surface sampled there; pixel centres it no longer covers are
  counted apart).

The ODM pair (orthophoto and DSM) is measured twice: heights inflated from the orthophoto, and
measured from the DSM (``height_source="measured"``, whose default bound is the DSM's noise).

With ``--auto``, the end-to-end comparison behind ``mesh="auto"``: the Build Relief operator (core
and Blender) on the 12 MP photo at ``max_size`` 500 to 4000 and on a 1500 x 1500 broccoli photo at
500 to 1500, grid and adaptive alternating in the same run, `--repeats` times each, and what
``auto`` chooses at each size against which was faster.

Then a 12 MP photo at full resolution (``max_size=4000``) through the operator with the adaptive
mesh. The photos are read from ../shared and never copied.

    python bench/bench_adaptive_mesh.py [--only NAME] [--no-peer] [--no-12mp] [--auto [--repeats N]]

`main(argv=None)` returns the figures as a dict (for bench/run_all.py).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np

# The extension registered in this process as the build benchmark loads it (_loader.register).
from bench_blender_build import ADDON, clear_scene, load_addon  # noqa: E402
from machine_info import describe, machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
PHOTOS = (
    "uav/broccoli/01_clip_raw_test.jpg",
    "uav/broccoli/2021a_grid_x03_y05-20220120171000-rze68yw.jpg",
    "uav/caliterra/IMG_9370.jpg",
    "uav/seneca_nir/IMG_0505.jpg",
    "uav/plantcv_dsm/rgb.tif",
    *(
        f"uav/lamberton_soybean/2018{day}_Lamberton_clipped.tif"
        for day in ("0815", "0822", "0829", "0905", "0914", "0917", "0925")
    ),
    "dsm/fieldimager_ex2/odm_orthophoto.tif",
)
# The ODM pair with measured heights (the default bound: the DSM's noise, at least 1 cm).
MEASURED = (
    "dsm/fieldimager_ex2/odm_orthophoto.tif",
    {"dsm": "dsm/fieldimager_ex2/dsm.tif", "height_source": "measured"},
)
FULL_RES = "uav/caliterra/IMG_9370.jpg"  # 4000 x 3000
# --auto: the photos and processing sizes of the end-to-end comparison behind mesh="auto".
AUTO_CASES = (
    ("uav/caliterra/IMG_9370.jpg", (500, 1000, 1250, 1500, 2000, 4000)),
    ("uav/broccoli/01_clip_raw_test.jpg", (500, 700, 1000, 1250, 1500)),
)
GOALS = {"triangle_ratio": 10.0, "blend_ratio": 5.0, "full_res_s": 3.0}


def run_operator(path, mesh, tmp, **kwargs):
    """The Build Relief operator's time and the scene.blend it leaves (bytes)."""
    import bpy

    clear_scene()
    start = time.perf_counter()
    result = bpy.ops.cliff_terrain.build_relief(filepath=str(path), mesh=mesh, **kwargs)
    seconds = time.perf_counter() - start
    assert result == {"FINISHED"}, result
    obj = bpy.context.active_object
    faces = len(obj.data.polygons)
    blend = Path(tmp) / f"{mesh}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    size = blend.stat().st_size
    blend.unlink()
    return seconds, faces, size


def surface_at_centres(x, y, z, triangles, shape):
    """A triangle surface sampled at every pixel centre (x = column, y = row, in pixels, centres at
    +0.5), the largest value where a centre lies in several triangles; NaN where it lies in none.

    Float edge functions with a tolerance: the peer's vertices lie anywhere, not on a lattice.
    """
    rows, cols = shape
    out = np.full(rows * cols, np.nan)
    tx, ty, tz = x[triangles], y[triangles], z[triangles].astype(np.float64)
    c_lo = np.clip(np.ceil(tx.min(1) - 0.5), 0, cols - 1).astype(np.int64)
    c_hi = np.clip(np.floor(tx.max(1) - 0.5), -1, cols - 1).astype(np.int64)
    r_lo = np.clip(np.ceil(ty.min(1) - 0.5), 0, rows - 1).astype(np.int64)
    r_hi = np.clip(np.floor(ty.max(1) - 0.5), -1, rows - 1).astype(np.int64)
    bw, bh = np.maximum(c_hi - c_lo + 1, 0), np.maximum(r_hi - r_lo + 1, 0)
    box = bw * bh
    area = (tx[:, 1] - tx[:, 0]) * (ty[:, 2] - ty[:, 0]) - (ty[:, 1] - ty[:, 0]) * (tx[:, 2] - tx[:, 0])
    ends = np.cumsum(box)
    start = 0
    while start < len(triangles):
        stop = max(
            int(np.searchsorted(ends, (ends[start - 1] if start else 0) + 2_000_000, "right")), start + 1
        )
        sel = np.arange(start, stop)
        counts = box[sel]
        tri = np.repeat(sel, counts)
        off = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        pr = r_lo[tri] + off // np.maximum(bw[tri], 1)
        pc = c_lo[tri] + off % np.maximum(bw[tri], 1)
        px, py = pc + 0.5, pr + 0.5
        x0, x1, x2 = tx[tri, 0], tx[tri, 1], tx[tri, 2]
        y0, y1, y2 = ty[tri, 0], ty[tri, 1], ty[tri, 2]
        a = area[tri]
        w0 = ((x2 - x1) * (py - y1) - (y2 - y1) * (px - x1)) / a
        w1 = ((x0 - x2) * (py - y2) - (y0 - y2) * (px - x2)) / a
        w2 = 1.0 - w0 - w1
        eps = -1e-9
        inside = (a != 0) & (w0 >= eps) & (w1 >= eps) & (w2 >= eps)
        value = w0 * tz[tri, 0] + w1 * tz[tri, 1] + w2 * tz[tri, 2]
        np.fmax.at(out, (pr * cols + pc)[inside], value[inside])
        start = stop
    return out.reshape(shape)


def run_peer(heights, target_triangles):
    """Decimate (collapse) on the grid relief's surface down to `target_triangles`: seconds, triangles,
    max vertical error at the pixel centres it covers, and the share of centres it no longer covers."""
    import bpy

    core = sys.modules[f"{ADDON}.cliff_terrain"]
    mesh_data = sys.modules[f"{ADDON}.scene.mesh_data"]
    clear_scene()
    rows, cols = heights.shape
    mesh = mesh_data.mesh_from_arrays("peer", core.grid_mesh(heights, two_sided=False))
    obj = bpy.data.objects.new("peer", mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    start = time.perf_counter()
    modifier = obj.modifiers.new("Decimate", "DECIMATE")
    modifier.decimate_type = "COLLAPSE"
    modifier.ratio = target_triangles / (2.0 * rows * cols)
    bpy.ops.object.modifier_apply(modifier=modifier.name)
    seconds = time.perf_counter() - start
    mesh = obj.data
    mesh.calc_loop_triangles()
    tris = np.empty(3 * len(mesh.loop_triangles), dtype=np.int32)
    mesh.loop_triangles.foreach_get("vertices", tris)
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)
    # Grid coordinates: x = column, y up from the last row (pixel size 1).
    surface = surface_at_centres(co[:, 0], rows - co[:, 1], co[:, 2], tris.reshape(-1, 3), (rows, cols))
    covered = ~np.isnan(surface)
    error = float(np.abs(surface - heights)[covered].max())
    return seconds, len(tris) // 3, error, float(1.0 - covered.mean())


def measure(path, tmp, *, peer, max_size=None, dsm=None, height_source="inflated"):
    import bpy  # noqa: F401  (the operator needs Blender)

    core = sys.modules[f"{ADDON}.cliff_terrain"]
    mesh_mod = importlib.import_module(f"{ADDON}.cliff_terrain.mesh.adaptive")
    tin = importlib.import_module(f"{ADDON}.cliff_terrain.mesh.tin_sample")
    sizes = {} if max_size is None else {"max_size": max_size}
    if dsm is not None:
        sizes.update(dsm=str(dsm), height_source=height_source)
    relief = core.build_relief(str(path), mesh="adaptive", **sizes)
    heights = relief.heights
    rows, cols = heights.shape
    grid_triangles = 2 * rows * cols
    start = time.perf_counter()
    mesh = mesh_mod.adaptive_mesh(heights, max_error=relief.max_error, pixel_size=relief.pixel_size)
    adaptive_s = time.perf_counter() - start
    front = mesh.front_triangles()  # as Blender splits the quads the triangles were paired into
    centres = tin.sample_front(mesh.vertices, front, (rows, cols))[1::2, 1::2]
    max_error = float(np.abs(centres - heights).max())
    grid_s, grid_faces, grid_blend = run_operator(path, "grid", tmp, **sizes)
    ours_s, ours_faces, ours_blend = run_operator(path, "adaptive", tmp, **sizes)
    row = {
        "photo": str(path.relative_to(SHARED)) + ("" if dsm is None else f" + DSM ({height_source})"),
        "grid": [rows, cols],
        "units": relief.units,
        "max_height": relief.max_height,
        "max_error_bound": relief.max_error,
        "max_error_rule": relief.max_error_rule,
        "max_error_measured": max_error,
        "within_bound": max_error <= relief.max_error * (1 + 1e-6),
        "grid_triangles": grid_triangles,
        "adaptive_triangles": len(front),
        "triangle_ratio": grid_triangles / len(front),
        "faces_grid": grid_faces,
        "faces_adaptive": ours_faces,
        "faces_ratio": grid_faces / ours_faces,
        "adaptive_mesh_s": adaptive_s,
        "operator_grid_s": grid_s,
        "operator_adaptive_s": ours_s,
        "operator_speedup": grid_s / ours_s,
        "blend_grid_mb": grid_blend / 1e6,
        "blend_adaptive_mb": ours_blend / 1e6,
        "blend_ratio": grid_blend / ours_blend,
    }
    if peer:
        peer_s, peer_tris, peer_error, uncovered = run_peer(heights / relief.pixel_size, len(front))
        row.update(
            decimate_s=peer_s,
            decimate_triangles=peer_tris,
            decimate_max_error=peer_error * relief.pixel_size,
            decimate_uncovered=uncovered,
        )
    clear_scene()
    return row


def compare_end_to_end(path, sizes, tmp, *, repeats):
    """Build Relief operator seconds (core and Blender) with each mesh at each of `sizes`,
    alternating grid and adaptive; `repeats` runs each, the faces, and what ``auto`` chooses."""
    choose_mesh = importlib.import_module(f"{ADDON}.cliff_terrain.mesh.adaptive").choose_mesh
    grid_shape = importlib.import_module(f"{ADDON}.cliff_terrain.build").grid_shape
    rows = []
    for size in sizes:
        seconds = {"grid": [], "adaptive": []}
        faces = {}
        for _ in range(repeats):
            for mesh in ("grid", "adaptive"):
                s, n, _size = run_operator(path, mesh, tmp, max_size=size)
                seconds[mesh].append(s)
                faces[mesh] = n
        shape = grid_shape(str(path), max_size=size)  # from the photo's header, as the operator does
        g, a = seconds["grid"], seconds["adaptive"]
        ratio = float(np.median(g) / np.median(a))
        auto, rule = choose_mesh("auto", shape)
        row = {
            "photo": str(path.relative_to(SHARED)),
            "max_size": size,
            "shape": list(shape),
            "seconds": seconds,
            "faces": faces,
            "grid_over_adaptive": ratio,
            "auto": auto,
            "auto_rule": rule,
        }
        rows.append(row)
        print(
            f"{path.name} at max_size={size} ({shape[1]}x{shape[0]}, {shape[0] * shape[1] / 1e6:.2f} MP): grid "
            f"{min(g):.2f}-{max(g):.2f} s, adaptive {min(a):.2f}-{max(a):.2f} s (median {np.median(g):.2f} vs "
            f"{np.median(a):.2f}: grid/adaptive {ratio:.2f}); faces {faces['grid']} / {faces['adaptive']}; "
            f"auto makes the {auto}",
            flush=True,
        )
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help="photos whose path contains this text")
    parser.add_argument("--no-peer", action="store_true", help="skip Blender's Decimate")
    parser.add_argument("--no-12mp", action="store_true", help="skip the 12 MP photo at max_size=4000")
    parser.add_argument("--max-size", type=int, default=None, help="processing size (default: the default)")
    parser.add_argument("--auto", action="store_true", help="only the end-to-end timings behind mesh='auto'")
    parser.add_argument("--repeats", type=int, default=3, help="--auto: runs of each mesh at each size")
    args = parser.parse_args(argv)

    import bpy

    info = machine()
    print(f"machine: {describe(info)}; Blender {bpy.app.version_string} (bpy module)")
    addon, registered_here = load_addon()
    rows_out, full, auto = [], None, None
    try:
        with tempfile.TemporaryDirectory(prefix="cliff_terrain_bench_") as tmp:
            if args.auto:
                bpy.ops.cliff_terrain.build_relief(filepath=str(SHARED / FULL_RES), max_size=64)  # warm-up
                auto = []
                for photo, sizes in AUTO_CASES:
                    if not args.only or args.only in photo:
                        auto += compare_end_to_end(SHARED / photo, sizes, tmp, repeats=args.repeats)
                return {"machine": info, "blender": bpy.app.version_string, "auto": auto}
            cases = [(p, {}) for p in PHOTOS] + [(MEASURED[0], {k: v for k, v in MEASURED[1].items()})]
            cases = [(SHARED / p, kw) for p, kw in cases if not args.only or args.only in p]
            for _, kw in cases:
                if "dsm" in kw:
                    kw["dsm"] = SHARED / kw["dsm"]
            photos = [p for p, _ in cases]
            missing = [str(p) for p in photos if not p.is_file()]
            if missing:
                print(f"not found (skipped): {', '.join(missing)}")
            cases = [(p, kw) for p, kw in cases if p.is_file()]
            if cases:  # warm-up: the first build imports SciPy, scikit-image and OpenCV
                bpy.ops.cliff_terrain.build_relief(filepath=str(cases[0][0]), max_size=64)
            for path, kw in cases:
                try:
                    row = measure(path, tmp, peer=not args.no_peer, max_size=args.max_size, **kw)
                except Exception as exc:  # one unreadable photo must not hide the others
                    print(f"{path.name}: {type(exc).__name__}: {exc}")
                    continue
                rows_out.append(row)
                peer = (
                    f" | Decimate {row['decimate_s']:.2f} s, {row['decimate_triangles']} tris, max error "
                    f"{row['decimate_max_error']:.3g} ({row['decimate_max_error'] / row['max_error_bound']:.1f}x "
                    f"the bound), {100 * row['decimate_uncovered']:.2f} % centres uncovered"
                    if "decimate_s" in row
                    else ""
                )
                print(
                    f"{row['photo']}: {row['grid'][1]}x{row['grid'][0]}, {row['triangle_ratio']:.1f}x fewer "
                    f"triangles ({row['adaptive_triangles']}), faces {row['faces_grid']} / {row['faces_adaptive']} "
                    f"({row['faces_ratio']:.1f}x), max error {row['max_error_measured']:.4g} <= "
                    f"{row['max_error_bound']:.4g} {row['units']} ({row['max_error_rule']}): {row['within_bound']}; TIN+mesh "
                    f"{row['adaptive_mesh_s']:.2f} s; operator {row['operator_grid_s']:.2f} -> "
                    f"{row['operator_adaptive_s']:.2f} s ({row['operator_speedup']:.2f}x); blend "
                    f"{row['blend_grid_mb']:.1f} -> {row['blend_adaptive_mb']:.1f} MB "
                    f"({row['blend_ratio']:.1f}x){peer}",
                    flush=True,
                )
            full_path = SHARED / FULL_RES
            if not args.no_12mp and full_path.is_file():
                runs = [run_operator(full_path, "adaptive", tmp, max_size=4000) for _ in range(2)]
                core = sys.modules[f"{ADDON}.cliff_terrain"]
                start = time.perf_counter()
                relief = core.build_relief(str(full_path), max_size=4000, mesh="adaptive")
                core_s = time.perf_counter() - start
                full = {
                    "photo": FULL_RES,
                    "operator_runs_s": [r[0] for r in runs],
                    "faces": runs[0][1],
                    "core_s": core_s,
                    "core_stages_s": relief.timings,
                    "grid": list(relief.heights.shape),
                }
                stages = ", ".join(f"{k} {v:.2f}" for k, v in relief.timings.items())
                print(
                    f"12 MP at max_size=4000, adaptive: operator {min(full['operator_runs_s']):.2f} s "
                    f"(runs {', '.join(f'{s:.2f}' for s in full['operator_runs_s'])}; goal <= "
                    f"{GOALS['full_res_s']:g} s), {full['faces']} faces; core alone {core_s:.2f} s ({stages})"
                )
            clear_scene()
    finally:
        if registered_here:
            addon.unregister()
    if rows_out:
        ratios = [r["triangle_ratio"] for r in rows_out]
        print(
            f"summary over {len(rows_out)} photos: triangles {min(ratios):.1f}-{max(ratios):.1f}x fewer (goal "
            f">= {GOALS['triangle_ratio']:g}x); every error within its bound: "
            f"{all(r['within_bound'] for r in rows_out)}; operator speed-up "
            f"{min(r['operator_speedup'] for r in rows_out):.2f}-{max(r['operator_speedup'] for r in rows_out):.2f}x; "
            f"scene.blend {min(r['blend_ratio'] for r in rows_out):.1f}-{max(r['blend_ratio'] for r in rows_out):.1f}x "
            f"smaller (goal >= {GOALS['blend_ratio']:g}x)"
        )
    return {"machine": info, "blender": bpy.app.version_string, "photos": rows_out, "full_res": full}


if __name__ == "__main__":
    main()
