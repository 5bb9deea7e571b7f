"""A synthetic surface model: the synthetic field's plants, with known heights, on a known ground.

The oracle of the canopy height: the ground is tilted, undulating and ridged along the crop rows,
the plants are ellipsoid caps of known heights, the surface has noise and no-data holes, and the
photo has plants' shadowed flanks coloured like soil (what fools a colour segmentation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import check_float, check_int
from .synthetic import synthetic_field


@dataclass
class SurfaceTruth:
    """What :func:`synthetic_surface` built (heights in metres).

    Attributes
    ----------
    ground : (rows, cols) float32
        The true ground.
    chm : (rows, cols) float32
        True canopy height (0 on soil).
    labels : (rows, cols) int32
        0 on soil, i + 1 on plant i.
    heights : (n,) float
        Each plant's top above the ground under its centre.
    shadow : (rows, cols) bool
        Plant pixels drawn in soil colour (shadowed flanks).
    holes : (rows, cols) bool
        Pixels without surface data (NaN in the DSM).
    """

    ground: np.ndarray
    chm: np.ndarray
    labels: np.ndarray
    heights: np.ndarray
    shadow: np.ndarray
    holes: np.ndarray


def synthetic_surface(
    *,
    shape=(600, 900),
    gsd=0.01,
    seed=0,
    slope=(0.03, -0.02),
    undulation_m=0.08,
    ridge_m=0.03,
    height_range=(0.15, 0.6),
    noise_m=0.004,
    n_holes=4,
    shadow=True,
):
    """A photo, its surface model and the truth.

    Parameters
    ----------
    shape : (int, int), optional
        (rows, cols) of the photo and the surface model.
    gsd : float, optional
        Metres per pixel (plants have radii of 10-22 pixels).
    seed : int, optional
    slope : (float, float), optional
        Ground gradient (metres per metre) along rows and columns.
    undulation_m : float, optional
        Amplitude of the ground's slow waves (periods of several metres at 1 cm/px... scaled
        with the field).
    ridge_m : float, optional
        Amplitude of the ridges along the crop rows (crests under the plants).
    height_range : (float, float), optional
        Plant heights in metres, drawn uniformly.
    noise_m : float, optional
        Standard deviation of the surface's noise.
    n_holes : int, optional
        Number of round no-data holes.
    shadow : bool, optional
        Colour each plant's shadowed flank like soil in the photo.

    Returns
    -------
    image : (rows, cols, 3) uint8
    dsm : (rows, cols) float32, NaN in the holes
    truth : SurfaceTruth

    Examples
    --------
    >>> img, dsm, truth = synthetic_surface(shape=(240, 360), seed=1)
    >>> img.shape, dsm.dtype, bool(np.isnan(dsm).any()), bool(len(truth.heights) == truth.labels.max())
    ((240, 360, 3), dtype('float32'), True, True)
    """
    gsd = check_float("gsd", gsd, minimum=0.0, strict_minimum=True)
    seed = check_int("seed", seed)
    rng = np.random.default_rng(seed + 7919)
    image, field = synthetic_field(shape=shape, seed=seed)
    rows, cols = image.shape[:2]
    rr, cc = np.mgrid[:rows, :cols].astype(np.float64)
    y, x = rr * gsd, cc * gsd
    # Ground: tilt + slow waves (periods of half the field) + ridges whose crests follow the rows.
    n_rows = max(1, round(rows / 120))
    pitch = rows / n_rows
    ground = 100.0 + slope[0] * y + slope[1] * x
    ground += (
        undulation_m
        * np.sin(2 * np.pi * x / (0.6 * cols * gsd) + 0.7)
        * np.cos(2 * np.pi * y / (0.8 * rows * gsd))
    )
    ground += ridge_m * np.cos(2 * np.pi * (rr - pitch / 2) / pitch)

    labels = np.zeros((rows, cols), dtype=np.int32)
    chm = np.zeros((rows, cols), dtype=np.float64)
    shadowed = np.zeros((rows, cols), dtype=bool)
    heights = rng.uniform(*height_range, size=field.n_plants)
    sun = rng.uniform(0, 2 * np.pi)
    for k, ((pr, pc), radius) in enumerate(zip(field.centres, field.radii, strict=True)):
        r0, r1 = int(max(0, pr - radius - 1)), int(min(rows, pr + radius + 2))
        c0, c1 = int(max(0, pc - radius - 1)), int(min(cols, pc + radius + 2))
        dr, dc = rr[r0:r1, c0:c1] - pr, cc[r0:r1, c0:c1] - pc
        d = np.hypot(dr, dc) / radius
        inside = (d <= 1.0) & field.mask[r0:r1, c0:c1]
        cap = heights[k] * np.sqrt(np.clip(1.0 - d**2, 0.0, 1.0))
        labels[r0:r1, c0:c1][inside] = k + 1
        chm[r0:r1, c0:c1][inside] = cap[inside]
        if shadow:
            # The flank away from the sun, outer third: dark, soil-coloured leaves.
            away = (dr * np.sin(sun) + dc * np.cos(sun)) / radius < -0.35
            shadowed[r0:r1, c0:c1] |= inside & away & (d > 0.65)
    if shadow:
        image = image.copy()
        image[shadowed] = (
            (rng.normal(0, 4, size=(int(shadowed.sum()), 3)) + (70, 58, 45)).clip(0, 255).astype(np.uint8)
        )

    dsm = ground + chm + rng.normal(0.0, noise_m, size=(rows, cols))
    holes = np.zeros((rows, cols), dtype=bool)
    for _ in range(int(n_holes)):
        hr, hc, hrad = rng.uniform(0, rows), rng.uniform(0, cols), rng.uniform(0.02, 0.05) * min(rows, cols)
        holes |= np.hypot(rr - hr, cc - hc) < hrad
    dsm[holes] = np.nan
    truth = SurfaceTruth(
        ground=ground.astype(np.float32),
        chm=chm.astype(np.float32),
        labels=labels,
        heights=heights,
        shadow=shadowed,
        holes=holes,
    )
    return image, dsm.astype(np.float32), truth
