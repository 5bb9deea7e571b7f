"""Make the README's pictures from the project's own synthetic field (never from shared data).

    python tools/readme_figures.py [--demo demo/synthetic_field_relief]

Writes docs/images/pipeline.png (photo, quaternion filter, mask, distance map, heights) from the
core alone, and, when the demo's render folder exists (`make demo`), small copies of its views.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cliff_terrain import build_relief, synthetic_field  # noqa: E402

OUT = ROOT / "docs" / "images"
# The demo's outputs -> the README's pictures: the annotated side view and mesh (ruler, colour bar).
VIEWS = {
    "xy.png": "xy.png",
    "xy_flat.png": "xy_flat.png",
    "xz_annotated.png": "xz.png",
    "view3d.png": "view3d.png",
    "mesh_annotated.png": "mesh.png",
}


def _panel(rgb, title, width):
    scale = width / rgb.shape[1]
    rgb = cv2.resize(rgb, (width, round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    bar = np.full((28, width, 3), 255, np.uint8)
    cv2.putText(bar, title, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (20, 20, 20), 1, cv2.LINE_AA)
    return np.vstack([bar, rgb])


def _colour(values):
    v = values.astype(np.float32)
    v = (255 * v / max(float(v.max()), 1e-6)).astype(np.uint8)
    return cv2.applyColorMap(v, cv2.COLORMAP_VIRIDIS)[..., ::-1]


def pipeline_figure(path, width=300):
    image, _ = synthetic_field(seed=0)
    relief = build_relief(image)
    filtered = np.clip(relief.filtered * 255, 0, 255).astype(np.uint8)
    mask = np.where(relief.mask[..., None], 255, 0).astype(np.uint8).repeat(3, axis=2)
    mask[relief.boundaries] = (255, 0, 160)
    panels = [
        _panel(relief.working, "photo (synthetic field)", width),
        _panel(filtered, "quaternion filter", width),
        _panel(mask, f"mask, {relief.n_regions} regions", width),
        _panel(_colour(relief.distance), "distance map", width),
        _panel(_colour(relief.heights), f"heights ({relief.params['profile']})", width),
    ]
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    row = np.hstack([p if i == 0 else np.hstack([gap, p]) for i, p in enumerate(panels)])
    cv2.imwrite(str(path), row[..., ::-1])
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", type=Path, default=ROOT / "demo" / "synthetic_field_relief")
    args = parser.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    pipeline_figure(OUT / "pipeline.png")
    for name, target in VIEWS.items():
        src = args.demo / name
        if src.is_file():
            img = cv2.imread(str(src), cv2.IMREAD_COLOR)
            scale = 480 / img.shape[1]
            img = cv2.resize(img, (480, round(img.shape[0] * scale)), interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(OUT / target), img)
            print(f"wrote {OUT / target}")
        else:
            print(f"skipped {name}: {src} not found (run `make demo` first)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
