"""The ground's occlusion check: soil the surface model cannot see between tall plots is said, and counted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_measured_heights import run_cli

from cliff_terrain.io.raster.geotiff import read_surface
from cliff_terrain.measure.ground import fit_ground
from cliff_terrain.measure.ground_occlusion import occlusion_check, occlusion_line
from cliff_terrain.measure.robust_plane import robust_plane

PAIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "dsm" / "fieldimager_ex2"


def occluded_trial(*, fill, height=0.8, pixel=0.05, seed=0):
    """A mature cereal trial on a tilted, undulating field: plots 1.5 m x 5 m, 0.3 m gaps between
    them and 0.5 m alleys between ranges, 5 m of open soil around. The surface model puts the soil
    of the gaps and alleys `fill` metres up (dense matching fills narrow openings between tall
    plots); the open soil it sees. Returns (dsm, true ground, canopy mask)."""
    rng = np.random.default_rng(seed)
    rows, cols = 500, 700
    rr, cc = np.mgrid[:rows, :cols]
    ground = 50.0 + 0.01 * cc * pixel + 0.03 * np.sin(2 * np.pi * rr * pixel / 17.0)
    trial = (rr >= 100) & (rr < 400) & (cc >= 100) & (cc < 600)
    canopy = trial & ((cc - 100) % 36 < 30) & ((rr - 100) % 110 < 100)
    opening = trial & ~canopy
    dsm = ground + np.where(
        canopy, height + rng.normal(0, 0.02, canopy.shape), rng.normal(0, 0.01, canopy.shape)
    )
    dsm = np.where(opening, dsm + fill, dsm)
    return dsm.astype(np.float32), ground, canopy


def test_soil_between_tall_plots_that_the_surface_fills_fails_the_check_and_counts_in_the_error():
    dsm, ground, canopy = occluded_trial(fill=0.3)
    # A ground forced by name follows the filled gaps; the held-out check passes all the same:
    # held-out gaps are as high as the gaps they are predicted from.
    fit = fit_ground(dsm, soil=~canopy, pixel_size=0.05, method="detailed")
    assert fit.check["passed"]
    missed = np.median((fit.ground - ground)[canopy])
    assert missed > 0.2  # so every plot reads about that much low
    occlusion = fit.check["occlusion"]
    assert occlusion["tested"] and not occlusion["passed"] and "ground" not in occlusion
    assert occlusion["rise_m"] == pytest.approx(0.3, abs=0.04)  # less the undulation the plane misses
    assert 0 < occlusion["spread_m"] < 0.05
    assert occlusion["canopy_from_narrow"] > 0.8  # the ground under the plots comes from the gaps
    note = occlusion["note"]
    assert "does not see the ground between the plots" in note and "heights may read that much low" in note
    assert "--dtm" in note
    # The plots' uncertainty holds what the check found: it covers the ground's real error.
    assert np.median(fit.sigma[canopy]) >= 0.9 * missed


def test_when_the_gaps_are_not_the_ground_the_ground_is_lowered_by_what_they_stand_up():
    dsm, ground, canopy = occluded_trial(fill=0.3)
    fit = fit_ground(dsm, soil=~canopy, pixel_size=0.05)
    occlusion = fit.check["occlusion"]
    assert not occlusion["passed"] and occlusion["ground"] == "lowered"
    assert "the ground is lowered by that much where it rests on that soil" in occlusion["note"]
    error = (fit.ground - ground)[canopy]
    # Within the undulation the open soil's plane misses (3 cm): 27 cm of the 30 are taken back
    # (less at the trial's edges, where the ground rests on open and narrow soil alike).
    assert abs(np.median(error)) < 0.04 and np.percentile(np.abs(error), 95) < 0.1
    # The ground is guessed where it rests on the gaps: its support falls there; the narrow soil's
    # spread about the rise counts in the error, which covers most of the ground's real error (not
    # all: the plane's 3 cm of undulation and the trial's edges are beyond that spread).
    assert fit.support[canopy].mean() < 0.15 and fit.check["support_where_guessed"] < 0.15
    assert np.mean(np.abs(error) <= 1.645 * fit.sigma[canopy]) > 0.75


def test_open_soil_on_one_side_only_lowers_the_ground_by_the_rise_and_no_more():
    # A headland below the trial is its only open soil; thin strips of soil run along the raster's
    # other edges (beyond them: no data, no obstacle). A plane through the open soil alone would
    # be metres off here; the rise bounds the change wherever the open soil cannot tell.
    rng = np.random.default_rng(0)
    rr, cc = np.mgrid[:360, :700]
    ground = 50.0 + 0.0005 * cc + 0.00025 * rr
    trial = (rr >= 6) & (rr < 306) & (cc >= 6) & (cc < 694)
    canopy = trial & ((cc - 6) % 36 < 30) & ((rr - 6) % 110 < 100)
    soil_noise = rng.normal(0, 0.01, canopy.shape)
    dsm = (
        ground
        + np.where(canopy, 0.8 + rng.normal(0, 0.02, canopy.shape), soil_noise)
        + 0.3 * (trial & ~canopy)
    )
    fit = fit_ground(dsm.astype(np.float32), soil=~canopy, pixel_size=0.05)
    assert fit.check["occlusion"]["ground"] == "lowered"
    error = (fit.ground - ground)[canopy]
    assert abs(np.median(error)) < 0.02
    assert np.percentile(error, 5) > -0.2 and np.percentile(error, 95) < 0.06


def test_a_forced_ground_is_kept_and_the_rise_counts_in_its_error():
    dsm, ground, canopy = occluded_trial(fill=0.3)
    for method in ("smooth", "baseline"):
        fit = fit_ground(dsm, soil=~canopy, pixel_size=0.05, method=method)
        occlusion = fit.check["occlusion"]
        assert not occlusion["passed"] and "ground" not in occlusion
        assert f"the {method} ground follows it" in occlusion["note"]
        assert np.median(fit.sigma[canopy]) >= occlusion["rise_m"]


def test_a_dsm_with_holes_and_a_nan_collar_is_checked_the_same():
    dsm, ground, canopy = occluded_trial(fill=0.3)
    holed = dsm.copy()
    holed[:12] = np.nan  # no data along one edge
    holed[200:210, 300:330] = np.nan  # a hole in the trial
    fit = fit_ground(holed, soil=~canopy, pixel_size=0.05)
    occlusion = fit.check["occlusion"]
    assert not occlusion["passed"] and occlusion["rise_m"] == pytest.approx(0.3, abs=0.04)
    assert np.isfinite(fit.ground).all() and abs(np.median((fit.ground - ground)[canopy])) < 0.04


def test_the_one_line_summary_says_both_notes():
    from cliff_terrain.measure.ground_evidence import evidence_note

    check = {
        "evidence": {"colour_contradicted": "the photo shows no plants"},
        "occlusion": {"passed": False, "note": "the surface model does not see the ground between the plots"},
    }
    assert evidence_note(check) == (
        "; soil from the surface: the photo shows no plants; the surface model does not see the ground between the plots"
    )
    assert evidence_note({"occlusion": {"passed": True, "note": ""}}) == ""


def test_soil_the_surface_sees_between_the_plots_passes_and_leaves_the_error_alone():
    dsm, ground, canopy = occluded_trial(fill=0.0)
    fit = fit_ground(dsm, soil=~canopy, pixel_size=0.05)
    occlusion = fit.check["occlusion"]
    assert occlusion["tested"] and occlusion["passed"] and occlusion["note"] == ""
    # The plane through the open soil cannot follow the field's 3 cm undulation: within that.
    assert abs(occlusion["rise_m"]) < 0.035
    assert occlusion["open_pixels"] > 0 and occlusion["narrow_pixels"] > 0
    assert abs(np.median((fit.ground - ground)[canopy])) < 0.03
    assert np.median(fit.sigma[canopy]) < 0.1


def test_high_narrow_soil_that_little_of_the_canopy_stands_next_to_passes():
    # Ridge tops showing between plants (a potato trial's hills) stand above the open furrows; the
    # ground under the canopy comes from the furrows, and the check says the rise but passes.
    rng = np.random.default_rng(2)
    rows, cols = np.mgrid[:300, :400]
    furrow = (cols % 40) < 20
    dsm = np.where(furrow, 0.0, 0.4).astype(np.float32) + rng.normal(0, 0.005, furrow.shape).astype(
        np.float32
    )
    ridge_soil = ~furrow & ((cols % 40) == 30) & ((rows % 30) < 3)  # specks between the plants
    dsm[ridge_soil] = 0.15
    out, lowering = occlusion_check(
        dsm, np.zeros_like(dsm), furrow | ridge_soil, pixel_size=0.05, block_px=100, tolerance_m=0.1
    )
    assert out["tested"] and out["rise_m"] > 0.1
    assert out["canopy_from_narrow"] < 0.5 and out["passed"] and out["note"] == ""
    assert lowering[:, 10::40].max() < 0.1  # the furrows' plants rest on the furrows: not lowered


def test_a_field_without_narrow_openings_or_without_canopy_is_not_tested():
    dsm = np.zeros((120, 120), np.float32)
    none, no_lowering = occlusion_check(
        dsm, np.zeros_like(dsm), np.ones(dsm.shape, bool), pixel_size=0.05, block_px=100, tolerance_m=0.1
    )
    assert (
        not none["tested"]
        and none["passed"]
        and none["rise_m"] is None
        and none["canopy_m"] is None
        and no_lowering is None
    )
    dsm[40:80, 40:80] = 0.5  # one plot in open soil: no soil is narrow
    soil = dsm == 0
    one, _ = occlusion_check(dsm, np.zeros_like(dsm), soil, pixel_size=0.05, block_px=100, tolerance_m=0.1)
    assert not one["tested"] and one["passed"] and one["narrow_pixels"] == 0 and one["canopy_m"] == 0.5


@pytest.mark.skipif(not PAIR.is_dir(), reason="../shared/data/dsm/fieldimager_ex2 is absent")
def test_the_real_potato_plots_openings_are_seen():
    # The OpenDroneMap pair: potato at flowering, its furrows and alleys wide for its canopy.
    from cliff_terrain.measure.canopy import measure_orthophoto

    _, _, _, canopy = measure_orthophoto(PAIR / "odm_orthophoto.tif", PAIR / "dsm.tif")
    occlusion = canopy.check["occlusion"]
    assert occlusion["tested"] and occlusion["passed"]
    assert 0.2 < occlusion["canopy_m"] < 0.6 and abs(occlusion["rise_m"]) < 0.1


def write_occluded_trial(folder):
    """`folder`/ortho.tif and dsm.tif of :func:`occluded_trial` (fill 0.3 m): golden plots on brown
    soil, UTM 16N at 5 cm. Returns the canopy mask."""
    from test_segmentation import _write_georeferenced

    dsm, _, canopy = occluded_trial(fill=0.3)
    rng = np.random.default_rng(1)
    golden, soil = np.array([200.0, 170.0, 100.0]), np.array([110.0, 90.0, 70.0])
    rgb = np.where(canopy[..., None], golden, soil) * (1 + 0.05 * rng.standard_normal((*canopy.shape, 1)))
    _write_georeferenced(folder, np.clip(rgb, 0, 255).astype(np.uint8), dsm, 0.05)
    return canopy


def test_heights_says_when_the_surface_model_cannot_see_between_the_plots(tmp_path):
    canopy = write_occluded_trial(tmp_path)
    out = tmp_path / "out"
    done = run_cli("heights", tmp_path / "ortho.tif", "--dsm", tmp_path / "dsm.tif", "--out", out)
    assert done.returncode == 0, done.stderr
    assert "does not see the ground between the plots" in done.stdout and done.stdout.count("\n") == 1
    assert "the ground is lowered by that much" in done.stdout
    occlusion = json.loads((out / "summary.json").read_text())["ground_check"]["occlusion"]
    assert not occlusion["passed"] and occlusion["ground"] == "lowered"
    assert occlusion["rise_m"] == pytest.approx(0.3, abs=0.04)  # less the undulation the plane misses
    # The canopy stands its 0.8 m again (less the 3 cm undulation the rise could not see).
    chm = read_surface(out / "chm.tif").data
    assert np.median(chm[canopy]) == pytest.approx(0.8, abs=0.04)


def test_the_robust_plane_is_least_squares_without_its_outliers():
    rng = np.random.default_rng(3)
    rows, cols = rng.uniform(0, 100, 500), rng.uniform(0, 100, 500)
    design = np.column_stack([np.ones(500), rows, cols])
    z = 2.0 + 0.01 * rows - 0.02 * cols + rng.normal(0, 0.01, 500)
    clean, *_ = np.linalg.lstsq(design, z, rcond=None)
    np.testing.assert_allclose(robust_plane(design, z), clean, atol=1e-3)
    z[:40] += 0.8  # canopy among the soil: dropped, the plane is the soil's
    a, b, c = robust_plane(design, z)
    assert abs(a - 2.0) < 0.005 and abs(b - 0.01) < 1e-4 and abs(c + 0.02) < 1e-4
    assert abs(np.linalg.lstsq(design, z, rcond=None)[0][0] - 2.0) > 0.03  # plain least squares is not


def test_the_panels_line_says_what_failed_and_nothing_when_it_passed():
    line = occlusion_line({"passed": False, "rise_m": 0.231, "ground": "lowered"})
    expected = "the DSM does not see the soil between the plots (+23 cm above the open soil); ground lowered by that much"
    assert line == expected
    assert occlusion_line({"passed": False, "rise_m": 0.12}).endswith("(+12 cm above the open soil)")
    assert occlusion_line({"passed": True, "rise_m": 0.3}) == "" and occlusion_line(None) == ""


@pytest.mark.blender
def test_the_sidebar_says_when_the_surface_model_cannot_see_between_the_plots(scene, tmp_path):
    import bpy
    from cliff_terrain_addon.panels.sidebar import key_figure_lines, relief_info

    write_occluded_trial(tmp_path)
    settings = scene.cliff_terrain
    settings.filepath = str(tmp_path / "ortho.tif")
    settings.dsm = str(tmp_path / "dsm.tif")
    settings.height_source = "measured"
    settings.max_size = 350
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    obj = bpy.context.active_object
    note = obj["cliff_terrain"]["ground_note"]
    assert note.startswith("the DSM does not see the soil between the plots (+")
    assert note.endswith("ground lowered by that much")
    assert key_figure_lines(relief_info(obj))[-1] == f"Ground: {note}"
