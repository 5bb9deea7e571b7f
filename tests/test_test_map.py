"""The map of which tests test which core module (tests/TEST_MAP.md, made by tools/test_map.py) is
current, and no module of the core with code is left without a test file."""

from pathlib import Path

from conftest import load_script

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    return load_script(ROOT / "tools" / "test_map.py", "_test_map")


TOOL = _tool()


def test_every_core_module_with_code_has_a_test_file():
    table = TOOL.test_map()
    missing = [m for m, (files, how) in table.items() if not files and how != "a package: see its modules"]
    assert not missing, (
        "core modules no test file imports: "
        + ", ".join(missing)
        + " (add a test, or name the tests that run them in tools/test_map.py's REACHED_THROUGH)"
    )


def test_the_map_names_existing_tests_and_no_stale_way_in():
    tests = {p.name for p in (ROOT / "tests").glob("test_*.py")}
    modules = TOOL.core_modules()
    table = TOOL.test_map()
    for module, (files, _how) in TOOL.REACHED_THROUGH.items():
        assert module in modules, f"REACHED_THROUGH names {module}, which is not in the core"
        assert set(files) <= tests, f"{module}: no such test file among {sorted(set(files) - tests)}"
        # A module a test imports needs no entry: the imports say it.
        assert table[module][1] != "imports", (
            f"{module} is imported by a test: remove it from REACHED_THROUGH"
        )


def test_the_map_in_tests_is_current():
    assert TOOL.MAP.read_text() == TOOL.markdown(TOOL.test_map()), (
        "tests/TEST_MAP.md is out of date: run `python tools/test_map.py --write`"
    )


def test_a_module_without_tests_is_found(tmp_path, monkeypatch):
    """The check above on a core with one more module that nothing tests."""
    core = tmp_path / "cliff_terrain"
    (core / "io").mkdir(parents=True)
    (core / "__init__.py").write_text('"""The core."""\n')
    (core / "io" / "__init__.py").write_text('"""Readers."""\n')
    (core / "io" / "tested.py").write_text("def read():\n    return 1\n")
    (core / "io" / "untested.py").write_text("def write():\n    return 2\n")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_io.py").write_text("from cliff_terrain.io.tested import read\n")
    monkeypatch.setattr(TOOL, "ROOT", tmp_path)
    monkeypatch.setattr(TOOL, "CORE", core)
    monkeypatch.setattr(TOOL, "TESTS", tmp_path / "tests")
    monkeypatch.setattr(TOOL, "REACHED_THROUGH", {})
    assert TOOL.test_map() == {
        "cliff_terrain": ([], "a package: see its modules"),
        "cliff_terrain.io": ([], "a package: see its modules"),
        "cliff_terrain.io.tested": (["test_io.py"], "imports"),
        "cliff_terrain.io.untested": ([], ""),
    }
