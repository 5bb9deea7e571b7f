"""A synthetic UAV field: seeded rows of round plants with known centres and radii on textured soil.

It is the project's own demo input (``python -m cliff_terrain.synthetic field.png``) and a test
oracle: the plants' true positions and sizes are known, so segmentation counts and dome heights
can be checked against them.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from ._validate import check_float, check_int
from .errors import CliffTerrainError


@dataclass
class FieldTruth:
    """What :func:`synthetic_field` drew.

    Attributes
    ----------
    centres : (n, 2) float array
        (row, col) of each plant's centre.
    radii : (n,) float array
        Radius of each plant in pixels.
    mask : (rows, cols) bool array
        Pixels covered by plants.
    """

    centres: np.ndarray
    radii: np.ndarray
    mask: np.ndarray

    @property
    def n_plants(self) -> int:
        return int(self.radii.size)


def synthetic_field(*, shape=(600, 900), n_rows=None, spacing=None, radius_range=(10.0, 22.0), seed=0):
    """Draw a nadir view of a field: crop rows of round plants on furrowed, textured soil.

    Parameters
    ----------
    shape : tuple of int, optional
        (rows, cols) of the image.
    n_rows : int, optional
        Number of crop rows (they run along the columns, i.e. left to right); default one per
        120 pixel rows.
    spacing : float, optional
        Distance between plant centres along a row; default 2.6 times the largest radius.
    radius_range : tuple of float, optional
        Plant radii are drawn uniformly from this range (pixels).
    seed : int, optional
        Seed of the random generator: the same seed gives the same field.

    Returns
    -------
    image : (rows, cols, 3) uint8 array
    truth : FieldTruth

    Examples
    --------
    >>> img, truth = synthetic_field(shape=(200, 300), n_rows=2, seed=1)
    >>> img.shape, img.dtype, truth.n_plants > 0
    ((200, 300, 3), dtype('uint8'), True)
    """
    if not (isinstance(shape, tuple | list) and len(shape) == 2):
        raise CliffTerrainError(f"`shape` must be (rows, cols), got {shape!r}")
    rows = check_int("shape[0]", shape[0], minimum=32)
    cols = check_int("shape[1]", shape[1], minimum=32)
    if n_rows is None:
        n_rows = max(1, round(rows / 120))
    n_rows = check_int("n_rows", n_rows, minimum=1)
    if not (isinstance(radius_range, tuple | list) and len(radius_range) == 2):
        raise CliffTerrainError(f"`radius_range` must be (min, max), got {radius_range!r}")
    r_lo = check_float("radius_range[0]", radius_range[0], minimum=2.0)
    r_hi = check_float("radius_range[1]", radius_range[1], minimum=r_lo)
    if spacing is None:
        spacing = 2.6 * r_hi
    spacing = check_float("spacing", spacing, minimum=2.0 * r_hi + 2.0)
    row_pitch = rows / n_rows
    if row_pitch < 2.0 * r_hi + 2.0:
        raise CliffTerrainError(
            f"`n_rows` must leave room for plants of radius {r_hi} in {rows} rows of pixels, got {n_rows}"
        )
    seed = check_int("seed", seed)
    rng = np.random.default_rng(seed)

    image = _soil(rows, cols, n_rows, rng)
    centres, radii = [], []
    for k in range(n_rows):
        r0 = (k + 0.5) * row_pitch
        c = r_hi + 1.0 + rng.uniform(0, 0.5 * spacing)
        while c + r_hi + 1.0 < cols:
            radius = rng.uniform(r_lo, r_hi)
            # Plants wander a little off the row line but never touch their neighbours.
            jitter = rng.uniform(-0.15, 0.15) * (spacing - 2 * r_hi)
            centres.append((r0 + rng.uniform(-0.1, 0.1) * (row_pitch - 2 * r_hi), c + jitter))
            radii.append(radius)
            c += spacing
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    radii = np.asarray(radii, dtype=np.float64)

    mask = np.zeros((rows, cols), dtype=bool)
    rr, cc = np.mgrid[:rows, :cols]
    leaf_noise = _noise(rows, cols, rng, scale=3.0)
    for (pr, pc), radius in zip(centres, radii, strict=True):
        r0, r1 = int(max(0, pr - radius - 1)), int(min(rows, pr + radius + 2))
        c0, c1 = int(max(0, pc - radius - 1)), int(min(cols, pc + radius + 2))
        d = np.hypot(rr[r0:r1, c0:c1] - pr, cc[r0:r1, c0:c1] - pc)
        inside = d <= radius
        mask[r0:r1, c0:c1] |= inside
        # Canopy: green, darker towards the edge (self-shading), leafy texture.
        shade = 1.0 - 0.35 * (d / radius) ** 2
        base = np.array([52.0, 128.0, 44.0]) * rng.uniform(0.85, 1.15)
        texture = 1.0 + 0.25 * leaf_noise[r0:r1, c0:c1]
        colour = base[None, None, :] * (shade * texture)[..., None]
        patch = image[r0:r1, c0:c1]
        patch[inside] = colour[inside]
    image = np.clip(image, 0, 255).astype(np.uint8)
    return image, FieldTruth(centres=centres, radii=radii, mask=mask)


def _noise(rows, cols, rng, *, scale):
    """Smooth noise with unit standard deviation, features about `scale` pixels wide."""
    n = rng.standard_normal((rows, cols)).astype(np.float32)
    n = cv2.GaussianBlur(n, (0, 0), scale)
    return n / (n.std() + 1e-6)


def _soil(rows, cols, n_rows, rng):
    """Brown soil: furrows between the crop rows, clods, and slow brightness changes."""
    rr = np.arange(rows, dtype=np.float32)[:, None]
    furrow = 0.5 + 0.5 * np.cos(2 * np.pi * (rr / (rows / n_rows)))  # dark between crop rows
    light = (
        1.0
        - 0.18 * furrow
        + 0.06 * _noise(rows, cols, rng, scale=40.0)
        + 0.07 * _noise(rows, cols, rng, scale=1.5)
    )
    soil = np.array([150.0, 112.0, 80.0], dtype=np.float32)
    return soil[None, None, :] * light[..., None]


def main(argv=None):
    """``python -m cliff_terrain.synthetic OUT.png [--seed N] [--size ROWSxCOLS]``: write the demo field."""
    parser = argparse.ArgumentParser(prog="python -m cliff_terrain.synthetic", description=main.__doc__)
    parser.add_argument("out", type=Path, help="PNG file to write")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", default="600x900", help="ROWSxCOLS (default 600x900)")
    args = parser.parse_args(argv)
    try:
        rows, cols = (int(v) for v in args.size.lower().split("x"))
        image, truth = synthetic_field(shape=(rows, cols), seed=args.seed)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(args.out)
    except (OSError, ValueError) as exc:
        print(f"error: could not write {args.out}: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({cols}x{rows}, {truth.n_plants} plants, seed {args.seed})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
