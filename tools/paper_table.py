"""The paper's Table 4 for a folder of photos: PSNR and SSIM of the lit top view against each photo.

    python tools/paper_table.py FOLDER [--out DIR] [--blender PATH] [--overwrite] [-- RENDER OPTIONS]

Runs ``render_views.py`` on every image in FOLDER (JPEG, PNG, TIFF, WebP, BMP; sub-folders too), each
into ``DIR/<relative path without suffix>/`` (default DIR: ``FOLDER_table/`` beside FOLDER), and prints a
Markdown table with the paper's row beside ours. An image whose metrics.json already exists is not
rendered again unless ``--overwrite`` is given. Options after ``--`` go to render_views.py unchanged.
With ``--blender PATH`` the images are rendered by that Blender (``blender -b -P``), else by this
Python (which needs the bpy wheel).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "render_views.py"
SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".bmp"}
sys.path.insert(0, str(ROOT))
from cliff_terrain.settings import PAPER_TABLE4  # noqa: E402  (imports nothing heavy)

# The paper's Table 4: its rendered top view against the photo.
PAPER = ("Paper (Table 4)", PAPER_TABLE4["psnr"], PAPER_TABLE4["ssim"])


def find_images(folder):
    return sorted(p for p in Path(folder).rglob("*") if p.is_file() and p.suffix.lower() in SUFFIXES)


def render_command(image, out, options, blender=None):
    args = [str(image), "--out", str(out), "--overwrite", *options]
    if blender:
        return [blender, "-b", "--factory-startup", "-P", str(SCRIPT), "--", *args]
    return [sys.executable, str(SCRIPT), *args]


def table(rows):
    """Markdown: one row per image (name, lit PSNR, lit SSIM, flat PSNR, flat SSIM, seconds), paper first."""
    lines = [
        "| Image | PSNR (dB) | SSIM | flat PSNR (dB) | flat SSIM | time (s) |",
        "|---|---:|---:|---:|---:|---:|",
        f"| {PAPER[0]} | {PAPER[1]:.2f} | {PAPER[2]:.4f} | - | - | - |",
    ]
    for name, m in rows:
        if m is None:
            lines.append(f"| {name} | failed | | | | |")
            continue
        flat = m.get("psnr_xy_flat")
        lines.append(
            f"| {name} | {m['psnr_xy']:.2f} | {m['ssim_xy']:.4f} | "
            f"{'inf' if flat is None else f'{flat:.2f}'} | {m['ssim_xy_flat']:.4f} | "
            f"{m['timings_s']['total']:.1f} |"
        )
    return "\n".join(lines)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    options = []
    if "--" in argv:
        options = argv[argv.index("--") + 1 :]
        argv = argv[: argv.index("--")]
    parser = argparse.ArgumentParser(prog="paper_table.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", metavar="FOLDER")
    parser.add_argument("--out", metavar="DIR", help="where the renders go (default FOLDER_table/)")
    parser.add_argument("--blender", metavar="PATH", help="render with this Blender executable")
    parser.add_argument("--overwrite", action="store_true", help="render again even if metrics.json exists")
    args = parser.parse_args(argv)
    folder = Path(args.folder)
    if not folder.is_dir():
        parser.error(f"not a folder: {folder}")
    images = find_images(folder)
    if not images:
        parser.error(f"no images in {folder}")
    out_root = Path(args.out) if args.out else folder.with_name(f"{folder.name}_table")

    rows = []
    for image in images:
        name = str(image.relative_to(folder))
        out = out_root / image.relative_to(folder).with_suffix("")
        metrics = out / "metrics.json"
        if args.overwrite or not metrics.is_file():
            print(f"rendering {name}", file=sys.stderr, flush=True)
            proc = subprocess.run(
                render_command(image, out, options, args.blender), capture_output=True, text=True
            )
            if proc.returncode != 0:
                last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
                print(f"  failed ({proc.returncode}): {last}", file=sys.stderr, flush=True)
                rows.append((name, None))
                continue
        rows.append((name, json.loads(metrics.read_text())))
    print(table(rows))
    return 0 if all(m is not None for _, m in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
