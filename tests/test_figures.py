"""Legends drawn after rendering (cliff_terrain.figures: legends, annotate, sheet): positions
measured on the drawn pixels, against values computed here from the inputs."""

from __future__ import annotations

import numpy as np
import pytest

from cliff_terrain import CliffTerrainError
from cliff_terrain.figures.annotate import annotate_colour_bar, annotate_side_view, annotate_top_view
from cliff_terrain.figures.drawing import INK, font_size
from cliff_terrain.figures.legends import (
    display_units,
    height_colours,
    nice_below,
    nice_step,
    vertical_exaggeration,
)
from cliff_terrain.figures.sheet import contact_sheet
from cliff_terrain.io.vector.transect import Transect, parse_transect


def ink_rows(column):
    """Rows of a (rows, 3) pixel column that are the legend's ink."""
    return np.flatnonzero(np.all(column == INK, axis=-1))


def side_view(rows=120, cols=400, ground=100, top=40):
    """A transparent side view with an opaque green slab from row `top` to the ground row."""
    view = np.zeros((rows, cols, 4), np.uint8)
    view[top:ground, 50:350] = (40, 160, 40, 255)
    return view


# ---- numbers -----------------------------------------------------------------------------------


@pytest.mark.parametrize("span", [0.07, 0.47, 1.0, 3.3, 26.0, 130.0, 999.0])
def test_nice_steps_are_round_and_give_about_five_ticks(span):
    step = nice_step(span)
    mantissa = step / 10.0 ** np.floor(np.log10(step))
    assert round(mantissa, 9) in (1.0, 2.0, 5.0)
    assert 2.0 <= span / step <= 10.0


def test_nice_below_never_exceeds_the_value():
    for value in np.geomspace(0.013, 870.0, 40):
        nice = nice_below(value)
        assert value / 2.5 - 1e-12 <= nice <= value


def test_crop_heights_under_a_metre_read_in_centimetres():
    assert display_units(0.42, "m") == (100.0, "cm")
    assert display_units(2.5, "m") == (1.0, "m")
    assert display_units(30.0, "px") == (1.0, "px")
    with pytest.raises(CliffTerrainError, match=r"`units` must be \"m\" or \"px\", got 'ft'"):
        display_units(1.0, "ft")


def test_exaggeration_makes_a_flat_field_rise_to_a_useful_share_of_the_view():
    # The broccoli: 1000 pixels wide, 26 pixels high -> a 31-row strip.
    factor = vertical_exaggeration(1000.0, 26.0)
    assert factor == 10.0
    assert 0.12 <= 26.0 * factor / 1000.0 <= 0.3
    assert vertical_exaggeration(10.0, 6.0) == 1.0  # never flattened
    with pytest.raises(
        CliffTerrainError, match=r"`relief_height` must be > 0, got 0.0 \(the relief is flat\)"
    ):
        vertical_exaggeration(1000.0, 0.0)
    with pytest.raises(CliffTerrainError, match=r"`width` must be > 0.0, got -3.0"):
        vertical_exaggeration(-3.0, 1.0)


def test_text_grows_with_the_image_and_stays_legible_when_small():
    assert font_size((31, 1000)) == 22
    assert font_size((40, 80)) == 12
    assert font_size((2000, 3000)) == 67


# ---- side view -----------------------------------------------------------------------------------


def test_side_view_ruler_ticks_fall_on_the_heights_they_name():
    # Heights 0..12 px drawn 5 rows per px: the slab (12 px high) spans rows 40..100.
    view = side_view()
    out = annotate_side_view(
        view, ground_row=100, rows_per_unit=5.0, max_height=12.0, units="px", exaggeration=5
    )
    # The view is pasted unchanged (opaque pixels) into the figure: find its offset.
    green = np.all(out == (40, 160, 40), axis=-1)
    slab_top, slab_left = np.argwhere(green).min(axis=0)  # view row 40, column 50
    offset_r, offset_c = slab_top - 40, slab_left - 50
    assert np.array_equal(
        out[offset_r + 40 : offset_r + 100, offset_c + 50 : offset_c + 350], view[40:100, 50:350, :3]
    )
    # The ruler is the margin's longest vertical ink line; its ticks (every 5 px, so 25 rows: a span
    # of 12 gets 2.4 intervals of 5 rather than 6 of 2) are the ink rows just left of it.
    black = np.all(out[:, :offset_c] == INK, axis=-1)
    line = int(np.argmax(black.sum(axis=0)))
    ticks = ink_rows(out[:, line - 2])
    line_rows = ink_rows(out[:, line])
    assert line_rows.min() == offset_r + 100 - 5 * 10 and line_rows.max() == offset_r + 100
    assert [row for row in ticks if row >= line_rows.min() - 1] == [
        offset_r + 100 - 5 * h for h in (10, 5, 0)
    ]
    # Light height lines run behind the relief (transparent pixels) but not over it.
    behind = out[offset_r + 100 - 5 * 5, offset_c + 10]
    assert tuple(behind) == (200, 200, 200)
    assert tuple(out[offset_r + 100 - 5 * 5, offset_c + 200]) == (40, 160, 40)


def test_side_view_in_metres_is_labelled_in_centimetres_and_keeps_its_ink_inside():
    out = annotate_side_view(side_view(), ground_row=100, rows_per_unit=60 / 0.35, max_height=0.35, units="m")
    assert out.dtype == np.uint8 and out.ndim == 3 and out.shape[2] == 3
    # Something is written in the caption band above the view.
    assert (out[:20] != 255).any()


@pytest.mark.parametrize("max_height", [0.0, 0])
def test_a_flat_relief_cannot_have_a_ruler(max_height):
    with pytest.raises(
        CliffTerrainError, match=r"cannot label the height ruler: `max_height` must be > 0, got 0.0"
    ):
        annotate_side_view(side_view(), ground_row=100, rows_per_unit=1.0, max_height=max_height, units="px")


def test_a_ruler_off_the_image_is_refused_with_the_rows():
    with pytest.raises(
        CliffTerrainError, match=r"heights 0 to 30 px fall on rows 100 to -50, outside the 120-row"
    ):
        annotate_side_view(side_view(), ground_row=100, rows_per_unit=5.0, max_height=30.0, units="px")


def test_a_side_view_must_be_an_image():
    with pytest.raises(CliffTerrainError, match=r"`image` must be a uint8 numpy array, got float64"):
        annotate_side_view(np.zeros((10, 10, 3)), ground_row=9, rows_per_unit=1.0, max_height=1.0, units="px")


# ---- colour bar ---------------------------------------------------------------------------------


def test_colour_bar_runs_from_the_lowest_to_the_highest_colour_of_the_mesh():
    view = np.full((360, 480, 3), 255, np.uint8)
    out = annotate_colour_bar(view, max_height=0.42, units="m")
    assert out.shape[0] == 360 and out.shape[1] > 480
    assert np.array_equal(out[:, :480], view)
    margin = out[:, 480:].astype(int)
    # The bar: the margin's most saturated column.
    chroma = margin.max(axis=-1) - margin.min(axis=-1)
    column = int(np.argmax((chroma > 100).sum(axis=0)))
    bar = np.flatnonzero(chroma[:, column] > 50)
    top, bottom = out[bar[0] + 1, 480 + column], out[bar[-1] - 1, 480 + column]
    expected_top = np.round(height_colours([1.0])[0] * 255)
    expected_bottom = np.round(height_colours([0.0])[0] * 255)
    assert np.abs(top.astype(int) - expected_top).max() <= 6
    assert np.abs(bottom.astype(int) - expected_bottom).max() <= 6


def test_colour_bar_needs_a_height_range():
    with pytest.raises(
        CliffTerrainError, match=r"cannot label the colour bar: `max_height` must be > 0, got 0.0"
    ):
        annotate_colour_bar(np.zeros((50, 50, 3), np.uint8), max_height=0.0, units="m")


# ---- top views ------------------------------------------------------------------------------------


def test_scale_bar_is_as_long_as_the_ground_distance_it_names():
    photo = np.full((300, 400, 3), 120, np.uint8)
    out = annotate_top_view(photo, metres_per_pixel=0.01)  # 400 px = 4 m: a 1 m bar is 100 px
    black = np.all(out == INK, axis=-1)
    row = int(np.argmax(black.sum(axis=1)))
    # The bar alternates a black and a white half with a black outline: the outline spans it.
    ink = np.flatnonzero(black[row])
    assert 98 <= ink.max() - ink.min() <= 102
    assert np.array_equal(out[:150], photo[:150])  # the upper part of the photo is untouched


def test_no_scale_without_a_ground_size_and_a_north_arrow_only_when_georeferenced():
    photo = np.full((300, 400, 3), 120, np.uint8)
    plain = annotate_top_view(photo)
    north = annotate_top_view(photo, georeferenced=True)
    corner = (slice(0, 100), slice(300, 400))
    assert np.array_equal(plain[corner], photo[corner])
    assert (north[corner] != photo[corner]).any()
    assert (plain[200:] != photo[200:]).any()  # "scale unknown (no GSD)"


def test_transect_outline_is_drawn_where_the_band_lies():
    photo = np.full((200, 300, 3), 120, np.uint8)
    band = parse_transect("rows=100:140", shape=(400, 600))  # the photo at half size
    out = annotate_top_view(photo, metres_per_pixel=0.05, transect=band, photo_shape=(400, 600))
    yellow = np.all(out == (255, 255, 0), axis=-1)
    rows = np.flatnonzero(yellow.any(axis=1))
    assert rows.min() in (49, 50) and rows.max() in (70, 71)


# ---- transects -------------------------------------------------------------------------------------


def test_transects_parse_bands_and_lines():
    band = parse_transect(" rows=140:100 ", shape=(400, 600))
    assert band == Transect((120.0, 0.0), (120.0, 600.0), 40.0, "rows=140:100")
    line = parse_transect("line=0,0,400,600", shape=(400, 600))
    assert line.width == 12.0 and line.length == pytest.approx(np.hypot(400, 600))
    corners = np.array(parse_transect("line=200,100,200,500,20", shape=(400, 600)).corners())
    assert sorted(corners[:, 0]) == [190.0, 190.0, 210.0, 210.0]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("rows=350:450", r"`--transect` point \(row 450, column 0\) is outside the 600 x 400 photo"),
        ("line=0,0,10,700", r"`--transect` point \(row 10, column 700\) is outside the 600 x 400 photo"),
        ("line=-1,0,10,10", r"`--transect` point \(row -1, column 0\)"),
        ("rows=5:5", r"`--transect` must span at least one row, got 'rows=5:5'"),
        ("line=5,5,5,5", r"`--transect` must be at least one pixel long"),
        ("line=0,0,10,10,0", r"`--transect` WIDTH must be > 0"),
        ("cols=1:2", r"`--transect` must be rows=R0:R1 or line=R0,C0,R1,C1\[,WIDTH\], got 'cols=1:2'"),
        ("rows=a:b", r"`--transect` must be rows=R0:R1"),
    ],
)
def test_bad_transects_name_the_parameter(text, message):
    with pytest.raises(CliffTerrainError, match=message):
        parse_transect(text, shape=(400, 600), name="--transect")


# ---- contact sheet ----------------------------------------------------------------------------------


def test_contact_sheet_shows_every_panel_scaled_into_its_tile():
    red = np.zeros((100, 200, 3), np.uint8)
    red[..., 0] = 255
    blue = np.zeros((300, 100, 4), np.uint8)
    blue[..., 2] = blue[..., 3] = 255
    sheet = contact_sheet([("photo", red), ("mask", blue)], facts=["plants 12"], tile=120, columns=3)
    is_red = np.all(sheet == (255, 0, 0), axis=-1)
    is_blue = np.all(sheet == (0, 0, 255), axis=-1)
    # Scaled to fit a 120-pixel tile with their aspect (less the anti-aliased rim).
    red_rows, red_cols = np.flatnonzero(is_red.any(1)), np.flatnonzero(is_red.any(0))
    assert red_cols.size == 120 and red_rows.size == 60
    assert np.flatnonzero(is_blue.any(1)).size == 120 and np.flatnonzero(is_blue.any(0)).size == 40
    # Side by side, the key figures in the third tile (dark text pixels right of both images).
    assert red_cols.max() < np.flatnonzero(is_blue.any(0)).min()
    assert (sheet[:, np.flatnonzero(is_blue.any(0)).max() + 20 :] < 100).any()


def test_contact_sheet_needs_panels():
    with pytest.raises(CliffTerrainError, match=r"`panels` must hold at least one"):
        contact_sheet([])
    with pytest.raises(CliffTerrainError, match=r"`tile` must be >= 64, got 10"):
        contact_sheet([("a", np.zeros((4, 4, 3), np.uint8))], tile=10)


def test_height_colours_are_matplotlibs_viridis():
    # The one height colour map (figures, Blender's Colour By and the mesh view): perceptual, not jet.
    matplotlib = pytest.importorskip(
        "matplotlib", reason="matplotlib (a command-line extra) is not installed"
    )
    t = np.linspace(0.0, 1.0, 1001)
    reference = matplotlib.colormaps["viridis"](t)[:, :3]
    assert np.abs(height_colours(t) - reference).max() < 0.025
    # Lightness rises monotonically (a height reads the same in grey).
    grey = height_colours(t) @ [0.2126, 0.7152, 0.0722]
    assert np.all(np.diff(grey) > 0)
