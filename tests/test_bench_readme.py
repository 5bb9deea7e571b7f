"""bench/run_all.py writes the README's benchmark table between its markers, and only there."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_all():
    spec = importlib.util.spec_from_file_location("run_all", ROOT / "bench" / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_table_goes_between_the_markers_and_replaces_the_last_one(run_all, tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"# Title\n\nbefore\n\n{run_all.BEGIN}\nold | table\n{run_all.END}\n\nafter\n")
    run_all.write_readme([("filter", "33.5 ms", "1263 ms", "37.7x", ">= 10x (met)")], readme=readme)
    run_all.write_readme([("a|b", "1 s", "", "2.00x", "")], readme=readme)
    text = readme.read_text()
    assert text.startswith("# Title\n\nbefore\n\n") and text.endswith(f"{run_all.END}\n\nafter\n")
    block = text.split(run_all.BEGIN, 1)[1].split(run_all.END, 1)[0]
    assert "Measured by `make bench` on " in block and "old | table" not in block and "filter" not in block
    # The header, its rule, then one row; a "|" inside a cell is escaped.
    assert block.strip().splitlines()[-3:] == [
        "| what | ours | peer | ratio | goal |",
        "|---|---|---|---|---|",
        "| a\\|b | 1 s |  | 2.00x |  |",
    ]


def test_a_readme_without_the_markers_is_refused_and_left_alone(run_all, tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# Title\n")
    with pytest.raises(RuntimeError, match="needs one"):
        run_all.write_readme([("a", "b", "c", "d", "e")], readme=readme)
    assert readme.read_text() == "# Title\n"


def test_the_project_readme_has_the_markers(run_all):
    text = (ROOT / "README.md").read_text()
    assert text.count(run_all.BEGIN) == 1 and text.count(run_all.END) == 1
    assert text.index(run_all.BEGIN) < text.index(run_all.END)
