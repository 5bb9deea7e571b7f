"""Does the surface model see the ground in the narrow openings? A check of the ground's evidence.

A photogrammetric surface model sees the soil at the bottom of an opening only from the cameras that
look into it. Between tall plots (a mature cereal's 0.2-0.3 m gaps and 0.5 m alleys) dense matching
fills the opening: its "soil" stands tens of centimetres above the ground, the lowest surface and
the held-out check both follow it (held-out soil is as high as the soil it is predicted from), and
every height reads low with a confident check. What the data can still show: soil in openings
narrower than the canopy is tall standing higher than soil in wide ones. Soil is open where a disc
as wide (in radius) as the canopy is tall fits between the plants around it (the morphological
opening of the space between them: a 45 degree view into it, from its centre). The reference is
the open soil's level around each narrow opening: the plane through the open soil (robust least
squares: the field's tilt) and its local offset from that plane, by normalized convolution at the
ground's block scale as the smooth ground's offset is made; only narrow soil with open soil near
enough to trust (kernel weight at least ``DETAIL_CONFIDENCE``) is compared, so that a field's
curvature between its open and its narrow soil is not read as a rise. The narrow openings' soil
should lie on that level as the open soil does; the check's tolerance
(`ground_check.CHECK_TOLERANCE_M`) is the largest rise that passes, and only where most of the
canopy rests on narrow soil does a rise matter.

On ``bench/bench_narrow_alleys.py``'s trial with 0.2 m gaps and 0.5 m alleys the narrow soil stood
20 cm above the open soil and the plots read 20 cm low behind a passing held-out check; on the real
potato dates of ``bench/validate_real.py`` it stood -0.4 to +6.5 cm above it.
"""

from __future__ import annotations

import numpy as np

from ..errors import CliffTerrainError
from .ground_detail import DETAIL_CONFIDENCE, blur
from .ground_evidence import MIN_SOIL_PIXELS
from .robust_plane import robust_plane

# Pixels the plane is fitted on at most (a regular sample of the open soil beyond that).
_PLANE_SAMPLE = 200_000


def occlusion_check(dsm, ground, evidence, *, pixel_size, block_px, tolerance_m):
    """How far the soil of narrow openings stands above the open soil around it.

    Parameters
    ----------
    dsm, ground : (rows, cols) float arrays
        The surface (NaN: no data) and the ground estimated from it.
    evidence : (rows, cols) bool array
        The ground's soil evidence.
    pixel_size : float
        Metres per pixel (> 0).
    block_px : float
        The ground's block in pixels (> 0): the scale of the open soil's local level.
    tolerance_m : float
        The largest rise that passes (>= 0).

    Returns
    -------
    record : dict
        ``{"tested", "canopy_m", "open_pixels", "narrow_pixels", "rise_m", "spread_m",
        "canopy_from_narrow", "tolerance_m", "passed", "note"}``: ``canopy_m`` the canopy's height
        above the ground (the median of its upper half), the radius of the discs that make an
        opening open; ``narrow_pixels`` the narrow soil compared (open soil near it); ``rise_m``
        its median height above the open soil's level, ``spread_m`` the robust deviation of those
        heights about it (None when not tested: too little of either, or no canopy);
        ``canopy_from_narrow`` the share of the canopy whose nearest soil is narrow. It fails when
        the rise passes `tolerance_m` and most of the canopy's ground comes from narrow soil; then
        ``note`` says so (else it is empty).
    lowering : (rows, cols) float32 array or None
        When the check was made: how much the ground would be lowered where it rests on narrow soil
        (each pixel's nearest soil, blurred over the discs' radius): the rise, or where open soil is
        near enough to trust its level, what the ground stands above that level (0 to the rise).

    Examples
    --------
    Plots 0.8 m tall with narrow alleys whose "soil" the surface model puts 0.3 m up, and open soil
    around them:

    >>> dsm = np.zeros((200, 200), np.float32)
    >>> trial = np.zeros((200, 200), bool); trial[40:160, 40:160] = True
    >>> canopy = trial.copy(); canopy[:, 58:62] = canopy[:, 98:102] = canopy[:, 138:142] = False
    >>> dsm[canopy] = 0.8; dsm[trial & ~canopy] = 0.3
    >>> ground = np.where(trial & ~canopy, 0.3, 0.0).astype(np.float32)   # a ground on the alleys
    >>> out, lowering = occlusion_check(dsm, ground, ~canopy, pixel_size=0.05, block_px=100, tolerance_m=0.1)
    >>> out["passed"], round(out["rise_m"], 2), round(float(lowering[100, 100]), 2), round(float(lowering[10, 10]), 2)
    (False, 0.3, 0.3, 0.0)
    """
    import cv2

    from .._validate import check_float

    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    block_px = check_float("block_px", block_px, minimum=0.0, strict_minimum=True)
    tolerance_m = check_float("tolerance_m", tolerance_m, minimum=0.0)
    dsm = np.asarray(dsm, dtype=np.float32)
    ground = np.asarray(ground, dtype=np.float32)
    evidence = np.asarray(evidence, dtype=bool)
    if dsm.ndim != 2 or ground.shape != dsm.shape or evidence.shape != dsm.shape:
        raise CliffTerrainError(
            f"`dsm`, `ground` and `evidence` must be (rows, cols) arrays of one shape, got "
            f"{dsm.shape}, {ground.shape} and {evidence.shape}"
        )
    finite = np.isfinite(dsm) & np.isfinite(ground)
    evidence = evidence & finite
    canopy = finite & ~evidence
    out = {
        "tested": False, "canopy_m": None, "open_pixels": 0, "narrow_pixels": 0, "rise_m": None,
        "spread_m": None, "canopy_from_narrow": None, "tolerance_m": tolerance_m, "passed": True, "note": "",
    }  # fmt: skip
    if np.count_nonzero(canopy) < MIN_SOIL_PIXELS:
        return out, None
    above = (dsm - ground)[canopy]
    height = float(np.median(above[above >= np.median(above)]))
    out["canopy_m"] = height
    if not height > 0:
        return out, None
    # Open soil: within a disc of radius `height` that holds no canopy (no data is no obstacle, nor
    # is what lies beyond the raster's edge: a strip of soil along it is open, not a gap): the
    # discs' centres lie that far from the canopy, their discs reach that far from the centres.
    radius = height / pixel_size
    pad = int(np.ceil(radius)) + 1
    free = np.pad(~canopy, pad, constant_values=True).astype(np.uint8)
    reach = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    del free
    cover = cv2.distanceTransform((reach < radius).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    del reach
    wide = evidence & (cover[pad:-pad, pad:-pad] <= radius)
    del cover
    narrow = evidence & ~wide
    out["open_pixels"], out["narrow_pixels"] = int(np.count_nonzero(wide)), int(np.count_nonzero(narrow))
    if min(out["open_pixels"], out["narrow_pixels"]) < MIN_SOIL_PIXELS:
        return out, None
    # The open soil's level around each narrow opening: its plane (the field's tilt), then its local
    # offset from the plane by normalized convolution at the ground's block scale (as the smooth
    # ground's), counted only where open soil is near enough to trust it.
    a, b, c = _soil_plane(dsm, wide)
    rows = np.arange(dsm.shape[0], dtype=np.float32)[:, None]
    cols = np.arange(dsm.shape[1], dtype=np.float32)[None, :]
    level = np.float32(a) + np.float32(b) * rows + np.float32(c) * cols
    off = np.where(finite, dsm - level, np.float32(0.0))
    weight = wide.astype(np.float32)
    den = blur(weight, block_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        level += blur(off * weight, block_px) / np.maximum(den, np.float32(1e-6))
    del off, weight
    near = narrow & (den >= DETAIL_CONFIDENCE)
    out["narrow_pixels"] = int(np.count_nonzero(near))
    if out["narrow_pixels"] < MIN_SOIL_PIXELS:
        return out, None
    level += np.float32(np.median((dsm - level)[wide]))  # on the open soil, as its median is
    heights = (dsm - level)[near]
    rise = float(np.median(heights))
    spread = float(1.4826 * np.median(np.abs(heights - rise)))
    # Which soil the ground under the canopy comes from: each pixel's nearest soil (looked up by
    # its label, whatever order OpenCV numbers the soil pixels in). Narrow soil that stands high
    # matters where most of the canopy's ground comes from it (between tall plots), not where it is
    # a few patches on ridges beside open furrows (a potato trial's hills).
    _, nearest = cv2.distanceTransformWithLabels(
        (~evidence).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    is_narrow = np.zeros(int(nearest.max()) + 1, bool)
    is_narrow[nearest[evidence]] = narrow[evidence]
    on_narrow = is_narrow[nearest]
    del nearest, is_narrow
    share = float(np.mean(on_narrow[canopy]))
    passed = rise <= tolerance_m or share < 0.5
    out.update(tested=True, rise_m=rise, spread_m=spread, canopy_from_narrow=share, passed=bool(passed))
    if not passed:
        out["note"] = (
            f"the soil in openings narrower than the canopy is tall ({height:.2f} m), nearest to "
            f"{share:.0%} of the canopy, stands {rise * 100:.0f} cm above the open soil: the surface "
            "model does not see the ground between the plots"
        )
    # How much to lower the ground where it rests on narrow soil: the rise, or, where the open soil
    # is near enough to trust its level, what the ground stands above that level (never more than
    # the rise, never less than 0): near a headland the ground is the open soil's already.
    resting = blur(on_narrow.astype(np.float32), radius)
    del on_narrow
    cap = np.float32(max(rise, 0.0))
    excess = np.clip(ground - level, 0.0, cap, dtype=np.float32)
    # Trusted as the smooth ground trusts its evidence (kernel weight over DETAIL_CONFIDENCE), at the
    # scale of the openings themselves: a strip of open soil beside the plots tells their ground.
    trust = np.clip(blur(wide.astype(np.float32), 2 * radius) / DETAIL_CONFIDENCE, 0.0, 1.0)
    lowering = resting * (trust * excess + (1 - trust) * cap)
    return out, np.where(finite, lowering, np.float32(0.0)).astype(np.float32)


def occlusion_line(record):
    """A short line for a panel when the check of `record` failed, else ``""``.

    Parameters
    ----------
    record : dict or None
        :func:`occlusion_check`'s record, as :func:`~.ground.fit_ground` keeps it in
        ``ground_check["occlusion"]`` (with ``"ground": "lowered"`` when it lowered the ground).

    Returns
    -------
    str

    Examples
    --------
    >>> occlusion_line({"passed": False, "rise_m": 0.23, "ground": "lowered"})
    'the DSM does not see the soil between the plots (+23 cm above the open soil); ground lowered by that much'
    >>> occlusion_line({"passed": True, "rise_m": 0.02})
    ''
    """
    if not record or record.get("passed", True):
        return ""
    line = f"the DSM does not see the soil between the plots ({record['rise_m'] * 100:+.0f} cm above the open soil)"
    return line + ("; ground lowered by that much" if record.get("ground") == "lowered" else "")


def _soil_plane(dsm, mask):
    """``(a, b, c)`` of the robust least-squares plane a + b row + c col of `dsm` over `mask`."""
    rows, cols = np.nonzero(mask)
    step = max(1, rows.size // _PLANE_SAMPLE)
    rows, cols = rows[::step], cols[::step]
    design = np.column_stack([np.ones(rows.size), rows, cols]).astype(np.float64)
    a, b, c = robust_plane(design, dsm[rows, cols].astype(np.float64))
    return float(a), float(b), float(c)
