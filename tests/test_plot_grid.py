"""Plot grids from a trial layout: geometry, numbering, field books, files, bad input, and the fit to
the crop on the shared soybean plots (their own polygons as the reference) and on the shared
OpenDroneMap orthophoto (every fitted plot on a block of crop)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, SHARED_UAV

from cliff_terrain.errors import CliffTerrainError, PlotFileError
from cliff_terrain.io.vector.plot_files import read_field_book, write_plots
from cliff_terrain.io.vector.plot_polygons import polygon_area, read_plots
from cliff_terrain.measure.field_plots import rasterize_plots
from cliff_terrain.measure.plot_grid import (
    Placement,
    grid_layout,
    placement_from_corners,
    plot_grid,
    plots_from,
)

ODM = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2" / "odm_orthophoto.tif"
SOYBEAN = SHARED_UAV / "lamberton_soybean"


def centres(plots):
    return np.array([rings[0][:4].mean(axis=0) for rings in plots.polygons])


def test_uneven_alleys_pitch_and_buffer_give_the_plots_their_sizes():
    plots = plot_grid(
        3, 2, plot_size=(1.0, 4.0), origin=(0.0, 0.0), alleys=([0.5, 1.5], 2.0), numbering="rows",
        start="bottom-left", buffer=(0.1, 0.25),
    )  # fmt: skip
    assert [polygon_area(rings) for rings in plots.polygons] == pytest.approx([0.8 * 3.5] * 6)
    # Columns start at 0, 1.5 and 4.0 (uneven alleys), rows at 0 and 6; trimmed by the buffer.
    assert centres(plots)[:3, 0] == pytest.approx([0.5, 2.0, 4.5])
    assert centres(plots)[[0, 3], 1] == pytest.approx([2.0, 8.0])
    pitched = plot_grid(3, 2, plot_size=(1.0, 4.0), origin=(0.0, 0.0), pitch=(1.2, 5.0))
    assert sorted(set(np.round(centres(pitched)[:, 0], 6))) == pytest.approx([0.5, 1.7, 2.9])


@pytest.mark.parametrize(
    ("numbering", "start", "first_row"),
    [
        ("rows", "top-left", [1, 2, 3]),
        ("rows", "bottom-right", [9, 8, 7]),  # the top row, seen left to right, when plot 1 is bottom-right
        ("columns", "top-left", [1, 4, 7]),
        ("serpentine", "top-left", [1, 2, 3]),
    ],
)
def test_numbering_starts_at_the_named_corner(numbering, start, first_row):
    plots = plot_grid(3, 3, plot_size=(1.0, 2.0), origin=(0.0, 0.0), numbering=numbering, start=start)
    xy = centres(plots)
    top = np.isclose(xy[:, 1], xy[:, 1].max())
    order = np.argsort(xy[top, 0])
    assert [plots.attributes[i]["plot"] for i in np.flatnonzero(top)[order]] == first_row
    if numbering == "serpentine":
        middle = np.isclose(xy[:, 1], np.median(xy[:, 1]))
        left_to_right = [
            plots.attributes[i]["plot"] for i in np.flatnonzero(middle)[np.argsort(xy[middle, 0])]
        ]
        assert left_to_right == [6, 5, 4]  # the second row runs back


def test_corners_in_any_order_give_the_same_rotated_grid():
    angle = np.radians(30.0)
    u, v = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
    corners = np.array([[0, 0], 10 * u, 10 * u + 40 * v, 40 * v]) + [500.0, 100.0]
    a = plot_grid(4, 5, plot_size=(2.0, 6.0), corners=corners)
    b = plot_grid(4, 5, plot_size=(2.0, 6.0), corners=corners[[2, 0, 3, 1]])
    np.testing.assert_allclose(centres(a), centres(b))
    # The plots are spread evenly between the corners: outer edges on the corners.
    every = np.concatenate([rings[0] for rings in a.polygons])
    assert (every - [500.0, 100.0]) @ u == pytest.approx(np.clip((every - [500.0, 100.0]) @ u, 0, 10))
    assert placement_from_corners(corners, (10.0, 40.0)).angle == pytest.approx(30.0)


def test_field_book_joined_by_plot_or_by_column_and_row(tmp_path):
    by_plot = tmp_path / "book.csv"
    by_plot.write_text("Plot,Name,Trait\n" + "".join(f"{k},G{k},{k * 2}\n" for k in range(1, 7)))
    plots = plot_grid(3, 2, plot_size=(1, 3), origin=(0, 0), field_book=read_field_book(by_plot))
    assert plots.fields == ("plot", "column", "row", "Name", "Trait")
    assert [(a["plot"], a["Name"]) for a in plots.attributes][:2] == [(1, "G1"), (2, "G2")]
    by_cell = tmp_path / "cells.csv"
    by_cell.write_text(
        "column,row,entry\n" + "".join(f"{c},{r},E{c}{r}\n" for c in (1, 2, 3) for r in (1, 2))
    )
    plots = plot_grid(3, 2, plot_size=(1, 3), origin=(0, 0), field_book=read_field_book(by_cell))
    assert all(a["entry"] == f"E{a['column']}{a['row']}" for a in plots.attributes)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("plot,x\n1,a\n2,b\n3,c\n4,d\n5,e\n", "no row for plots plot=6"),
        ("plot,x\n1,a\n1,b\n2,c\n3,d\n4,e\n5,f\n6,g\n", "plot plot=1 appears twice"),
        ("plot,x\n" + "".join(f"{k},a\n" for k in range(1, 8)), "names plots the grid does not have: plot=7"),
        ("name,x\nA,1\n", "needs a `plot` column"),
        # A ragged row and a semicolon book: a traceback (AttributeError) until 2026-12-06.
        ("plot,x\n1,a\n2,b,\n", "row 3 has 3 values for the header's 2 columns (a trailing comma"),
        ("plot;x;yield\n1;a;3,5\n", "its header is one column, 'plot;x;yield': save it comma-separated"),
    ],
)
def test_bad_field_books_are_refused_by_name(tmp_path, text, words):
    path = tmp_path / "book.csv"
    path.write_text(text)
    with pytest.raises(PlotFileError, match="book.csv") as caught:
        plot_grid(3, 2, plot_size=(1, 3), origin=(0, 0), field_book=read_field_book(path))
    assert words in str(caught.value)


def test_geojson_and_shapefile_read_back_into_the_same_plot_tables(tmp_path):
    plots = plot_grid(3, 2, plot_size=(1.0, 3.0), origin=(500000.0, 4000000.0), alleys=(0.5, 1.0), crs=32616)
    for name in ("plots.geojson", "plots.shp"):
        write_plots(plots, tmp_path / name, crs=32616)
        back = read_plots(tmp_path / name)
        assert back.crs == 32616 and len(back) == 6
        assert [a["plot"] for a in back.attributes] == [1, 2, 3, 4, 5, 6]
        transform = [[0.1, 0, 499999.0], [0, -0.1, 4000008.0]]
        np.testing.assert_array_equal(
            rasterize_plots(back, transform=transform, shape=(100, 60)),
            rasterize_plots(plots, transform=transform, shape=(100, 60)),
        )


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"plot_size": (0.0, 3.0)}, "`plot width` must be > 0"),
        ({"plot_size": (1.0, 3.0), "pitch": (0.5, 4.0)}, "`column pitch` must be >= 1"),
        ({"corners": [(0, 0), (1, 1), (2, 2), (3, 3)]}, "do not form a convex quadrilateral"),
        ({"corners": [(0, 0), (10, 10), (10, 0), (0, 10)], "plot_size": (1.0, 3.0)}, None),
        ({"plot_size": (1.0, 3.0), "buffer": 0.5}, "trims the whole plot"),
    ],
)
def test_bad_layouts_are_refused_by_name(kwargs, words):
    kwargs = {"plot_size": (1.0, 3.0), "origin": (0.0, 0.0), **kwargs}
    if "corners" in kwargs:
        kwargs.pop("origin")
    if words is None:  # a crossed order of the same four points is still a quadrilateral
        assert len(plot_grid(2, 2, **kwargs)) == 4
        return
    with pytest.raises(CliffTerrainError, match=words.replace("(", r"\(").replace(")", r"\)")):
        plot_grid(2, 2, **kwargs)


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *map(str, args)], capture_output=True, text=True, cwd=REPO
    )


def odm():
    if not ODM.is_file():
        pytest.skip(f"shared OpenDroneMap pair {ODM} not found (../shared is absent)")
    from cliff_terrain.io.raster.geotiff import read_orthophoto

    return read_orthophoto(ODM)


# Four blocks of plots, nine plots each, read off the photo by hand (pixel col, row of the outer corners).
ODM_CORNERS_PX = [(91, 109), (434, 122), (434, 389), (91, 377)]


def _map(transform, col, row):
    return f"{transform[0, 2] + transform[0, 0] * col:.3f},{transform[1, 2] + transform[1, 1] * row:.3f}"


@pytest.mark.parametrize("seed", [0, 1])
def test_fit_puts_every_plot_on_its_block_of_crop(tmp_path, seed):
    from cliff_terrain.measure.canopy import plant_mask

    ortho = odm()
    plants = plant_mask(ortho.data, valid=ortho.valid)
    rng = np.random.default_rng(seed)
    # Clicked within a quarter of the row pitch (6 m): up to 1.2 m off in each direction.
    corners = [
        _map(ortho.transform, c + rng.uniform(-6, 6), r + rng.uniform(-6, 6)) for c, r in ODM_CORNERS_PX
    ]
    covers = {}
    for fit in (False, True):
        out = tmp_path / f"plots{fit}.geojson"
        args = ["plots", ODM, "--grid", "4x9", "--plot-size", "14.2x4.8", "--corners", *corners, "--out", out]
        done = run_cli(*args, *(["--fit"] if fit else []))
        assert done.returncode == 0, done.stderr
        labels = rasterize_plots(read_plots(out), transform=ortho.transform, shape=ortho.shape)
        covers[fit] = np.array([plants[labels == k].mean() for k in range(1, 37)])
    assert covers[True].min() >= 0.85, covers[True].round(2)
    assert covers[True].mean() > covers[False].mean()
    report = json.loads((tmp_path / "plotsTrue.geojson.fit.json").read_text())
    assert abs(report["angle_deg"] + 2.0) < 1.5  # the blocks lean by about 2 degrees
    assert 0.0 <= report["confidence"] <= 1.0


def test_fit_matches_the_soybean_plots_from_rough_corners_and_from_nothing():
    from cliff_terrain.io.raster.geotiff import read_orthophoto
    from cliff_terrain.measure.canopy import plant_mask
    from cliff_terrain.measure.plot_fit import fit_grid

    tif = SOYBEAN / "20180822_Lamberton_clipped.tif"
    if not tif.is_file():
        pytest.skip(f"{tif} not found (../shared is absent)")
    reference = read_plots(SOYBEAN / "plots.geojson")
    ortho = read_orthophoto(tif)
    plants = plant_mask(ortho.data, valid=ortho.valid)
    quads = np.array([rings[0][:4] for rings in reference.polygons])
    u = quads[0][1] - quads[0][0]
    u /= np.hypot(*u)
    v = np.array([-u[1], u[0]])
    pu, pv = quads.reshape(-1, 2) @ u, quads.reshape(-1, 2) @ v
    outer = [
        a * u + b * v
        for a, b in ((pu.min(), pv.min()), (pu.max(), pv.min()), (pu.max(), pv.max()), (pu.min(), pv.max()))
    ]
    ref_labels = rasterize_plots(reference, transform=ortho.transform, shape=ortho.shape)
    ref_centres = centres(reference)
    rng = np.random.default_rng(3)
    rough = [c + rng.uniform(-0.28, 0.28, 2) for c in outer]  # within a quarter of the 1.59 m pitch
    layout = grid_layout(5, 8, plot_size=(1.592, 5.2725))
    for placement in (placement_from_corners(rough, layout.extent), None):
        fit = fit_grid(plants, ortho.transform, layout, placement=placement, valid=ortho.valid)
        plots = plots_from(fit.layout, fit.placement)
        got = centres(plots)
        distance = np.hypot(*(got[:, None, :] - ref_centres[None]).transpose(2, 0, 1))
        nearest = distance.argmin(axis=0)
        assert len(set(nearest)) == len(reference)  # one to one
        assert distance.min(axis=0).max() < 0.5 * 1.592  # within half a column pitch
        labels = rasterize_plots(plots, transform=ortho.transform, shape=ortho.shape)
        ious = [
            ((ref_labels == k + 1) & (labels == nearest[k] + 1)).sum()
            / ((ref_labels == k + 1) | (labels == nearest[k] + 1)).sum()
            for k in range(len(reference))
        ]
        assert np.mean(ious) >= 0.6
        share = (plants & (labels > 0)).sum() / plants.sum()
        assert share >= (plants & (ref_labels > 0)).sum() / plants.sum() - 0.005


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--grid", "0x9", "--plot-size", "14x4.8", "--origin", "296590,4888240"], "at least one column"),
        (["--grid", "4x9", "--plot-size", "14x4.8", "--origin", "0,0"], "lie outside"),
        (["--grid", "4x9", "--plot-size", "14x4.8"], "place the grid"),
        (
            ["--grid", "4x9", "--plot-size", "14x4.8", "--origin", "296590,4888240", "--pitch", "10x6"],
            "`column pitch` must be >= 14",
        ),
        (
            ["--grid", "4x9", "--plot-size", "14x4.8", "--corners", "1,1", "2,2", "3,3", "4,4"],
            "quadrilateral",
        ),
        # GeoJSON written under a .kml name, exit 0, until 2026-12-06; `heights --plots` then refused it.
        (
            [
                "--grid",
                "4x9",
                "--plot-size",
                "14x4.8",
                "--origin",
                "296590,4888240",
                "--out-name",
                "plots.kml",
            ],
            "must end in .geojson (or .json) or .shp",
        ),
    ],
)
def test_plots_command_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, args, words):
    odm()
    name = args[args.index("--out-name") + 1] if "--out-name" in args else "plots.geojson"
    args = [a for a in args if a not in ("--out-name", name)]
    out = tmp_path / name
    done = run_cli("plots", ODM, *args, "--out", out)
    assert done.returncode == 2, done.stdout
    assert words in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_corners_and_origin_take_negative_map_coordinates(tmp_path):
    # A local metric CRS puts fields at negative coordinates: "--corners -120.5,40 ..." was taken
    # for an unknown option (argparse: "expected 4 arguments") until 2026-12-07.
    import tifffile

    from cliff_terrain.io.raster.geotiff import geotiff_tags

    ortho = odm()
    shift = np.array([-ortho.transform[0, 2] - 500.0, -ortho.transform[1, 2] - 10.0])  # map metres
    moved = ortho.transform.copy()
    moved[:2, 2] += shift
    assert moved[0, 2] < 0 and moved[1, 2] < 0  # every map coordinate of the photo is negative
    photo = tmp_path / "negative.tif"
    alpha = ortho.valid.astype(np.uint8) * 255
    tifffile.imwrite(
        photo, np.dstack([ortho.data, alpha]), photometric="rgb", extrasamples=[2],
        extratags=geotiff_tags(moved, ortho.crs),
    )  # fmt: skip
    corners = [_map(moved, c, r) for c, r in ODM_CORNERS_PX]
    assert all(c.startswith("-") for c in corners)
    out = tmp_path / "plots.geojson"
    done = run_cli(
        "plots", photo, "--grid", "4x9", "--plot-size", "14.2x4.8", "--corners", *corners, "--out", out
    )
    assert done.returncode == 0, done.stderr
    moved_plots = read_plots(out)
    done = run_cli(
        "plots", ODM, "--grid", "4x9", "--plot-size", "14.2x4.8",
        "--corners", *[_map(ortho.transform, c, r) for c, r in ODM_CORNERS_PX], "--out", tmp_path / "odm.geojson",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    for got, want in zip(moved_plots.polygons, read_plots(tmp_path / "odm.geojson").polygons, strict=True):
        np.testing.assert_allclose(np.asarray(got[0]) - shift, np.asarray(want[0]), atol=1e-3)
    origin = f"{moved[0, 2] + 20:.3f},{moved[1, 2] - 30:.3f}"
    done = run_cli(
        "plots", photo, "--grid", "2x2", "--plot-size", "1x3", "--origin", origin, "--out", out, "--overwrite"
    )
    assert done.returncode == 0, done.stderr
    done = run_cli(
        "plots", photo, "--grid", "2x2", "--plot-size", "1x3", "--origin", "-5,x", "--out", out, "--overwrite"
    )
    assert done.returncode == 2 and "got '-5,x'" in done.stderr, done.stderr


def test_plots_feed_the_heights_command(tmp_path):
    ortho = odm()
    t = ortho.transform
    corners = [_map(t, c, r) for c, r in ODM_CORNERS_PX]
    out = tmp_path / "plots.shp"
    done = run_cli(
        "plots", ODM, "--grid", "4x9", "--plot-size", "14.2x4.8", "--corners", *corners, "--out", out
    )
    assert done.returncode == 0, done.stderr
    dsm = ODM.with_name("dsm.tif")
    done = run_cli("heights", ODM, "--dsm", dsm, "--plots", out, "--out", tmp_path / "heights")
    assert done.returncode == 0, done.stderr
    header, *rows = (tmp_path / "heights" / "plots.csv").read_text().splitlines()
    assert header.startswith("plot,plot_attr,column,row,area_m2") and len(rows) == 36
    assert all(row.split(",")[-1] == "" for row in rows)  # every plot measured, none partial


def test_a_placement_maps_the_frame_bilinearly():
    placement = Placement(np.array([[0.0, 0.0], [4.0, 0.0], [5.0, 3.0], [0.0, 2.0]]))
    assert placement.to_map(0.5, 0.5).tolist() == pytest.approx([2.25, 1.25])
    assert placement.to_map(1.0, 1.0).tolist() == [5.0, 3.0]
