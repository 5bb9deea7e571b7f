"""Run every benchmark in bench/ (each prints its own figures and ratios) and write the benchmark page's table.

python bench/run_all.py            # all, then the table of docs/benchmarks.md
python bench/run_all.py filter     # the ones whose name contains "filter" (the page is left alone)

A benchmark's ``main`` returns its figures; those with ``rows`` (what, ours, peer, ratio, goal) make
the table of the docs' benchmark page (docs/benchmarks.md), between the markers below, so that its numbers are always a run's output and
never copied by hand. The Build benchmark also runs on the declared minimum Blender when its
environment (.venv-bpy42, ``make venv42``) exists. The page is written only after a run of every
benchmark in which none failed.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PAGE = ROOT / "docs" / "benchmarks.md"
BEGIN = "<!-- bench:begin (written by `make bench`, bench/run_all.py; not edited by hand) -->"
END = "<!-- bench:end -->"
BPY42_PYTHON = ROOT / ".venv-bpy42" / "bin" / "python"


def run_module(path):
    """Run one benchmark in this process; its figures (a dict) or None if it failed."""
    print(f"\n=== {path.stem} ===", flush=True)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    # Registered under its name, as an import would: a benchmark whose peer sends one of its
    # functions to worker processes (bench_season's multiprocessing pool) pickles it by that name.
    sys.modules[path.stem] = module
    start = time.perf_counter()
    try:
        spec.loader.exec_module(module)
        return module.main([]) or {}
    except Exception as exc:  # report and go on: one broken bench must not hide the others
        print(f"{path.stem} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return None
    finally:
        print(f"({path.stem} took {time.perf_counter() - start:.1f} s)", flush=True)


def run_build_on_bpy42():
    """bench_blender_build.py with the bpy 4.2 environment; its figures, or None."""
    print("\n=== bench_blender_build (bpy 4.2 environment) ===", flush=True)
    with tempfile.TemporaryDirectory(prefix="cliff_terrain_bench42_") as tmp:
        out = Path(tmp) / "figures.json"
        proc = subprocess.run(
            [str(BPY42_PYTHON), str(HERE / "bench_blender_build.py"), "--json", str(out)], check=False
        )
        if proc.returncode != 0 or not out.is_file():
            print(f"bench_blender_build on bpy 4.2 failed (exit {proc.returncode})", file=sys.stderr)
            return None
        return json.loads(out.read_text())


def table(rows):
    """A Markdown table of (what, ours, peer, ratio, goal) rows."""
    lines = ["| what | ours | peer | ratio | goal |", "|---|---|---|---|---|"]
    for row in rows:
        lines.append("| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |")
    return "\n".join(lines)


def write_page(rows, page=PAGE, *, start_load=None):
    """Put the table (with the machine, its load and the day it ran) between the page's markers."""
    sys.path.insert(0, str(HERE))
    import cv2
    import numpy as np
    from machine_info import describe

    text = page.read_text()
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        raise RuntimeError(f"{page.name} needs one {BEGIN!r} line, then one {END!r} line")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    started = "" if start_load is None else f" (it was {start_load:.2f} when the run started)"
    block = (
        f"Measured by `make bench` on {date.today().isoformat()}: {describe()}{started}, "
        f"numpy {np.__version__}, OpenCV {cv2.__version__}. The load average is the machine's as the "
        "run ended: other processes may share its cores, and absolute times move with the load more "
        "than ratios do.\n\n" + table(rows)
    )
    page.write_text(f"{head}{BEGIN}\n{block}\n{END}{tail}")
    print(f"\nwrote {len(rows)} rows into {page}")


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    start_load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    selected = [p for p in sorted(HERE.glob("bench_*.py")) if not argv or any(a in p.stem for a in argv)]
    results, failed = {}, []
    for path in selected:
        figures = run_module(path)
        if figures is None:
            failed.append(path.stem)
        results[path.stem] = figures or {}
        if path.stem == "bench_blender_build" and BPY42_PYTHON.is_file():
            figures = run_build_on_bpy42()
            if figures is None:
                failed.append("bench_blender_build (bpy 4.2)")
            results["bench_blender_build (bpy 4.2)"] = figures or {}
    if failed:
        print(f"\nfailed: {', '.join(failed)}; the benchmark page is left as it was", file=sys.stderr)
        return 1
    if not argv:
        # Some benchmarks return their rows of figures as a list (the memory and coarse-grid ones):
        # only a dict's "rows" go into the page's table.
        tables = [figures.get("rows", []) for figures in results.values() if isinstance(figures, dict)]
        rows = [tuple(row) for table_rows in tables for row in table_rows]
        write_page(rows, start_load=start_load)
    return 0


if __name__ == "__main__":
    sys.exit(main())
