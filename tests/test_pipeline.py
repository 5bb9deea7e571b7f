"""build_relief end to end: the synthetic oracle, real photos, units, progress and bad arguments."""

import numpy as np
import pytest
from conftest import uav_image

from cliff_terrain import CliffTerrainError, build_relief, synthetic_field
from cliff_terrain.data.synthetic import main as synthetic_main


@pytest.fixture(scope="module")
def field():
    return synthetic_field(shape=(600, 900), seed=11)


def test_plants_counted_and_domes_as_tall_as_their_radii(field):
    image, truth = field
    relief = build_relief(image, max_size=900)
    assert abs(relief.n_regions - truth.n_plants) <= 0.05 * truth.n_plants
    rc = np.round(truth.centres).astype(int)
    peaks = np.array([relief.heights[relief.labels == relief.labels[r, c]].max() for r, c in rc])
    np.testing.assert_allclose(peaks, truth.radii, rtol=0.10)
    # Soil stays flat (a pixel's margin for the plants' soft edges).
    from scipy.ndimage import binary_dilation

    soil = ~binary_dilation(truth.mask, iterations=2)
    assert relief.heights[soil].max() == 0.0


def test_without_a_mesh_the_heights_are_the_grid_builds(field, tmp_path):
    """``mesh=None`` (what a season's tables need): the same stages, no mesh, no helper thread."""
    import threading

    from PIL import Image

    image, _ = field
    path = tmp_path / "field.png"
    Image.fromarray(image).save(path)
    threads = []
    seen = []

    def progress(fraction, stage):
        seen.append(stage)
        threads.append(threading.active_count())

    bare = build_relief(path, max_size=450, mesh=None, progress=progress)
    full = build_relief(path, max_size=450)
    assert bare.mesh is None and full.mesh is not None
    for name in ("working", "mask", "labels", "distance", "heights"):
        np.testing.assert_array_equal(getattr(bare, name), getattr(full, name))
    assert seen == ["load", "resize", "filter", "segment", "heights", "mesh", "done"]
    assert max(threads) == threading.active_count()  # nothing started beside this thread


def test_stages_are_consistent(field):
    image, _ = field
    seen = []
    relief = build_relief(image, max_size=450, mesh="grid", progress=lambda f, s: seen.append((f, s)))
    rows, cols = relief.working.shape[:2]
    assert (rows, cols) == (300, 450)
    for name in ("mask", "labels", "boundaries", "distance", "heights"):
        assert getattr(relief, name).shape == (rows, cols)
    assert relief.filtered.shape == (rows, cols, 3) and relief.filtered.dtype == np.float32
    assert relief.mesh.grid_shape == (rows, cols)
    assert relief.mesh.n_vertices == (rows + 1) * (cols + 1) + 2 * (rows + cols)
    assert relief.mesh.vertices[:, 2].max() == pytest.approx(relief.max_height, rel=0.05)
    stages = [s for _, s in seen]
    assert stages == ["load", "resize", "filter", "segment", "heights", "mesh", "done"]
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[0] == 0.0 and fractions[-1] == 1.0
    assert set(relief.timings) == {"load", "resize", "filter", "segment", "heights", "mesh"}
    assert relief.params["max_size"] == 450 and relief.units == "px"


def test_a_caller_meshes_the_heights_itself_from_the_grid_shape(field, tmp_path):
    """What the Blender operator does: build without a mesh (in a thread of its own), make the
    grid's topology from the photo's header meanwhile, and place the vertices when the heights come."""
    import threading

    from PIL import Image

    from cliff_terrain import grid_shape
    from cliff_terrain.mesh.grid import grid_topology, place_vertices

    image, _ = field
    path = tmp_path / "field.jpg"
    Image.fromarray(image).save(path, quality=95)
    caller = threading.get_ident()
    for source in (image, path):
        stages = []
        shape = grid_shape(source, max_size=450)
        assert shape == (300, 450)
        bare = build_relief(
            source,
            max_size=450,
            mesh=None,
            progress=lambda f, s, stages=stages: stages.append((s, threading.get_ident())),
        )
        # A plain sequential function: every stage reported in order, in the calling thread.
        assert [s for s, _ in stages] == ["load", "resize", "filter", "segment", "heights", "mesh", "done"]
        assert {t for _, t in stages} == {caller}
        assert bare.mesh is None and bare.heights.shape == shape
        plain = build_relief(source, max_size=450, mesh="grid")
        for name in ("working", "labels", "heights"):
            np.testing.assert_array_equal(getattr(bare, name), getattr(plain, name))
        mesh = place_vertices(grid_topology(shape), bare.heights, pixel_size=bare.pixel_size)
        np.testing.assert_array_equal(mesh.vertices, plain.mesh.vertices)
        np.testing.assert_array_equal(mesh.corner_verts, plain.mesh.corner_verts)


def test_errors_of_a_stage_propagate(field, monkeypatch, tmp_path):
    import cliff_terrain.build as pipeline

    image, _ = field
    # A photo whose pixel data is cut: the header passes, the decode fails.
    cut = tmp_path / "cut.jpg"
    from PIL import Image

    Image.fromarray(image).save(cut, quality=95)
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(CliffTerrainError, match="the file is truncated"):
        build_relief(cut, max_size=300)

    def failing_segment(*args, **kwargs):
        raise CliffTerrainError("segmentation failed")

    monkeypatch.setattr(pipeline, "segment", failing_segment)
    stages = []
    with pytest.raises(CliffTerrainError, match="segmentation failed"):
        build_relief(image, max_size=300, progress=lambda f, s: stages.append(s))
    assert stages == ["load", "resize", "filter", "segment"]


def test_relief_params_round_trip_through_build_relief_properties_and_arguments(field, tmp_path):
    import argparse

    from cliff_terrain import ReliefParams

    image, _ = field
    params = ReliefParams(max_size=300, profile="poisson", exaggeration=2.0, gsd=0.01, two_sided=False)
    relief = build_relief(image, params)
    assert relief.params["max_size"] == 300 and relief.params["gsd"] == 0.01
    assert ReliefParams.from_properties(relief.params) == params
    np.testing.assert_array_equal(relief.heights, build_relief(image, **params.as_kwargs()).heights)
    # Keywords replace the params' values.
    assert build_relief(image, params, max_size=200).heights.shape == (133, 200)
    # ID properties hold no None: 0 stands for it, once each way.
    props = ReliefParams().to_properties()
    assert props["gsd"] == props["max_height"] == props["max_error"] == props["dsm"] == 0.0
    assert props["height_source"] == "inflated"
    assert ReliefParams.from_properties(props) == ReliefParams()
    assert ReliefParams.from_properties(params.to_properties()) == params
    assert ReliefParams.from_properties({"dsm": "", "gsd": 0.0}) == ReliefParams()
    # One argparse definition; its defaults are the core's.
    parser = argparse.ArgumentParser()
    ReliefParams.add_arguments(parser)
    assert ReliefParams.from_args(parser.parse_args([])) == ReliefParams()
    args = parser.parse_args(["--max-size", "300", "--profile", "poisson", "--exaggeration", "2"])
    args2 = parser.parse_args(["--gsd", "0.01", "--one-sided"], namespace=args)
    assert ReliefParams.from_args(args2) == params
    dsm = str(tmp_path / "dsm.tif")
    assert ReliefParams.from_args(parser.parse_args(["--dsm", dsm])).height_source == "measured"
    with pytest.raises(CliffTerrainError, match="`max_size` must be >= 16, got 3"):
        ReliefParams.from_args(parser.parse_args(["--max-size", "3"]))
    with pytest.raises(CliffTerrainError, match="`params` must be a ReliefParams or None"):
        build_relief(image, {"max_size": 300})


def test_the_old_heights_keyword_still_works_with_a_deprecation_warning(field):
    image, _ = field
    with pytest.warns(DeprecationWarning, match="pass `height_source` instead"):
        relief = build_relief(image, max_size=200, heights="inflated")
    assert relief.params["height_source"] == "inflated"
    with pytest.warns(DeprecationWarning), pytest.raises(CliffTerrainError, match="needs a `dsm`"):
        build_relief(image, max_size=200, heights="measured")


def test_the_options_are_the_declarations_and_the_old_heights_option_still_works(tmp_path, capsys):
    import argparse

    from cliff_terrain import ReliefParams
    from cliff_terrain.settings import PARAMETERS, ids

    parser = argparse.ArgumentParser(prog="relief")
    ReliefParams.add_arguments(parser)
    actions = {}
    for action in parser._actions:  # the first of a dest: --heights follows --height-source
        actions.setdefault(action.dest, action)
    for name, parameter in PARAMETERS.items():
        if not parameter.relief_option:
            assert name not in actions
            continue
        action = actions[name]
        assert action.option_strings[0] == parameter.flag
        assert parameter.help in action.help or parameter.option_help == action.help
        assert parameter.limits in action.help
        if parameter.choices:
            assert tuple(action.choices) == ids(parameter.choices)
    # A value outside the declared limits is refused with the core's message.
    with pytest.raises(CliffTerrainError, match=r"`max_size` must be <= 16384, got 20000"):
        ReliefParams.from_args(parser.parse_args(["--max-size", "20000"]))
    with pytest.raises(CliffTerrainError, match=r"`exaggeration` must be > 0.0, got 0.0"):
        ReliefParams.from_args(parser.parse_args(["--exaggeration", "0"]))
    # --height-source is the option; --heights, its old name, still works and says so.
    dsm = str(tmp_path / "dsm.tif")
    new = ReliefParams.from_args(parser.parse_args(["--dsm", dsm, "--height-source", "calibrated"]))
    assert new.height_source == "calibrated" and "deprecated" not in capsys.readouterr().err
    old = ReliefParams.from_args(parser.parse_args(["--dsm", dsm, "--heights", "calibrated"]))
    assert old == new
    assert capsys.readouterr().err == "relief: warning: --heights is deprecated: use --height-source\n"
    assert "--heights" not in parser.format_help()  # the help names only the new option
    with pytest.raises(SystemExit):
        parser.parse_args(["--heights", "domes"])  # the old name checks the choices too
    # A relief recorded before the rename (its `heights`) reads as it was built.
    recorded = {**ReliefParams(dsm=dsm, height_source="measured").to_properties(), "dsm": dsm}
    recorded["heights"] = recorded.pop("height_source")
    assert ReliefParams.from_properties(recorded).height_source == "measured"


def test_gsd_gives_metres(field):
    image, _ = field
    px = build_relief(image, max_size=450)
    m = build_relief(image, max_size=450, gsd=0.01)
    # 900 original columns on a 450-column grid: each processing pixel is 2 cm.
    assert m.units == "m" and m.pixel_size == pytest.approx(0.02)
    np.testing.assert_allclose(m.heights, px.heights * 0.02, rtol=1e-6)
    assert m.mesh.vertices[:, 0].max() == pytest.approx(9.0)


def test_two_sided_false_and_exaggeration(field):
    image, _ = field
    one = build_relief(image, max_size=300, two_sided=False, exaggeration=2.0)
    ref = build_relief(image, max_size=300)
    assert one.mesh.n_faces == one.mesh.n_front_faces
    np.testing.assert_allclose(one.heights, 2 * ref.heights, rtol=1e-6)


def test_float_image_in_unit_range_is_accepted(field):
    image, _ = field
    r8 = build_relief(image, max_size=300)
    rf = build_relief(image.astype(np.float32) / 255.0, max_size=300)
    np.testing.assert_array_equal(r8.labels, rf.labels)


def test_real_photo_with_exif_from_a_path():
    path = uav_image("broccoli/01_clip_raw_test.jpg")
    relief = build_relief(path, max_size=500)
    assert max(relief.working.shape[:2]) == 500
    assert relief.metadata.width == 1500
    assert relief.n_regions > 10 and relief.max_height > 5


def test_orthophoto_with_georeference_is_in_metres():
    relief = build_relief(uav_image("lamberton_soybean/20180822_Lamberton_clipped.tif"), max_size=800)
    assert relief.units == "m"
    width_m = relief.mesh.vertices[:, 0].max()
    assert width_m == pytest.approx(relief.metadata.width * relief.metadata.gsd_m_per_px, rel=1e-3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_size": 3}, "`max_size` must be >= 16, got 3"),
        ({"max_size": 2.5}, "`max_size` must be an integer, got 2.5"),
        ({"segmentation": "kmeans"}, "`segmentation` must be one of 'vegetation', 'paper', got 'kmeans'"),
        (
            {"profile": "cone"},
            "`profile` must be one of 'auto', 'circular', 'poisson', 'plateau', got 'cone'",
        ),
        ({"exaggeration": -1}, r"`exaggeration` must be > 0.0, got -1.0"),
        ({"gsd": 0}, r"`gsd` must be > 0.0, got 0.0"),
        ({"two_sided": "yes"}, "`two_sided` must be True or False, got 'yes'"),
        ({"progress": 3}, "`progress` must be callable or None, got 3"),
        ({"mesh": "tin"}, "`mesh` must be one of 'auto', 'grid', 'adaptive', got 'tin'"),
        ({"dsm": 3}, "`dsm` must be a file path or None, got 3"),
        ({"dtm": "dtm.tif"}, "`dtm` needs a `dsm`, got dtm='dtm.tif' and dsm=None"),
        ({"height_source": "measured"}, "`height_source` 'measured' needs a `dsm`"),
    ],
)
def test_bad_settings_name_the_parameter(kwargs, match):
    with pytest.raises(CliffTerrainError, match=match):
        build_relief(np.zeros((20, 20, 3), np.uint8), **kwargs)


def test_bad_images_name_the_problem(tmp_path):
    with pytest.raises(CliffTerrainError, match=r"`image_or_path` must have shape \(rows, cols, 3\)"):
        build_relief(np.zeros((20, 20), np.uint8))
    with pytest.raises(
        CliffTerrainError, match=r"as a float array must hold values in \[0, 1\], got \[2, 2\]"
    ):
        build_relief(np.full((20, 20, 3), 2.0))
    with pytest.raises(CliffTerrainError, match="must be uint8 or floating point, got dtype int64"):
        build_relief(np.zeros((20, 20, 3), np.int64))
    with pytest.raises(CliffTerrainError, match="missing.jpg"):
        build_relief(tmp_path / "missing.jpg")


def test_uniform_colour_has_no_regions():
    relief = build_relief(np.full((64, 80, 3), (120, 90, 60), np.uint8))
    assert relief.n_regions == 0 and relief.max_height == 0.0


def test_synthetic_cli_writes_the_demo_field(tmp_path):
    from PIL import Image

    out = tmp_path / "demo field é" / "field.png"
    assert synthetic_main([str(out), "--seed", "4", "--size", "200x300"]) == 0
    written = np.asarray(Image.open(out))
    expected, _ = synthetic_field(shape=(200, 300), seed=4)
    np.testing.assert_array_equal(written, expected)
    assert synthetic_main([str(out), "--size", "10x10"]) == 2


def test_orthophoto_no_data_stays_flat():
    import cv2

    relief = build_relief(uav_image("plantcv_dsm/rgb.tif"), max_size=284, segmentation="paper")
    valid = relief.metadata.valid_mask
    assert valid is not None and 0.2 < valid.mean() < 0.8
    valid = (
        cv2.resize(valid.astype(np.uint8), relief.heights.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    )
    # Even the literal paper mode, which raises whatever is bright, leaves the no-data corners flat.
    assert relief.heights[~valid].max() == 0.0
    assert relief.heights[valid].max() > 0.0


@pytest.mark.parametrize(
    ("shape", "max_size", "expected"),
    [
        ((2300, 3500), 2000, (1314, 2000)),
        ((3500, 2300), 2000, (2000, 1314)),
        ((600, 900), 900, (600, 900)),
        ((600, 900), 1000, (600, 900)),
        ((3, 5000), 1000, (1, 1000)),
        ((1001, 1001), 1000, (1000, 1000)),
    ],
)
def test_resized_shape_is_the_shape_resize_longest_makes(shape, max_size, expected):
    from cliff_terrain.photo_heights.resize import resize_longest, resized_shape

    assert resized_shape(shape, max_size) == expected
    assert resize_longest(np.zeros((*shape, 3), np.uint8), max_size).shape[:2] == expected


def test_the_mask_digest_tells_a_rebuild_from_another_mask(field):
    """A rebuild from the same photo and settings has the same digest (the relief object's record
    keeps it to know the relief it shows); one plant pixel less gives another."""
    import dataclasses

    image, _ = field
    relief = build_relief(image, max_size=300, mesh=None)
    digest = relief.mask_digest
    assert len(digest) == 16 and int(digest, 16) >= 0  # 8 bytes, hexadecimal
    assert build_relief(image, max_size=300, mesh=None).mask_digest == digest
    mask = relief.mask.copy()
    mask[np.argwhere(mask)[0][0], np.argwhere(mask)[0][1]] = False
    assert dataclasses.replace(relief, mask=mask).mask_digest != digest
