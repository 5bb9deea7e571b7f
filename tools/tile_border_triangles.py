"""Picture and count the long, thin triangles along a mosaic's tile borders (issue #28, item 5).

A synthetic field (the benchmark's, ``bench/bench_mosaic.py``) is written as a tiled GeoTIFF of
2 x 2 tiles and meshed as Import Mosaic meshes it (:func:`cliff_terrain.mosaic.meshes.tile_meshes`,
by default the benchmark's 0.5-pixel bound). A front triangle is *thin* along a border when all its corners
lie within the tile's last two lines of pixel centres (1.5 px of its side), it is at least
`--min-length` pixels long and it is not level (its corners' heights differ by more than the
bound): such a triangle draws a streak in a lit view. Prints the counts and sizes per border and
draws the longest one's neighbourhood as a wireframe over the heights.

    python tools/tile_border_triangles.py [--out docs/images/tile_border_triangles.png]
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PHOTO = ROOT.parent / "shared" / "data" / "uav" / "caliterra" / "IMG_9370.jpg"
sys.path.insert(0, str(ROOT))

from cliff_terrain.data.synthetic import synthetic_field  # noqa: E402
from cliff_terrain.io.raster.mosaic import MosaicReader  # noqa: E402
from cliff_terrain.mosaic.meshes import tile_meshes  # noqa: E402


def write_field(path, side, seed=5, photo=None):
    import tifffile

    if photo is None:
        field, _ = synthetic_field(shape=(side, side), seed=seed)
    else:
        from cliff_terrain.io.photo import load_image

        field = load_image(photo)[0]
    tifffile.imwrite(path, field, tile=(256, 256), photometric="rgb", compression="zlib")


def thin_border_triangles(mesh, *, min_length, max_error):
    """(triangle corners (n, 3, 3), side names, lengths, widths) of the thin, sloped border triangles."""
    faces = mesh.front_triangles()
    corners = mesh.vertices[faces]  # (n, 3, 3)
    x, y, z = corners[..., 0], corners[..., 1], corners[..., 2]
    width, height = mesh.vertices[:, 0].max(), mesh.vertices[:, 1].max()
    # The TIN's triangles only (corners on pixel centres, not on the half-pixel frame).
    tin = (x > 0.25).all(1) & (x < width - 0.25).all(1) & (y > 0.25).all(1) & (y < height - 0.25).all(1)
    sides = {
        "left": tin & (x <= 1.5).all(1),
        "right": tin & (x >= width - 1.5).all(1),
        "bottom": tin & (y <= 1.5).all(1),
        "top": tin & (y >= height - 1.5).all(1),
    }
    edges = np.stack([corners[:, k] - corners[:, (k + 1) % 3] for k in range(3)], 1)[..., :2]
    lengths = np.linalg.norm(edges, axis=2).max(1)
    area = 0.5 * np.abs(edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0])
    widths = 2 * area / np.maximum(lengths, 1e-9)
    sloped = np.ptp(z, axis=1) > max_error
    out = []
    for name, along in sides.items():
        keep = along & sloped & (lengths >= min_length)
        out += [(corners[i], name, lengths[i], widths[i]) for i in np.flatnonzero(keep)]
    return out


def draw(tile, found, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    corners, side, length, _ = max(found, key=lambda f: f[2])
    mesh = tile.mesh
    rows = tile.relief.heights.shape[0]
    cx, cy = corners[:, 0].mean(), corners[:, 1].mean()
    width = mesh.vertices[:, 0].max()
    along, across = max(40.0, 1.8 * length), max(16.0, 0.4 * length)
    # From a pixel of the neighbour's side of the border into the tile.
    if side in ("left", "right"):
        x0 = -1.0 if side == "left" else width + 1.0 - across
        x0, x1, y0, y1 = x0, x0 + across, cy - along / 2, cy + along / 2
    else:
        y0 = -1.0 if side == "bottom" else rows + 1.0 - across
        x0, x1, y0, y1 = cx - along / 2, cx + along / 2, y0, y0 + across
    faces = mesh.front_triangles()
    tri = mesh.vertices[faces]
    near = (
        (tri[..., 0].max(1) >= x0)
        & (tri[..., 0].min(1) <= x1)
        & (tri[..., 1].max(1) >= y0)
        & (tri[..., 1].min(1) <= y1)
    )
    thin = {tuple(np.round(c[:, :2].ravel(), 3)) for c, *_ in found}
    is_thin = np.array([tuple(np.round(t[:, :2].ravel(), 3)) in thin for t in tri[near]])
    fig, ax = plt.subplots(figsize=(7.2, 3.6) if side in ("top", "bottom") else (4.2, 6.4), dpi=110)
    heights = tile.relief.heights
    # The heights raster under the mesh, image rows downwards = mesh y upwards.
    image = ax.imshow(
        heights,
        cmap="Greys",
        vmax=1.4 * float(heights.max()) or 1.0,
        origin="upper",
        extent=(0, heights.shape[1], 0, rows),
        interpolation="nearest",
    )
    fig.colorbar(image, ax=ax, shrink=0.8, label="height (px)")
    ax.add_collection(
        PolyCollection(tri[near][~is_thin][..., :2], facecolors="none", edgecolors="tab:blue", linewidths=0.4)
    )
    ax.add_collection(
        PolyCollection(
            tri[near][is_thin][..., :2], facecolors=(1, 0, 0, 0.35), edgecolors="red", linewidths=1.2
        )
    )
    border_x = heights.shape[1] if side == "right" else 0
    border_y = rows if side == "top" else 0
    if side in ("left", "right"):
        ax.axvline(border_x, color="black", lw=1.2, label="tile border")
    else:
        ax.axhline(border_y, color="black", lw=1.2, label="tile border")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    # Scale bar: 10 pixels.
    bx, by = x0 + 0.05 * (x1 - x0), y0 + 0.08 * (y1 - y0)
    ax.plot([bx, bx + 10], [by, by], color="black", lw=3)
    ax.text(bx + 5, by + 0.03 * (y1 - y0), "10 px", ha="center", va="bottom", fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(
        f"TIN of the tile at rows {tile.core[0]}-{tile.core[1]}, columns {tile.core[2]}-{tile.core[3]}, "
        f"its {side} border:\nthin sloped triangles in red (the longest {length:.0f} px)",
        fontsize=8,
    )
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=110)
    plt.close(fig)
    from PIL import Image

    # A palette of 96 colours keeps the picture small (it is a wireframe over a colour ramp).
    Image.open(buffer).convert("RGB").quantize(96).save(out, optimize=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--side", type=int, default=2048, help="the field's side in pixels")
    parser.add_argument("--tile", type=int, default=1024)
    parser.add_argument(
        "--max-error", type=float, default=0.5, help="the bound in pixels (0.5: the benchmark's)"
    )
    parser.add_argument(
        "--min-length", type=float, default=8.0, help="thin triangles at least this long (px)"
    )
    parser.add_argument(
        "--photo",
        default=str(PHOTO) if PHOTO.is_file() else None,
        help="the photo to use as the mosaic (default caliterra IMG_9370, the 12 MP shared photo); "
        "'' for the benchmark's synthetic field",
    )
    parser.add_argument("--out", default=str(ROOT / "docs" / "images" / "tile_border_triangles.png"))
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "field.tif"
        write_field(path, args.side, photo=args.photo or None)
        with MosaicReader(path) as reader:
            tiles = list(tile_meshes(reader, max_error=args.max_error, tile=args.tile, overlap=256))
        shape = reader.shape
    found_all, best, n_borders = [], None, 0
    for tile in tiles:
        r0, r1, c0, c1 = tile.core
        # Only the borders shared with another tile (not the mosaic's outer border).
        shared = {"left": c0 > 0, "right": c1 < shape[1], "top": r0 > 0, "bottom": r1 < shape[0]}
        n_borders += sum(shared.values())
        found = thin_border_triangles(tile.mesh, min_length=args.min_length, max_error=args.max_error)
        found = [f for f in found if shared[f[1]]]
        found_all += found
        n_inner = {}
        for _, side, length, width in found:
            n_inner.setdefault(side, []).append((length, width))
        print(
            tile.core,
            f"{len(tile.mesh.front_triangles())} front triangles;",
            "; ".join(
                f"{side}: {len(v)}, {min(a for a, _ in v):.0f}-{max(a for a, _ in v):.0f} px long, "
                f"{min(b for _, b in v):.2f}-{max(b for _, b in v):.2f} px wide"
                for side, v in sorted(n_inner.items())
            ),
        )
        if found and (best is None or max(f[2] for f in found) > max(f[2] for f in best[1])):
            best = (tile, found)
    lengths = np.array([f[2] for f in found_all])
    widths = np.array([f[3] for f in found_all])
    print(
        f"{n_borders} tile sides on a shared border: {len(found_all)} thin sloped triangles >= {args.min_length:g} px long; length median "
        f"{np.median(lengths):.0f}, max {lengths.max():.0f} px; width median {np.median(widths):.2f}, max {widths.max():.2f} px"
    )
    draw(*best, args.out)
    print("wrote", args.out, Path(args.out).stat().st_size // 1024, "KB")


if __name__ == "__main__":
    main()
