"""Growth curves and traits per plot: a synthetic season with known logistic curves, the shared soybean
season's senescence against an independent estimate, and the traits command's files."""

from __future__ import annotations

import csv
import datetime as dt
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, SHARED_UAV

from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.season.growth import fit_growth, gompertz, logistic
from cliff_terrain.season.traits import TRAIT_COLUMNS, season_traits

START = dt.date(2026, 5, 1)


def synthetic_season(n_plots=100, seed=1):
    """Weekly flights of plots whose height follows a known logistic (2 % noise) and whose cover closes."""
    rng = np.random.default_rng(seed)
    days = np.arange(10, 121, 7)
    rows, truth = [], {}
    for plot in range(n_plots):
        a, k, t0 = rng.uniform(0.3, 1.2), rng.uniform(0.08, 0.25), rng.uniform(40, 75)
        truth[plot] = (a, t0)
        height = logistic(days, a, k, t0) * (1 + rng.normal(0, 0.02, days.size))
        cover = np.clip(logistic(days, 0.97, 1.2 * k, t0 - 5) + rng.normal(0, 0.01, days.size), 0, 1)
        for day, h, c in zip(days, height, cover, strict=True):
            date = (START + dt.timedelta(days=int(day))).isoformat()
            rows.append({"date": date, "plot": plot, "cover": c, "height_p90": h, "entry": f"G{plot % 5}"})
    return rows, truth


def test_known_logistic_asymptotes_and_inflections_are_found():
    rows, truth = synthetic_season()
    traits = season_traits(rows)
    assert len(traits) == 100 and all(set(TRAIT_COLUMNS) <= set(t) for t in traits)
    asymptote = inflection = 0
    for trait in traits:
        a, t0 = truth[trait["plot"]]
        asymptote += abs(trait["max_height_m"] - a) <= 0.05 * a
        inflection += abs((dt.date.fromisoformat(trait["max_growth_date"]) - START).days - t0) <= 1.0
        assert trait["entry"] == f"G{trait['plot'] % 5}"  # the plot's attributes are kept
    assert asymptote >= 95 and inflection >= 95, (asymptote, inflection)
    assert {t["height_model"] for t in traits} == {"logistic"}  # AICc picks the true model
    assert all(t["canopy_closure_date"] for t in traits)


def test_models_recover_their_own_curves_and_auto_names_its_choice():
    t = np.arange(0.0, 140.0, 8.0)
    fit = fit_growth(t, gompertz(t, 0.9, 0.07, 60.0), model="auto")
    assert fit.model == "gompertz" and fit.params == pytest.approx((0.9, 0.07, 60.0), rel=1e-3)
    noisy = np.array([0.1, 0.12, 0.3, 0.28, 0.5, 0.7, 0.69, 0.8])
    spline = fit_growth(np.arange(8.0) * 10, noisy, model="spline")
    assert (np.diff(spline.curve(np.linspace(0, 70, 50))) >= -1e-12).all()  # monotone
    with pytest.raises(CliffTerrainError, match="`model` must be one of"):
        fit_growth(t, t, model="cubic")
    with pytest.raises(CliffTerrainError, match="at least 3 dates"):
        fit_growth([1.0, 2.0], [0.1, 0.2])


def test_flags_say_what_is_wrong_with_a_plot():
    rows, _ = synthetic_season(n_plots=3)
    rows = [r for r in rows if not (r["plot"] == 0 and r["date"] > "2026-05-30")]  # 3 dates left
    wild = sorted(r["date"] for r in rows if r["plot"] == 1)[8]
    for r in rows:
        if r["plot"] == 1 and r["date"] == wild:
            r["height_p90"] = 5.0  # a wild value
        if r["plot"] == 2:
            r["height_p90"] = 0.4  # no growth
    flags = {t["plot"]: t["flag"] for t in season_traits(rows)}
    assert "fewer than 4 dates" in flags[0]
    assert "dropped as an outlier" in flags[1]
    assert "no growth" in flags[2]


@pytest.fixture(scope="module")
def soybean_season(tmp_path_factory):
    if not SHARED_UAV.is_dir():
        pytest.skip(f"real UAV images not found at {SHARED_UAV}")
    out = tmp_path_factory.mktemp("soybean")
    photos = sorted((SHARED_UAV / "lamberton_soybean").glob("*.tif"))
    plots = SHARED_UAV / "lamberton_soybean" / "plots.geojson"
    command = [sys.executable, "-m", "cliff_terrain", "season", *map(str, photos), "--plots", str(plots)]
    done = subprocess.run(
        [*command, "--out", str(out), "--workers", "0"], capture_output=True, text=True, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    return out


def linear_half_crossing(days, cover):
    """Where cover first falls below half its maximum after its peak, linearly between dates."""
    k = int(np.argmax(cover))
    half = 0.5 * cover[k]
    for i in range(k, len(cover) - 1):
        if cover[i + 1] <= half:
            return days[i] + (cover[i] - half) / (cover[i] - cover[i + 1]) * (days[i + 1] - days[i])
    return None


def test_soybean_senescence_agrees_with_the_covers_own_half_crossing(soybean_season, tmp_path):
    out = tmp_path / "traits"
    args = [
        "traits",
        str(soybean_season),
        "--out",
        str(out),
        "--color-by",
        "ID",
        "--trait",
        "senescence_date",
    ]
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *args], capture_output=True, text=True, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    for name in ("traits.csv", "traits.geojson", "growth.png", "traits_map.png"):
        assert (out / name).is_file(), name
    with open(soybean_season / "season.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    with open(out / "traits.csv", newline="") as stream:
        traits = list(csv.DictReader(stream))
    assert len(traits) == 40 and set(TRAIT_COLUMNS) <= set(traits[0])
    first = min(dt.date.fromisoformat(r["date"]) for r in rows)
    compared = agreed = 0
    for trait in traits:
        mine = sorted((r for r in rows if r["plot"] == trait["plot"]), key=lambda r: r["date"])
        days = np.array([(dt.date.fromisoformat(r["date"]) - first).days for r in mine], float)
        estimate = linear_half_crossing(days, np.array([float(r["cover"]) for r in mine]))
        if estimate is None:
            continue
        compared += 1
        if trait["senescence_date"]:
            agreed += abs((dt.date.fromisoformat(trait["senescence_date"]) - first).days - estimate) <= 4
    assert compared >= 30 and agreed >= 0.9 * compared, (agreed, compared)
    geo = json.loads((out / "traits.geojson").read_text())
    assert len(geo["features"]) == 40 and "senescence_date" in geo["features"][0]["properties"]
    # Existing files are kept.
    again = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *args], capture_output=True, text=True, cwd=REPO
    )
    assert again.returncode == 2 and "--overwrite" in again.stderr


def test_a_season_run_again_on_other_dates_removes_the_traits_fitted_on_the_old_one(soybean_season, tmp_path):
    # The season's folder updates in place (its cache keeps the measured dates); the traits/ beside
    # it, fitted on the season it replaced, stood there unchanged until 2026-12-07.
    season = tmp_path / "season"
    shutil.copytree(soybean_season, season)
    photos = sorted((SHARED_UAV / "lamberton_soybean").glob("*.tif"))
    plots = SHARED_UAV / "lamberton_soybean" / "plots.geojson"

    def run(*args):
        done = subprocess.run(
            [sys.executable, "-m", "cliff_terrain", *map(str, args)], capture_output=True, text=True, cwd=REPO
        )
        assert done.returncode == 0, done.stderr
        return done.stdout

    run("traits", season)
    fitted = sorted(p.name for p in (season / "traits").iterdir())
    assert fitted == ["growth.png", "traits.csv", "traits.geojson", "traits_map.png"]
    same = run("season", *photos, "--plots", plots, "--out", season, "--workers", "0")
    assert sorted(p.name for p in (season / "traits").iterdir()) == fitted and "removed" not in same
    fewer = run("season", *photos[:-1], "--plots", plots, "--out", season, "--workers", "0")
    assert list((season / "traits").iterdir()) == []
    assert "removed traits.csv, traits.geojson, growth.png, traits_map.png from" in fewer
