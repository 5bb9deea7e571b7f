"""The ground under the crop, from one flight: geometry first, checked against the field itself.

A digital surface model (DSM) is the top of everything: soil where it is bare, leaves where there
are plants. One flight has no bare-earth model, so the ground is estimated from the DSM's own shape,
with the photo's colour as evidence, never as the gate (:func:`fit_ground`):

1. **Lowest surface** (``"baseline"``): the 2nd percentile of the DSM in blocks of `block_m`
   (5 m), interpolated bilinearly between the block centres. No segmentation: the lowest
   surfaces of a DSM are the ground wherever every block holds some bare soil (alleys, furrows,
   gaps), the assumption behind the progressive morphological and slope-based filters (PMF:
   Zhang et al. 2003, IEEE TGRS 41(4); SMRF: Pingel et al. 2013, ISPRS J. 77) and the cloth
   simulation (CSF: Zhang et al. 2016, Remote Sens. 8(6)), reduced to a block percentile because
   crop fields are smooth at the block's scale. It is the naive peer, kept as a candidate.
2. **Ground evidence** (:mod:`.ground_evidence`): pixels standing at most `MICRORELIEF_M`
   (25 cm: ridges, beds and furrows, never a crop's height) above the lowest surface that the
   photo calls bare soil, where the surface agrees with the colour: most of the colour's soil lies
   within the microrelief, and the colour's plants stand above its soil by more than the soil's
   own band (the surface's lowest mode). Otherwise (a senescent or yellow canopy the colour calls
   soil, a grey photo, a photo that shows no plants) the surface decides: the evidence is the
   pixels within three robust deviations of the lowest mode of the height above the lowest
   surface, less those the colour still calls plants.
3. **Smooth** (``"smooth"``): the lowest surface lifted onto the evidence by a smooth offset
   (normalized convolution at the block's scale, fading into the field's median offset where
   there is no evidence): the 2nd percentile sits in the furrows and below the DSM's noise, the
   soil the plants stand on does not. A block whose evidence is less than the percentile's share
   of its pixels with data (a closed canopy's block) has no soil at its 2nd percentile: its level
   comes from the blocks around it that hold soil (:class:`~.ground_blocks.BlockLevels`).
4. **Detailed** (``"detailed"``): the smooth ground plus the evidence's local detail (ridges under
   the rows), by local quadratic fits from fine to coarse scales (normalized convolution). The
   check tests that detail on held-out soil. The ground keeps its broad part (scales from a fifth
   of a block) and, of the finer part, only its level under the canopy, one number for the field
   (:func:`canopy_level`): under a canopy the fine detail is extrapolation from the soil beside
   the plants, and it varied from plot to plot more than the ground does.

**What the check cannot see** (:mod:`.ground_occlusion`): soil in openings narrower than the canopy
is tall, which a photogrammetric DSM fills between tall plots. Where it stands more than the check's
tolerance above the open soil around it and most of the canopy rests on it, ``method="auto"``
lowers the ground by that rise where it rests on that soil, and the record says so.

**The check** (:mod:`cliff_terrain.measure.ground_check`): the evidence is split into five
spatial folds of `block_m` blocks; each candidate is built without a fold and predicts its
evidence. ``method="auto"`` takes the candidate with the smallest held-out error, refuses the
ground (:class:`~cliff_terrain.errors.GroundError`) when even that one misses the held-out soil by
more than `CHECK_TOLERANCE_M`, and the held-out errors against the distance to the nearest
evidence give every pixel's standard error of the ground (``GroundFit.sigma``).

The canopy height model is CHM = DSM - ground, negatives set to 0, NaN where the DSM has no data.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import settings
from .._validate import check_choice, check_float
from ..errors import CliffTerrainError
from ..io.raster.surface_values import surface_data
from .ground_blocks import (
    BASELINE_PERCENTILE,
    DEFAULT_BLOCK_M,
    block_levels,
    naive_block_ground,
)
from .ground_check import check_ground, ground_sigma, ground_support
from .ground_detail import canopy_level, detail_above, evidence_offset
from .ground_evidence import MIN_SOIL_PIXELS, exposed_soil, ground_evidence, soil_top
from .ground_occlusion import occlusion_check

DEFAULT_DETAIL_M = 0.15
# What `method` accepts, and the candidates, simplest first (ties go to the simpler one).
GROUND_METHODS = settings.ids(settings.GROUND_METHODS)
CANDIDATES = GROUND_METHODS[1:]
# The detailed ground's broad part starts at this fraction of a block (1 m in 5 m blocks); finer
# detail is kept under the canopy as one level. Chosen on the potato trial's dates with either
# field left out (1 m against 0.4 m, every scale and none; docs/validation.md).
BROAD_DETAIL = 0.2
# The smooth offset's Gaussian sigma, in blocks (0.5 and 0.25 measured worse on a real potato
# trial's day 100: RMSE 2.2 -> 2.5 and 2.6 cm).
OFFSET_SCALE = 1.0


@dataclass
class GroundFit:
    """A single-flight ground and how far it can be trusted (see :func:`fit_ground`).

    Attributes
    ----------
    ground : (rows, cols) float32
        Ground heights in metres, everywhere.
    method : str
        The candidate used: ``"baseline"``, ``"smooth"`` or ``"detailed"``.
    evidence : (rows, cols) bool
        The pixels taken as bare soil (the ground's evidence).
    evidence_source : str
        ``"colour and surface"`` (soil by colour, near the lowest surface) or ``"surface"``
        (the surface's own soil peak: no colour given, or the colour contradicted by the surface).
    support : (rows, cols) float32
        Share of evidence in the `block_m` window around each pixel (:func:`ground_support`).
    sigma : (rows, cols) float32
        Standard error of the ground at each pixel (metres), from the held-out check and, for
        the detailed ground, its level under the canopy (which no held-out soil checks); without a
        photo, also how far the plants' soil may stand above the surface's lowest mode
        (``check["sigma_model"]["soil_top_m"]``).
    check : dict
        The held-out check (:func:`cliff_terrain.measure.ground_check.check_ground`): each
        candidate's error, the choice, ``passed`` and why.
    """

    ground: np.ndarray
    method: str
    evidence: np.ndarray
    evidence_source: str
    support: np.ndarray
    sigma: np.ndarray
    check: dict = field(default_factory=dict)


def fit_ground(
    dsm,
    *,
    soil=None,
    pixel_size,
    block_m=DEFAULT_BLOCK_M,
    detail_m=DEFAULT_DETAIL_M,
    method="auto",
    source="the surface model",
    run=None,
):
    """The ground under a crop from its surface model, checked on held-out bare soil.

    Parameters
    ----------
    dsm : (rows, cols) float array
        Surface heights in metres, NaN where there is no data.
    soil : (rows, cols) bool array, optional
        Pixels the photo calls bare soil: evidence that weights the ground, never the gate.
        None: the surface alone.
    pixel_size : float
        Metres per pixel (> 0).
    block_m : float, optional
        Side of the blocks of the lowest surface and of the check's folds, in metres.
    detail_m : float, optional
        Finest scale (Gaussian sigma, metres) of the ``"detailed"`` candidate.
    method : {"auto", "baseline", "smooth", "detailed"}, optional
        ``"auto"`` takes the candidate that predicts held-out bare soil best and refuses a
        ground that fails the check; a name forces that candidate (still checked and reported).
    source : str, optional
        Names the surface model in error messages.
    run : callable, optional
        ``run(function, argument tuples, shared)``: runs the held-out check's folds and returns
        their results in order (:func:`~cliff_terrain.measure.ground_check.check_ground`), for
        example on threads or a Dask cluster's workers; by default one after another, here. The
        result does not depend on it.

    Returns
    -------
    GroundFit

    Raises
    ------
    GroundError
        Too little bare soil, or (``method="auto"``) no candidate passes the held-out check; the
        message names `source` and suggests a terrain model.

    Examples
    --------
    >>> rows, cols = np.mgrid[:300, :300]
    >>> ground = 100.0 + 0.01 * cols                      # 1 cm/px tilt, 0.05 m pixels
    >>> plants = (np.hypot(rows % 60 - 30, cols % 60 - 30) < 12)
    >>> dsm = (ground + 0.5 * plants).astype(np.float32)
    >>> fit = fit_ground(dsm, soil=~plants, pixel_size=0.05)
    >>> fit.method, bool(np.abs(fit.ground - ground).max() < 0.01), fit.check["passed"]
    ('smooth', True, True)
    """
    from ..errors import GroundError

    dsm = np.asarray(dsm, dtype=np.float32)
    if dsm.ndim != 2:
        raise CliffTerrainError(f"`dsm` must be a (rows, cols) array, got shape {dsm.shape}")
    if soil is not None:
        soil = np.asarray(soil, dtype=bool)
        if soil.shape != dsm.shape:
            raise CliffTerrainError(f"`soil` must have the shape of `dsm` {dsm.shape}, got {soil.shape}")
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    block_m = check_float("block_m", block_m, minimum=0.0, strict_minimum=True)
    detail_m = check_float("detail_m", detail_m, minimum=0.0)
    check_choice("method", method, GROUND_METHODS)
    finite = surface_data(dsm)
    if not finite.all():
        dsm = np.where(finite, dsm, np.float32(np.nan))
    if not finite.any():
        raise GroundError(f"{source} has no surface data to estimate the ground from; give a DTM")
    if soil is not None:
        # A photo that shows no bare soil at all is evidence too: the lowest surfaces of a closed
        # canopy are leaves, not the ground.
        check_enough_soil(soil & finite, finite, source=source)
    # A field too small for three blocks across takes smaller blocks (the check's folds do too); the
    # baseline stays the naive peer, in blocks of `block_m` whatever the field.
    small_m = min(block_m, max(2, min(dsm.shape) // 3) * pixel_size)
    blocks = block_levels(dsm, pixel_size=pixel_size, block_m=small_m)
    options = {"pixel_size": pixel_size, "block_m": small_m, "detail_m": detail_m}

    exposed = None if soil is None else exposed_soil(soil, pixel_size=pixel_size)
    evidence, evidence_source, colour = ground_evidence(dsm, blocks.surface(), soil=soil, exposed=exposed)
    if evidence.any():
        # Once more, near the smooth ground instead of the block percentile: on a slope the soil at
        # a block's upper end stands higher above the block's lowest pixels than any microrelief.
        smooth = CandidateGrounds(dsm, blocks.surface(evidence), **options)(("smooth",), evidence)["smooth"]
        evidence, evidence_source, colour = ground_evidence(dsm, smooth, soil=soil, exposed=exposed)
    check_enough_soil(evidence, finite, source=source)
    # The lowest surface of the blocks that hold evidence (:class:`~.ground_blocks.BlockLevels`),
    # decided once with all of it: like the baseline, a property of the surface in the check's folds.
    build = CandidateGrounds(dsm, blocks.surface(evidence), **options)

    # Without a photo, nothing tells a low leaf from a ridge at the detail's scale: on a real potato
    # trial's surface model alone the detail put the ground 5.6 cm high, the smooth one 3.7 cm low.
    # With one, even where the surface decided the soil, the colour takes its plants out of it, and
    # the check chose the detailed ground on that trial's straw-coloured photos: 3.6 and 3.1 cm
    # RMSE on days 40 and 55 against 8.4 and 6.6 cm smooth.
    names = CANDIDATES if soil is not None else ("baseline", "smooth")
    if method not in ("auto", *names):
        names = (*names, method)
    # The baseline does not depend on the evidence: made once, outside the folds.
    baseline = naive_block_ground(dsm, pixel_size=pixel_size, block_m=block_m, percentile=BASELINE_PERCENTILE)
    check, residuals = check_ground(
        dsm, evidence, build, pixel_size=pixel_size, block_m=block_m, names=names,
        fixed={"baseline": baseline}, run=run,
    )  # fmt: skip
    check["evidence"] = {"source": evidence_source, "share": float(evidence.sum() / finite.sum()), **colour}
    chosen = check["chosen"] if method == "auto" else method
    check["method"] = chosen
    if method == "auto" and not check["passed"]:
        raise GroundError(f"{source}: {check['reason']}; give a terrain model (--dtm, `dtm=`)")
    if chosen == "detailed":
        local = build(("smooth", "detailed"), evidence)
        broad = detail_above(
            dsm, local["smooth"], evidence, detail_m / pixel_size, small_m / pixel_size,
            smallest=BROAD_DETAIL * small_m / pixel_size,
        )  # fmt: skip
        ground, level = canopy_level(dsm, local["smooth"] + broad, local["detailed"], evidence)
        check["detail_under_canopy_m"] = level
    elif chosen == "baseline":
        ground, level = baseline, 0.0
    else:
        ground, level = build((chosen,), evidence)[chosen], 0.0
    sigma = ground_sigma(residuals[chosen], evidence, pixel_size=pixel_size)
    check["sigma_model"] = {**sigma.model, "canopy_level_m": level}
    # No held-out soil checks the level under the canopy: it counts in full (on the potato trial's
    # day 55, +2.2 cm, the plots' coverage went from 79 % to 96 %).
    error = sigma.raster if level == 0.0 else np.sqrt(sigma.raster**2 + np.float32(level) ** 2)
    # Only the detailed ground follows the soil's relief finer than its blocks (ridges, hills,
    # furrows). What the smooth ground or the baseline misses of the soil beside the soil itself
    # (`at_soil_m`, the held-out error at distance 0) lies under the plants too, which stand on that
    # relief, and a plot's pixels do not average it away: it counts in full (on the potato trial
    # measured from its surface alone, the plots' coverage went from 60 % to 100 %).
    relief = 0.0 if chosen == "detailed" else sigma.model["at_soil_m"]
    check["sigma_model"]["relief_m"] = relief
    if relief:
        error = np.sqrt(error**2 + np.float32(relief) ** 2)
    # Nor does it check soil the surface model cannot see: narrow openings' soil standing above the
    # open soil's is said, and the ground lowered by that much where it rests on it
    # (:mod:`.ground_occlusion`).
    occlusion, lowering = occlusion_check(
        dsm, ground, evidence, pixel_size=pixel_size, block_px=OFFSET_SCALE * small_m / pixel_size,
        tolerance_m=check["tolerance_m"],
    )  # fmt: skip
    check["occlusion"] = occlusion
    supported = evidence
    if not occlusion["passed"]:
        rise = np.float32(occlusion["rise_m"])
        if method == "auto":
            # The narrow soil is not the ground: where the ground rests on it, it is lowered by what
            # that soil stands above the open soil (near open soil, down to the open soil's level
            # and no further). One measured level, as the canopy's level: its shape stays the
            # evidence's (the field's tilt and undulation wherever the open soil lies), the change
            # is bounded by the rise, and how much the narrow soil's height varies about it counts
            # in the error.
            ground = (ground - lowering).astype(np.float32)
            error = np.sqrt(error**2 + np.float32(occlusion["spread_m"]) ** 2)
            supported = evidence & (lowering < 0.5 * rise)
            occlusion["ground"] = "lowered"
            occlusion["note"] += (
                f"; the ground is lowered by that much where it rests on that soil (its spread, "
                f"{occlusion['spread_m'] * 100:.0f} cm, counted in the error)"
            )
        else:
            error = np.sqrt(error**2 + rise**2)
            occlusion["note"] += (
                f"; the {chosen} ground follows it: heights may read that much low (counted in the error)"
            )
        occlusion["note"] += "; give a terrain model (--dtm) or calibrate with --ruler"
    # Without a photo, nothing tells the soil at the surface's lowest mode (furrows) from the soil of
    # ridges or beds above it, on which the plants may stand, or from the lowest leaves: the plants'
    # soil lies anywhere from the ground up to where the surface thins below the canopy
    # (`soil_top`), and that spread (uniform: its RMS about the ground, top / sqrt(3)) counts in the
    # error. A real hilled potato trial's surface model cut to its plots' box read 11 cm high with
    # a stated 4 cm: its soil mode was the furrows, the hills' soil stood 15 cm above them.
    if soil is None:
        top = soil_top((dsm - ground)[finite])
        check["sigma_model"]["soil_top_m"] = top
        error = np.sqrt(error**2 + np.float32(top * top / 3.0))
    # A colour the surface overruled confirms no soil level: where the ground stands above the lowest
    # surface (the naive baseline), that lift rests on the surface's lowest layer alone, which in a
    # window without open soil is the canopy's own (a real closed potato canopy cut to its plots:
    # 15 of 22 cuts read 7-19 cm low behind a passing check). It counts in full in the error.
    if soil is not None and "colour_contradicted" in check["evidence"]:
        lift = np.maximum(ground - baseline, np.float32(0.0))
        error = np.sqrt(error**2 + lift**2)
        check["sigma_model"]["unconfirmed_lift_m"] = float(np.median(lift[finite]))
    support = ground_support(supported, pixel_size=pixel_size, block_m=small_m)
    guessed = finite & ~supported
    check["support_where_guessed"] = float(np.mean(support[guessed])) if guessed.any() else 1.0
    return GroundFit(
        ground, chosen, evidence, evidence_source, support, error.astype(np.float32, copy=False), check
    )


def estimate_ground(dsm, *, soil=None, pixel_size, block_m=DEFAULT_BLOCK_M, detail_m=DEFAULT_DETAIL_M):
    """The ground surface under a crop: :func:`fit_ground`'s ground (``method="auto"``).

    Examples
    --------
    >>> rows, cols = np.mgrid[:300, :300]
    >>> ground = 100.0 + 0.01 * cols
    >>> plants = (np.hypot(rows % 60 - 30, cols % 60 - 30) < 12)
    >>> dsm = (ground + 0.5 * plants).astype(np.float32)
    >>> est = estimate_ground(dsm, soil=~plants, pixel_size=0.05)
    >>> bool(np.abs(est - ground).max() < 0.01)
    True
    """
    return fit_ground(dsm, soil=soil, pixel_size=pixel_size, block_m=block_m, detail_m=detail_m).ground


@dataclass(eq=False, frozen=True)
class CandidateGrounds:
    """``build(names, evidence) -> {name: ground}``: :func:`ground_candidates` of one surface.

    An object rather than a closure so that the held-out check's folds can be sent to a Dask
    cluster's workers, the surface once to each (`run` of :func:`fit_ground`).
    """

    dsm: np.ndarray
    lowest: np.ndarray
    pixel_size: float
    block_m: float
    detail_m: float

    def __call__(self, names, evidence):
        return ground_candidates(
            self.dsm, self.lowest, evidence, pixel_size=self.pixel_size, block_m=self.block_m,
            detail_m=self.detail_m, names=names,
        )  # fmt: skip


def ground_candidates(dsm, lowest, evidence, *, pixel_size, block_m, detail_m, names=CANDIDATES):
    """{name: ground} of the candidates ``"smooth"`` and ``"detailed"`` among `names` (see the module)
    from the `evidence` pixels and the `lowest` surface (the baseline is :func:`naive_block_ground`)."""
    out = {}
    if "smooth" in names or "detailed" in names:
        above = np.where(evidence, dsm - lowest, 0.0).astype(np.float32)
        offset = float(np.median(above[evidence])) if evidence.any() else 0.0
        local = evidence_offset(above - offset, evidence, OFFSET_SCALE * block_m / pixel_size)  # one scale
        smooth = (lowest + offset + local).astype(np.float32)
        if "smooth" in names:
            out["smooth"] = smooth
        if "detailed" in names:
            detailed = smooth
            if detail_m > 0:
                detail = detail_above(dsm, smooth, evidence, detail_m / pixel_size, block_m / pixel_size)
                detailed = (smooth + detail).astype(np.float32)
            out["detailed"] = detailed
    return out


# Below this share of bare soil (of the pixels with data) one flight cannot carry a ground.
MIN_SOIL_FRACTION = 0.01


def check_enough_soil(soil, valid, *, source):
    """Refuse a single-flight ground carried by too little bare soil (:class:`GroundError`).

    `source` names the surface model in the message. Returns the soil's share of `valid`.
    """
    from ..errors import GroundError

    n_soil = int(np.count_nonzero(soil))
    n_valid = max(1, int(np.count_nonzero(valid)))
    share = n_soil / n_valid
    if n_soil < MIN_SOIL_PIXELS or share < MIN_SOIL_FRACTION:
        raise GroundError(
            f"{source}: only {n_soil} bare-soil pixels ({share:.2%} of the pixels with data) to estimate "
            f"the ground under the crop from; at least {MIN_SOIL_FRACTION:.0%} and {MIN_SOIL_PIXELS} "
            "pixels are needed, or the heights would be measured from the canopy. Give a terrain model "
            "(--dtm, `dtm=`)"
        )
    return share


def canopy_height(dsm, ground):
    """CHM = DSM - ground, negatives set to 0, NaN where either has no data (a no-data marker the
    DSM did not declare included: :func:`surface_data`).

    Examples
    --------
    >>> canopy_height(np.array([[1.5, np.nan, 0.9, -9999.0]]), np.array([[1.0, 1.0, 1.0, 1.0]]))
    array([[0.5, nan, 0. , nan]], dtype=float32)
    """
    dsm = np.asarray(dsm, dtype=np.float32)
    ground = np.asarray(ground, dtype=np.float32)
    if dsm.shape != ground.shape:
        raise CliffTerrainError(f"`ground` must have the shape of `dsm` {dsm.shape}, got {ground.shape}")
    chm = dsm - ground
    np.maximum(chm, 0.0, out=chm)  # NaN stays NaN
    chm[~surface_data(dsm)] = np.nan
    return chm
