"""Does the surface model see the ground in the narrow openings? A check of the ground's evidence.

A photogrammetric surface model sees the soil at the bottom of an opening only from the cameras that
look into it. Between tall plots (a mature cereal's 0.3 m gaps and 0.5 m alleys) dense matching
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
(`ground_check.CHECK_TOLERANCE_M`) is the largest rise that passes.

On a synthetic mature-wheat trial (0.2 m gaps, 0.5 m alleys, a smoothed surface model) the narrow
openings' soil stood 23 cm above the plane and the heights read 21 cm low; on the real potato
trial's dates (``bench/validate_real.py``) it stood -1.6 to +3.9 cm above it.
"""

from __future__ import annotations

import numpy as np

from .ground_detail import DETAIL_CONFIDENCE, blur
from .ground_evidence import MIN_SOIL_PIXELS

# Pixels the plane is fitted on at most (a regular sample of the open soil beyond that).
_PLANE_SAMPLE = 200_000


def occlusion_check(dsm, ground, evidence, *, pixel_size, block_px, tolerance_m):
    """How far the soil of narrow openings stands above the open soil around it: ``(record, open soil)``.

    Parameters
    ----------
    dsm, ground : (rows, cols) float arrays
        The surface (NaN: no data) and the ground estimated from it.
    evidence : (rows, cols) bool array
        The ground's soil evidence.
    pixel_size : float
        Metres per pixel.
    block_px : float
        The ground's block in pixels: the scale of the open soil's local level.
    tolerance_m : float
        The largest rise that passes.

    Returns
    -------
    record : dict
        ``{"tested", "canopy_m", "open_pixels", "narrow_pixels", "rise_m", "canopy_from_narrow",
        "tolerance_m", "passed", "note"}``: ``canopy_m`` the canopy's height above the ground (the
        median of its upper half), the radius of the discs that make an opening open;
        ``narrow_pixels`` the narrow soil compared (open soil near it); ``rise_m`` its height above
        the open soil's level (None when not tested: too little of either, or no canopy);
        ``canopy_from_narrow`` the share of the canopy whose nearest soil is narrow. It fails when
        the rise passes `tolerance_m` and most of the canopy's ground comes from narrow soil; then
        ``note`` says so (else it is empty).
    open_soil : (rows, cols) bool array or None
        The evidence at least ``canopy_m`` from the canopy (the centres of the open discs), when
        the check was made: the soil a ground can rest on where the narrow soil cannot.

    Examples
    --------
    Plots 0.8 m tall with narrow alleys whose "soil" the surface model puts 0.3 m up, and open soil
    around them:

    >>> dsm = np.zeros((200, 200), np.float32)
    >>> trial = np.zeros((200, 200), bool); trial[40:160, 40:160] = True
    >>> canopy = trial.copy(); canopy[:, 58:62] = canopy[:, 98:102] = canopy[:, 138:142] = False
    >>> dsm[canopy] = 0.8; dsm[trial & ~canopy] = 0.3
    >>> out, open_soil = occlusion_check(dsm, np.zeros_like(dsm), ~canopy, pixel_size=0.05, block_px=100, tolerance_m=0.1)
    >>> out["passed"], round(out["rise_m"], 2), bool(open_soil[:20].all()), bool(open_soil[100, 58:62].any())
    (False, 0.3, True, False)
    """
    import cv2

    dsm = np.asarray(dsm, dtype=np.float32)
    finite = np.isfinite(dsm)
    evidence = np.asarray(evidence, dtype=bool) & finite
    canopy = finite & ~evidence
    out = {
        "tested": False, "canopy_m": None, "open_pixels": 0, "narrow_pixels": 0,
        "rise_m": None, "canopy_from_narrow": None, "tolerance_m": float(tolerance_m), "passed": True, "note": "",
    }  # fmt: skip
    if np.count_nonzero(canopy) < MIN_SOIL_PIXELS:
        return out, None
    above = (dsm - ground)[canopy]
    upper = above[above >= np.median(above)]
    height = float(np.median(upper)) if upper.size else 0.0
    out["canopy_m"] = height
    if not height > 0:
        return out, None
    # Open soil: within a disc of radius `height` that holds no canopy (no data is no obstacle):
    # the discs' centres lie that far from the canopy, their discs reach that far from the centres.
    radius = height / pixel_size
    reach = cv2.distanceTransform((~canopy).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    centres = reach >= radius
    cover = cv2.distanceTransform((~centres).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    wide = evidence & (cover <= radius)
    narrow = evidence & ~wide
    out["open_pixels"], out["narrow_pixels"] = int(np.count_nonzero(wide)), int(np.count_nonzero(narrow))
    if min(out["open_pixels"], out["narrow_pixels"]) < MIN_SOIL_PIXELS:
        return out, None
    # The open soil's level around each narrow opening: its plane, then its local offset from the
    # plane by normalized convolution at the ground's block scale (as the smooth ground's), counted
    # only where open soil is near enough to trust it.
    a, b, c = _soil_plane(dsm, wide)
    plane = a + b * np.arange(dsm.shape[0], dtype=np.float64)[:, None] + c * np.arange(dsm.shape[1])[None, :]
    off = np.where(finite, dsm - plane.astype(np.float32), np.float32(0.0))
    del plane
    weight = wide.astype(np.float32)
    den = blur(weight, block_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        local = blur(off * weight, block_px) / den
    near = narrow & (den >= DETAIL_CONFIDENCE)
    out["narrow_pixels"] = int(np.count_nonzero(near))
    if out["narrow_pixels"] < MIN_SOIL_PIXELS:
        return out, None
    rise = float(np.median((off - local)[near]) - np.median((off - local)[wide]))
    del off, local, den, weight
    # Which soil the ground under the canopy comes from: each canopy pixel's nearest soil. Narrow
    # soil that stands high matters where most of the canopy's ground comes from it (between tall
    # plots), not where it is a few patches on ridges beside open furrows (a potato trial's hills).
    _, nearest = cv2.distanceTransformWithLabels(
        (~evidence).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    share = float(np.mean(narrow[evidence][nearest[canopy] - 1]))
    passed = rise <= tolerance_m or share < 0.5
    out.update(tested=True, rise_m=rise, canopy_from_narrow=share, passed=bool(passed))
    if not passed:
        out["note"] = (
            f"the soil in openings narrower than the canopy is tall ({height:.2f} m), nearest to "
            f"{share:.0%} of the canopy, stands {rise * 100:.0f} cm above the open soil: the surface "
            "model does not see the ground between the plots"
        )
    # The ground's open soil: the discs' centres, at least the canopy's height from it (the edges
    # of the wide openings, the ends of the narrow ones near them, are left out).
    return out, evidence & centres


def occlusion_line(record):
    """A short line for a panel when the check of `record` (:func:`occlusion_check`'s, in
    ``ground_check["occlusion"]``) failed, else ``""``.

    Examples
    --------
    >>> occlusion_line({"passed": False, "rise_m": 0.23, "ground": "open soil"})
    'the DSM does not see the soil between the plots (+23 cm above the open soil); ground from the open soil'
    >>> occlusion_line({"passed": True, "rise_m": 0.02})
    ''
    """
    if not record or record.get("passed", True):
        return ""
    line = f"the DSM does not see the soil between the plots ({record['rise_m'] * 100:+.0f} cm above the open soil)"
    return line + ("; ground from the open soil" if record.get("ground") == "open soil" else "")


def _soil_plane(dsm, mask):
    """``(a, b, c)`` of the robust least-squares plane a + b row + c col of `dsm` over `mask` (3-sigma trimmed)."""
    rows, cols = np.nonzero(mask)
    step = max(1, rows.size // _PLANE_SAMPLE)
    rows, cols = rows[::step], cols[::step]
    z = dsm[rows, cols].astype(np.float64)
    design = np.column_stack([np.ones(z.size), rows, cols]).astype(np.float64)
    keep = np.ones(z.size, bool)
    coef = np.array([np.median(z), 0.0, 0.0])
    for _ in range(5):
        coef, *_ = np.linalg.lstsq(design[keep], z[keep], rcond=None)
        residual = z - design @ coef
        spread = max(1.4826 * float(np.median(np.abs(residual[keep] - np.median(residual[keep])))), 1e-3)
        new_keep = np.abs(residual) <= 3.0 * spread
        if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return float(coef[0]), float(coef[1]), float(coef[2])
