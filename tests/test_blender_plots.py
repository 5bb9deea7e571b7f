"""Blender: a plot grid over a relief of the shared OpenDroneMap orthophoto: added, edited live, fitted to the
field and exported in the orthophoto's CRS (the same plots the core and the command line make)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO

pytestmark = pytest.mark.blender

ODM = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2" / "odm_orthophoto.tif"
# Four blocks of nine plots, read off the photo by hand: the grid's (0, 0) corner (bottom-left), pixels.
BOTTOM_LEFT_PX = (91, 377)


@pytest.fixture
def relief(scene):
    import bpy

    if not ODM.is_file():
        pytest.skip(f"shared OpenDroneMap pair {ODM} not found (../shared is absent)")
    settings = scene.cliff_terrain
    settings.filepath = str(ODM)
    settings.dsm = str(ODM.with_name("dsm.tif"))
    settings.height_source = "measured"
    settings.max_size = 250
    settings.two_sided = False
    assert bpy.ops.cliff_terrain.build_relief() == {"FINISHED"}
    return bpy.context.active_object


def test_add_edit_fit_and_export_a_plot_grid(relief, tmp_path):
    import bpy
    from cliff_terrain_addon.scene.plot_grid_object import MapFrame, grid_plots

    from cliff_terrain.io.raster.geotiff import read_orthophoto
    from cliff_terrain.io.vector.plot_polygons import read_plots
    from cliff_terrain.measure.canopy import plant_mask
    from cliff_terrain.measure.field_plots import rasterize_plots

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 4, 9
    settings.plot_width, settings.plot_length = 14.2, 4.8
    settings.plot_alley_across, settings.plot_alley_along = 3.8, 1.4
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    grid = bpy.context.active_object
    assert grid.name.endswith("plots") and len(grid.data.polygons) == 36
    columns = np.zeros(36, np.int32)
    grid.data.attributes["column"].data.foreach_get("value", columns)
    assert sorted(set(columns.tolist())) == [0, 1, 2, 3]

    # Live: the sidebar's rows rebuild the grid at once.
    settings.plot_rows = 5
    assert len(grid.data.polygons) == 20
    settings.plot_rows = 9
    assert len(grid.data.polygons) == 36

    # Put it roughly where the plots are (as a user drags it with G), 1 m off, then Fit to Field.
    ortho = read_orthophoto(ODM)
    t = ortho.transform
    col, row = BOTTOM_LEFT_PX
    corner = np.array([t[0, 2] + t[0, 0] * col, t[1, 2] + t[1, 1] * row]) + [1.0, -0.8]
    frame = MapFrame(relief)
    x, y = frame.to_world(corner)[0]
    grid.location = (x, y, grid.location.z)
    assert bpy.ops.cliff_terrain.fit_plot_grid() == {"FINISHED"}
    report = grid["cliff_terrain_fit"]
    assert 0.0 <= report["confidence"] <= 1.0 and abs(report["angle_deg"] + 2.0) < 1.5
    # Every face carries the fit's confidence and flag; the flagged ones are red in `fit_colour`.
    confidence, flag = np.zeros(36, np.float32), np.zeros(36, np.int32)
    grid.data.attributes["fit_confidence"].data.foreach_get("value", confidence)
    grid.data.attributes["fit_flag"].data.foreach_get("value", flag)
    colour = np.zeros(36 * 4 * 4, np.float32)  # four corners a plot
    grid.data.color_attributes["fit_colour"].data.foreach_get("color", colour)
    np.testing.assert_allclose(flag, confidence < 0.5)
    green = colour.reshape(36, 4, 4)[:, :, 1]
    np.testing.assert_allclose(
        green, np.repeat(np.where(flag == 1, 0.1, 0.85)[:, None], 4, axis=1), atol=1e-6
    )
    assert grid.data.color_attributes.active_color.name == "fit_colour"
    assert confidence.max() == pytest.approx(report["confidence"], abs=1e-3)

    out = tmp_path / "plots.geojson"
    assert bpy.ops.cliff_terrain.export_plots(filepath=str(out)) == {"FINISHED"}
    plots = read_plots(out)
    assert plots.crs == ortho.crs == 32616 and len(plots) == 36
    assert sorted(a["plot"] for a in plots.attributes) == list(range(1, 37))
    # The exported plots are the grid as the panel numbers it, and each sits on its block of crop.
    same, _ = grid_plots(grid, settings)
    np.testing.assert_allclose(
        [rings[0] for rings in plots.polygons], [rings[0] for rings in same.polygons], atol=1e-6
    )
    plants = plant_mask(ortho.data, valid=ortho.valid)
    labels = rasterize_plots(plots, transform=t, shape=ortho.shape)
    covers = np.array([plants[labels == k].mean() for k in range(1, 37)])
    assert covers.min() >= 0.85, covers.round(2)


def test_plot_operators_grey_out_with_the_reason(scene):
    import bpy

    assert not bpy.ops.cliff_terrain.add_plot_grid.poll()
    assert not bpy.ops.cliff_terrain.fit_plot_grid.poll()
    assert not bpy.ops.cliff_terrain.export_plots.poll()


def test_measure_plots_shows_the_plot_table_of_the_relief(relief, tmp_path):
    import bpy
    from cliff_terrain_addon.panels.sidebar import plot_table_lines
    from cliff_terrain_addon.scene.plot_grid_object import TABLE_KEY, grid_plots

    from cliff_terrain.build import build_relief
    from cliff_terrain.measure.field_plots import plot_table, rasterize_plots

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 3, 4
    settings.plot_width, settings.plot_length = 14.2, 4.8
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    grid = bpy.context.active_object
    assert bpy.ops.cliff_terrain.plot_table() == {"FINISHED"}
    table = [dict(row) for row in grid[TABLE_KEY]]
    assert sorted(row["plot"] for row in table) == list(range(1, 13))
    # The same figures as the core's plot table on the relief built with the same settings.
    reference = build_relief(
        str(ODM), dsm=str(ODM.with_name("dsm.tif")), height_source="measured", max_size=250, mesh=None
    )
    plots, _ = grid_plots(grid, settings)
    canopy = reference.canopy
    labels = rasterize_plots(plots, transform=canopy.transform, shape=reference.mask.shape)
    rows = plot_table(
        plots, labels, mask=reference.mask, heights=canopy.chm, pixel_area_m2=canopy.pixel_area_m2
    )
    by_plot = {row["plot"]: row for row in table}
    for row in rows:
        number = row["plot_attr"]  # the plot's own number (`plot` is its index in the set)
        assert by_plot[number]["cover"] == pytest.approx(row["cover"])
        assert by_plot[number]["height_p90_m"] == pytest.approx(row["height_p90_m"], nan_ok=True)
    # Each plot's p90 carries the ground's standard error (the rms of chm_err over the plot), shown
    # as "p90 ± err" in the panel.
    sigma_rows = plot_table(
        plots, labels, mask=reference.mask, heights=canopy.chm, pixel_area_m2=canopy.pixel_area_m2,
        sigma=canopy.sigma,
    )  # fmt: skip
    for row in sigma_rows:
        assert by_plot[row["plot_attr"]]["height_p90_err_m"] == pytest.approx(
            row["height_p90_err_m"], nan_ok=True
        )
    assert any(row["height_p90_m"] > 0.1 for row in table)  # measured heights, not NaN or zero
    lines = plot_table_lines(table)
    assert lines[0] == ("Plot", "Cover", "p90") and lines[1][0] == "1" and len(lines) == 13
    first = min(table, key=lambda r: r["plot"])
    if first["height_p90_m"] == first["height_p90_m"]:
        assert lines[1][2] == f"{first['height_p90_m'] * 100:.0f} ± {first['height_p90_err_m'] * 100:.0f} cm"

    # Colour By Plot Trait: offered now that a plot table exists; each plot's vertices take the viridis
    # colour of its p90 between the lowest and the highest plot's, vertices outside the plots grey.
    from cliff_terrain.figures.legends import height_colours

    settings.color_trait = "height_p90_m"
    settings.color_by = "PLOT_TRAIT"
    mesh = relief.data
    n = len(mesh.vertices)
    colours = np.empty(4 * n, np.float32)
    mesh.color_attributes.active_color.data.foreach_get("color_srgb", colours)
    xyz = np.empty(3 * n, np.float32)
    mesh.attributes["position"].data.foreach_get("vector", xyz)
    xy = xyz.reshape(-1, 3)[:, :2] / canopy.pixel_size
    rows_, cols_ = reference.mask.shape
    col = np.clip(np.floor(xy[:, 0]).astype(int), 0, cols_ - 1)
    row = np.clip(rows_ - 1 - np.floor(xy[:, 1]).astype(int), 0, rows_ - 1)
    p90 = np.array([np.nan] + [row_["height_p90_m"] for row_ in rows])
    values = p90[labels[row, col]]
    t = (values - np.nanmin(p90)) / (np.nanmax(p90) - np.nanmin(p90))
    expected = np.where(np.isnan(t)[:, None], 0.35, height_colours(np.nan_to_num(t)))
    np.testing.assert_allclose(colours.reshape(-1, 4)[:, :3], expected, atol=1.5 / 255)
    assert relief["cliff_terrain_legend"]["title"] == "Canopy Height p90"
    settings.color_by = "PHOTO"
    # A layout edit makes the table stale: it goes.
    settings.plot_rows = 5
    assert TABLE_KEY not in grid


def test_undo_takes_back_add_and_fit(relief):
    import bpy

    # Headless, Blender pushes no undo step after an operator: pushed here as the UI pushes them.
    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 4, 9
    settings.plot_width, settings.plot_length = 14.2, 4.8
    settings.plot_alley_across, settings.plot_alley_along = 3.8, 1.4
    bpy.ops.ed.undo_push(message="before")
    before = sorted(bpy.data.objects.keys())
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    name = bpy.context.active_object.name
    bpy.ops.ed.undo_push(message="Add Plot Grid")
    placed = tuple(bpy.data.objects[name].matrix_world.translation)
    assert bpy.ops.cliff_terrain.fit_plot_grid() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Fit to Field")
    assert tuple(bpy.data.objects[name].matrix_world.translation) != placed
    bpy.ops.ed.undo()  # the fit
    grid = bpy.data.objects[name]
    assert tuple(grid.matrix_world.translation) == pytest.approx(placed)
    assert "cliff_terrain_fit" not in grid
    bpy.ops.ed.undo()  # the grid
    assert sorted(bpy.data.objects.keys()) == before


def test_a_grid_follows_its_renamed_relief_and_greys_out_when_it_is_gone(relief, tmp_path):
    # The grid recorded its relief's name only: renamed in the Outliner, Fit, Measure and Export
    # still looked runnable and each failed "the relief ... is gone".
    import bpy

    from cliff_terrain.io.vector.plot_polygons import read_plots

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 2, 3
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    grid = bpy.context.active_object
    relief.name = "Field A 2024"
    assert bpy.ops.cliff_terrain.export_plots.poll()
    assert bpy.ops.cliff_terrain.export_plots(filepath=str(tmp_path / "p.geojson")) == {"FINISHED"}
    assert len(read_plots(tmp_path / "p.geojson")) == 6
    assert bpy.ops.cliff_terrain.plot_table() == {"FINISHED"}
    settings.color_by = "PLOT_TRAIT"  # offered: the renamed relief has a measured grid
    assert relief["cliff_terrain_legend"]["mode"] == "PLOT_TRAIT"
    # A layout edit drops the table: the relief goes back to its photo, without the colour bar.
    settings.plot_rows = 4
    assert settings.color_by == "PHOTO" and "cliff_terrain_legend" not in relief
    # Deleted as a user deletes it (X in the viewport): freed, not kept alive by its grid.
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == relief)
    bpy.context.view_layer.objects.active = relief
    assert bpy.ops.object.delete() == {"FINISHED"}
    assert "Field A 2024" not in bpy.data.objects
    bpy.context.view_layer.objects.active = grid
    for op in (
        bpy.ops.cliff_terrain.fit_plot_grid,
        bpy.ops.cliff_terrain.plot_table,
        bpy.ops.cliff_terrain.export_plots,
    ):
        assert not op.poll()


def test_a_layout_edit_drops_the_last_fits_figures_and_red_wire(relief):
    import bpy

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 4, 9
    settings.plot_width, settings.plot_length = 14.2, 4.8
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    grid = bpy.context.active_object
    grid["cliff_terrain_fit"] = {"confidence": 0.1}
    grid.color = (0.9, 0.1, 0.1, 1.0)  # as a fit unsure of its plots leaves it
    settings.plot_rows = 8
    assert "cliff_terrain_fit" not in grid
    assert tuple(grid.color) == pytest.approx((1.0, 0.85, 0.1, 1.0))


def test_each_grid_keeps_its_own_layout_and_selecting_one_shows_it(relief, tmp_path):
    # The layout was the scene's: once a second grid was edited to 2 x 2, the first, drawn with
    # 32 plots, exported and measured 4.
    import bpy
    from cliff_terrain_addon.operators.properties import show_grid_settings

    from cliff_terrain.io.vector.plot_polygons import read_plots

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 4, 8
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    first = bpy.context.active_object
    bpy.context.view_layer.objects.active = relief
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    second = bpy.context.active_object
    settings.plot_columns, settings.plot_rows = 2, 2
    settings.plot_numbering = "columns"
    assert len(second.data.polygons) == 4 and len(first.data.polygons) == 32
    bpy.context.view_layer.objects.active = first
    out = tmp_path / "first.geojson"
    assert bpy.ops.cliff_terrain.export_plots(filepath=str(out)) == {"FINISHED"}
    assert len(read_plots(out)) == 32
    assert bpy.ops.cliff_terrain.plot_table() == {"FINISHED"}
    assert len(first["cliff_terrain_plot_table"]) == 32
    # Selecting it shows its layout in the fields (Blender calls this on a change of the active
    # object), rebuilding nothing: its table stays.
    show_grid_settings(first, settings)
    assert (settings.plot_columns, settings.plot_rows, settings.plot_numbering) == (4, 8, "serpentine")
    assert "cliff_terrain_plot_table" in first and len(second.data.polygons) == 4
    # A numbering edit renumbers the same plots: their table (old numbers) goes, the mesh stays.
    settings.plot_start = "bottom-right"
    assert "cliff_terrain_plot_table" not in first and len(first.data.polygons) == 32
    assert first["cliff_terrain_layout"]["plot_start"] == "bottom-right"


def test_export_plots_writes_what_its_name_says_and_reports_the_files_written(relief, tmp_path):
    import bpy

    from cliff_terrain.io.vector.plot_polygons import read_plots

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 2, 2
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    assert bpy.ops.cliff_terrain.export_plots(filepath=str(tmp_path / "plots")) == {"FINISHED"}
    assert len(read_plots(tmp_path / "plots.geojson")) == 4 and not (tmp_path / "plots").exists()
    with pytest.raises(RuntimeError, match=r"GeoJSON \(.geojson\) or a Shapefile \(.shp\), not '.gpkg'"):
        bpy.ops.cliff_terrain.export_plots(filepath=str(tmp_path / "plots.gpkg"))
    assert not (tmp_path / "plots.gpkg").exists()
    assert bpy.ops.cliff_terrain.export_plots(filepath=str(tmp_path / "upper.SHP")) == {"FINISHED"}
    assert len(read_plots(tmp_path / "upper.shp")) == 4


def test_an_edit_changes_only_its_field_and_a_grid_from_an_earlier_version_keeps_its_drawn_layout(
    relief, tmp_path
):
    # After an undo the fields may show another grid's layout (the undo step holds the fields as
    # they were): an edit then mixed the two. And a grid made before grids kept their layout took the
    # scene's fields: drawn with 32 plots, it exported 4.
    import bpy
    from cliff_terrain_addon.operators.properties import show_grid_settings

    from cliff_terrain.io.vector.plot_polygons import read_plots

    settings = bpy.context.scene.cliff_terrain
    settings.plot_columns, settings.plot_rows = 4, 8
    settings.plot_width, settings.plot_length, settings.plot_alley_across = 3.0, 5.0, 0.5
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    first = bpy.context.active_object
    bpy.context.view_layer.objects.active = relief
    assert bpy.ops.cliff_terrain.add_plot_grid() == {"FINISHED"}
    second = bpy.context.active_object
    settings.plot_columns, settings.plot_rows = 2, 2
    bpy.context.view_layer.objects.active = first
    show_grid_settings(second, settings)  # the fields as an undo may leave them: the other grid's
    settings.plot_columns = 3
    assert len(first.data.polygons) == 3 * 8 and (settings.plot_columns, settings.plot_rows) == (3, 8)
    # An earlier version's grid: no layout of its own, its mesh says what it is.
    del first["cliff_terrain_layout"]
    settings.plot_columns, settings.plot_rows = 1, 1  # edits the active grid...
    assert len(first.data.polygons) == 1
    settings.plot_columns, settings.plot_rows = 3, 8
    del first["cliff_terrain_layout"]
    bpy.context.view_layer.objects.active = second  # ...so the fields change with another active
    settings.plot_columns, settings.plot_rows = 2, 1
    bpy.context.view_layer.objects.active = first
    out = tmp_path / "old.geojson"
    assert bpy.ops.cliff_terrain.export_plots(filepath=str(out)) == {"FINISHED"}
    plots = read_plots(out)
    assert len(plots) == 24
    ring = plots.polygons[0][0]
    assert np.ptp(ring[:, 0]) == pytest.approx(3.0, abs=1e-3) or np.ptp(ring[:, 1]) == pytest.approx(
        3.0, abs=1e-3
    )
