"""The ground from a surface model alone: what it cannot tell (a ridge's soil from low leaves) counts in the error."""

from __future__ import annotations

import numpy as np
import pytest

from cliff_terrain.measure.ground import fit_ground
from cliff_terrain.measure.ground_evidence import soil_top


def hilled(*, rows=600, cols=480, pixel=0.03, hill=0.15, plant=0.30, seed=0):
    """Rounded hills 0.9 m apart, `hill` m above their furrows, plants on their crests with bare gaps.

    No headland: a field cut to its plots' box, whose lowest soil is the furrows'.
    """
    rng = np.random.default_rng(seed)
    rr, cc = np.mgrid[:rows, :cols]
    phase = 2 * np.pi * cc / round(0.9 / pixel)
    soil = 50.0 + 0.004 * rr * pixel + hill * (1 + np.cos(phase)) / 2
    plants = (np.cos(phase) > 0.5) & ((rr // round(0.3 / pixel)) % 3 != 0)  # a plant, a plant, a gap
    dsm = (
        soil + rng.normal(0, 0.008, soil.shape) + np.where(plants, plant + rng.normal(0, 0.03, soil.shape), 0)
    )
    return dsm.astype(np.float32), soil, plants


def test_the_hills_soil_above_the_furrows_counts_in_the_error_of_a_ground_from_the_surface_alone():
    # The surface's soil mode is the furrows; the plants stand on the hills' crests, 11-15 cm above
    # them. Nothing but a photo (or a terrain model) tells the hills' flanks from low leaves: the
    # plants' soil may lie anywhere up to where the surface thins below the canopy, and that spread
    # counts in the error, which then covers the plants' heights read from the furrows.
    dsm, soil, plants = hilled()
    fit = fit_ground(dsm, pixel_size=0.03)
    model = fit.check["sigma_model"]
    assert 0.15 <= model["soil_top_m"] < 0.25  # above the hills' soil, below the plants' tops
    miss = (fit.ground - soil)[plants]
    assert np.median(miss) < -0.08  # read from the furrows, the heights stand high
    assert np.mean(np.abs(miss) <= 1.645 * fit.sigma[plants]) > 0.95
    held_out = np.hypot(model["floor_m"], model["relief_m"])
    assert np.mean(np.abs(miss) <= 1.645 * held_out) < 0.2  # the held-out check alone: confidently wrong
    np.testing.assert_allclose(fit.sigma, np.sqrt(held_out**2 + model["soil_top_m"] ** 2 / 3), rtol=1e-5)


def test_a_surface_with_a_gap_between_its_soil_and_its_canopy_keeps_a_narrow_error():
    # Flat soil and plants taller than the microrelief: the surface is empty between them, its
    # soil's top is its noise, and the error stays near what the held-out check says.
    rng = np.random.default_rng(2)
    rr, cc = np.mgrid[:400, :400]
    plants = np.hypot(rr % 40 - 20, cc % 40 - 20) < 12
    ground = 100.0 + 0.002 * cc
    dsm = (ground + rng.normal(0, 0.008, rr.shape) + 0.6 * plants).astype(np.float32)
    fit = fit_ground(dsm, pixel_size=0.05)
    model = fit.check["sigma_model"]
    assert model["soil_top_m"] < 0.05
    assert np.median(fit.sigma) < np.hypot(model["floor_m"], model["relief_m"]) + 0.01
    assert np.median(np.abs(fit.ground - ground)[plants]) < 0.01


def test_with_a_photo_the_colour_tells_and_no_soil_top_is_counted():
    dsm, soil, plants = hilled()
    fit = fit_ground(dsm, soil=~plants, pixel_size=0.03)
    assert "soil_top_m" not in fit.check["sigma_model"]
    assert np.median(np.abs(fit.ground - soil)[plants]) < 0.05


def test_the_soil_top_is_where_the_surface_thins_below_the_canopy():
    rng = np.random.default_rng(0)
    furrow = rng.normal(0, 0.01, 40000)
    flanks = rng.uniform(0.0, 0.12, 20000)  # the soil of ridges, their crests under the plants
    canopy = rng.uniform(0.18, 0.8, 60000)
    assert 0.12 <= soil_top(np.concatenate([furrow, flanks, canopy])) <= 0.18
    # A canopy whose lower flank thins all the way up the microrelief: its top (25 cm).
    flank = 0.6 - np.sqrt(rng.uniform(0.0, 0.36, 60000))  # density falling linearly to 0.6 m
    assert soil_top(np.concatenate([furrow, flanks, 0.12 + flank])) == pytest.approx(0.25, abs=0.01)
    # Raised beds with steep walls: the beds' tops are a mode of their own, the search starts there.
    beds = np.concatenate([furrow, rng.normal(0.15, 0.005, 20000), rng.uniform(0.25, 0.8, 40000)])
    assert 0.15 < soil_top(beds) < 0.22
    # A canopy whose mode stands just above the microrelief, a little soil below it: never 0.
    assert soil_top(np.concatenate([rng.normal(0, 0.005, 500), rng.normal(0.26, 0.03, 60000)])) > 0.15
    # Nothing within the microrelief, or nothing at all: it tells nothing, the microrelief's top.
    assert soil_top(np.full(1000, 0.4)) == soil_top(np.array([], np.float32)) == 0.25
