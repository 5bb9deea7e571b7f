"""The single-flight ground checked against the field itself: held-out bare soil, without labels.

No one flight says where the ground is under a closed canopy, but every flight says where it is
at the bare soil it shows. :func:`check_ground` hides that soil block by block (five spatial folds
of ground blocks, so a held-out pixel lies up to half a block from the evidence left, as the
ground under a plot does), rebuilds every candidate ground from the rest and measures how far each
misses the hidden soil. The same held-out errors, against the distance to the nearest evidence
left, give the ground's standard error everywhere (:func:`ground_sigma`): near bare soil it is the
DSM's noise and microrelief; under a wide canopy it grows as the check measured it grow.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import check_float

FOLDS = 5
# A ground that misses held-out bare soil by more than this cannot measure crops (metres).
CHECK_TOLERANCE_M = 0.10
# Distance classes (metres to the nearest evidence) of the uncertainty model.
_DISTANCE_EDGES_M = (0.0, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, np.inf)
_MIN_BIN = 50
# The standard error of a plot's height next to bare soil (metres): chosen leave one field out
# on the validation fields (see the docs' validation page) for 85-95 % coverage.
SIGMA_FLOOR_M = 0.025
# Held-out pixels kept per fold and candidate for the error figures and the uncertainty model.
_SAMPLE = 200_000


def spatial_folds(shape, *, block_px):
    """Fold number (0..4) of every pixel: blocks of `block_px`, fold (i + 2 j) mod 5.

    No two blocks that share a side or a corner fall in the same fold, so a held-out block is
    always surrounded by evidence that is kept.

    Examples
    --------
    >>> spatial_folds((4, 6), block_px=2)
    array([[0, 0, 2, 2, 4, 4],
           [0, 0, 2, 2, 4, 4],
           [1, 1, 3, 3, 0, 0],
           [1, 1, 3, 3, 0, 0]])
    """
    rows, cols = shape
    bi = np.arange(rows) // block_px
    bj = np.arange(cols) // block_px
    return (bi[:, None] + 2 * bj[None, :]) % FOLDS


def robust_error(errors):
    """sqrt(median² + (1.4826 MAD)²): an RMSE that a few leaves taken for soil do not dominate.

    Examples
    --------
    >>> round(robust_error(np.array([0.01, -0.01, 0.02, 0.0, 5.0])), 4)
    0.0179
    """
    errors = np.asarray(errors, dtype=np.float64)
    if errors.size == 0:
        return float("nan")
    med = float(np.median(errors))
    mad = 1.4826 * float(np.median(np.abs(errors - med)))
    return float(np.hypot(med, mad))


def check_ground(dsm, evidence, build, *, pixel_size, block_m, names, tolerance_m=None, fixed=None, run=None):
    """Each candidate ground's error on held-out evidence, and the choice.

    Parameters
    ----------
    dsm : (rows, cols) float32
    evidence : (rows, cols) bool
        The bare soil the grounds are built from.
    build : callable
        ``build(names, train_evidence) -> {name: ground}``; picklable to run the folds elsewhere.
    pixel_size, block_m : float
        Metres per pixel; the folds' block side in metres.
    names : tuple of str
        The candidates, simplest first (a tie goes to the simpler one).
    tolerance_m : float, optional
        The largest held-out error that passes (default `CHECK_TOLERANCE_M`).
    fixed : dict, optional
        {name: ground} of candidates among `names` that do not depend on the evidence (the
        baseline): measured on every fold as they are, not built.
    run : callable, optional
        ``run(function, argument tuples, shared)``, the results in order: runs the folds
        (:func:`fold_grounds`, `build` shared), on threads or a cluster's workers. Default: here,
        one after another.

    Returns
    -------
    check : dict
        ``{"folds", "fold_block_m", "held_out_pixels", "candidates": {name: {"error_m",
        "bias_m", "spread_m"}}, "chosen", "tolerance_m", "passed", "reason"}``; ``bias_m`` is
        the median of DSM - ground on held-out soil (positive: the ground is too low).
    residuals : dict
        {name: (errors, distances_m)} of the held-out pixels (a sample), for :func:`ground_sigma`.
    """
    import cv2

    tolerance_m = CHECK_TOLERANCE_M if tolerance_m is None else float(tolerance_m)
    # Blocks of the ground's size, or smaller on a field too small for three of them across.
    block_px = max(2, min(round(block_m / pixel_size), min(evidence.shape) // 3))
    folds = spatial_folds(evidence.shape, block_px=block_px)
    errors = {name: [] for name in names}
    distances = {name: [] for name in names}
    fold_errors = {name: [] for name in names}
    fixed = dict(fixed or {})
    built = tuple(name for name in names if name not in fixed)
    rng = np.random.default_rng(0)  # the same sample on every run
    samples = []
    for k in range(FOLDS):
        test = evidence & (folds == k)
        train = evidence & (folds != k)
        if not test.any() or not train.any():
            continue
        rr, cc = np.nonzero(test)
        if rr.size > _SAMPLE:
            keep = rng.choice(rr.size, _SAMPLE, replace=False)
            rr, cc = rr[keep], cc[keep]
        samples.append((train, rr, cc))
    used = len(samples)
    if run is None:
        run = _here
    # The folds are independent: the same numbers however and wherever `run` runs them.
    tasks = ((built, train, rr, cc) for train, rr, cc in samples)
    at_samples = iter(run(fold_grounds, tasks, build))
    for train, rr, cc in samples:
        gap = cv2.distanceTransform((~train).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        gap_m = gap[rr, cc].astype(np.float64) * pixel_size
        values = {name: ground[rr, cc] for name, ground in fixed.items()}
        values.update(next(at_samples))
        for name in names:
            errors[name].append((dsm[rr, cc] - values[name]).astype(np.float64))
            distances[name].append(gap_m)
            fold_errors[name].append(robust_error(errors[name][-1]))
    candidates = {}
    residuals = {}
    for name in names:
        e = np.concatenate(errors[name]) if errors[name] else np.zeros(0)
        d = np.concatenate(distances[name]) if distances[name] else np.zeros(0)
        residuals[name] = (e, d)
        med = float(np.median(e)) if e.size else float("nan")
        candidates[name] = {
            "error_m": robust_error(e),
            "bias_m": med,
            "spread_m": float(1.4826 * np.median(np.abs(e - med))) if e.size else float("nan"),
            "fold_errors_m": [float(v) for v in fold_errors[name]],
        }
    held_out = int(residuals[names[0]][0].size)
    scored = [n for n in names if np.isfinite(candidates[n]["error_m"])]
    chosen = min(scored, key=lambda n: candidates[n]["error_m"]) if scored else names[0]
    best = candidates[chosen]["error_m"]
    if used < 3:
        passed, reason = (
            False,
            (
                f"its bare soil lies in {used} of {FOLDS} folds of {block_px * pixel_size:.3g} m blocks: too little, "
                "or too clustered, to check a ground on it"
            ),
        )
    elif not best <= tolerance_m:
        passed, reason = (
            False,
            (
                f"no ground candidate predicts held-out bare soil within {tolerance_m * 100:.0f} cm "
                f"(the best, {chosen!r}, misses it by {best * 100:.1f} cm)"
            ),
        )
    else:
        passed, reason = True, f"{chosen!r} predicts held-out bare soil within {best * 100:.1f} cm"
    check = {
        "folds": FOLDS,
        "folds_used": used,
        "fold_block_m": float(block_px * pixel_size),
        "held_out_pixels": held_out,
        "candidates": candidates,
        "chosen": chosen,
        "tolerance_m": tolerance_m,
        "passed": bool(passed),
        "reason": reason,
    }
    return check, residuals


def fold_grounds(names, train, rr, cc, build):
    """One fold of :func:`check_ground`: {name: ground at the held-out pixels ``(rr, cc)``} of the
    candidates `names` built from the `train` evidence."""
    return {name: ground[rr, cc] for name, ground in build(names, train).items()}


def _here(function, arguments, shared=None):
    """The default runner: each call in turn, in this thread."""
    return (function(*args, shared) for args in arguments)


@dataclass
class GroundSigma:
    """The ground's standard error: a raster and its model ``sqrt(a² + (g d)²)`` of the distance d."""

    raster: np.ndarray
    model: dict


def ground_sigma(residual, evidence, *, pixel_size):
    """Standard error of the ground at every pixel, from the held-out check.

    The held-out errors are grouped by the distance to the nearest evidence left in their fold;
    each group's robust RMSE is fitted by sigma(d)² = a² + (g d)² (least squares, a and g >= 0):
    `a` is the error at the soil (pixel noise, microrelief), `g` how fast it grows with the
    distance into a canopy. Every pixel then takes sqrt(SIGMA_FLOOR_M² + (g d)²) at its own
    distance d to the evidence: a plot's height averages the pixel noise away, but not the error
    no bare soil can show (`a` is reported here; :func:`~cliff_terrain.measure.ground.fit_ground`
    adds it for the grounds that do not follow the soil's relief).

    Parameters
    ----------
    residual : (errors, distances_m)
        The chosen candidate's held-out errors and distances (from :func:`check_ground`).
    evidence : (rows, cols) bool
    pixel_size : float

    Returns
    -------
    GroundSigma
    """
    import cv2

    errors, dist = residual
    bins = []
    for lo, hi in zip(_DISTANCE_EDGES_M[:-1], _DISTANCE_EDGES_M[1:], strict=True):
        pick = (dist >= lo) & (dist < hi)
        if np.count_nonzero(pick) >= _MIN_BIN:
            bins.append((float(np.mean(dist[pick])), robust_error(errors[pick]), int(pick.sum())))
    if bins:
        d = np.array([b[0] for b in bins])
        s = np.array([b[1] for b in bins])
        w = np.sqrt([b[2] for b in bins])
        design = np.column_stack([np.ones_like(d), d**2]) * w[:, None]
        coef, *_ = np.linalg.lstsq(design, s**2 * w, rcond=None)
        a2 = max(float(coef[0]), float(np.min(s)) ** 2 * 0.25, 1e-8)
        g2 = max(float(coef[1]), 0.0)
        if g2 == 0.0 and len(bins) > 1:
            # No growth measurable: the largest distance's error holds from there on.
            g2 = max(0.0, (float(s[-1]) ** 2 - a2) / max(float(d[-1]) ** 2, 1e-6))
    else:
        a2, g2 = (robust_error(errors) if errors.size else 0.05) ** 2, 0.0
    gap = cv2.distanceTransform((~evidence).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    gap_m = gap.astype(np.float32) * np.float32(pixel_size)
    # A plot's height averages the pixel noise that `a` holds away, but not what no bare soil shows
    # (the ground under the plants, the canopy's own surface): SIGMA_FLOOR_M stands for that.
    floor2 = np.float32(SIGMA_FLOOR_M**2)
    raster = np.sqrt(floor2 + np.float32(g2) * gap_m * gap_m).astype(np.float32)
    model = {
        "floor_m": SIGMA_FLOOR_M,
        "at_soil_m": float(np.sqrt(a2)),
        "growth_per_m": float(np.sqrt(g2)),
        "bins": [{"distance_m": b[0], "error_m": b[1], "pixels": b[2]} for b in bins],
    }
    return GroundSigma(raster, model)


def ground_support(soil, *, pixel_size, block_m):
    """How much bare soil carried the ground at each pixel: its share in a block around the pixel.

    The share of `soil` pixels in the `block_m` x `block_m` window centred on each pixel, the
    scale at which :func:`cliff_terrain.measure.ground.fit_ground` fits its trend. 0 means that
    no soil lies within half a block: the ground there is interpolated from farther blocks.

    Parameters
    ----------
    soil : (rows, cols) bool array
        The soil the ground was estimated from.
    pixel_size : float
        Metres per pixel (> 0).
    block_m : float
        Block side in metres.

    Returns
    -------
    (rows, cols) float32 array in [0, 1]

    Examples
    --------
    >>> soil = np.zeros((100, 100), bool); soil[:, :10] = True
    >>> support = ground_support(soil, pixel_size=0.1, block_m=2.0)
    >>> float(support[50, 9]), float(support[50, 50])
    (0.5, 0.0)
    """
    import cv2

    soil = np.asarray(soil, dtype=bool)
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    size = max(1, round(block_m / pixel_size)) | 1  # odd: centred on the pixel
    share = cv2.blur(soil.astype(np.float32), (size, size), borderType=cv2.BORDER_CONSTANT)
    # The window's part inside the raster: the border's missing pixels are not missing soil.
    inside = cv2.blur(np.ones(soil.shape, np.float32), (size, size), borderType=cv2.BORDER_CONSTANT)
    return np.clip(share / np.maximum(inside, 1e-6), 0.0, 1.0).astype(np.float32)
