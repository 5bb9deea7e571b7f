"""`cliff-terrain season` on the 7 dated Lamberton soybean orthophotos: the table against an independent
reference, serial against Dask (a local cluster and a scheduler this test starts on loopback), the
cache surviving a killed run, failures on their rows, the growth chart, and bad input.

Dask and matplotlib are imported inside the tests only: this module must import without them.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
from conftest import REPO, SHARED_UAV

from cliff_terrain.errors import CliffTerrainError

SOYBEAN = SHARED_UAV / "lamberton_soybean"
DATES = (
    "2018-08-15",
    "2018-08-22",
    "2018-08-29",
    "2018-09-05",
    "2018-09-14",
    "2018-09-17",
    "2018-09-25",
)


@pytest.fixture(scope="module")
def soybean():
    if not (SOYBEAN / "plots.geojson").is_file():
        pytest.skip(f"the Lamberton soybean season is not at {SOYBEAN} (../shared is absent)")
    return SOYBEAN


def season(*args, timeout=600, progress=False):
    """Run ``python -m cliff_terrain season ARGS`` (a fresh process, as a user would)."""
    return subprocess.run(
        [sys.executable, "-m", "cliff_terrain", "season", *map(str, args)]
        + ([] if progress else ["--no-progress"]),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def read_table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def serial(soybean, tmp_path_factory):
    """The whole season run serially (``--workers 0``): the reference of the other runs."""
    out = tmp_path_factory.mktemp("serial")
    done = season(soybean, "--plots", soybean / "plots.geojson", "--out", out, "--workers", "0")
    assert done.returncode == 0, done.stderr
    return out


def test_table_is_tidy_and_dated(serial, soybean):
    rows = read_table(serial / "season.csv")
    n_plots = len(json.loads((soybean / "plots.geojson").read_text())["features"])
    assert len(rows) == len(DATES) * n_plots
    assert list(rows[0])[:6] == ["date", "date_source", "image", "plot", "fid", "ID"]
    for column in ("cover", "volume_m3", "height_p50", "height_p90", "height_max", "height_mode", "error"):
        assert column in rows[0]
    assert sorted({r["date"] for r in rows}) == list(DATES)
    assert {r["date_source"] for r in rows} == {"filename"}  # the files hold no EXIF or TIFF date
    assert {r["height_mode"] for r in rows} == {"inflated"}
    assert all(r["error"] == "" and r["reason"] == "" for r in rows)
    # One row per date and plot, in date order then plot order.
    assert [(r["date"], int(r["plot"])) for r in rows] == [(d, p) for d in DATES for p in range(n_plots)]
    # The canopy closes then senesces: green cover in August, none on bare stubble in late September.
    cover = {d: np.median([float(r["cover"]) for r in rows if r["date"] == d]) for d in DATES}
    assert cover["2018-08-15"] > 0.4 and cover["2018-09-25"] < 0.01


def test_plot_figures_against_an_independent_reference(serial, soybean):
    """Cover, p90 and volume of each plot on one date, recomputed with matplotlib's point-in-polygon."""
    from matplotlib.path import Path as Polygon

    from cliff_terrain import build_relief
    from cliff_terrain.season.reader import read_season

    outputs = read_season(serial)
    date = outputs.dates[0]
    relief = build_relief(date.image, two_sided=False)
    # The cached grid is the relief's (the season passes the GeoTIFF's GSD in float64; the photo
    # reader's own is a hair different).
    np.testing.assert_allclose(date.heights, relief.heights, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(date.mask, relief.mask)
    rows, cols = relief.heights.shape
    t = date.transform
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    centres = np.column_stack(
        [(t[0, 0] * cc + t[0, 1] * rr + t[0, 2]).ravel(), (t[1, 0] * cc + t[1, 1] * rr + t[1, 2]).ravel()]
    )
    pixel_area = abs(t[0, 0] * t[1, 1] - t[0, 1] * t[1, 0])
    table = [r for r in read_table(serial / "season.csv") if r["date"] == date.date]
    features = json.loads((soybean / "plots.geojson").read_text())["features"]
    for row, feature in zip(table, features, strict=True):
        inside = Polygon(feature["geometry"]["coordinates"][0]).contains_points(centres).reshape(rows, cols)
        assert inside.sum() > 1000  # a whole plot: ~5.3 m x 1.6 m at 4.4 cm
        assert float(row["cover"]) == pytest.approx(relief.mask[inside].mean(), rel=1e-5, abs=1e-6)
        h = relief.heights[inside].astype(np.float64)
        assert float(row["height_p90"]) == pytest.approx(np.percentile(h, 90), rel=1e-4, abs=1e-6)
        assert float(row["height_max"]) == pytest.approx(h.max(), rel=1e-5)
        assert float(row["volume_m3"]) == pytest.approx(h.sum() * pixel_area, rel=1e-4)
        assert float(row["area_m2"]) == pytest.approx(inside.sum() * pixel_area, rel=1e-5)


@pytest.mark.slow
def test_local_cluster_table_is_byte_identical(serial, soybean, tmp_path):
    done = season(
        soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path, "--workers", "2", progress=True
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "season.csv").read_bytes() == (serial / "season.csv").read_bytes()
    assert "7 images computed, 0 from the cache" in done.stdout
    # Asked for, a cluster runs however small the season, and says so.
    assert "ran on local cluster, 2 workers: workers=2 asked for it" in done.stdout.splitlines()
    assert (
        json.loads((tmp_path / "season.json").read_text())["runner"]["runner"] == "local cluster, 2 workers"
    )
    # The height grids too, to the bit (the animation reads them).
    from cliff_terrain.season.reader import read_season

    for ours, theirs in zip(read_season(tmp_path).dates, read_season(serial).dates, strict=True):
        assert ours.heights.tobytes() == theirs.heights.tobytes()
    # The progress bar is drawn on a terminal only (test_bad_input_table.py draws one): a pipe gets
    # the summary lines, and stderr nothing at all.
    assert done.stderr == "", done.stderr


def test_a_closing_cluster_keeps_its_workers_heartbeat_tracebacks_off_stderr():
    """A worker may send one more heartbeat after the scheduler has let it go, and log a traceback
    for it (dask/distributed#7105; seen once in CI as the stderr of the test above). Run on the
    workers as a local cluster closes, the filter drops that line and no other error."""
    import logging

    from cliff_terrain.season.cluster import _not_a_heartbeat_failure, _quiet_heartbeat_failures

    logger = logging.getLogger("distributed.worker")
    seen = []
    handler = logging.Handler()
    handler.emit = seen.append
    logger.addHandler(handler)
    try:
        _quiet_heartbeat_failures()
        try:
            raise OSError("Stream is closed")
        except OSError:
            logger.exception("Failed to communicate with scheduler during heartbeat.")
            logger.exception("Compute Failed")
    finally:
        logger.removeHandler(handler)
        logger.removeFilter(_not_a_heartbeat_failure)
    assert [record.getMessage() for record in seen] == ["Compute Failed"]


def test_small_season_runs_in_process_by_default(serial, soybean, tmp_path):
    """No --workers: the 7 soybean dates (6.6 MP) are too little work for a cluster to pay off, so
    they run in this process, the same table, and the command, the record and season.json say why."""
    done = season(soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "season.csv").read_bytes() == (serial / "season.csv").read_bytes()
    line = next(line for line in done.stdout.splitlines() if line.startswith("ran "))
    assert re.fullmatch(
        r"ran in this process: 7 images, 6\.\d MP of work \(about \d\.\d s in one process\), under the "
        r"4 s a local cluster needs to pay off; --workers N forces a cluster",
        line,
    ), line
    runner = json.loads((tmp_path / "season.json").read_text())["runner"]
    assert runner["runner"] == "in-process" and runner["reason"] in line


def test_default_runner_choice(serial, soybean, monkeypatch):
    """The choice from the headers: cached images cost nothing, enough work starts a cluster of one
    worker per core (not below two cores), and a given setting always wins."""
    from cliff_terrain.season import cluster as runner_module
    from cliff_terrain.season.cluster import choose_runner
    from cliff_terrain.season.plan import plan_season

    jobs, _ = plan_season([soybean], plots=soybean / "plots.geojson")
    for job in jobs:
        job.cache = str(serial / "cache")
        job.plots_hash = runner_module.file_hash(job.plots)
        job.version = __import__("cliff_terrain").__version__
    workers, name, reason = choose_runner(jobs)
    assert (workers, name) == (0, "in-process")
    assert reason.startswith("0 images (7 cached), 0.0 MP of work")
    for job in jobs:
        job.cache = str(serial / "no-such-cache")
    monkeypatch.setattr(runner_module, "CLUSTER_PAYS_S", 0.5)
    monkeypatch.setattr(runner_module, "usable_cores", lambda: 3)
    workers, name, reason = choose_runner(jobs)
    assert (workers, name) == (3, "local cluster, 3 workers")
    assert reason.endswith("over the 0.5 s a local cluster needs to pay off")
    monkeypatch.setattr(runner_module, "usable_cores", lambda: 1)
    assert choose_runner(jobs)[:2] == (0, "in-process")
    assert choose_runner(jobs, workers=1)[:2] == (1, "local cluster, 1 worker")
    assert choose_runner(jobs, workers=0)[:2] == (0, "in-process")
    assert choose_runner(jobs, scheduler="tcp://127.0.0.1:1")[1] == "the Dask scheduler tcp://127.0.0.1:1"


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs):
    """Interrupt the Dask processes (the last started first) and wait for them."""
    for proc in reversed(procs):
        proc.send_signal(signal.SIGINT)
    for proc in reversed(procs):
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture
def scheduler(tmp_path):
    """A dask.distributed scheduler and one worker process on loopback, as separate processes."""
    pytest.importorskip("distributed", reason="the `season` extra (dask[distributed]) is not installed")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    bin_dir = Path(sys.executable).parent
    procs = [
        subprocess.Popen(
            [bin_dir / "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        procs.append(
            subprocess.Popen(
                [bin_dir / "dask", "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                env=env,
                cwd=tmp_path,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(1, timeout=60)
        yield address
    finally:
        _stop(procs)


@pytest.mark.slow
def test_existing_scheduler_on_loopback(serial, soybean, scheduler, tmp_path):
    from distributed import Client

    with Client(scheduler, timeout=60) as client:
        started = time.time()
        client.get_task_stream(start=started)  # installs the scheduler's task-stream recorder
        done = season(
            soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path, "--scheduler", scheduler
        )
        stream = client.get_task_stream(start=started)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "season.csv").read_bytes() == (serial / "season.csv").read_bytes()
    # One image, one task: the scheduler ran exactly one task per photo.
    names = sorted(task["key"].rsplit("-", 1)[-1] for task in stream if task["key"].startswith("season-"))
    assert names == sorted(p.name for p in soybean.glob("*.tif"))


def test_unreachable_scheduler_is_one_line(soybean, tmp_path):
    pytest.importorskip("distributed", reason="the `season` extra (dask[distributed]) is not installed")
    address = f"tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    done = season(
        soybean,
        "--plots",
        soybean / "plots.geojson",
        "--out",
        tmp_path,
        "--scheduler",
        address,
        "--timeout",
        "2",
        timeout=120,
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert re.fullmatch(
        rf"cliff-terrain season: error: cannot reach the Dask scheduler `{address}` within 2 s \(\w+\)",
        lines[0],
    )


def test_killed_run_resumes_without_recomputing(serial, soybean, tmp_path):
    command = [
        sys.executable,
        "-m",
        "cliff_terrain",
        "season",
        str(soybean),
        "--plots",
        str(soybean / "plots.geojson"),
    ]
    command += ["--out", str(tmp_path), "--workers", "0", "--no-progress"]
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    cache = tmp_path / "cache"
    deadline = time.monotonic() + 300
    while (
        not (cache.is_dir() and any(cache.glob("*.json")))
        and proc.poll() is None
        and time.monotonic() < deadline
    ):
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = len(list(cache.glob("*.json")))
    assert 1 <= finished < len(DATES), "the run was not killed part-way"
    assert not (tmp_path / "season.csv").exists()
    done = season(soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path, "--workers", "0")
    assert done.returncode == 0, done.stderr
    assert f"{len(DATES) - finished} images computed, {finished} from the cache" in done.stdout
    assert (tmp_path / "season.csv").read_bytes() == (serial / "season.csv").read_bytes()


def _subset(soybean, folder, names):
    folder.mkdir()
    for name in names:
        shutil.copyfile(soybean / name, folder / name)
    return folder


def test_failed_image_gets_its_error_on_its_rows(serial, soybean, tmp_path):
    names = sorted(p.name for p in soybean.glob("*.tif"))[:3]
    photos = _subset(soybean, tmp_path / "photos", names)
    broken = photos / names[1]
    # Its header and georeference are whole (the season is planned), its pixels are not a photo: the
    # failure comes while it is computed. (A truncated file is refused before any work: issue 40.)
    with tifffile.TiffFile(soybean / names[1]) as tif:
        page = tif.pages[0]
        geo = [(t.code, t.dtype, t.count, t.value, True) for t in page.tags.values() if t.code >= 33550]
        shape = page.shape
    tifffile.imwrite(broken, np.full(shape, 1000.0, np.float32), extratags=geo, photometric="rgb")
    done = season(photos, "--plots", soybean / "plots.geojson", "--out", tmp_path / "out", "--workers", "0")
    assert done.returncode == 1
    assert "1 of 3 images failed" in done.stderr and names[1] in done.stderr
    rows = read_table(tmp_path / "out" / "season.csv")
    bad = [r for r in rows if r["image"] == names[1]]
    assert len(bad) == 40 and all(r["error"] and r["cover"] == "" and r["height_p90"] == "" for r in bad)
    # The others are computed, and aligned between themselves as a season of the two good dates is.
    good_only = _subset(soybean, tmp_path / "good", [names[0], names[2]])
    done = season(
        good_only, "--plots", soybean / "plots.geojson", "--out", tmp_path / "good_out", "--workers", "0"
    )
    assert done.returncode == 0, done.stderr
    good = [r for r in rows if r["image"] != names[1]]
    assert good == read_table(tmp_path / "good_out" / "season.csv")
    # The failure is not cached: once the file is whole again only it is computed.
    shutil.copyfile(soybean / names[1], broken)
    done = season(photos, "--plots", soybean / "plots.geojson", "--out", tmp_path / "out", "--workers", "0")
    assert done.returncode == 0 and "1 images computed, 2 from the cache" in done.stdout


def _plots_with(soybean, path, *, crs=None, extra_feature=None, treatment=False):
    data = json.loads((soybean / "plots.geojson").read_text())
    if crs is not None:
        data["crs"]["properties"]["name"] = f"urn:ogc:def:crs:EPSG::{crs}"
    if treatment:
        for i, feature in enumerate(data["features"]):
            feature["properties"]["treatment"] = "early" if i % 2 else "late"
    if extra_feature is not None:
        data["features"].append(extra_feature)
    path.write_text(json.dumps(data))
    return path


def test_plot_outside_the_photos_gets_an_empty_row_with_a_reason(soybean, tmp_path):
    far = {
        "type": "Feature",
        "properties": {"fid": 99, "ID": 99},
        "geometry": {
            "type": "Polygon",
            "coordinates": [[[300000, 4800000], [300005, 4800000], [300005, 4800002], [300000, 4800000]]],
        },
    }
    plots = _plots_with(soybean, tmp_path / "plots.geojson", extra_feature=far)
    photos = _subset(soybean, tmp_path / "photos", ["20180815_Lamberton_clipped.tif"])
    done = season(photos, "--plots", plots, "--out", tmp_path / "out", "--workers", "0")
    assert done.returncode == 0, done.stderr
    rows = read_table(tmp_path / "out" / "season.csv")
    assert len(rows) == 41
    last = rows[-1]
    assert last["plot"] == "40" and last["ID"] == "99"
    assert (
        last["reason"].startswith("outside the raster") and last["cover"] == "" and last["height_p90"] == ""
    )


def test_growth_chart_coloured_by_an_attribute(soybean, serial, tmp_path):
    from PIL import Image

    plots = _plots_with(soybean, tmp_path / "plots.geojson", treatment=True)
    # The cache of the serial run is keyed by the plots file too, so this run computes afresh.
    done = season(
        soybean, "--plots", plots, "--out", tmp_path / "out", "--workers", "0", "--color-by", "treatment"
    )
    assert done.returncode == 0, done.stderr
    assert read_table(tmp_path / "out" / "season.csv")[0]["treatment"] == "late"
    png = np.asarray(Image.open(tmp_path / "out" / "growth.png").convert("RGB")).astype(int)
    assert png.shape[0] > 400 and png.shape[1] > 1000

    def pixels_of(rgb):
        return int((np.abs(png - np.array(rgb)).sum(axis=2) <= 6).sum())

    # The two groups' bold medians in matplotlib's first two tab10 colours; no other colour is used.
    assert pixels_of((31, 119, 180)) > 500 and pixels_of((255, 127, 14)) > 500
    assert pixels_of((44, 160, 44)) == 0
    bad = season(
        soybean, "--plots", plots, "--out", tmp_path / "out", "--workers", "0", "--color-by", "genotype"
    )
    assert (
        bad.returncode == 2
        and "`--color-by` must be one of the plots' attributes (fid, ID, treatment), got 'genotype'"
        in bad.stderr
    )


def test_bad_input_messages(soybean, tmp_path):
    plots = soybean / "plots.geojson"
    undated = _subset(soybean, tmp_path / "undated", [])
    shutil.copyfile(soybean / "20180815_Lamberton_clipped.tif", undated / "north_field.tif")
    done = season(undated, "--plots", plots, "--out", tmp_path / "o1", "--workers", "0")
    assert done.returncode == 2
    assert (
        "no date for" in done.stderr
        and "north_field.tif" in done.stderr
        and re.search(r"--dates \S*north_field\.tif=", done.stderr)  # its path: a name may not be unique
    )
    done = season(
        undated,
        "--plots",
        plots,
        "--out",
        tmp_path / "o1",
        "--workers",
        "0",
        "--dates",
        "north_field.tif=2018-08-15",
    )
    assert done.returncode == 0, done.stderr
    assert {r["date_source"] for r in read_table(tmp_path / "o1" / "season.csv")} == {"option"}

    shutil.copyfile(soybean / "20180815_Lamberton_clipped.tif", undated / "copy_2018-08-15.tif")
    done = season(
        undated,
        "--plots",
        plots,
        "--out",
        tmp_path / "o2",
        "--workers",
        "0",
        "--dates",
        "north_field.tif=2018-08-15",
    )
    assert done.returncode == 2 and "two photos of 2018-08-15" in done.stderr

    (tmp_path / "empty").mkdir()
    done = season(tmp_path / "empty", "--plots", plots, "--out", tmp_path / "o3")
    assert done.returncode == 2 and "no images in folder" in done.stderr

    other = _plots_with(soybean, tmp_path / "utm16.geojson", crs=32616)
    done = season(soybean, "--plots", other, "--out", tmp_path / "o4", "--workers", "0")
    assert done.returncode == 2
    assert "EPSG:32616" in done.stderr and "EPSG:32615" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_dsm_gives_measured_heights(tmp_path):
    """--dsm: the plots' heights are the surface model's canopy height (issue 13's measured mode)."""
    from matplotlib.path import Path as Polygon

    from cliff_terrain import build_relief
    from cliff_terrain.season.reader import read_season

    folder = SHARED_UAV.parent / "dsm" / "fieldimager_ex2"
    if not (folder / "dsm.tif").is_file():
        pytest.skip(f"the FIELDimageR orthophoto and DSM are not at {folder} (../shared is absent)")
    square = [[296600, 4888190], [296620, 4888190], [296620, 4888210], [296600, 4888210], [296600, 4888190]]
    plots = tmp_path / "plots.geojson"
    plots.write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32616"}},
                "features": [
                    {
                        "type": "Feature",
                        "properties": {"name": "a"},
                        "geometry": {"type": "Polygon", "coordinates": [square]},
                    }
                ],
            }
        )
    )
    ortho = folder / "odm_orthophoto.tif"
    args = [
        ortho,
        "--plots",
        plots,
        "--out",
        tmp_path / "out",
        "--workers",
        "0",
        "--dates",
        "odm_orthophoto.tif=2019-07-01",
    ]
    bad = season(*args, "--heights", "measured")
    assert bad.returncode == 2 and "`--height-source` 'measured' needs `--dsm`" in bad.stderr
    done = season(*args, "--dsm", folder / "dsm.tif")
    assert done.returncode == 0, done.stderr
    (row,) = read_table(tmp_path / "out" / "season.csv")
    assert (row["height_mode"], row["date_source"], row["reason"]) == ("measured", "option", "")
    # Independent reference: the relief built directly, the plot's pixels by matplotlib's point-in-polygon.
    relief = build_relief(str(ortho), dsm=folder / "dsm.tif", height_source="measured", two_sided=False)
    t = read_season(tmp_path / "out").dates[0].transform
    rows, cols = relief.heights.shape
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    centres = np.column_stack([(t[0, 0] * cc + t[0, 2]).ravel(), (t[1, 1] * rr + t[1, 2]).ravel()])
    inside = Polygon(square).contains_points(centres).reshape(rows, cols)
    assert inside.sum() > 1000
    h = relief.heights[inside].astype(np.float64)
    assert float(row["height_p90"]) == pytest.approx(np.percentile(h, 90), rel=1e-3)
    assert float(row["height_max"]) == pytest.approx(h.max(), rel=1e-5)
    assert 0.2 < float(row["height_p90"]) < 1.5  # soybean-sized plants, in metres


def test_opencv_distance_is_exact_with_two_threads(soybean):
    """Why each task gives OpenCV two threads (task.exact_opencv): its precise distance transform
    then equals SciPy's exact Euclidean one, whatever happened in the process before."""
    import cv2
    from PIL import Image
    from scipy import ndimage

    from cliff_terrain.photo_heights.labels import distance_map, region_interiors
    from cliff_terrain.photo_heights.resize import resize_longest
    from cliff_terrain.photo_heights.segmentation import segment

    rgb = np.asarray(Image.open(soybean / "20180905_Lamberton_clipped.tif").convert("RGB"))
    labels = segment(resize_longest(rgb, 1000)).labels
    exact = ndimage.distance_transform_edt(region_interiors(labels)).astype(np.float32)
    saved = cv2.getNumThreads()
    try:
        cv2.setNumThreads(2)
        for size in (1, 10**5, 3 * 10**5):
            np.ones(size)  # a different heap each time
            np.testing.assert_array_equal(distance_map(labels), exact)
    finally:
        cv2.setNumThreads(saved)


@pytest.mark.slow
def test_given_client_is_used_and_left_open(serial, soybean, tmp_path):
    """`run_season(client=...)`: a notebook's client runs the tasks (one per photo) and stays open;
    the local cluster it runs on keeps glibc's adaptive allocator (no MALLOC_TRIM_THRESHOLD_)."""
    from distributed import Client

    from cliff_terrain.season.cluster import local_cluster
    from cliff_terrain.season.plan import plan_season
    from cliff_terrain.season.runner import run_season

    jobs, plots = plan_season([soybean], plots=soybean / "plots.geojson")
    with local_cluster(1) as cluster, Client(cluster) as client:
        env = client.run(
            lambda: (
                os.environ.get("MALLOC_TRIM_THRESHOLD_"),
                os.environ.get("OPENCV_FOR_THREADS_NUM"),
                __import__("dask").config.get("distributed.worker.profile.enabled"),
            )
        )
        assert list(env.values()) == [(None, "2", False)]
        started = time.time()
        client.get_task_stream(start=started)
        done = run_season(jobs, plots, out=tmp_path, client=client, progress=False, chart=False)
        stream = client.get_task_stream(start=started)
        assert client.status == "running"
        assert client.submit(sum, [1, 2]).result() == 3
    assert done.computed == len(jobs) and not done.failures
    assert done.runner == "the given Dask client"
    assert (tmp_path / "season.csv").read_bytes() == (serial / "season.csv").read_bytes()
    assert sum(task["key"].startswith("season-") for task in stream) == len(jobs)
    with pytest.raises(CliffTerrainError, match=r"`client` must be a distributed.Client, got 'tcp://x'"):
        run_season(jobs, plots, out=tmp_path, client="tcp://x")


def _moved_copy(source, target, rows, cols):
    """The GeoTIFF `source` with its pixels moved down `rows` and right `cols` (no data where they
    leave), its georeference kept: a date whose orthophoto is off by that much."""
    import tifffile

    with tifffile.TiffFile(source) as tif:
        page = tif.pages[0]
        data = page.asarray()
        geo = [
            (tag.code, tag.dtype, tag.count, tag.value, True)
            for tag in page.tags.values()
            if tag.code in (33550, 33922, 34264, 34735, 34736, 34737, 42112, 42113)
        ]
    moved = np.zeros_like(data)
    moved[rows:, cols:] = data[:-rows, :-cols]
    tifffile.imwrite(target, moved, photometric="rgb", extrasamples=["unassalpha"], extratags=geo)


def test_a_date_moved_by_a_known_shift_is_found_and_read_in_place(serial, soybean, tmp_path):
    names = sorted(p.name for p in soybean.glob("*.tif"))
    moved_name = names[2]  # 29 August: the canopy half closed
    photos = _subset(soybean, tmp_path / "photos", names)
    _moved_copy(soybean / moved_name, photos / moved_name, 12, 30)
    plots = soybean / "plots.geojson"
    done = season(photos, "--plots", plots, "--out", tmp_path / "aligned", "--workers", "0")
    assert done.returncode == 0, done.stderr
    raw = season(photos, "--plots", plots, "--out", tmp_path / "raw", "--workers", "0", "--no-align")
    assert raw.returncode == 0, raw.stderr

    def date_record(folder):
        dates = json.loads((folder / "season.json").read_text())["dates"]
        return next(d for d in dates if Path(d["image"]).name == moved_name)

    unmoved, found = date_record(serial), date_record(tmp_path / "aligned")
    # The dates of this season drift by up to a few pixels on their own: the moved date's shift is
    # its unmoved shift plus the move.
    np.testing.assert_allclose(np.subtract(found["shift_px"], unmoved["shift_px"]), [12.0, 30.0], atol=0.5)
    assert found["shift_m"] == pytest.approx(np.hypot(12 * 0.0266, 30 * 0.0266), rel=0.1)
    assert "shift_flag" in found  # 0.86 m: more than a quarter of the 1.59 m plots
    assert "shift_px" not in date_record(tmp_path / "raw")  # --no-align: the georeference as it is

    def cover(folder):
        return np.array(
            [float(r["cover"]) for r in read_table(folder / "season.csv") if r["image"] == moved_name]
        )

    reference, aligned, unaligned = cover(serial), cover(tmp_path / "aligned"), cover(tmp_path / "raw")
    plants = reference >= 0.1  # relative errors of plots with some canopy
    aligned_error = np.mean(np.abs(aligned - reference)[plants] / reference[plants])
    unaligned_error = np.mean(np.abs(unaligned - reference)[plants] / reference[plants])
    assert aligned_error <= 0.02, aligned_error
    assert unaligned_error > 0.10, unaligned_error


def _certificates(folder):
    """A CA and one certificate it signed (for 127.0.0.1), made with the openssl command line."""
    openssl = shutil.which("openssl")
    assert openssl, "the TLS test makes its certificates with the openssl command (apt-get install openssl)"
    folder.mkdir()

    def run(*args):
        subprocess.run([openssl, *args], cwd=folder, check=True, capture_output=True)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "1",
        "-subj", "/CN=cliff-terrain test CA")  # fmt: skip
    run(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "key.pem",
        "-out",
        "req.csr",
        "-subj",
        "/CN=127.0.0.1",
    )
    (folder / "ext.cnf").write_text("subjectAltName=IP:127.0.0.1\n")
    run("x509", "-req", "-in", "req.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-out",
        "cert.pem", "-days", "1", "-extfile", "ext.cnf")  # fmt: skip
    return {name: folder / f"{name}.pem" for name in ("ca", "cert", "key")}


@pytest.mark.slow
def test_tls_scheduler_on_loopback_with_certificates_made_here(serial, soybean, tmp_path):
    pytest.importorskip("distributed", reason="the `season` extra (dask[distributed]) is not installed")
    pem = _certificates(tmp_path / "tls")
    tls = ["--tls-ca-file", pem["ca"], "--tls-cert", pem["cert"], "--tls-key", pem["key"]]
    port = _free_port()
    address = f"tls://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    bin_dir = Path(sys.executable).parent
    quiet = {"env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = [
        subprocess.Popen(
            [
                bin_dir / "dask",
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--protocol",
                "tls",
                "--no-dashboard",
                *map(str, tls),
            ],
            **quiet,
        )  # fmt: skip
    ]
    try:
        procs.append(
            subprocess.Popen(
                [
                    bin_dir / "dask",
                    "worker",
                    address,
                    "--nworkers",
                    "1",
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    *map(str, tls),
                ],
                cwd=tmp_path,
                **quiet,
            )  # fmt: skip
        )
        from distributed import Client
        from distributed.security import Security

        security = Security(
            tls_ca_file=str(pem["ca"]), tls_client_cert=str(pem["cert"]), tls_client_key=str(pem["key"])
        )
        with Client(address, security=security, timeout=60) as client:
            client.wait_for_workers(1, timeout=60)
        plots = soybean / "plots.geojson"
        done = season(soybean, "--plots", plots, "--out", tmp_path / "out", "--scheduler", address, *tls)
        assert done.returncode == 0, done.stderr
        assert (tmp_path / "out" / "season.csv").read_bytes() == (serial / "season.csv").read_bytes()
        # Without the key, the TLS scheduler cannot be joined: one line, nothing written.
        plain = season(soybean, "--plots", plots, "--out", tmp_path / "plain", "--scheduler", address)
        assert plain.returncode == 2 and "needs --tls-ca-file, --tls-cert, --tls-key" in plain.stderr
        assert not (tmp_path / "plain" / "season.csv").exists()
    finally:
        _stop(procs)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--scheduler", "tcp://192.0.2.7:8786"], "refusing the plain-TCP scheduler `tcp://192.0.2.7:8786`"),
        (["--scheduler", "tls://127.0.0.1:8786"], "needs --tls-ca-file, --tls-cert, --tls-key"),
        (["--scheduler", "tcp://127.0.0.1:1", "--tls-cert", "x.pem"], "use a tls:// address"),
        (["--tls-key", "x.pem"], "are for a tls:// --scheduler"),
    ],
)
def test_schedulers_that_need_a_key_are_refused_before_any_work(soybean, tmp_path, args, words):
    done = season(soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path / "out", *args)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], done.stderr
    assert not (tmp_path / "out" / "season.csv").exists()


@pytest.mark.parametrize("command", ["season", "traits"])
def test_without_the_season_extra_the_commands_say_so_before_any_work(soybean, tmp_path, command):
    # A base install (no matplotlib): `season` measured every date, then stopped with a traceback and
    # no table; `traits` left an empty folder. Now one line, after the inputs' checks and before any
    # work, naming the extra.
    hide = "import sys, runpy; sys.modules['matplotlib'] = None; sys.argv[0] = 'cliff-terrain'; "
    hide += "runpy.run_module('cliff_terrain', run_name='__main__')"
    args = [soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path / "out", "--workers", "0"]
    args += ["--no-progress"]
    if command == "traits":
        (tmp_path / "season").mkdir()
        (tmp_path / "season" / "season.csv").write_text("plot,date,cover\n0,2018-08-15,0.5\n")
        args = [tmp_path / "season", "--out", tmp_path / "out"]
    done = subprocess.run(
        [sys.executable, "-c", hide, command, *map(str, args)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs matplotlib, which is not installed" in lines[0], done.stderr
    assert "pip install 'cliff-terrain[season]'" in lines[0] and "pip install '.[season]'" in lines[0]
    assert not (tmp_path / "out").exists()


def test_insecure_joins_a_plain_tcp_scheduler_elsewhere(soybean, tmp_path):
    pytest.importorskip("distributed", reason="the `season` extra (dask[distributed]) is not installed")
    # 192.0.2.0/24 is TEST-NET-1: nothing answers, so --insecure gets as far as trying to connect.
    done = season(
        soybean, "--plots", soybean / "plots.geojson", "--out", tmp_path / "out",
        "--scheduler", "tcp://192.0.2.7:8786", "--insecure", "--timeout", "1",
    )  # fmt: skip
    assert done.returncode == 2
    assert "cannot reach the Dask scheduler `tcp://192.0.2.7:8786` within 1 s" in done.stderr


def test_an_attribute_named_like_a_season_column_gets_the_suffix_plots_csv_gives_it():
    # A layout from `cliff-terrain plots` carries its 1-based `plot` number; season.csv called it
    # `attr_plot` while plots.csv called it `plot_attr`.
    from cliff_terrain.io.vector.plot_polygons import PlotSet
    from cliff_terrain.measure.field_plots import table_columns
    from cliff_terrain.season.table import season_columns

    square = [np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])]
    plots = PlotSet(
        [square] * 2, [{"plot": 1, "entry": "G1"}, {"plot": 2, "entry": "G2"}], ("plot", "entry"), None, ""
    )
    season = season_columns(plots)
    assert season[:6] == ("date", "date_source", "image", "plot", "plot_attr", "entry")
    assert table_columns(plots)[:3] == ["plot", "plot_attr", "entry"]
