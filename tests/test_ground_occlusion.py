"""The ground's occlusion check: soil the surface model cannot see between tall plots is said, and counted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_measured_heights import UTM16N, geokeys, run_cli, write_tiff

from cliff_terrain.io.raster.geotiff import read_surface
from cliff_terrain.measure.ground import fit_ground
from cliff_terrain.measure.ground_occlusion import occlusion_check, occlusion_line

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
    assert occlusion["canopy_from_narrow"] > 0.8  # the ground under the plots comes from the gaps
    note = occlusion["note"]
    assert "does not see the ground between the plots" in note and "heights may read that much low" in note
    assert "--dtm" in note
    # The plots' uncertainty holds what the check found: it covers the ground's real error.
    assert np.median(fit.sigma[canopy]) >= 0.9 * missed


def test_when_the_gaps_are_not_the_ground_the_open_soil_alone_carries_it():
    dsm, ground, canopy = occluded_trial(fill=0.3)
    fit = fit_ground(dsm, soil=~canopy, pixel_size=0.05)
    occlusion = fit.check["occlusion"]
    assert not occlusion["passed"] and occlusion["ground"] == "open soil"
    assert "the ground comes from the open soil alone" in occlusion["note"]
    error = (fit.ground - ground)[canopy]
    assert abs(np.median(error)) < 0.01 and np.percentile(np.abs(error), 95) < 0.05
    # The ground is guessed across the trial: its support falls there. It was checked as every
    # ground is, on its own held-out (open) soil, and its uncertainty is that check's: it covers the
    # ground's real error under the plots.
    assert fit.support[canopy].mean() < 0.15 and fit.check["support_where_guessed"] < 0.15
    assert occlusion["open_check"]["passed"] and occlusion["open_check"]["folds_used"] >= 3
    assert occlusion["open_check"]["error_m"] < 0.03 and "held-out open soil within" in occlusion["note"]
    assert np.mean(np.abs(error) <= 1.645 * fit.sigma[canopy]) > 0.95


def test_an_open_soil_ground_that_fails_its_own_check_is_not_taken(monkeypatch):
    # Whatever makes the open soil's ground miss its own held-out soil (here: a ground built 0.5 m
    # off), the narrow soil's ground stays, the rise counts in its error, and the note says why.
    from cliff_terrain.measure import ground as ground_module

    build = ground_module.OpenGrounds.__call__
    monkeypatch.setattr(
        ground_module.OpenGrounds,
        "__call__",
        lambda self, names, evidence: {"open": build(self, names, evidence)["open"] + np.float32(0.5)},
    )
    dsm, ground, canopy = occluded_trial(fill=0.3)
    fit = fit_ground(dsm, soil=~canopy, pixel_size=0.05)
    occlusion = fit.check["occlusion"]
    assert not occlusion["passed"] and "ground" not in occlusion
    assert not occlusion["open_check"]["passed"] and occlusion["open_check"]["error_m"] > 0.4
    assert "the open soil cannot carry it either" in occlusion["note"]
    assert "heights may read that much low" in occlusion["note"]
    assert np.median((fit.ground - ground)[canopy]) > 0.2  # the filled gaps' ground, as forced
    assert np.median(fit.sigma[canopy]) >= occlusion["rise_m"]


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
    out, open_soil = occlusion_check(
        dsm, np.zeros_like(dsm), furrow | ridge_soil, pixel_size=0.05, block_px=100, tolerance_m=0.1
    )
    assert out["tested"] and out["rise_m"] > 0.1
    assert out["canopy_from_narrow"] < 0.5 and out["passed"] and out["note"] == ""
    assert open_soil[:, 10::40].all() and not open_soil[ridge_soil].any()  # furrow centres, not the specks


def test_a_field_without_narrow_openings_or_without_canopy_is_not_tested():
    dsm = np.zeros((120, 120), np.float32)
    none, no_soil = occlusion_check(
        dsm, np.zeros_like(dsm), np.ones(dsm.shape, bool), pixel_size=0.05, block_px=100, tolerance_m=0.1
    )
    assert (
        not none["tested"]
        and none["passed"]
        and none["rise_m"] is None
        and none["canopy_m"] is None
        and no_soil is None
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
    from cliff_terrain.io.raster.geotiff import write_geotiff

    dsm, _, canopy = occluded_trial(fill=0.3)
    rng = np.random.default_rng(1)
    golden, soil = np.array([200.0, 170.0, 100.0]), np.array([110.0, 90.0, 70.0])
    rgb = np.where(canopy[..., None], golden, soil) * (1 + 0.05 * rng.standard_normal((*canopy.shape, 1)))
    tie, gsd = (500000.0, 4000000.0), 0.05
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    write_tiff(folder / "ortho.tif", rgb, scale=(gsd, gsd), tie=tie, keys=geokeys(UTM16N), photometric="rgb")
    write_geotiff(folder / "dsm.tif", dsm, transform=[[gsd, 0, tie[0]], [0, -gsd, tie[1]]], crs=UTM16N)
    return canopy


def test_heights_says_when_the_surface_model_cannot_see_between_the_plots(tmp_path):
    canopy = write_occluded_trial(tmp_path)
    out = tmp_path / "out"
    done = run_cli("heights", tmp_path / "ortho.tif", "--dsm", tmp_path / "dsm.tif", "--out", out)
    assert done.returncode == 0, done.stderr
    assert "does not see the ground between the plots" in done.stdout and done.stdout.count("\n") == 1
    assert "the ground comes from the open soil alone" in done.stdout
    occlusion = json.loads((out / "summary.json").read_text())["ground_check"]["occlusion"]
    assert not occlusion["passed"] and occlusion["ground"] == "open soil"
    assert occlusion["rise_m"] == pytest.approx(0.3, abs=0.04)  # less the undulation the plane misses
    # The canopy stands its 0.8 m again above the open soil's ground.
    chm = read_surface(out / "chm.tif").data
    assert np.median(chm[canopy]) == pytest.approx(0.8, abs=0.03)


def test_the_panels_line_says_what_failed_and_nothing_when_it_passed():
    line = occlusion_line({"passed": False, "rise_m": 0.231, "ground": "open soil"})
    assert (
        line
        == "the DSM does not see the soil between the plots (+23 cm above the open soil); ground from the open soil"
    )
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
    assert note.startswith("the DSM does not see the soil between the plots (+") and note.endswith(
        "open soil"
    )
    assert key_figure_lines(relief_info(obj))[-1] == f"Ground: {note}"
