"""The automatic plot-grid fit against a hand-drawn reference on the shared OpenDroneMap orthophoto.

tests/data/odm_plots_by_hand.geojson holds one polygon per plot, drawn by eye along the canopy's edges
for the top nine plots of each of the four blocks (numbered as ``cliff-terrain plots`` numbers them by
default: serpentine from the top-left). ``plots --fit`` must find every one of them: one fitted plot
per drawn plot, its centre within half a pitch, a mean IoU of at least 0.5, and at least as many of the
plant pixels inside the fitted plots as inside the drawn ones.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO

from cliff_terrain.io.vector.plot_polygons import read_plots
from cliff_terrain.measure.field_plots import rasterize_plots

ODM = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2" / "odm_orthophoto.tif"
REFERENCE = REPO / "tests" / "data" / "odm_plots_by_hand.geojson"
GRID = ["--grid", "4x9", "--plot-size", "14.2x4.8"]


def orthophoto():
    if not ODM.is_file():
        pytest.skip(f"shared OpenDroneMap orthophoto {ODM} not found (../shared is absent)")
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    return read_orthophoto(ODM)


def centres(plots):
    return np.array([rings[0][:4].mean(axis=0) for rings in plots.polygons])


def pitch_of(plots):
    """The smaller pitch of a set of plots: the median distance from a plot's centre to its nearest."""
    xy = centres(plots)
    distance = np.hypot(*(xy[:, None, :] - xy[None]).transpose(2, 0, 1))
    np.fill_diagonal(distance, np.inf)
    return float(np.median(distance.min(axis=1)))


def outer_corners(plots):
    """The four corners of the rectangle around all the plots, along the plots' own axes."""
    quads = np.array([rings[0][:4] for rings in plots.polygons])
    u = quads[0][1] - quads[0][0]
    u /= np.hypot(*u)
    v = np.array([-u[1], u[0]])
    pu, pv = quads.reshape(-1, 2) @ u, quads.reshape(-1, 2) @ v
    return [
        a * u + b * v
        for a, b in ((pu.min(), pv.min()), (pu.max(), pv.min()), (pu.max(), pv.max()), (pu.min(), pv.max()))
    ]


def test_the_hand_drawn_reference_covers_the_crop():
    from cliff_terrain.io.vector.plot_files import check_plots_fit
    from cliff_terrain.measure.canopy import plant_mask

    ortho = orthophoto()
    reference = read_plots(REFERENCE)
    assert reference.crs == ortho.crs
    assert sorted(a["plot"] for a in reference.attributes) == list(range(1, 37))
    assert {(a["column"], a["row"]) for a in reference.attributes} == {
        (c, r) for c in range(1, 5) for r in range(1, 10)
    }
    check_plots_fit(reference, transform=ortho.transform, shape=ortho.shape, source=str(REFERENCE))
    plants = plant_mask(ortho.data, valid=ortho.valid)
    labels = rasterize_plots(reference, transform=ortho.transform, shape=ortho.shape)
    cover = np.array([plants[labels == k].mean() for k in range(1, 37)])
    assert cover.min() >= 0.85, cover.round(2)  # drawn on the canopy, not on the alleys
    assert 5.5 < pitch_of(reference) < 6.5  # the row pitch, about 6 m


@pytest.mark.parametrize(
    "start",
    [
        0,
        1,
        # No corners and no spacing: the fit finds the pitches (about 18.2 x 6.0 m, not the touching
        # plots' 14.2 x 4.8 m) and the position from the mask alone.
        pytest.param(None, id="no-placement"),
    ],
)
def test_fit_finds_every_hand_drawn_plot(tmp_path, start):
    from cliff_terrain.measure.canopy import plant_mask

    ortho = orthophoto()
    reference = read_plots(REFERENCE)
    pitch = pitch_of(reference)
    placement = []
    if start is not None:
        # Corners clicked within a quarter of the pitch of the drawn grid's outer corners.
        rng = np.random.default_rng(start)
        clicked = []
        for corner in outer_corners(reference):
            angle, radius = rng.uniform(0, 2 * np.pi), rng.uniform(0, 0.25 * pitch)
            clicked.append(corner + radius * np.array([np.cos(angle), np.sin(angle)]))
        placement = ["--corners", *(f"{x:.3f},{y:.3f}" for x, y in clicked)]
    out = tmp_path / "plots.geojson"
    command = ["plots", str(ODM), *GRID, *placement, "--fit", "--out", str(out)]
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *command], capture_output=True, text=True, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    fitted = read_plots(out)
    assert len(fitted) == len(reference)

    distance = np.hypot(*(centres(fitted)[:, None, :] - centres(reference)[None]).transpose(2, 0, 1))
    nearest = distance.argmin(axis=0)  # the fitted plot nearest each drawn one
    assert len(set(nearest)) == len(reference), "two drawn plots share their nearest fitted plot"
    off = distance.min(axis=0)
    assert off.max() < 0.5 * pitch, f"a fitted plot's centre is {off.max():.2f} m off (pitch {pitch:.2f} m)"
    numbers = [(a["plot"], a["column"], a["row"]) for a in reference.attributes]
    assert [
        (fitted.attributes[i]["plot"], fitted.attributes[i]["column"], fitted.attributes[i]["row"])
        for i in nearest
    ] == numbers

    drawn = rasterize_plots(reference, transform=ortho.transform, shape=ortho.shape)
    labels = rasterize_plots(fitted, transform=ortho.transform, shape=ortho.shape)
    ious = []
    for k, i in enumerate(nearest):
        mine, theirs = drawn == k + 1, labels == i + 1
        ious.append((mine & theirs).sum() / (mine | theirs).sum())
    assert np.mean(ious) >= 0.5, np.round(ious, 2)

    plants = plant_mask(ortho.data, valid=ortho.valid)
    share = (plants & (labels > 0)).sum() / plants.sum()
    assert share >= (plants & (drawn > 0)).sum() / plants.sum() - 0.005
