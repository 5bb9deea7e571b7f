"""Where the Build Relief operator's time goes: each step's start and end, per thread.

The operator runs on the benchmark's photo (see bench_blender_build.py) with the core's and the
add-on's main steps wrapped in timers; each run prints a table of (thread, start ms, end ms,
duration ms, step), in start order. It shows which steps of the main thread (Blender's calls) run
beside which steps of the worker thread (decoding, segmentation, the watershed). The timers add
about a millisecond. Not a benchmark: no peer, no ratio.

    python bench/build_timeline.py [--max-size 2000] [--runs 3]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_blender_build as bench  # noqa: E402

# module (under the add-on's package) -> the functions or methods timed in it
STEPS = {
    "cliff_terrain.build": [
        "open_image",
        "resize_longest",
        "quaternion_filter",
        "segment",
        "grid_topology",
        "distance_map",
        "inflate",
        "place_vertices",
        "adaptive_mesh",
    ],
    "cliff_terrain.mesh.adaptive": ["tin_mesh", "triangulate"],
    "cliff_terrain.io.photo": ["OpenImage.decode"],
    "cliff_terrain.photo_heights.segmentation": [
        "_vegetation_mask",
        "clean_mask",
        "distance_map",
        "colour_edges",
        "inner_boundaries",
    ],
    # split_regions looks these up in its own module
    "cliff_terrain.photo_heights.watershed": [
        "label4",
        "label_max",
        "_watershed_raveled",
        "_flood_components",
    ],
    "operators.build": [
        "allocate_mesh",
        "checked_topology",
        "fill_topology",
        "show_relief",
    ],
    "scene.relief_object": [
        "set_positions",
        "mesh_from_arrays",
        "load_photo",
        "textured_object",
    ],
    "scene.datablocks": ["relief_material"],
}


def wrap_steps(log, clock):
    """Replace each step by a timed wrapper that appends (thread, start, end, name) to `log`."""
    for module_name, names in STEPS.items():
        module = importlib.import_module(f"{bench.ADDON}.{module_name}")
        for name in names:
            owner, attribute = module, name
            if "." in name:
                class_name, attribute = name.split(".")
                owner = getattr(module, class_name)
            function = getattr(owner, attribute)

            def timed(*args, _function=function, _name=name, **kwargs):
                start = time.perf_counter()
                try:
                    return _function(*args, **kwargs)
                finally:
                    thread = "main" if threading.current_thread() is threading.main_thread() else "worker"
                    log.append((thread, start - clock[0], time.perf_counter() - clock[0], _name))

            setattr(owner, attribute, functools.wraps(function)(timed))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--max-size", type=int, default=2000, help="processing grid's longest side")
    parser.add_argument("--runs", type=int, default=3, help="runs to print (the first is often slow)")
    parser.add_argument("--mesh", choices=("grid", "adaptive"), default="grid", help="the relief's mesh")
    parser.add_argument("--photo", type=Path, help="this photo instead of the benchmark's")
    args = parser.parse_args(argv)

    import bpy

    addon, registered_here = bench.load_addon()
    importlib.import_module(f"{bench.ADDON}.cliff_terrain")  # the operator imports it when it first runs
    log, clock = [], [0.0]
    wrap_steps(log, clock)
    try:
        with tempfile.TemporaryDirectory(prefix="cliff_terrain_timeline_") as tmp:
            photo = args.photo
            if photo is None:
                photo = Path(tmp) / "bench_photo.jpg"
                bench.write_photo(photo)
            for run in range(args.runs):
                bench.clear_scene()
                log.clear()
                clock[0] = time.perf_counter()
                result = bpy.ops.cliff_terrain.build_relief(
                    filepath=str(photo), max_size=args.max_size, mesh=args.mesh
                )
                total = time.perf_counter() - clock[0]
                assert result == {"FINISHED"}, result
                print(f"run {run + 1}: {1000 * total:.0f} ms")
                for thread, start, end, name in sorted(log, key=lambda entry: entry[1]):
                    print(
                        f"  {thread:6s} {1000 * start:7.1f} {1000 * end:7.1f} {1000 * (end - start):6.1f}  {name}"
                    )
            bench.clear_scene()
    finally:
        if registered_here:
            addon.unregister()


if __name__ == "__main__":
    main()
