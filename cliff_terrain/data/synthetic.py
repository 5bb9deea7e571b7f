"""A synthetic UAV field: seeded rows of round plants with known centres and radii on textured soil.

It is the project's own demo input (``python -m cliff_terrain.data.synthetic field.png``) and a test
oracle: the plants' true positions and sizes are known, so segmentation counts and dome heights
can be checked against them. Its closed-canopy mode (``canopy="closed"``) draws late-season rows
whose leaves touch and join at the row ends, enclosing strips of soil, beside a row of isolated
plants; the plant mask, the enclosed soil strips and the canopy height are known.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from .._validate import check_choice, check_float, check_int
from ..errors import CliffTerrainError


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
    strips : (rows, cols) bool array
        Soil enclosed by canopy (the strips between closed rows); all False for an open field.
    canopy_height : float
        Radius of a typical isolated plant in pixels (the median radius of the plants that touch
        no other): the height a closed canopy should have.
    """

    centres: np.ndarray
    radii: np.ndarray
    mask: np.ndarray
    strips: np.ndarray = None
    canopy_height: float = 0.0

    def __post_init__(self):
        if self.strips is None:
            self.strips = np.zeros(self.mask.shape, dtype=bool)

    @property
    def n_plants(self) -> int:
        return int(self.radii.size)


CANOPIES = ("open", "closed")


def synthetic_field(
    *, shape=(600, 900), n_rows=None, spacing=None, radius_range=(10.0, 22.0), seed=0, canopy="open"
):
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
    canopy : {"open", "closed"}, optional
        ``"open"``: rows of separate plants. ``"closed"``: a row of isolated plants along the top,
        and below it rows of overlapping plants (centres 1.2 smallest radii apart) whose ends join
        two wide headland blocks of closed canopy, so that the soil strips between the rows (one
        largest radius wide) are enclosed by canopy. `n_rows` then counts the closed rows (default
        as many as fit) and `spacing` applies to the isolated row.

    Returns
    -------
    image : (rows, cols, 3) uint8 array
    truth : FieldTruth

    Examples
    --------
    >>> img, truth = synthetic_field(shape=(200, 300), n_rows=2, seed=1)
    >>> img.shape, img.dtype, truth.n_plants > 0
    ((200, 300, 3), dtype('uint8'), True)
    >>> img, truth = synthetic_field(shape=(300, 400), radius_range=(8, 10), canopy="closed")
    >>> bool(truth.strips.any()), bool((truth.strips & truth.mask).any()), truth.canopy_height > 7
    (True, False, True)
    """
    check_choice("canopy", canopy, CANOPIES)
    if canopy == "closed":
        return _closed_field(shape, n_rows, spacing, radius_range, seed)
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

    mask = _draw_plants(image, centres, radii, rng)
    image = np.clip(image, 0, 255).astype(np.uint8)
    canopy_height = float(np.median(radii)) if radii.size else 0.0
    return image, FieldTruth(centres=centres, radii=radii, mask=mask, canopy_height=canopy_height)


def _check_shape_and_radii(shape, radius_range):
    if not (isinstance(shape, tuple | list) and len(shape) == 2):
        raise CliffTerrainError(f"`shape` must be (rows, cols), got {shape!r}")
    rows = check_int("shape[0]", shape[0], minimum=32)
    cols = check_int("shape[1]", shape[1], minimum=32)
    if not (isinstance(radius_range, tuple | list) and len(radius_range) == 2):
        raise CliffTerrainError(f"`radius_range` must be (min, max), got {radius_range!r}")
    r_lo = check_float("radius_range[0]", radius_range[0], minimum=2.0)
    r_hi = check_float("radius_range[1]", radius_range[1], minimum=r_lo)
    return rows, cols, r_lo, r_hi


def _closed_field(shape, n_rows, spacing, radius_range, seed):
    """``synthetic_field(canopy="closed")``: isolated plants on top, closed rows enclosing soil below."""
    rows, cols, r_lo, r_hi = _check_shape_and_radii(shape, radius_range)
    if spacing is None:
        spacing = 2.6 * r_hi
    spacing = check_float("spacing", spacing, minimum=2.0 * r_hi + 2.0)
    seed = check_int("seed", seed)
    # The enclosure: below the isolated row, headland blocks 6 radii wide at both ends.
    top, bottom = int(3 * r_hi + 12), int(rows - r_hi - 4)
    left, right = int(r_hi + 4), int(cols - r_hi - 4)
    headland = 6.0 * r_hi
    pitch = 3.0 * r_hi  # rows 2 radii wide, strips 1 radius wide
    fits = int((bottom - top - 2 * r_hi) // pitch) + 1
    if fits < 2 or right - left < 2 * headland + 4 * r_hi:
        raise CliffTerrainError(
            f"`shape` must leave room for two closed rows of plants of radius {r_hi}, got {shape!r}"
        )
    if n_rows is None:
        n_rows = fits
    n_rows = check_int("n_rows", n_rows, minimum=2, maximum=fits)
    rng = np.random.default_rng(seed)

    image = _soil(rows, cols, n_rows, rng)
    centres, radii, isolated = [], [], []
    # The isolated row: plants that touch nothing, as in the open field.
    c = r_hi + 1.0 + rng.uniform(0, 0.5 * spacing)
    while c + r_hi + 1.0 < cols:
        centres.append((r_hi + 4.0, c + rng.uniform(-0.15, 0.15) * (spacing - 2 * r_hi)))
        radii.append(rng.uniform(r_lo, r_hi))
        isolated.append(True)
        c += spacing
    step = 1.2 * r_lo  # overlapping plants: no soil shows through a row or a block
    # The closed rows run from one headland into the other.
    span = bottom - top - 2 * r_hi
    for k in range(n_rows):
        r0 = top + r_hi + (span * k / (n_rows - 1) if n_rows > 1 else 0.0)
        for c in np.arange(left + headland - r_hi, right - headland + r_hi + step, step):
            centres.append((r0, c))
            radii.append(rng.uniform(r_lo, r_hi))
            isolated.append(False)
    # The headlands: a grid of overlapping plants filling the ends of the enclosure.
    for c0 in (left, right - headland):
        for r in np.arange(top + r_lo, bottom - r_lo + 1e-6, step):
            for c in np.arange(c0 + r_lo, c0 + headland - r_lo + 1e-6, step):
                centres.append((r, c))
                radii.append(rng.uniform(r_lo, r_hi))
                isolated.append(False)
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    radii = np.asarray(radii, dtype=np.float64)
    mask = _draw_plants(image, centres, radii, rng)
    image = np.clip(image, 0, 255).astype(np.uint8)
    # The strips: soil that cannot be reached from the frame.
    flood = np.pad((~mask).astype(np.uint8), 1, constant_values=1)
    cv2.floodFill(flood, None, (0, 0), 0)
    strips = flood[1:-1, 1:-1] > 0
    canopy_height = float(np.median(radii[np.asarray(isolated)]))
    return image, FieldTruth(
        centres=centres, radii=radii, mask=mask, strips=strips, canopy_height=canopy_height
    )


def _draw_plants(image, centres, radii, rng):
    """Paint the plants onto `image` (float, in place); return their mask."""
    rows, cols = image.shape[:2]
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
    return mask


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
    """``python -m cliff_terrain.data.synthetic OUT.png [--seed N] [--size RxC] [--canopy C]``: the demo field."""
    parser = argparse.ArgumentParser(prog="python -m cliff_terrain.data.synthetic", description=main.__doc__)
    parser.add_argument("out", type=Path, help="PNG file to write")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", default="600x900", help="ROWSxCOLS (default 600x900)")
    parser.add_argument(
        "--canopy", choices=CANOPIES, default="open", help="open or closed rows (default open)"
    )
    args = parser.parse_args(argv)
    try:
        rows, cols = (int(v) for v in args.size.lower().split("x"))
        image, truth = synthetic_field(shape=(rows, cols), seed=args.seed, canopy=args.canopy)
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
