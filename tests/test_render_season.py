"""The season as a Blender animation: render_season.py (bpy wheel, in a subprocess) and the sidebar's
Season Animation operator, on three real soybean dates computed serially (no Dask, no matplotlib).

The frames are checked against the photos (greener on the green date), the date label against the
stamp's own pixels, the alignment against the georeference, the video by loading it back in Blender.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, SHARED_UAV

from cliff_terrain.errors import CliffTerrainError

pytestmark = pytest.mark.blender

SOYBEAN = SHARED_UAV / "lamberton_soybean"
NAMES = ("20180815_Lamberton_clipped.tif", "20180829_Lamberton_clipped.tif", "20180925_Lamberton_clipped.tif")


@pytest.fixture(scope="module")
def season_dir(tmp_path_factory):
    if not (SOYBEAN / "plots.geojson").is_file():
        pytest.skip(f"the Lamberton soybean season is not at {SOYBEAN} (../shared is absent)")
    from cliff_terrain.season.plan import plan_season
    from cliff_terrain.season.runner import run_season

    photos = tmp_path_factory.mktemp("photos")
    for name in NAMES:
        shutil.copyfile(SOYBEAN / name, photos / name)
    out = tmp_path_factory.mktemp("season")
    jobs, plots = plan_season([photos], plots=SOYBEAN / "plots.geojson", max_size=400)
    done = run_season(jobs, plots, out=out, workers=0, progress=False, chart=False)
    assert not done.failures
    return out


def _png(path):
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB")).astype(np.float64)


def _excess_green(rgb):
    total = rgb.sum(axis=2) + 1e-9
    r, g, b = (rgb[..., i] / total for i in range(3))
    return float(np.mean(2 * g - r - b))


def test_render_season_script(season_dir, tmp_path):
    out = tmp_path / "anim"
    done = subprocess.run(
        [sys.executable, str(REPO / "render_season.py"), str(season_dir), "--out", str(out)]
        + ["--size", "480x270", "--hold", "2", "--fps", "4"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    frames = sorted((out / "frames").glob("*.png"))
    assert [f.name for f in frames] == ["date_0001.png", "date_0002.png", "date_0003.png"]
    images = [_png(f) for f in frames]
    assert all(im.shape == (270, 480, 3) for im in images)
    # The field in the middle of the frame follows its photo: green canopy in mid-August, stubble
    # by late September (excess green of the frame's centre against that of the photo).
    photos = [_png(SOYBEAN / name) for name in NAMES]
    frame_green = [_excess_green(im[100:170, 120:360]) for im in images]
    photo_green = [_excess_green(p) for p in photos]
    assert np.argsort(frame_green).tolist() == np.argsort(photo_green).tolist()
    assert frame_green[0] > frame_green[2] + 0.05
    # The date label: Blender's stamp, light text on a dark band at the bottom-left, different each date.
    corner = [im[-60:, :240].mean(axis=2) for im in images]
    band = corner[0] < 150  # 80 % black over the light background (231)
    rows, cols = np.nonzero(band)
    assert band.sum() > 1000 and cols.min() == 0 and rows.max() == band.shape[0] - 1
    box = (slice(rows.min(), None), slice(0, cols.max() + 1))
    for label in corner:
        assert (label[box] > 200).sum() > 40  # white text inside the band
    assert np.abs(corner[0][box] - corner[1][box]).max() > 100
    assert np.abs(corner[1][box] - corner[2][box]).max() > 100
    assert (out / "season.mp4").stat().st_size > 10_000
    assert (out / "season.blend").is_file()


def _render(season_dir, out, *args):
    return subprocess.run(
        [sys.executable, str(REPO / "render_season.py"), str(season_dir), "--out", str(out)]
        + ["--size", "320x180", "--no-video", "--engine", "CYCLES", *args],
        capture_output=True,
        text=True,
        timeout=900,
    )


def test_frames_coloured_by_cover(season_dir, tmp_path):
    """--color-by cover: inside the plots each date's cover in viridis on the season's one scale (mid-
    August's closing canopy towards yellow-green, late September's bare stubble purple), the photo
    outside them, the scale stamped and printed."""
    plain = _render(season_dir, tmp_path / "plain", "--no-plots")
    assert plain.returncode == 0, plain.stderr[-2000:]
    done = _render(season_dir, tmp_path / "cover", "--no-plots", "--color-by", "cover")
    assert done.returncode == 0, done.stderr[-2000:]
    rows = list(csv.DictReader(open(season_dir / "season.csv", newline="")))
    cover = {
        d: [float(r["cover"]) for r in rows if r["date"] == d and r["cover"]]
        for d in {r["date"] for r in rows}
    }
    low, high = min(map(min, cover.values())), max(map(max, cover.values()))
    assert f"colour by cover (season.csv, per date): {low:.3g} (purple) to {high:.3g} (yellow)" in done.stdout
    first = np.mean(cover["2018-08-15"])
    last = np.mean(cover["2018-09-25"])
    assert first > last + 0.3  # the premise: the canopy closes mid-August, gone by late September

    frames = [
        (_png(tmp_path / "plain/frames" / n), _png(tmp_path / "cover/frames" / n))
        for n in ("date_0001.png", "date_0003.png")
    ]
    stamp = np.zeros(frames[0][0].shape[:2], dtype=bool)  # the stamps (date, and the scale on top)
    stamp[:40], stamp[-40:] = True, True
    for photo, coloured in frames:
        changed = (np.abs(coloured - photo).max(axis=2) > 40) & ~stamp
        # The plots are coloured: a good part of the field, within its frame and not outside it.
        assert 0.1 < changed.mean() < 0.6
        rows_changed, cols_changed = np.nonzero(changed)
        outside = np.ones_like(changed)
        outside[rows_changed.min() : rows_changed.max() + 1, cols_changed.min() : cols_changed.max() + 1] = (
            False
        )
        outside &= ~stamp
        # Outside the plots the photo is unchanged.
        assert np.abs(coloured - photo)[outside].mean() < 1.0
    (p1, c1), (p3, c3) = frames
    inside1 = (np.abs(c1 - p1).max(axis=2) > 40) & ~stamp
    inside3 = (np.abs(c3 - p3).max(axis=2) > 40) & ~stamp
    # Viridis runs purple (blue over green) -> green -> yellow: high cover greener than low cover.
    green1, green3 = c1[inside1].mean(axis=0), c3[inside3].mean(axis=0)
    assert green1[1] > green3[1] + 60
    assert green3[2] > green3[1] + 20  # late September: purple


def test_colours_from_traits_are_per_plot_and_dates_read_as_dates(season_dir, tmp_path):
    """A trait of traits.csv colours a plot the same on every date; a date trait reads as days, its
    scale written as dates; text columns are not offered."""
    from cliff_terrain.season.reader import plot_colours, read_season

    season = read_season(season_dir)
    n = 40
    (season_dir / "traits").mkdir(exist_ok=True)
    try:
        lines = ["plot,fid,max_height_m,senescence_date,flag"]
        lines += [
            f"{i},{i + 1},{0.5 + i / 100:.2f},2018-09-{1 + i % 20:02d},{'no growth' if i else ''}"
            for i in range(n)
        ]
        (season_dir / "traits" / "traits.csv").write_text("\n".join(lines) + "\n")
        height = plot_colours(season, "max_height_m", n_plots=n)
        assert height.source == "traits/traits.csv" and not height.is_date
        assert (height.values == height.values[0]).all() and (height.low, height.high) == (0.5, 0.89)
        np.testing.assert_allclose(height.normalised(1)[[0, 39]], [0.0, 1.0])
        senescence = plot_colours(season, "senescence_date", n_plots=n)
        assert senescence.is_date
        assert senescence.legend() == "senescence_date: 2018-09-01 (purple) to 2018-09-20 (yellow)"
        with pytest.raises(CliffTerrainError) as caught:
            plot_colours(season, "flag", n_plots=n)
        assert str(caught.value) == (
            "`color_by` must be one of cover, area_m2, volume_m3, height_mean, height_p50, height_p90, "
            "height_max, max_height_m, senescence_date, got 'flag'"
        )
        cover = plot_colours(season, "cover", n_plots=n)
        assert cover.source == "season.csv" and not (cover.values == cover.values[0]).all()
    finally:
        shutil.rmtree(season_dir / "traits")


def test_unknown_color_by_is_one_line(season_dir, tmp_path):
    done = _render(season_dir, tmp_path, "--color-by", "nope")
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("render_season.py: error: `color_by` must be one of cover, area_m2, volume_m3, ")
    assert line.endswith("got 'nope' (traits appear after `cliff-terrain traits SEASON`)")


def test_bad_season_folder_is_one_line(tmp_path):
    done = subprocess.run(
        [sys.executable, str(REPO / "render_season.py"), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"render_season.py: error: no season in {str(tmp_path)!r}: season.json is missing "
        "(run `cliff-terrain season` first)"
    ]


def test_sidebar_operator_builds_and_renders_the_season(addon, scene, season_dir):
    import bpy

    from cliff_terrain.season.reader import read_season

    # The user's scene, which the animation replaced the markers, frames and camera of.
    scene.timeline_markers.new("spraying", frame=40)
    scene.frame_start, scene.frame_end = 1, 250
    result = bpy.ops.cliff_terrain.season_animation(directory=str(season_dir), show_plots=True, render=True)
    assert result == {"FINISHED"}
    assert [m.name for m in scene.timeline_markers] == ["spraying"] and scene.frame_end == 250
    assert scene.camera is None and scene.render.filepath == "/tmp/"
    scene = bpy.data.scenes["Cliff Terrain Season"]  # the season's own
    season = read_season(season_dir)
    dates = [d.date for d in season.dates]
    assert [m.name for m in sorted(scene.timeline_markers, key=lambda m: m.frame)] == dates
    assert (scene.frame_start, scene.frame_end) == (1, 3)
    reliefs = [bpy.data.objects[f"Season {d}"] for d in dates]
    assert bpy.data.objects["Season plots"].type == "CURVE"
    assert scene.camera.name == "Season Camera"

    # Aligned by georeference: every relief's corner vertices land where its grid's corners are on
    # the map, less one common origin.
    origin = None
    for obj, date in zip(reliefs, season.dates, strict=True):
        rows, cols = date.heights.shape
        t = date.transform
        world = np.array([obj.matrix_world @ v.co for v in obj.data.vertices])[:, :2]
        expected = np.array([[0, 0, 1], [cols, 0, 1], [0, rows, 1], [cols, rows, 1]], float) @ t.T
        corners = world[[0, cols, rows * (cols + 1), rows * (cols + 1) + cols]]
        offset = expected - corners
        np.testing.assert_allclose(offset, offset[[0]].repeat(4, axis=0), atol=1e-3)
        origin = offset[0] if origin is None else origin
        np.testing.assert_allclose(offset[0], origin, atol=1e-3)

    # One date per frame.
    for frame in (1, 2, 3):
        scene.frame_set(frame)
        assert [not obj.hide_render for obj in reliefs] == [i + 1 == frame for i in range(3)]

    frames = sorted((season_dir / "animation" / "frames").glob("*.png"))
    assert len(frames) == 3
    clip = bpy.data.movieclips.load(str(season_dir / "animation" / "season.mp4"))
    try:
        assert tuple(clip.size) == (1280, 720)
        assert clip.frame_duration == 3 * 12
    finally:
        bpy.data.movieclips.remove(clip)
    manifest = json.loads((season_dir / "season.json").read_text())
    assert [d["date"] for d in manifest["dates"]] == dates


def test_building_and_rendering_the_season_tell_their_progress(addon, scene, season_dir, tmp_path):
    # Season Animation showed nothing while it made the reliefs and rendered every date: the sidebar's
    # operator now draws its progress bar from these calls (one per date made, one per frame).
    import bpy
    from cliff_terrain_addon.scene.season_animation import build_season_scene, render_season

    from cliff_terrain.season.reader import read_season

    told = []
    built = build_season_scene(
        bpy.context, read_season(season_dir), progress=lambda f, s: told.append((f, s))
    )
    assert told == [(k / 3, "making the dates' reliefs") for k in (1, 2, 3)]
    told.clear()
    render_season(built, tmp_path, video=False, log=lambda m: None, progress=lambda f, s: told.append((f, s)))
    assert told == [(0.0, "rendering the dates")] + [(k / 3, "rendering the dates") for k in (1, 2, 3)]
    assert len(list((tmp_path / "frames").glob("*.png"))) == 3
    assert not any(h.__name__ == "rendered" for h in bpy.app.handlers.render_post)  # the handler is gone


def test_sidebar_operator_colours_by_cover(addon, scene, season_dir):
    import bpy

    from cliff_terrain.season.reader import read_season

    result = bpy.ops.cliff_terrain.season_animation(
        directory=str(season_dir), show_plots=False, render=False, color_by="cover"
    )
    assert result == {"FINISHED"}
    for date in read_season(season_dir).dates:
        obj = bpy.data.objects[f"Season {date.date}"]
        colours = np.zeros(len(obj.data.vertices) * 4, dtype=np.float32)
        obj.data.color_attributes["Cliff Terrain Colour"].data.foreach_get("color", colours)
        alpha = colours.reshape(-1, 4)[:, 3]
        assert 0.1 < (alpha > 0.5).mean() < 0.9  # the plots coloured, the rest left to the photo
        mix = obj.active_material.node_tree.nodes["Cliff Terrain Colour By"]
        factor = next(s for s in mix.inputs if s.identifier == "Factor_Float")
        assert factor.links and factor.links[0].from_socket.name == "Alpha"
    assert "Season plots" not in bpy.data.objects
    with pytest.raises(RuntimeError, match=r"`color_by` must be one of cover, .* got 'nope'"):
        bpy.ops.cliff_terrain.season_animation(directory=str(season_dir), color_by="nope")
