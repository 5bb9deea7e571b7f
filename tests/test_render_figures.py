"""The figures render_views.py draws after rendering: the side view's exaggeration and ruler measured
on the rendered pixels, the transect, the legends on copies of the renders, and summary.png."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import RENDER_VIEWS_OUTPUTS
from PIL import Image

from cliff_terrain import build_relief, synthetic_field

pytestmark = pytest.mark.blender
if importlib.util.find_spec("bpy") is None:
    pytest.skip("the bpy wheel (Blender as a Python module) is not installed", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "render_views.py"


def run(*args, env=None, timeout=600):
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=ROOT,
    )


def read(path):
    with Image.open(path) as image:
        return np.asarray(image)


def top_opaque_rows(rgba):
    """Per column, the first row (from the top) with an opaque pixel; -1 where none is."""
    opaque = rgba[..., 3] > 127
    return np.where(opaque.any(axis=0), opaque.argmax(axis=0), -1)


@pytest.fixture(scope="module")
def transect_run(tmp_path_factory):
    """The synthetic field rendered with a transect: a band of rows through its tallest plant."""
    folder = tmp_path_factory.mktemp("transect")
    image, truth = synthetic_field(shape=(240, 320), seed=1)
    photo = folder / "field.png"
    Image.fromarray(image).save(photo)
    relief = build_relief(str(photo))  # the same relief render_views.py builds (default settings)
    row = int(np.unravel_index(np.argmax(relief.heights), relief.heights.shape)[0])
    band = (max(0, row - 8), min(240, row + 8))
    out = folder / "views"
    proc = run(str(photo), "--out", str(out), "--transect", f"rows={band[0]}:{band[1]}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    return out, image, truth, relief, band, metrics, proc


def test_every_figure_is_written_and_the_raw_renders_are_kept(transect_run):
    out, image, *_ = transect_run
    assert sorted(p.name for p in out.iterdir()) == sorted(RENDER_VIEWS_OUTPUTS)
    rows, cols = image.shape[:2]
    assert read(out / "xy.png").shape == (rows, cols, 3)  # the compared view is Blender's own


def test_side_view_ruler_matches_the_rendered_relief(transect_run):
    out, _, _, relief, band, metrics, proc = transect_run
    side = metrics["side_view"]
    view = read(out / "xz.png")
    tops = top_opaque_rows(view)
    # The band holds the tallest plant: the highest rendered pixel is where the ruler puts max_height.
    summit = side["ground_row"] - relief.max_height * side["rows_per_unit"]
    assert abs(tops[tops >= 0].min() - summit) <= 2.0
    # Column by column, the rendered profile is the band's highest point where the ruler puts it
    # (the strip's columns map onto the relief's; bare ground, seen edge-on, draws nothing above 0).
    band_top = relief.heights[band[0] : band[1]].max(axis=0).astype(np.float64)
    c0, c1 = side["strip_columns"]
    centres = c0 + (np.arange(band_top.size) + 0.5) * (c1 - c0) / band_top.size
    columns = np.round(centres - 0.5).astype(int)
    expected = side["ground_row"] - band_top * side["rows_per_unit"]
    raised = band_top > 0.1 * relief.max_height
    drawn = tops[columns]
    assert (drawn[raised] >= 0).all()
    assert np.median(np.abs(drawn[raised] - expected[raised])) <= 1.5
    # (two columns clear of any plant: a mesh cell spans its neighbours' corners)
    bare = drawn[np.convolve(band_top > 0, np.ones(5), mode="same") == 0]
    assert bare.size >= 10 and ((bare < 0) | (bare >= side["ground_row"] - 1.0)).all()
    # The exaggeration makes the relief rise to a useful share of the view, and is said so.
    rise = (side["ground_row"] - summit) / view.shape[1]
    assert 0.12 <= rise <= 0.3 or side["exaggeration"] == 1.0
    assert side["exaggeration"] >= 1.0 and side["transect"].startswith("rows=")
    assert f"vertical exaggeration {side['exaggeration']:g}x" in proc.stdout


def test_a_transect_through_low_plants_is_exaggerated_for_them(tmp_path):
    """The side view's exaggeration comes from the strip's own top, not the whole relief's."""
    image, _ = synthetic_field(shape=(240, 320), seed=1)
    photo = tmp_path / "field.png"
    Image.fromarray(image).save(photo)
    relief = build_relief(str(photo), mesh="adaptive")
    # The 16-row band whose plants are lowest (but present): well below the relief's top.
    tops = [relief.heights[r : r + 16].max() for r in range(0, 224, 4)]
    start = int(np.argmin([t if t > 0.1 * relief.max_height else np.inf for t in tops])) * 4
    band_top = float(tops[start // 4])
    assert band_top < 0.5 * relief.max_height
    out = tmp_path / "views"
    proc = run(
        str(photo),
        "--out",
        str(out),
        "--transect",
        f"rows={start}:{start + 16}",
        "--samples",
        "1",
        "--mesh",
        "adaptive",
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    side = json.loads((out / "metrics.json").read_text())["side_view"]
    # The view frames the strip's top, not the relief's: the highest point of the mesh's surface
    # in the strip. The adaptive surface is within max_error of every pixel centre and
    # runs straight from the band's outer pixel centres to the next rows' out to the strip's edges.
    assert relief.mesh_kind == "adaptive"
    near_top = float(relief.heights[max(start - 1, 0) : start + 17].max()) + relief.max_error
    assert 0.7 * band_top <= side["top"] <= near_top + 1e-6, (side["top"], band_top, near_top)
    assert side["top"] < 0.75 * relief.max_height
    view = read(out / "xz.png")
    drawn = top_opaque_rows(view)
    summit = side["ground_row"] - side["top"] * side["rows_per_unit"]
    assert abs(drawn[drawn >= 0].min() - summit) <= 2.0  # drawn where the ruler puts it
    # It rises to a useful share of the view, as a band through the tallest plant does.
    rise = (side["ground_row"] - summit) / view.shape[1]
    assert 0.12 <= rise <= 0.3, (rise, side["exaggeration"])
    assert f"vertical exaggeration {side['exaggeration']:g}x" in proc.stdout


def test_transect_is_outlined_on_the_top_view(transect_run):
    out, image, _, _, band, _, _ = transect_run
    annotated = read(out / "xy_annotated.png")
    yellow = np.all(annotated == (255, 255, 0), axis=-1)
    rows = np.flatnonzero(yellow.mean(axis=1) > 0.5)  # the band's long edges cross the whole view
    assert abs(rows.min() - band[0]) <= 2 and abs(rows.max() - band[1]) <= 2
    # Elsewhere the annotated copy is the render.
    xy = read(out / "xy.png")
    assert np.array_equal(annotated[: band[0] - 3], xy[: band[0] - 3])


def test_colour_bar_copy_keeps_the_mesh_view(transect_run):
    out, *_ = transect_run
    mesh = read(out / "mesh.png").astype(np.float64)
    annotated = read(out / "mesh_annotated.png")
    rows, cols = mesh.shape[:2]
    assert annotated.shape[0] == rows and annotated.shape[1] > cols
    alpha = mesh[..., 3:] / 255.0
    on_white = np.round(mesh[..., :3] * alpha + 255.0 * (1 - alpha))
    assert np.abs(annotated[:, :cols].astype(np.float64) - on_white).max() <= 1.0


def test_key_figures_in_metrics_and_summary(transect_run):
    out, _, truth, relief, _, metrics, _ = transect_run
    assert metrics["plants"] == truth.n_plants
    mask = read(out / "mask.png") > 0
    assert metrics["cover"] == pytest.approx(mask.mean())
    tops = [relief.heights[relief.labels == k].max() for k in range(1, relief.n_regions + 1)]
    # Without a GSD the heights are in processing pixels (exaggeration 1: the relief's own).
    assert metrics["units"] == "px"
    assert metrics["plant_height_median_px"] == pytest.approx(float(np.median(tops)), rel=1e-6)
    plant_heights = relief.heights[relief.mask]
    assert metrics["canopy_height_p90_px"] == pytest.approx(float(np.percentile(plant_heights, 90)), rel=1e-6)
    assert metrics["figures"]["raw_renders"] == "unchanged"
    summary = read(out / "summary.png")
    assert summary.ndim == 3 and summary.shape[1] >= 1000 and summary.shape[0] >= 1000
    # Mostly paper, with the panels on it (not a blank or black sheet).
    assert 0.2 < (summary == 255).all(axis=-1).mean() < 0.9


@pytest.mark.parametrize(
    ("transect", "fragment"),
    [
        ("rows=200:300", "`--transect` point (row 300, column 0) is outside the 320 x 240 photo"),
        ("line=0,0,10,400", "`--transect` point (row 10, column 400) is outside the 320 x 240 photo"),
        ("diagonal", "`--transect` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got 'diagonal'"),
    ],
)
def test_a_transect_outside_the_photo_is_refused_before_blender_starts(tmp_path, no_bpy, transect, fragment):
    photo = tmp_path / "p.png"
    Image.fromarray(np.zeros((240, 320, 3), np.uint8)).save(photo)
    proc = run(str(photo), "--transect", transect, env=no_bpy, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert fragment in proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert not (tmp_path / "p_relief").exists()
