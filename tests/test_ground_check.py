"""The single-flight ground, geometry first and checked on held-out soil (issue 38); the ruler."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from conftest import grey_copy
from scipy import stats
from test_measured_heights import run_cli, write_synthetic_pair

from cliff_terrain.data.synthetic_surface import synthetic_surface
from cliff_terrain.errors import CliffTerrainError, GroundError, RulerError
from cliff_terrain.io.raster.geotiff import read_surface
from cliff_terrain.io.vector.plot_polygons import PlotSet
from cliff_terrain.measure.field_book import read_ruler
from cliff_terrain.measure.ground import fit_ground, naive_block_ground
from cliff_terrain.measure.ground_check import robust_error, spatial_folds
from cliff_terrain.measure.ground_detail import canopy_level
from cliff_terrain.measure.ground_evidence import soil_peak
from cliff_terrain.measure.ruler import Z90, agreement, calibrate, calibrated_err


def beds(*, rows=400, cols=600, pixel=0.05, height=0.7, seed=0):
    """Closed canopy beds 3 m wide between 1 m alleys of bare soil, on a tilted, undulating field."""
    rng = np.random.default_rng(seed)
    rr, cc = np.mgrid[:rows, :cols]
    ground = 50.0 + 0.01 * cc * pixel + 0.05 * np.sin(2 * np.pi * rr * pixel / 15.0)
    bed = (rr % 80) < 60
    dsm = ground + np.where(bed, height + rng.normal(0, 0.03, bed.shape), rng.normal(0, 0.01, bed.shape))
    return dsm.astype(np.float32), ground, bed


def test_folds_never_put_neighbouring_blocks_together():
    folds = spatial_folds((90, 120), block_px=10)
    blocks = folds[::10, ::10]
    assert set(np.unique(blocks)) == {0, 1, 2, 3, 4}
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = blocks[max(0, -di) : blocks.shape[0] - max(0, di), max(0, -dj) : blocks.shape[1] - max(0, dj)]
        b = blocks[max(0, di) :, max(0, dj) :][: a.shape[0], : a.shape[1]]
        assert not np.any(a == b), (di, dj)


def test_robust_error_is_the_rmse_of_clean_errors_and_ignores_a_few_leaves():
    rng = np.random.default_rng(1)
    clean = rng.normal(0.01, 0.02, 20000)
    assert robust_error(clean) == pytest.approx(np.sqrt(np.mean(clean**2)), rel=0.03)
    dirty = np.concatenate([clean, np.full(500, 0.6)])  # 2.5 % leaves taken for soil
    assert robust_error(dirty) < 1.1 * robust_error(clean)


def test_the_baseline_candidate_is_the_naive_block_percentile():
    dsm, _, bed = beds()
    fit = fit_ground(dsm, soil=~bed, pixel_size=0.05, method="baseline")
    np.testing.assert_array_equal(fit.ground, naive_block_ground(dsm, pixel_size=0.05, percentile=2.0))
    assert fit.method == "baseline" and fit.check["method"] == "baseline"


def test_auto_beats_the_baseline_on_held_out_soil_and_under_the_canopy():
    dsm, ground, bed = beds()
    fit = fit_ground(dsm, soil=~bed, pixel_size=0.05)
    errors = {name: c["error_m"] for name, c in fit.check["candidates"].items()}
    assert fit.check["passed"] and fit.method == min(errors, key=errors.get)
    assert errors[fit.method] < 0.6 * errors["baseline"]
    baseline = naive_block_ground(dsm, pixel_size=0.05, percentile=2.0)
    ours_error = np.abs(fit.ground - ground)[bed].mean()
    assert ours_error < 0.02 and ours_error < 0.5 * np.abs(baseline - ground)[bed].mean()


def test_the_detailed_ground_keeps_its_broad_detail_and_one_level_of_the_fine_under_the_canopy():
    # The beds' 5 cm undulation (15 m period) is broad: the detailed ground follows it closer than the
    # smooth one. The field has no ridges: the finer detail's level under the beds is about 0.
    dsm, ground, bed = beds()
    detailed = fit_ground(dsm, soil=~bed, pixel_size=0.05, method="detailed")
    smooth = fit_ground(dsm, soil=~bed, pixel_size=0.05, method="smooth")
    assert abs(detailed.check["detail_under_canopy_m"]) < 0.01
    error = {fit.method: np.abs(fit.ground - ground)[bed].mean() for fit in (detailed, smooth)}
    assert error["detailed"] < 0.8 * error["smooth"], error


def test_the_level_under_the_canopy_counts_in_full_in_the_uncertainty():
    # The synthetic field's ridges stand under its rows: the level lifts the ground under the plants, and
    # no held-out soil checks it, so every pixel's standard error holds it.
    img, dsm, truth = synthetic_surface(gsd=0.03, seed=3)
    fit = fit_ground(dsm, soil=~truth.chm.astype(bool), pixel_size=0.03, method="detailed")
    level = fit.check["detail_under_canopy_m"]
    assert fit.check["sigma_model"]["canopy_level_m"] == level and abs(level) > 0.005
    floor = fit.check["sigma_model"]["floor_m"]
    assert np.all(fit.sigma >= np.float32(np.hypot(floor, level)) * (1 - 1e-6))
    assert fit.check["sigma_model"]["relief_m"] == 0.0  # the detailed ground follows the ridges


def test_a_ground_that_does_not_follow_the_ridges_counts_what_it_misses_at_the_soil():
    # The smooth ground passes under the synthetic field's 3 cm ridges, on which the plants stand:
    # what it misses at the soil itself (the held-out error at distance 0) counts in every pixel's
    # standard error, and the error under the plants against the true ground is then covered.
    img, dsm, truth = synthetic_surface(gsd=0.03, seed=3)
    plants = truth.chm.astype(bool)
    smooth = fit_ground(dsm, soil=~plants, pixel_size=0.03, method="smooth")
    model = smooth.check["sigma_model"]
    assert model["canopy_level_m"] == 0.0 and 0.02 < model["relief_m"] == model["at_soil_m"] < 0.05
    assert smooth.sigma.min() == pytest.approx(np.hypot(model["floor_m"], model["relief_m"]), rel=1e-6)
    miss = np.abs(smooth.ground - truth.ground)[plants]
    assert np.mean(miss <= 1.645 * smooth.sigma[plants]) > 0.9  # 97 % (the floor alone: 60 %)
    assert np.mean(miss <= 1.645 * model["floor_m"]) < 0.85


def test_the_finer_detail_under_a_canopy_is_one_level_whatever_its_noise():
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[:200, :200]
    canopy = (rows % 40) < 30
    dsm = np.where(canopy, 0.5 + rng.uniform(0, 0.2, canopy.shape), 0.0).astype(np.float32)
    smooth = np.zeros_like(dsm)
    # Extrapolated crests: 4 cm on average under the canopy, +-3 cm from place to place.
    detailed = np.where(canopy, 0.04 + rng.uniform(-0.03, 0.03, canopy.shape), 0.0).astype(np.float32)
    ground, level = canopy_level(dsm, smooth, detailed, ~canopy)
    assert level == pytest.approx(0.04, abs=0.002)
    assert np.ptp(ground) == 0.0 and ground[0, 0] == np.float32(level)


def test_a_senescent_canopy_the_colour_calls_soil_is_overruled_by_the_surface():
    # Breeders fly at maturity: the photo calls the whole yellow canopy soil. The ground must come
    # from the alleys, the heights stay the canopy's, and the support falls on the beds.
    dsm, ground, bed = beds(height=0.74)
    fit = fit_ground(dsm, soil=np.ones(dsm.shape, bool), pixel_size=0.05)
    assert fit.evidence_source == "surface"
    assert fit.check["evidence"]["colour_soil_above"] > 0.5
    assert not fit.evidence[bed].any() or fit.evidence[bed].mean() < 0.02
    heights = (dsm - fit.ground)[bed]
    assert abs(np.median(heights) - 0.74) < 0.03
    # The colour alone would give the beds a support of 1 (all 'soil'); the alleys' share is 1/4.
    assert fit.support[bed].mean() < 0.35
    assert fit.check["support_where_guessed"] < 0.35


@pytest.mark.parametrize("colour", ["all soil", "random"])
def test_a_short_canopy_the_colour_does_not_follow_is_overruled_by_the_surface(colour):
    # A 20 cm canopy stands within the microrelief: the share of 'soil' standing high cannot
    # tell. The colour is then tested against the surface: a photo with no plants, or whose plants
    # stand no higher than its soil, does not decide; the surface's lowest mode does.
    dsm, ground, bed = beds(height=0.20)
    rng = np.random.default_rng(1)
    soil = np.ones(dsm.shape, bool) if colour == "all soil" else rng.random(dsm.shape) < 0.6
    fit = fit_ground(dsm, soil=soil, pixel_size=0.05)
    evidence = fit.check["evidence"]
    assert fit.evidence_source == "surface"
    assert evidence["colour_soil_above"] < 0.5  # the old test alone took the canopy for soil
    if colour == "all soil":
        assert evidence["colour_plants_rise_m"] is None
        assert evidence["colour_contradicted"] == "the photo shows no plants"
    else:
        assert abs(evidence["colour_plants_rise_m"]) < 0.02
        assert evidence["colour_contradicted"].startswith("the photo's plants stand no higher")
        assert not (fit.evidence & ~soil).any()  # the colour still takes its plants out
    assert fit.evidence[bed].mean() < 0.02
    heights = (dsm - fit.ground)[bed]
    assert abs(np.median(heights) - 0.20) < 0.03


def test_where_the_surface_overrules_the_colour_the_grounds_lift_counts_in_the_error():
    # Nothing confirms the surface's soil level when the colour is overruled: where the ground
    # stands above the lowest surface (the naive baseline), the lift counts in full in the error. On
    # a real closed potato canopy cut to its plots the surface's lowest layer was the canopy's, and
    # the plots read 7-19 cm low with a stated error of 2.5-3.7 cm.
    dsm, ground, bed = beds(height=0.20)
    soil = np.random.default_rng(1).random(dsm.shape) < 0.6
    fit = fit_ground(dsm, soil=soil, pixel_size=0.05)
    assert fit.check["evidence"]["colour_contradicted"].startswith("the photo's plants stand no higher")
    lift = np.maximum(fit.ground - naive_block_ground(dsm, pixel_size=0.05, percentile=2.0), 0.0)
    assert fit.check["sigma_model"]["unconfirmed_lift_m"] == pytest.approx(float(np.median(lift)), abs=1e-6)
    assert lift[bed].mean() > 0.01  # the furrow-level baseline lies below the soil the ground rests on
    assert (fit.sigma >= lift - 1e-6).all() and (fit.sigma**2 - lift**2 > 0.02**2 - 1e-6).all()
    trusted = fit_ground(dsm, soil=~bed, pixel_size=0.05)  # the colour's plants stand above its soil
    assert "unconfirmed_lift_m" not in trusted.check["sigma_model"]
    assert float(np.median(fit.sigma)) > float(np.median(trusted.sigma)) + 0.005


def test_the_soil_band_ends_above_the_lowest_mode_not_the_largest_nor_a_shoulder():
    rng = np.random.default_rng(0)
    soil = rng.normal(0.02, 0.01, 40_000)
    canopy = rng.normal(0.18, 0.02, 120_000)  # a short closed canopy: the larger mode
    band = soil_peak(np.concatenate([soil, canopy]))
    assert 0.04 < band < 0.07  # the soil's mode, 2 cm, plus three of its deviations
    # A shoulder below the soil's mode (a few furrows 4 cm lower) is not a mode of its own: taken as
    # one, the band would end near 1 cm; it widens the soil's lower side instead.
    furrows = rng.normal(-0.02, 0.01, 15_000)
    assert soil_peak(np.concatenate([furrows, soil, soil])) > band
    # Noise is no mode: a few scattered pits far below do not move the band.
    pits = rng.uniform(-0.2, -0.1, 50)
    assert soil_peak(np.concatenate([pits, soil, canopy])) == pytest.approx(band, abs=0.005)


def test_a_photo_whose_plants_stand_above_its_soil_is_the_evidence():
    dsm, ground, bed = beds(height=0.20)
    fit = fit_ground(dsm, soil=~bed, pixel_size=0.05)
    evidence = fit.check["evidence"]
    assert fit.evidence_source == "colour and surface"
    assert "colour_contradicted" not in evidence
    assert evidence["colour_plants_rise_m"] == pytest.approx(0.20, abs=0.03)
    assert evidence["colour_plants_rise_m"] > evidence["surface_soil_band_m"]
    assert abs(np.median((dsm - fit.ground)[bed]) - 0.20) < 0.03


def test_the_uncertainty_grows_from_the_alleys_into_the_beds():
    dsm, ground, bed = beds()
    fit = fit_ground(dsm, soil=~bed, pixel_size=0.05)
    centre = (np.arange(dsm.shape[0]) % 80 == 30)[:, None] & np.ones(dsm.shape, bool)
    assert fit.sigma[centre].mean() > fit.sigma[~bed].mean()
    assert fit.check["sigma_model"]["at_soil_m"] > 0


def test_a_ground_that_misses_held_out_soil_is_refused_and_names_the_file():
    rng = np.random.default_rng(2)
    dsm = (50 + rng.normal(0, 0.3, (300, 300))).astype(np.float32)  # 'soil' as rough as a canopy
    with pytest.raises(GroundError, match=r"field\.tif.*held-out bare soil within 10 cm.*--dtm"):
        fit_ground(dsm, soil=np.ones(dsm.shape, bool), pixel_size=0.05, source="field.tif")
    forced = fit_ground(dsm, soil=np.ones(dsm.shape, bool), pixel_size=0.05, method="smooth", source="f")
    assert not forced.check["passed"]  # a forced method still reports the failed check


def test_the_checks_folds_run_anywhere_with_the_same_numbers():
    """`run` sends the five folds elsewhere (threads, a cluster): the builder goes by pickle, and
    the ground, its check and its uncertainty are the same to the bit as one after another here."""
    import pickle
    from concurrent.futures import ThreadPoolExecutor

    dsm, _, bed = beds()
    calls = []

    def on_threads(function, arguments, shared):
        shared = pickle.loads(pickle.dumps(shared))  # as a cluster's workers get it
        arguments = list(arguments)
        calls.append(len(arguments))
        with ThreadPoolExecutor(2) as pool:
            return list(pool.map(lambda args: function(*args, shared), arguments))

    here = fit_ground(dsm, soil=~bed, pixel_size=0.05)
    there = fit_ground(dsm, soil=~bed, pixel_size=0.05, run=on_threads)
    assert calls == [here.check["folds_used"]] == [5]
    assert here.method == there.method == "detailed"
    for name in ("ground", "sigma", "support"):
        assert getattr(here, name).tobytes() == getattr(there, name).tobytes(), name
    assert json.dumps(here.check, sort_keys=True, default=float) == json.dumps(
        there.check, sort_keys=True, default=float
    )


def test_bad_method_names_the_parameter():
    with pytest.raises(CliffTerrainError, match="`method`.*'auto'"):
        fit_ground(np.zeros((50, 50), np.float32), pixel_size=0.1, method="cloth")


# --- The ruler ------------------------------------------------------------------------------------


def test_agreement_against_scipy_and_lins_formula():
    rng = np.random.default_rng(4)
    truth = rng.uniform(0.3, 1.0, 60)
    est = 0.9 * truth - 0.05 + rng.normal(0, 0.04, 60)
    a = agreement(est, truth)
    assert a["r"] == pytest.approx(stats.pearsonr(est, truth)[0], abs=1e-12)
    assert a["rmse_m"] == pytest.approx(np.sqrt(np.mean((est - truth) ** 2)))
    assert a["bias_m"] == pytest.approx(np.mean(est - truth))
    # Lin (1989): 2 s_xy / (s_x^2 + s_y^2 + (mean_x - mean_y)^2), population moments.
    sxy = np.cov(est, truth, bias=True)[0, 1]
    ccc = 2 * sxy / (est.var() + truth.var() + (est.mean() - truth.mean()) ** 2)
    assert a["ccc"] == pytest.approx(ccc)


def test_calibration_recovers_a_line_and_its_leave_one_out_error_is_refitting():
    rng = np.random.default_rng(5)
    x = rng.uniform(0.2, 0.8, 25)
    y = 0.08 + 1.15 * x + rng.normal(0, 0.02, 25)
    fit = calibrate(x, y)
    slope, intercept = np.polyfit(x, y, 1)
    assert fit["b"] == pytest.approx(slope) and fit["a_m"] == pytest.approx(intercept)
    loo = []
    for i in range(x.size):
        keep = np.arange(x.size) != i
        b, a = np.polyfit(x[keep], y[keep], 1)
        loo.append(y[i] - (a + b * x[i]))
    assert fit["loo_rmse_m"] == pytest.approx(np.sqrt(np.mean(np.square(loo))))


def test_the_calibrated_error_is_the_textbook_prediction_error_and_covers_new_plots():
    rng = np.random.default_rng(8)
    x = rng.uniform(0.2, 0.8, 40)
    y = 0.08 + 1.15 * x + rng.normal(0, 0.03, 40)
    fit = calibrate(x, y)
    # Independent: the prediction variance s² (1 + x0 (X'X)^-1 x0'), s² on n - 2 degrees of freedom.
    design = np.column_stack([np.ones_like(x), x])
    residual = y - design @ np.linalg.lstsq(design, y, rcond=None)[0]
    s2 = residual @ residual / (x.size - 2)
    new = np.array([0.1, 0.5, 1.0])
    x0 = np.column_stack([np.ones_like(new), new])
    expected = np.sqrt(s2 * (1 + np.einsum("ij,jk,ik->i", x0, np.linalg.inv(design.T @ design), x0)))
    np.testing.assert_allclose(calibrated_err(fit, new), expected, rtol=1e-10)
    # Its leave-one-out check, by refitting without each plot.
    inside = []
    for i in range(x.size):
        keep = np.arange(x.size) != i
        one = calibrate(x[keep], y[keep])
        miss = y[i] - (one["a_m"] + one["b"] * x[i])
        inside.append(abs(miss) <= Z90 * calibrated_err(one, x[i : i + 1])[0])
    assert fit["coverage"] == pytest.approx(np.mean(inside), abs=1e-3)
    # On plots the ruler did not measure, drawn alike, the error covers about 90 %.
    more = rng.uniform(0.2, 0.8, 4000)
    truth = 0.08 + 1.15 * more + rng.normal(0, 0.03, 4000)
    covered = np.abs(fit["a_m"] + fit["b"] * more - truth) <= Z90 * calibrated_err(fit, more)
    assert 0.85 < covered.mean() < 0.95
    # Three plots fit a line but leave no scatter to check it with.
    three = calibrate(x[:3], y[:3])
    assert three["coverage"] is None and np.isnan(calibrated_err(three, new)).all()


def test_agreement_says_how_many_plots_the_uncertainty_covers():
    est, truth = np.array([0.5, 0.6, 0.7, 0.8, np.nan]), np.array([0.52, 0.6, 0.8, 0.8, 0.9])
    a = agreement(est, truth, err=np.array([0.02, 0.02, 0.02, np.nan, 0.02]))
    # Plots 1-3 have both heights and an error: 0.02 and 0 are within 1.645 x 0.02, 0.1 is not.
    assert a["coverage"] == pytest.approx(2 / 3, abs=1e-3) and a["n"] == 4
    assert "coverage" not in agreement(est, truth)
    # A terrain model given: no error to cover with (0 everywhere), no coverage claimed.
    assert agreement(est, truth, err=np.zeros(5))["coverage"] is None


def test_the_ruler_chart_draws_each_heights_error_bars_where_they_reach():
    from cliff_terrain.figures.ruler_chart import CALIBRATED, OURS, ruler_figure

    x = np.array([0.40, 0.50, 0.60, 0.70])
    y = 0.1 + 1.2 * x
    fit = calibrate(x, y + np.array([0.01, -0.01, 0.01, -0.01]))
    kwargs = {"agreement": agreement(x, y), "calibrated": fit["a_m"] + fit["b"] * x, "calibration": fit}
    plain = np.asarray(ruler_figure(x, y, **kwargs))
    err = np.full(4, 0.05)
    barred = np.asarray(ruler_figure(x, y, err=err, calibrated_err=err, **kwargs))
    for colour in (OURS, CALIBRATED):
        ink = [np.all(chart[150:] == colour, axis=-1) for chart in (plain, barred)]
        # +-5 cm bars: about 70 px more ink per plot, and the ink spans further up and down.
        assert ink[1].sum() - ink[0].sum() > 4 * 50, colour
        rows = np.flatnonzero(ink[1].any(axis=1))
        assert np.ptp(rows) > np.ptp(np.flatnonzero(ink[0].any(axis=1))) + 40


def _plots(ids):
    square = [np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])]
    return PlotSet(
        [square] * len(ids), [{"PlotID": i, "name": f"n{i}"} for i in ids], ("PlotID", "name"), None, ""
    )


@pytest.mark.parametrize(
    "text, kwargs, words",
    [
        ("plot,yield\n1,3\n", {}, "no column named like a height"),
        ("plot,height_cm\n91,70\n92,80\n", {}, "none of its ids names a plot"),
        ("plot,height,unit\n1,70,cm\n2,0.8,m\n", {}, "mixes units"),
        ("plot,height\n1,70\n", {}, "--ruler-units"),
        ("plot,height_cm\n1,tall\n", {}, "is not a number"),
        # Until 2026-12-07 accepted: --calibrate then fitted a negative slope.
        (
            "plot,height_cm\n1,70\n2,-48\n",
            {},
            r"height '-48' of plot '2' \(column 'height_cm', row 3\) is not a height",
        ),
        ("plot,height_cm\n1,inf\n", {}, "is not a height"),
        ("plot,height_cm\n1,70\n", {"height_column": "ph_cm"}, "no column 'ph_cm'"),
        # Until 2026-12-06: the last of two heights taken silently, and a semicolon file refused as
        # "tried columns  against ...".
        ("plot,height_cm\n1,70\n2,80\n1,90\n", {}, r"plot '1' appears twice \(rows 2 and 4\)"),
        ("plot;height_cm\n1;70\n", {}, "its header is one column, 'plot;height_cm': save it comma-separated"),
    ],
)
def test_bad_ruler_files_say_what_is_wrong(tmp_path, text, kwargs, words):
    path = tmp_path / "ruler.csv"
    path.write_text(text)
    with pytest.raises(RulerError, match=words) as caught:
        read_ruler(path, _plots([1, 2, 3]), **kwargs)
    assert "ruler.csv" in str(caught.value)


def test_a_ruler_keyed_by_a_plot_number_each_trial_repeats_is_refused_not_joined_off_by_one(tmp_path):
    # Two trials numbering their plots 1-3 each: the ruler's 1, 2, 3 matched the 0-based plot index
    # instead (plots 2, 3 and 4 of the file), every height on the wrong plot, and nothing said so.
    square = [np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])]
    attributes = [{"trial": t, "PlotName": k} for t in ("A", "B") for k in (1, 2, 3)]
    plots = PlotSet([square] * 6, attributes, ("trial", "PlotName"), None, "")
    path = tmp_path / "ruler.csv"
    path.write_text("PlotName,height_cm\n1,70\n2,80\n3,90\n")
    with pytest.raises(
        RulerError, match="its column 'PlotName' matches the plots' 'PlotName', which names several"
    ):
        read_ruler(path, plots)


@pytest.mark.parametrize(
    "header, row, unit, metres",
    [
        # A breeding program's export: the trait abbreviated, the unit in a column of its own.
        ("PlotID,Name,HD,HT,MAT,Units", "2,Glenn,52,31,88,inches", "in", 31 * 0.0254),
        ("PlotID,PH_cm,Yield", "2,74,3.1", "cm", 0.74),
        ("PlotID,PLTHT (in)", "2,29.5", "in", 29.5 * 0.0254),
        ("PlotID,plant_height_inch", "2,30", "in", 30 * 0.0254),
        ("PlotID,PH 2023-07-26 (cm)", "2,74", "cm", 0.74),
    ],
)
def test_a_field_books_abbreviated_height_and_inches_are_read(tmp_path, header, row, unit, metres):
    path = tmp_path / "book.csv"
    path.write_text(f"{header}\n{row}\n")
    ruler = read_ruler(path, _plots([1, 2, 3]))
    # "2" names the plot whose PlotID is 2 and the 0-based plot 2 alike: the column's name decides.
    assert ruler.unit == unit and ruler.plot_field == "PlotID"
    np.testing.assert_allclose(ruler.heights_m, [np.nan, metres, np.nan])


@pytest.mark.parametrize(
    "header",
    [
        "Plot,WEIGHT,units",
        "Plot,phase,units",
        "Plot,HT,PH,units",
        "Plot,soil_pH,units",
        "Plot,HT_notes,units",
    ],
)
def test_words_that_only_contain_a_heights_letters_are_not_a_height(tmp_path, header):
    path = tmp_path / "book.csv"
    path.write_text(f"{header}\n2,1,1,cm\n")
    words = "several height columns" if ",HT," in header else "no column named like a height"
    with pytest.raises(RulerError, match=words):
        read_ruler(path, _plots([1, 2, 3]))


def test_ids_that_name_plots_through_two_fields_alike_are_refused_unless_the_column_says_which(tmp_path):
    # Ids 1 and 2 name the 0-based rows 1, 2 and the PlotIDs 1, 2 alike: one of the two joins every
    # height to a neighbour. The old code took the index, a first fix the attribute; both were wrong
    # for someone.
    path = tmp_path / "book.csv"
    path.write_text("Plot,height_cm\n1,70\n2,80\n")
    with pytest.raises(RulerError, match=r"name as many plots through the plots' 'PlotID' and 'plot'"):
        read_ruler(path, _plots([1, 2, 3]))
    path.write_text("PlotID,height_cm\n1,70\n2,80\n")
    assert read_ruler(path, _plots([1, 2, 3])).plot_field == "PlotID"
    path.write_text("plot,height_cm\n1,70\n2,80\n")  # plots.csv's own 0-based column
    assert read_ruler(path, _plots([1, 2, 3])).plot_field == "plot"


def test_a_utf16_field_book_is_read(tmp_path):
    # Excel's and PowerShell's "Unicode" text: UTF-16 with its byte order mark, once called binary.
    path = tmp_path / "book.csv"
    path.write_bytes("PlotID,height_cm\n2,40\n".encode("utf-16"))
    np.testing.assert_allclose(read_ruler(path, _plots([1, 2, 3])).heights_m, [np.nan, 0.4, np.nan])


def test_a_binary_field_book_is_refused(tmp_path):
    path = tmp_path / "book.xlsx"
    path.write_bytes(b"PK\x03\x04\x00\x00binary")
    with pytest.raises(RulerError, match="not a text CSV"):
        read_ruler(path, _plots([1]))


def test_ruler_matches_by_the_attribute_that_fits_and_converts_units(tmp_path):
    path = tmp_path / "ruler.csv"
    path.write_text("Plot ID,Height (mm),note\n3,800,\n1.0,710,x\n9,500,not a plot\n")
    ruler = read_ruler(path, _plots([1, 2, 3]))
    assert ruler.id_column == "Plot ID" and ruler.plot_field == "PlotID" and ruler.unit == "mm"
    np.testing.assert_allclose(ruler.heights_m, [0.71, np.nan, 0.8])
    assert ruler.matched == 2 and ruler.unmatched == 1


# --- The heights command with its check, uncertainty and ruler ------------------------------------


@pytest.fixture
def trial(tmp_path):
    """The synthetic pair with 8 plots of 1.5 m and a ruler: 0.05 m + 1.1 x each plot's true p90."""
    from cliff_terrain.io.raster.geotiff import read_orthophoto
    from cliff_terrain.io.vector.plot_polygons import read_plots
    from cliff_terrain.measure.field_plots import rasterize_plots

    truth = write_synthetic_pair(tmp_path)
    features = []
    for k in range(8):
        x0, y0 = 500000.6 + 2.1 * (k % 4), 3999999.6 - 2.6 * (k // 4)
        ring = [[x0, y0], [x0 + 1.5, y0], [x0 + 1.5, y0 - 1.5], [x0, y0 - 1.5], [x0, y0]]
        features.append(
            {
                "type": "Feature",
                "properties": {"PlotID": f"P{k + 1}"},
                "geometry": {"type": "Polygon", "coordinates": [ring]},
            }
        )
    doc = {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "EPSG:32616"}},
        "features": features,
    }
    (tmp_path / "plots.geojson").write_text(json.dumps(doc))
    ortho = read_orthophoto(tmp_path / "ortho.tif")
    labels = rasterize_plots(
        read_plots(tmp_path / "plots.geojson"), transform=ortho.transform, shape=ortho.shape
    )
    true_p90 = np.array([np.percentile(truth.chm[labels == k + 1], 90) for k in range(8)])
    rng = np.random.default_rng(7)
    measured = 0.05 + 1.1 * true_p90 + rng.normal(0, 0.005, 8)
    lines = ["plot_id,height_cm"] + [f"P{k + 1},{100 * h:.2f}" for k, h in enumerate(measured)]
    (tmp_path / "ruler.csv").write_text("\n".join(lines) + "\n")
    return tmp_path, truth, measured


def test_heights_reports_its_check_uncertainty_and_the_ruler(trial):
    folder, truth, measured = trial
    out = folder / "out"
    args = ("heights", folder / "ortho.tif", "--dsm", folder / "dsm.tif", "--plots", folder / "plots.geojson")
    done = run_cli(*args, "--ruler", folder / "ruler.csv", "--calibrate", "--out", out)
    assert done.returncode == 0, done.stderr
    assert "held-out bare soil within" in done.stdout and "against the ruler (8 plots)" in done.stdout
    summary = json.loads((out / "summary.json").read_text())
    check = summary["ground_check"]
    assert check["passed"] and summary["ground_method"] == check["chosen"] == check["method"]
    assert set(check["candidates"]) >= {"baseline", "smooth"}
    ruler = summary["ruler"]
    assert ruler["plots_matched"] == 8 and ruler["unit"] == "cm" and ruler["plot_field"] == "PlotID"
    with open(out / "plots.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    ours = np.array([float(r["height_p90_m"]) for r in rows])
    np.testing.assert_allclose([float(r["ruler_height_m"]) for r in rows], measured, atol=1e-4)
    assert ruler["height_p90_m"]["r"] == pytest.approx(
        stats.pearsonr(ours, measured)[0], abs=1e-4
    )  # the CSV rounds
    assert ruler["height_p90_m"]["bias_m"] == pytest.approx(np.mean(ours - measured), abs=1e-4)
    # The calibration undoes the ruler's 5 cm + 10 %: its leave-one-out error is small.
    calibrated = np.array([float(r["height_calibrated_m"]) for r in rows])
    fit = ruler["calibration"]
    np.testing.assert_allclose(calibrated, fit["a_m"] + fit["b"] * ours, atol=1e-4)
    assert fit["loo_rmse_m"] < 0.5 * ruler["height_p90_m"]["rmse_m"]
    # Each calibrated height carries its prediction error, and the check of that error on the ruler.
    calibrated_err = np.array([float(r["height_calibrated_err_m"]) for r in rows])
    assert np.all(calibrated_err >= fit["residual_sd_m"]) and 0 <= fit["coverage"] <= 1
    # The ruler reads 5 cm + 10 % above the DSM: the ground's uncertainty cannot cover that, and the
    # record and the summary line say so instead of claiming it.
    assert ruler["height_p90_m"]["coverage"] < 0.8 and "covers only" in ruler["warning"]
    assert "too few: see the ruler's warning" in done.stdout
    # The uncertainty: a column per plot and a raster beside chm.tif, positive where measured.
    err = np.array([float(r["height_p90_err_m"]) for r in rows])
    assert np.all(err > 0) and np.all(err < 0.1)
    sigma = read_surface(out / "chm_err.tif")
    assert sigma.shape == read_surface(out / "chm.tif").shape and np.nanmin(sigma.data) > 0
    # The chart: the plots' points in the DSM's blue and the calibrated red, the figures above.
    from PIL import Image

    chart = np.asarray(Image.open(out / "ruler.png").convert("RGB"))
    assert chart.shape == (720, 720, 3)
    blue = np.all(chart == (31, 119, 180), axis=-1)
    red = np.all(chart == (214, 39, 40), axis=-1)
    assert blue[150:].sum() > 8 * 9 and red[150:].sum() > 8 * 9  # 8 plots each, below the title


def test_heights_with_the_baseline_is_the_naive_peer(trial):
    folder, _, _ = trial
    out = folder / "base"
    done = run_cli(
        "heights", folder / "ortho.tif", "--dsm", folder / "dsm.tif", "--ground", "baseline", "--out", out
    )
    assert done.returncode == 0, done.stderr
    chm = read_surface(out / "chm.tif")
    dsm = read_surface(folder / "dsm.tif")
    from cliff_terrain.io.raster.geotiff import resample

    surface = resample(dsm, transform=chm.transform, shape=chm.shape)
    expected = np.maximum(surface - naive_block_ground(surface, pixel_size=0.02, percentile=2.0), 0)
    ok = np.isfinite(chm.data)
    np.testing.assert_allclose(chm.data[ok], expected[ok], atol=1e-5)


def test_heights_on_a_grey_photo_says_the_surface_decided_and_measures_the_same(trial):
    # A photo whose colour tells nothing (grey: a senescent canopy over dry soil, for an RGB
    # threshold): the ground comes from the surface, the one-line summary says so, and the plots
    # measure what they measure with the colour.
    folder, _, _ = trial
    grey_copy(folder / "ortho.tif", folder / "grey.tif")
    runs = {}
    for name in ("ortho", "grey"):
        out = folder / f"h_{name}"
        done = run_cli(
            "heights", folder / f"{name}.tif", "--dsm", folder / "dsm.tif", "--plots", folder / "plots.geojson",
            "--out", out,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        evidence = json.loads((out / "summary.json").read_text())["ground_check"]["evidence"]
        with open(out / "plots.csv", newline="") as stream:
            p90 = np.array([float(row["height_p90_m"]) for row in csv.DictReader(stream)])
        runs[name] = done.stdout, evidence, p90
    stdout, evidence, p90 = runs["grey"]
    assert evidence["source"] == "surface" and evidence["colour_contradicted"]
    assert f"soil from the surface: {evidence['colour_contradicted']} (the ground stands " in stdout
    assert "above the lowest surface, median, with no colour to confirm it: counted in the error)" in stdout
    assert "soil from the surface" not in runs["ortho"][0]
    assert "colour_contradicted" not in runs["ortho"][1]
    assert np.abs(p90 - runs["ortho"][2]).max() < 0.03


@pytest.mark.parametrize(
    "extra, words",
    [
        (("--ruler", "{folder}/ruler.csv"), "needs --plots"),
        (("--plots", "{folder}/plots.geojson", "--calibrate"), "--calibrate needs --ruler"),
        (
            ("--plots", "{folder}/plots.geojson", "--ruler", "{folder}/other.csv"),
            "none of its ids names a plot",
        ),
        (
            ("--plots", "{folder}/plots.geojson", "--ruler", "{folder}/missing.csv"),
            "cannot read the ruler file",
        ),
    ],
)
def test_heights_bad_ruler_exits_2_with_one_line_and_writes_nothing(trial, extra, words):
    folder, _, _ = trial
    (folder / "other.csv").write_text("plot,height_cm\nX9,70\n")
    extra = [e.format(folder=folder) for e in extra]
    done = run_cli(
        "heights", folder / "ortho.tif", "--dsm", folder / "dsm.tif", *extra, "--out", folder / "o"
    )
    assert done.returncode == 2, done.stdout
    assert len(done.stderr.strip().splitlines()) == 1 and words in done.stderr
    assert not (folder / "o").exists()


def test_a_closed_canopy_strip_takes_its_ground_from_the_soil_beside_it_not_its_own_lowest_pixels():
    # A strip 5.5 m wide cut along a trial's edge (a real closed potato canopy's, day 90, read 10 cm
    # low this way): a headland, then plots 0.45 m tall with 1 % of their pixels soil and an alley
    # every 4.5 m. The strip's blocks shrink to 1.8 m, and the canopy's blocks' 2nd percentile is
    # leaves: it stood 10.6 cm above the ground under the canopy, behind a passing check.
    rng = np.random.default_rng(1)
    rr, cc = np.mgrid[:600, :84]
    ground = 10.0 + 0.002 * rr
    canopy = (cc >= 28) & (rr % 68 >= 8)
    leaves = canopy & (rng.random(canopy.shape) >= 0.01)
    dsm = (
        ground + 0.01 * rng.standard_normal(rr.shape) + leaves * (0.45 + 0.05 * rng.standard_normal(rr.shape))
    )
    fit = fit_ground(dsm.astype(np.float32), soil=~leaves, pixel_size=0.066)
    error = (fit.ground - ground)[leaves]
    assert fit.check["passed"] and abs(np.median(error)) < 0.03
    assert np.percentile(np.abs(error), 90) < 0.08
