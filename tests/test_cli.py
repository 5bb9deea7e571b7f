"""The `cliff-terrain` command's core jobs: `synthetic` and `relief` (outputs against the API, bad input)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
import tifffile
from PIL import Image

from cliff_terrain import build_relief, load_image
from cliff_terrain.cli import COMMANDS, main


def cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "field.png"
    run = cli("synthetic", path, "--size", "150x220", "--seed", "3")
    assert run.returncode == 0, run.stderr
    return path


def test_synthetic_writes_the_same_field_as_the_api(field):
    from cliff_terrain import synthetic_field

    expected, _ = synthetic_field(shape=(150, 220), seed=3)
    np.testing.assert_array_equal(load_image(field)[0], expected)


def test_relief_writes_what_build_relief_computes(field, tmp_path):
    out = tmp_path / "relief"
    run = cli("relief", field, "--out", out, "--max-size", "200", "--gsd", "0.01")
    assert run.returncode == 0, run.stderr
    relief = build_relief(str(field), max_size=200, gsd=0.01, two_sided=False)
    np.testing.assert_allclose(tifffile.imread(out / "height.tif"), relief.heights, rtol=1e-6)
    with tifffile.TiffFile(out / "height.tif") as tif:  # as render_views.py writes it: with its units
        assert tif.shaped_metadata[0]["units"] == "m"
        assert tif.shaped_metadata[0]["pixel_size"] == pytest.approx(relief.pixel_size)
    np.testing.assert_array_equal(tifffile.imread(out / "labels.tif"), relief.labels)
    np.testing.assert_array_equal(np.asarray(Image.open(out / "mask.png")) > 0, relief.mask)
    summary = json.loads((out / "relief.json").read_text())
    assert summary["regions"] == relief.n_regions and summary["units"] == "m"
    with open(out / "regions.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert [int(r["id"]) for r in rows] == list(range(1, relief.n_regions + 1))
    # Each plant's tallest point and pixel count, against the arrays.
    for row in rows[:10]:
        region = relief.labels == int(row["id"])
        assert int(row["area_px"]) == np.count_nonzero(region)
        assert float(row["height_max_m"]) == pytest.approx(float(relief.heights[region].max()), rel=1e-5)


def test_existing_outputs_are_kept_and_bad_input_is_one_line(field, tmp_path):
    out = tmp_path / "relief"
    assert cli("relief", field, "--out", out, "--max-size", "64").returncode == 0
    before = (out / "height.tif").read_bytes()
    run = cli("relief", field, "--out", out, "--max-size", "100")
    assert run.returncode == 2 and "height.tif' exists; pass --overwrite" in run.stderr
    assert (out / "height.tif").read_bytes() == before
    for args, words in [
        (("relief", tmp_path / "missing.jpg", "--out", tmp_path / "x"), "no such file"),
        (("relief", field, "--out", tmp_path / "x", "--max-size", "3"), "`--max-size` must be >= 16, got 3"),
        (("synthetic", tmp_path / "f.png", "--size", "big"), "`--size` must be ROWSxCOLS"),
        (("relief", field), "the following arguments are required: --out"),
        (("nonsense",), "invalid choice: 'nonsense'"),
    ]:
        run = cli(*args)
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(lines) == 1 and words in lines[0], (args, run.stderr)
    assert not (tmp_path / "x").exists()


def test_help_lists_every_command_without_importing_the_heavy_libraries(capsys):
    code = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys\nfrom cliff_terrain.cli import build_parser\nbuild_parser()\n"
            "print(sorted(m for m in ('cv2', 'scipy', 'skimage', 'dask', 'matplotlib') if m in sys.modules))",
        ],
        capture_output=True,
        text=True,
    )
    assert code.stdout.strip() == "[]", code.stdout + code.stderr
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for name in COMMANDS:
        assert name in text


def test_without_a_gsd_no_region_size_is_given_in_metres():
    # The equivalent diameter was the pixels' under a `_m` name (5.17 "m" for a 21-pixel plant).
    from cliff_terrain.measure.tables import region_table

    labels = np.zeros((8, 8), int)
    labels[2:6, 2:6] = 1
    row = region_table(labels, heights=labels * 0.5)[0]
    assert row["area_px"] == 16 and np.isnan(row["area_m2"]) and np.isnan(row["equivalent_diameter_m"])
    metres = region_table(labels, heights=labels * 0.5, pixel_size=0.01)[0]
    assert metres["equivalent_diameter_m"] == pytest.approx(2 * np.sqrt(16 / np.pi) * 0.01)
