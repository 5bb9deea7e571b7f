"""Progress and interruption of the measuring commands (issue 40): tqdm's bar with an ETA on a
terminal and none elsewhere; Ctrl-C or a kill leaves no output that looks complete, and the same
command then runs again without ``--overwrite``."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import pty
import re
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest
from conftest import REPO

from cliff_terrain import cli
from cliff_terrain.measure.tables import RENAMING_JOURNAL

ODM_PAIR = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"
ORTHO, DSM = ODM_PAIR / "odm_orthophoto.tif", ODM_PAIR / "dsm.tif"
OUTPUTS = ["chm.tif", "chm_err.tif", "ground_support.tif", "regions.csv", "regions.geojson", "summary.json"]


@pytest.fixture
def pair():
    if not ORTHO.is_file():
        pytest.skip(f"the shared OpenDroneMap pair is not at {ODM_PAIR}")
    return ORTHO, DSM


def heights_args(out, *extra):
    return ["heights", str(ORTHO), "--dsm", str(DSM), "--out", str(out), *extra]


def on_a_terminal(args):
    """Run the CLI with stderr on a pseudo-terminal; returns (status, what the terminal showed)."""
    pytest.importorskip("tqdm")
    main, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a 100 x 24 terminal
    proc = subprocess.Popen(
        [sys.executable, "-m", "cliff_terrain", *args], stdout=subprocess.DEVNULL, stderr=child, cwd=REPO
    )
    os.close(child)
    shown = b""
    while True:
        try:
            chunk = os.read(main, 4096)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        shown += chunk
    os.close(main)
    return proc.wait(timeout=600), shown.decode("utf-8", "replace")


def test_a_terminal_gets_tqdms_bar_with_an_eta_and_no_progress_silences_it(pair, tmp_path):
    status, shown = on_a_terminal(heights_args(tmp_path / "a"))
    assert status == 0, shown
    # tqdm's bar: the percentage, elapsed<remaining (the ETA), the stage being run; cleared at the end.
    assert "heights odm_orthophoto.tif" in shown and re.search(r"\d+%\|", shown), shown
    assert re.search(r"\d\d:\d\d<\d\d:\d\d", shown), shown
    assert "segment" in shown, shown  # the stages' names, as build_relief reports them
    status, shown = on_a_terminal(heights_args(tmp_path / "b", "--no-progress"))
    assert status == 0 and shown == "", shown


def test_ctrl_c_while_writing_leaves_nothing_and_the_command_runs_again(pair, tmp_path, monkeypatch, capsys):
    import cliff_terrain.io.raster.geotiff as geotiff

    out = tmp_path / "out"
    real = geotiff.write_geotiff
    calls = []

    def interrupted(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:  # the second raster: the tables and chm.tif already written
            raise KeyboardInterrupt
        return real(path, *args, **kwargs)

    monkeypatch.setattr(geotiff, "write_geotiff", interrupted)
    assert cli.main(heights_args(out, "--no-progress")) == 130
    assert capsys.readouterr().err == "cliff-terrain heights: interrupted\n"
    assert sorted(p.name for p in out.iterdir()) == []  # no output, complete-looking or not
    monkeypatch.setattr(geotiff, "write_geotiff", real)
    assert cli.main(heights_args(out, "--no-progress")) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUTS)


def test_a_killed_runs_leftovers_are_replaced_and_a_finished_run_is_kept(pair, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    # What a kill during the renames leaves: some outputs without summary.json (renamed last), the
    # journal of the renames, and a dead process's .part file.
    (out / "chm.tif").write_bytes(b"half of a raster")
    (out / "regions.csv").write_text("id\n")
    (out / RENAMING_JOURNAL).write_text("chm.tif\nregions.csv\nsummary.json\n")
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    (out / f"summary.json.part-{dead.stdout.strip()}").write_text("{")
    (out / "notes.txt").write_text("the user's own file\n")
    done = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *heights_args(out, "--no-progress")],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted([*OUTPUTS, "notes.txt"])
    assert json.loads((out / "summary.json").read_text())["ground"] == "estimated"
    assert (out / "notes.txt").read_text() == "the user's own file\n"
    # A finished run (its summary.json there) is kept: the same command now refuses in one line.
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = subprocess.run(
        [sys.executable, "-m", "cliff_terrain", *heights_args(out, "--no-progress")],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "--overwrite" in again.stderr
    assert {p.name: p.read_bytes() for p in Path(out).iterdir()} == before


def test_writers_run_at_once_all_or_nothing_and_the_first_error_is_raised(tmp_path):
    # The windowed rasters are written on threads: the writers overlap, and a failing one leaves
    # none of the files (not even the text written before), raising its own error.
    import threading

    from cliff_terrain.measure.tables import write_files

    both = threading.Barrier(2, timeout=10)  # each writer waits for the other: only at once can they pass

    def writer(tmp):
        both.wait()
        Path(tmp).write_bytes(b"tiff")

    write_files(
        {tmp_path / "a.tif": writer, tmp_path / "b.tif": writer, tmp_path / "s.json": "{}"}, threads=2
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.tif", "b.tif", "s.json"]

    def broken(tmp):
        Path(tmp).write_bytes(b"half")
        raise OSError("disk full")

    out = tmp_path / "again"
    out.mkdir()
    with pytest.raises(OSError, match="disk full"):
        write_files({out / "s.json": "{}", out / "a.tif": broken, out / "b.tif": lambda tmp: None}, threads=2)
    assert list(out.iterdir()) == []


def test_a_users_own_files_in_out_are_never_replaced_without_overwrite_nor_an_input_ever(pair, tmp_path):
    # A folder holding the user's own field book as plots.csv and their plots as plots.geojson: names
    # the command writes, but no finished run's (no summary.json) nor an interrupted one's (no
    # journal). Until 2026-12-06 both were taken for leftovers and replaced.
    ortho, dsm = pair
    out = tmp_path / "trial"
    out.mkdir()
    book = "plot,genotype\n1,G1\n"
    (out / "plots.csv").write_text(book)
    original = (REPO / "tests" / "data" / "odm_plots_by_hand.geojson").read_text()
    (out / "plots.geojson").write_text(original)
    base = [sys.executable, "-m", "cliff_terrain", "heights", str(ortho), "--dsm", str(dsm), "--no-progress"]
    plots = tmp_path / "plots.geojson"
    plots.write_text(original)
    done = subprocess.run(
        [*base, "--plots", str(plots), "--out", str(out)], capture_output=True, text=True, cwd=REPO
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert f"'{out / 'plots.csv'}' exists; pass --overwrite to replace it" in done.stderr
    # The plots read from the folder the tables go to: refused, --overwrite or not.
    for extra in ((), ("--overwrite",)):
        done = subprocess.run(
            [*base, "--plots", str(out / "plots.geojson"), "--out", str(out), *extra],
            capture_output=True,
            text=True,
            cwd=REPO,
        )
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert (
            f"--plots '{out / 'plots.geojson'}' is where --out '{out}' writes its plots.geojson: "
            "the run would replace its own input; give another --out"
        ) in done.stderr
    assert (out / "plots.csv").read_text() == book and (out / "plots.geojson").read_text() == original
    assert sorted(p.name for p in out.iterdir()) == ["plots.csv", "plots.geojson"]


def test_ctrl_c_on_a_local_clusters_terminal_prints_one_line_and_leaves_nothing(pair, tmp_path):
    # A terminal's Ctrl-C reaches the whole process group: each Dask worker printed its
    # KeyboardInterrupt traceback (67 lines on stderr) before "interrupted", until 2026-12-06.
    import signal
    import time

    from conftest import load_script

    pytest.importorskip("distributed")
    field = tmp_path / "field"
    field.mkdir()
    load_script(REPO / "bench" / "bench_scale.py", "bench_scale").build_field(4, field, target_plots=300)
    out = tmp_path / "out"
    command = ["heights", str(field / "ortho.tif"), "--dsm", str(field / "dsm.tif"), "--out", str(out)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "cliff_terrain", *command, "--no-progress", "--windowed", "--window", "64",
         "--workers", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a shell starts it
    )  # fmt: skip

    def read(path):  # a thread or a short-lived child can end between a listing and a read
        try:
            return path.read_bytes()
        except (FileNotFoundError, ProcessLookupError):
            return b""

    def workers():  # the cluster's worker processes: children of any of this run's threads
        with contextlib.suppress(FileNotFoundError):
            tasks = list(Path(f"/proc/{proc.pid}/task").iterdir())
            children = (child for task in tasks for child in read(task / "children").split())
            return [c for c in children if b"spawn_main" in read(Path(f"/proc/{c.decode()}/cmdline"))]
        return []

    def ignores_ctrl_c():  # while it starts the cluster, this process ignores SIGINT too
        status = Path(f"/proc/{proc.pid}/status").read_text()
        mask = int(next(line for line in status.splitlines() if line.startswith("SigIgn:")).split()[1], 16)
        return bool(mask & (1 << (signal.SIGINT - 1)))

    deadline = start = time.monotonic()
    deadline += 120
    seen = []  # (seconds, workers, ignoring) as they changed: what the failure message shows
    while time.monotonic() < deadline and proc.poll() is None:
        with contextlib.suppress(FileNotFoundError, StopIteration):
            state = (len(workers()), ignores_ctrl_c())
            if not seen or seen[-1][1:] != state:
                seen.append((round(time.monotonic() - start, 2), *state))
            if state[0] >= 2 and not state[1]:
                break
        time.sleep(0.05)
    assert proc.poll() is None, f"the run ended before it could be interrupted: {seen}, {proc.communicate()}"
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal sends it: to every process of the group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and err == "cliff-terrain heights: interrupted\n", err
    assert not (out / "summary.json").exists()


def test_overwrite_removes_the_earlier_runs_outputs_this_run_does_not_write_and_keeps_the_users(
    pair, tmp_path
):
    # A run with plots, then one without them (and windowed: no regions) over it with --overwrite:
    # the first run's plots.csv and regions stood beside the second's summary, a folder mixing two
    # runs that looked complete.
    out = tmp_path / "out"
    plots = REPO / "tests" / "data" / "odm_plots_by_hand.geojson"
    assert cli.main([*heights_args(out, "--no-progress"), "--plots", str(plots)]) == 0
    assert {"plots.csv", "regions.csv"} <= {p.name for p in out.iterdir()}
    assert cli.main([*heights_args(out, "--no-progress"), "--overwrite", "--windowed"]) == 0
    windowed = ["chm.tif", "chm_err.tif", "ground_support.tif", "summary.json"]
    assert sorted(p.name for p in out.iterdir()) == windowed
    # Files of those names with no earlier run's summary.json (nor its journal) are the user's: kept.
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "plots.csv").write_text("plot,genotype\n1,G1\n")
    assert cli.main([*heights_args(mine, "--no-progress"), "--overwrite"]) == 0
    assert (mine / "plots.csv").read_text() == "plot,genotype\n1,G1\n"
    # ... and so they stay beside a finished run that did not write them (its summary.json lists
    # what it wrote): a reviewer's only copy of the plots was deleted so.
    (mine / "plots.geojson").write_text("{}")
    assert cli.main([*heights_args(mine, "--no-progress"), "--overwrite"]) == 0
    assert (mine / "plots.geojson").read_text() == "{}" and (mine / "plots.csv").is_file()
    # A summary.json of a run from before it listed its outputs: nothing is taken for that run's.
    (mine / "summary.json").write_text('{"ground": "estimated"}')
    assert cli.main([*heights_args(mine, "--no-progress"), "--overwrite"]) == 0
    assert (mine / "plots.geojson").read_text() == "{}" and (mine / "plots.csv").is_file()
