"""The heights command's memory estimate (issue 40): a run past the cap is refused before the work,
in one line naming the file and the --max-size / --resolution that fit, and those options fit.

The estimate's coefficients come from bench/bench_heights_memory.py (peaks are measured there,
never here); these tests run the refusal on the shared OpenDroneMap pair with small caps.
"""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from conftest import REPO, empty_raster

from cliff_terrain.commands.memory_estimate import GRID_GIB_PER_MP, heights_estimate
from cliff_terrain.io.raster.geotiff import raster_size

ODM_PAIR = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"
ORTHO, DSM = ODM_PAIR / "odm_orthophoto.tif", ODM_PAIR / "dsm.tif"


@pytest.fixture
def pair():
    if not ORTHO.is_file():
        pytest.skip(f"the shared OpenDroneMap pair is not at {ODM_PAIR}")
    rows, cols = raster_size(ORTHO)
    drows, dcols = raster_size(DSM)
    return rows, cols, [rows * cols / 1e6, drows * dcols / 1e6]


def heights(tmp_path, *extra):
    command = [sys.executable, "-m", "cliff_terrain", "heights", str(ORTHO), "--dsm", str(DSM)]
    command += ["--out", str(tmp_path / "out"), "--no-progress", *extra]
    return subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=600)


def test_past_the_cap_the_run_is_refused_with_the_options_that_fit_and_they_do(pair, tmp_path):
    rows, cols, files = pair
    full = heights_estimate(files, rows * cols / 1e6)
    cap = round(heights_estimate(files, 0.0) + 0.25 * (full - heights_estimate(files, 0.0)), 3)
    done = heights(tmp_path, "--max-memory", str(cap))
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith(f"cliff-terrain heights: error: measuring '{ORTHO}' ({cols} x {rows} pixels)")
    assert f"needs about {full:.2f} GiB, more than the {cap:g} GiB cap" in lines[0]
    assert not (tmp_path / "out").exists()
    size, resolution = re.search(r"use --max-size (\d+) or --resolution ([\d.]+)", lines[0]).groups()
    # A quarter of the grid's memory: half the side, to the pixel.
    assert int(size) == pytest.approx(max(rows, cols) * 0.5, abs=2)
    # Each suggestion fits under the same cap, and the run then measures.
    fitted = heights(tmp_path, "--max-memory", str(cap), "--max-size", size)
    assert fitted.returncode == 0 and fitted.stderr == "", fitted.stderr
    refitted = heights(tmp_path, "--max-memory", str(cap), "--resolution", resolution, "--overwrite")
    assert refitted.returncode == 0 and refitted.stderr == "", refitted.stderr
    # One pixel more than suggested does not fit.
    over = heights(tmp_path, "--max-memory", str(cap), "--max-size", str(int(size) + 3), "--overwrite")
    assert over.returncode == 2 and "more than the" in over.stderr


def test_when_reading_alone_passes_the_cap_it_says_to_split_the_files(pair, tmp_path):
    _, _, files = pair
    cap = round(heights_estimate(files, 0.0) + 0.5 * GRID_GIB_PER_MP * 0.01, 4)
    done = heights(tmp_path, "--max-memory", str(cap))
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "reading the files alone needs" in done.stderr and "crop or split the orthophoto" in done.stderr


def test_the_default_cap_lets_the_shared_pair_through_and_refuses_a_nonsense_cap(pair, tmp_path):
    done = heights(tmp_path, "--max-memory", "-1")
    assert done.returncode == 2 and "`--max-memory` must be > 0.0, got -1.0" in done.stderr
    assert heights_estimate(pair[2], pair[0] * pair[1] / 1e6) < 4.0


def test_an_orthophoto_past_the_readers_limit_is_refused_whatever_the_grid(tmp_path):
    # A 151 MP header with almost no data (tiles of zeros compress to nothing; never decoded).

    from cliff_terrain.io.photo import MAX_PIXELS

    rows, cols = 12_300, 12_300
    assert rows * cols > MAX_PIXELS
    path = empty_raster(tmp_path / "huge.tif", rows, cols, 0.01)
    command = [
        sys.executable,
        "-m",
        "cliff_terrain",
        "heights",
        str(path),
        "--dsm",
        str(DSM),
        "--max-size",
        "1000",
    ]
    done = subprocess.run(
        [*command, "--out", str(tmp_path / "out")], capture_output=True, text=True, cwd=REPO, timeout=600
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert f"'{path}' is 12300 x 12300 pixels (151 MP), more than the 150 MP" in done.stderr
    assert "even with --max-size or --resolution; crop or split it" in done.stderr


def test_both_suggestions_fit_where_a_coarser_grid_would_need_more(tmp_path):
    # The ground's grid gathers whole pixels up to 5 cm: a 1.24 cm grid's ground is 4.96 cm, a
    # 1.3 cm grid's 3.9 cm, so a coarser grid can need more memory. Under every cap of a range
    # that crosses such steps, both the --max-size and the --resolution (rounded up to the
    # millimetre) that the message suggests are measured.
    import numpy as np

    from cliff_terrain.commands.heights import grid_size
    from cliff_terrain.commands.memory_estimate import check_heights_memory, grid_estimate
    from cliff_terrain.errors import CliffTerrainError

    ortho = empty_raster(tmp_path / "ortho.tif", 4000, 4000, 0.007)  # 16 MP at 7 mm
    dsm = empty_raster(tmp_path / "dsm.tif", 1334, 1334, 0.021, bands=1, dtype=np.float32)
    files = [16.0, 1334**2 / 1e6]
    assert grid_estimate(ortho, files, 2154)[0] > grid_estimate(ortho, files, 2264)[0]  # 1.3 and 1.24 cm
    for cap in np.arange(1.10, 1.30, 0.01):
        with pytest.raises(CliffTerrainError) as refused:
            check_heights_memory(ortho, (dsm,), longest=4000, cap_gib=cap)
        size, resolution = re.search(
            r"use --max-size (\d+) or --resolution ([\d.]+)", str(refused.value)
        ).groups()
        assert check_heights_memory(ortho, (dsm,), longest=int(size), cap_gib=cap) <= cap
        longest = grid_size(ortho, resolution=float(resolution))
        assert (
            longest <= int(size) and check_heights_memory(ortho, (dsm,), longest=longest, cap_gib=cap) <= cap
        )
