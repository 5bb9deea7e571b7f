"""The ground's evidence: which pixels of a surface model are bare soil (step 2 of :mod:`.ground`).

Geometry first: the soil is the surface's lowest mode, within the microrelief of the lowest surface.
The photo's colour is evidence where the surface agrees with it, and otherwise only takes its plants
out of the surface's soil.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Colour soil counts this far (metres) from anything the photo does not call soil.
DEFAULT_EXPOSURE_M = 0.06
# Highest microrelief (ridges, beds, furrows) the ground follows; crops stand taller than that.
MICRORELIEF_M = 0.25
# Fewest pixels that make soil evidence (or a mode of the surface's soil).
MIN_SOIL_PIXELS = 100
# The height histogram's bin (metres).
_BIN_M = 0.005
# The surface's own soil peak: this many robust deviations of its lower side.
_PEAK_SPREAD = 3.0


def ground_evidence(dsm, reference, *, soil=None, exposed=None):
    """Pixels taken as bare soil near the `reference` surface: ``(evidence, source, colour figures)``.

    See the module's step 2; `reference` is the lowest surface, then the smooth ground.
    `exposed` is the colour soil away from plants (:func:`exposed_soil`), default `soil`.
    """
    above = dsm - reference
    finite = np.isfinite(above)
    near = finite & (above <= MICRORELIEF_M)
    band = soil_peak(above[near])
    low = finite & (above <= band)
    colour = {"surface_soil_band_m": band}
    if soil is None:
        return low, "surface", colour
    soil = soil & finite
    kept = soil if exposed is None else exposed & finite
    n_soil = int(np.count_nonzero(soil))
    high = int(np.count_nonzero(soil & ~near))
    plants = finite & ~soil
    rise = None
    if n_soil and np.count_nonzero(plants) >= MIN_SOIL_PIXELS:
        rise = float(np.median(above[plants]) - np.median(above[soil]))
    colour.update(
        colour_soil_share_above_m=MICRORELIEF_M,
        colour_soil_above=high / max(1, n_soil),
        colour_plants_rise_m=rise,
    )
    # The colour counts where the surface agrees with it: most of its soil lies within the
    # microrelief, and its plants stand above its soil by more than the soil's own band. A photo
    # whose colour does not follow the crop (a senescent or yellow canopy, a grey photo) calls the
    # canopy soil: on a real potato trial with its photos turned straw-coloured, the colour's
    # evidence took the closed canopy (every pixel within the microrelief) for soil, and the plots'
    # p90 came out 23-34 cm low on days 100 and 90.
    if not n_soil or high > 0.5 * n_soil:
        colour["colour_contradicted"] = "most of the photo's soil stands above the microrelief"
    elif rise is None:
        colour["colour_contradicted"] = "the photo shows no plants"
    elif rise <= band:
        colour["colour_contradicted"] = "the photo's plants stand no higher than its soil's band"
    else:
        return kept & near, "colour and surface", colour
    # Then the surface decides which pixels are soil (its lowest mode), and the colour only takes
    # out what it still calls plants there.
    if np.count_nonzero(kept & low) >= MIN_SOIL_PIXELS:
        return kept & low, "surface", colour
    return low, "surface", colour


def exposed_soil(soil, *, pixel_size, exposure_m=DEFAULT_EXPOSURE_M):
    """`soil` at least `exposure_m` from anything else: a leaf's shadowed flank next to it is not soil.

    Small gaps in a canopy are shadowed leaves more often than soil. When that leaves almost
    nothing (a canopy without wide gaps), all of `soil` counts.
    """
    import cv2

    reach = exposure_m / pixel_size
    if reach < 1.0 or not soil.any() or soil.all():
        return soil
    radius = int(np.ceil(reach))
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    disc = (np.hypot(yy, xx) < reach).astype(np.uint8)
    near_other = cv2.dilate((~soil).astype(np.uint8), disc) > 0
    exposed = soil & ~near_other
    if np.count_nonzero(exposed) < max(MIN_SOIL_PIXELS, 1e-3 * np.count_nonzero(soil)):
        return soil
    return exposed


def soil_peak(above):
    """Upper end (metres above the lowest surface) of the surface's lowest soil mode.

    The lowest peak of the height histogram that is a mode of its own, not the highest: a short
    closed canopy (within the microrelief) is the histogram's largest mode. A peak is a mode when
    it is resolved (the valleys beside it fall below half its height, the half-maximum criterion),
    rises out of its counts' noise (three standard deviations of a smoothed bin's Poisson noise, a
    mean of five counts: sqrt(n / 5)) and holds `MIN_SOIL_PIXELS`. A shoulder is not a mode: on a
    real ridged potato field's surface model alone (potato_fieldimager_ex1) a shoulder 4.5 cm below
    the soil's mode (prominence 5 % of its height), taken as the mode, raised the plots' p90 bias
    against the two-flight difference from +3.7 to +5.3 cm.
    """
    if above.size == 0:
        return 0.0
    peaks = _histogram_peaks(above)
    pick = peaks.significant & peaks.resolved
    # float64, as the bins are: under NumPy 2 a Python float would let float32 `above` be compared
    # and subtracted in float32.
    mode = np.float64(peaks.levels[pick][0] if pick.any() else peaks.highest)
    low = peaks.low
    lower = above[(above <= mode) & (above >= low)] - mode
    spread = float(np.sqrt(np.mean(lower**2))) if lower.size else _BIN_M
    return float(min(MICRORELIEF_M, mode + _PEAK_SPREAD * max(spread, _BIN_M)))


def soil_top(above):
    """Height (metres, >= 0) up to which the surface alone cannot tell soil from leaves.

    Without a photo the surface's soil is its lowest mode (as :func:`soil_peak` finds it): furrows,
    say. Above it, the surface's low part runs on into the flanks and tops of ridges or beds, whose
    soil the plants may stand on, and into the lowest leaves, which the surface alone cannot tell
    apart. That low part ends where the surface is thinnest above its highest mode within the
    microrelief (a bed's top is a mode of its own) and up to the microrelief's top: the first bin
    holding the lowest count of the smoothed height histogram there. Above it stands the canopy.
    The histogram runs to twice the microrelief, so that it does not end where it is searched.
    A surface with nothing within the microrelief above the ground tells nothing: the
    microrelief's top.

    Parameters
    ----------
    above : 1-D float array
        Heights above the ground (metres), finite.

    Returns
    -------
    float

    Examples
    --------
    Furrows at 0, rounded ridges 15 cm high whose crests the plants cover (their flanks bare), and
    the plants' leaves from 25 to 60 cm:

    >>> rng = np.random.default_rng(0)
    >>> ridges = 0.15 * (1 + np.cos(rng.uniform(-np.pi, np.pi, 6000))) / 2
    >>> above = np.concatenate([ridges[ridges < 0.11], rng.uniform(0.25, 0.6, 3000)])
    >>> 0.10 < soil_top(above) < 0.25
    True
    >>> round(soil_top(rng.normal(0, 0.005, 5000)), 2)  # flat soil: its noise and the smoothing's reach
    0.03
    """
    above = above[above <= 2 * MICRORELIEF_M]
    within = above <= MICRORELIEF_M
    if not within.any():
        return MICRORELIEF_M
    peaks = _histogram_peaks(above)
    span = peaks.centres <= MICRORELIEF_M
    modes = peaks.significant & peaks.resolved & (peaks.levels <= MICRORELIEF_M)
    start = (
        float(peaks.levels[modes][-1])
        if modes.any()
        else float(peaks.centres[span][np.argmax(peaks.smooth[span])])
    )
    span &= peaks.centres > start
    if not span.any():
        return MICRORELIEF_M
    counts = np.where(span, peaks.smooth, np.inf)
    return max(0.0, float(peaks.centres[np.argmin(counts)]))


@dataclass
class _Peaks:
    """The smoothed height histogram and its peaks (:func:`_histogram_peaks`)."""

    centres: np.ndarray  # bin centres (metres)
    smooth: np.ndarray  # counts, smoothed over five bins
    levels: np.ndarray  # the peaks' bin centres, lowest first
    significant: np.ndarray  # rises out of its counts' noise and holds MIN_SOIL_PIXELS
    resolved: np.ndarray  # the valleys beside it fall below half its height
    highest: float  # the level of the histogram's largest bin
    low: float  # where the histogram starts


def _histogram_peaks(above):
    """The peaks of the histogram of `above` in 5 mm bins smoothed over five (see :func:`soil_peak`)."""
    from scipy.signal import find_peaks

    step = _BIN_M
    # From the 1st percentile: a few pits (or unmarked no-data) far below must not stretch the bins.
    low = max(float(np.percentile(above, 1.0)), float(above.max()) - 2.0)
    # At least five bins: "same" convolution returns max(bins, 5) values, and on a flat or
    # quantized surface (every soil pixel within 2 cm) fewer bins would overrun the edges.
    top = max(float(above.max()), low + 4 * step)
    edges = np.arange(low, top + 2 * step, step)
    hist, edges = np.histogram(above[above >= low], bins=edges)
    smooth = np.convolve(hist, np.ones(5) / 5, mode="same")
    peaks, props = find_peaks(np.concatenate([[0.0], smooth, [0.0]]), prominence=0.0)
    peaks, prominence = peaks - 1, props["prominences"]
    height = smooth[peaks]
    significant = (prominence >= 3.0 * np.sqrt(np.maximum(height, 1.0) / 5.0)) & (
        5 * height >= MIN_SOIL_PIXELS
    )
    centres = edges[: smooth.size] + step / 2
    return _Peaks(
        centres,
        smooth,
        centres[peaks],
        significant,
        prominence >= 0.5 * height,
        float(centres[np.argmax(smooth)]),
        low,
    )


def evidence_note(check):
    """``"; soil from the surface: <why>"`` when a ground check's colour was overruled, and
    ``"; <occlusion note>"`` when its narrow openings' soil stands above the open soil
    (:mod:`.ground_occlusion`), else ``""``: for the one-line summary, so that the user reads that
    the photo's colour, or the soil between the plots, was not trusted."""
    evidence = (check or {}).get("evidence") or {}
    why = evidence.get("colour_contradicted")
    note = f"; soil from the surface: {why}" if why else ""
    lift = ((check or {}).get("sigma_model") or {}).get("unconfirmed_lift_m")
    if why and lift is not None and lift >= 0.005:
        note += f" (the ground stands {lift * 100:.0f} cm above the lowest surface, median, with no colour to confirm it: counted in the error)"
    occluded = ((check or {}).get("occlusion") or {}).get("note")
    return f"{note}; {occluded}" if occluded else note
