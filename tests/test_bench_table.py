"""bench/run_all.py writes the benchmark table of docs/benchmarks.md between its markers, and only there."""

from pathlib import Path

import pytest
from conftest import load_script

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_all():
    return load_script(ROOT / "bench" / "run_all.py", "run_all")


def test_the_table_goes_between_the_markers_and_replaces_the_last_one(run_all, tmp_path):
    page = tmp_path / "benchmarks.md"
    page.write_text(f"# Title\n\nbefore\n\n{run_all.BEGIN}\nold | table\n{run_all.END}\n\nafter\n")
    run_all.write_page([("filter", "33.5 ms", "1263 ms", "37.7x", ">= 10x (met)")], page=page)
    run_all.write_page([("a|b", "1 s", "", "2.00x", "")], page=page)
    text = page.read_text()
    assert text.startswith("# Title\n\nbefore\n\n") and text.endswith(f"{run_all.END}\n\nafter\n")
    block = text.split(run_all.BEGIN, 1)[1].split(run_all.END, 1)[0]
    assert "Measured by `make bench` on " in block and "old | table" not in block and "filter" not in block
    # The header, its rule, then one row; a "|" inside a cell is escaped.
    assert block.strip().splitlines()[-3:] == [
        "| what | ours | peer | ratio | goal |",
        "|---|---|---|---|---|",
        "| a\\|b | 1 s |  | 2.00x |  |",
    ]


def test_a_page_without_the_markers_is_refused_and_left_alone(run_all, tmp_path):
    page = tmp_path / "benchmarks.md"
    page.write_text("# Title\n")
    with pytest.raises(RuntimeError, match="needs one"):
        run_all.write_page([("a", "b", "c", "d", "e")], page=page)
    assert page.read_text() == "# Title\n"


def test_the_benchmark_page_has_the_markers_and_a_table_between_them(run_all):
    assert run_all.PAGE == ROOT / "docs" / "benchmarks.md"
    text = run_all.PAGE.read_text()
    assert text.count(run_all.BEGIN) == 1 and text.count(run_all.END) == 1
    assert text.index(run_all.BEGIN) < text.index(run_all.END)
    block = text.split(run_all.BEGIN, 1)[1].split(run_all.END, 1)[0]
    # The machine it ran on, then the table's header: what run_all writes.
    assert "Measured by `make bench` on " in block and "| what | ours | peer | ratio | goal |" in block
    # The README no longer carries a copy of the table (one place, written by the run).
    assert run_all.BEGIN not in (ROOT / "README.md").read_text()
