"""Run every benchmark in bench/ (each prints its own figures and ratios) and say which ran.

python bench/run_all.py            # all
python bench/run_all.py filter     # the ones whose name contains "filter"
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    selected = [p for p in sorted(HERE.glob("bench_*.py")) if not argv or any(a in p.stem for a in argv)]
    failed = []
    for path in selected:
        print(f"\n=== {path.stem} ===", flush=True)
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        t = time.perf_counter()
        try:
            spec.loader.exec_module(module)
            module.main([])
        except Exception as exc:  # report and go on: one broken bench must not hide the others
            failed.append(path.stem)
            print(f"{path.stem} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        print(f"({path.stem} took {time.perf_counter() - t:.1f} s)", flush=True)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
