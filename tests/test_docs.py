"""Docs that work when pasted and stay true: every core docstring example, every example on the
README and the docs' pages (run, or said which test runs it or why it cannot run), and the pages'
lists and tables that mirror the code (public names, parameters, stages, layout) checked against it."""

from __future__ import annotations

import csv
import dataclasses
import doctest
import importlib
import os
import pkgutil
import re
import stat
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, load_script

import cliff_terrain

DOCS = REPO / "docs"
PAGES = [REPO / "README.md", *sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts)]
RUN = {"python", "bash"}
# Blocks that are not examples: directory trees and outputs, and the docs' own directives.
OTHER = {"text", "{eval-rst}", "{toctree}", "{include}"}
FENCE = re.compile(r"^```(\S*)\n(.*?)^```$", re.M | re.S)
NOT_RUN = re.compile(r"<!-- not run(?: here)?: (.+?) -->")

# Modules whose examples need the command-line extras (Dask, matplotlib) import them lazily, so
# every module imports here; examples that need files of the user's are marked +SKIP in place.
MODULES = sorted(
    name
    for _, name, _ in pkgutil.walk_packages(cliff_terrain.__path__, "cliff_terrain.")
    if not name.endswith("__main__")
)


def _name(path):
    return str(path.relative_to(REPO))


def code_blocks(path):
    """[(language, code, reason it is not run or None)] of a Markdown page, in order."""
    text = path.read_text()
    found = []
    for match in FENCE.finditer(text):
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        reason = NOT_RUN.fullmatch(before.strip())
        found.append((match.group(1), match.group(2), reason.group(1) if reason else None))
    return found


def run_page(path, folder, capsys):
    """Run a page's examples in order in `folder`: Python in one namespace, shell with bash -e, with
    `cliff-terrain` the command of this checkout (as `pip install .` would make it)."""
    bin_dir = folder / ".bin"
    bin_dir.mkdir()
    shim = bin_dir / "cliff-terrain"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m cliff_terrain "$@"\n')
    shim.chmod(shim.stat().st_mode | stat.S_IEXEC)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    namespace, outputs = {}, []
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        for language, code, reason in code_blocks(path):
            if reason is not None or language not in RUN:
                continue
            if language == "python":
                exec(compile(code, _name(path), "exec"), namespace)
                outputs.append(capsys.readouterr().out)
            else:
                proc = subprocess.run(
                    ["bash", "-euo", "pipefail", "-c", code], env=env, capture_output=True, text=True
                )
                assert proc.returncode == 0, f"{_name(path)}: `{code.strip()}` failed:\n{proc.stderr}"
                outputs.append(proc.stdout + proc.stderr)
    finally:
        os.chdir(cwd)
    return namespace, "".join(outputs)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(
        module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (see above)"


@pytest.mark.parametrize("page", PAGES, ids=_name)
def test_every_code_block_is_an_example_that_runs_or_says_why_not(page):
    for language, code, reason in code_blocks(page):
        assert language in RUN | OTHER, f"{_name(page)}: a block in {language or 'no language'!r}:\n{code}"
        if reason is None:
            continue
        assert language in RUN, f"{_name(page)}: a {language} block marked 'not run'"
        assert len(reason.split()) >= 4, f"{_name(page)}: say why this block is not run: {reason!r}"
        for test in re.findall(r"tests/[\w/]+\.py", reason):
            assert (REPO / test).is_file(), f"{_name(page)}: {test} (named as running a block) is missing"


# Pages whose examples have their own test below, with assertions on what they print and write.
DEDICATED = ("README.md", "docs/api.md", "docs/cli.md")


def _runnable(page):
    return any(language in RUN and reason is None for language, _, reason in code_blocks(page))


def test_every_other_page_with_examples_runs_them(tmp_path, capsys):
    assert all(_runnable(REPO / name) for name in DEDICATED)
    for page in PAGES:
        if _name(page) not in DEDICATED and _runnable(page):
            folder = tmp_path / _name(page).replace("/", "_")
            folder.mkdir()
            run_page(page, folder, capsys)


@pytest.mark.parametrize("page", ["README.md", "docs/api.md"])
def test_the_python_example_runs(page, tmp_path, capsys):
    namespace, out = run_page(REPO / page, tmp_path, capsys)
    relief, truth = namespace["relief"], namespace["truth"]
    assert f"{relief.n_regions} plants, {truth.n_plants} drawn" in out
    assert relief.n_regions == pytest.approx(truth.n_plants, rel=0.2)
    assert np.isfinite(relief.heights).all()


@pytest.mark.slow
def test_the_command_line_guide_runs_from_files_to_tables_and_pictures(tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the `season` extra (matplotlib) is not installed")
    _, out = run_page(DOCS / "cli.md", tmp_path, capsys)

    def rows(path):
        with open(tmp_path / path, newline="") as stream:
            return list(csv.DictReader(stream))

    for name in ("height.tif", "mask.png", "labels.tif", "regions.csv", "relief.json"):
        assert (tmp_path / "field_relief" / name).is_file(), name
    assert len(rows("field_relief/regions.csv")) > 10  # the demo field's plants
    plots = rows("heights/plots.csv")
    assert [p["plot_attr"] if "plot_attr" in p else p["plot"] for p in plots] and len(plots) == 6
    # The synthetic plants are 30-60 cm tall on the last date: the plots' p90 lies below their tops.
    assert all(0.0 < float(p["height_p90_m"]) < 0.6 for p in plots), plots
    season = rows("season/season.csv")
    assert len(season) == 4 * 6 and {r["height_mode"] for r in season} == {"measured"}
    assert sorted({r["date"] for r in season}) == ["2024-06-01", "2024-06-08", "2024-06-15", "2024-06-22"]
    traits = rows("season/traits/traits.csv")
    assert len(traits) == 6 and all(np.isfinite(float(t["max_height_m"])) for t in traits)
    for picture in ("season/growth.png", "season/traits/growth.png", "season/traits/traits_map.png"):
        assert (tmp_path / picture).stat().st_size > 1000, picture
    assert "wrote" in out


def test_the_api_reference_documents_every_public_name():
    text = (DOCS / "api.md").read_text()
    documented = set(re.findall(r"\.\. auto(?:function|class|exception):: cliff_terrain\.(\w+)\n", text))
    assert documented == set(cliff_terrain.__all__) - {"__version__"}


def test_the_parameter_table_names_every_setting_with_its_default():
    from cliff_terrain.params import ReliefParams

    text = (DOCS / "api.md").read_text()
    section = text.split("## Parameters\n", 1)[1].split("\n## ", 1)[0]
    table = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 3:
            for name in re.findall(r"`(\w+)`", cells[0]):
                table[name] = cells[1]
    fields = {f.name: f.default for f in dataclasses.fields(ReliefParams)}
    assert set(table) == set(fields) | {"progress"}
    for name, default in fields.items():
        shown = table[name].strip("`")
        expected = f'"{default}"' if isinstance(default, str) else repr(default)
        assert shown == expected, f"{name}: the table says {table[name]}, ReliefParams {default!r}"


def test_the_parameter_table_is_made_from_the_declarations():
    tool = load_script(REPO / "tools" / "parameter_table.py", "_parameter_table")
    text = (DOCS / "api.md").read_text()
    assert tool.page_table(text) == tool.parameter_table(), (
        "docs/api.md's parameters are not their declarations': run `python tools/parameter_table.py --write`"
    )
    # The table says what the command line and the sidebar show: each option, label and limit.
    from cliff_terrain.settings import PARAMETERS

    table = tool.page_table(text)
    for parameter in PARAMETERS.values():
        assert f"`{parameter.flag}`" in table and parameter.limits in table
        assert not parameter.sidebar or f"*{parameter.label}*" in table


def test_the_architecture_lists_the_stages_the_architecture_test_enforces():
    import test_architecture

    text = (DOCS / "development.md").read_text()
    section = text.split("## The architecture\n", 1)[1].split("\n## ", 1)[0]
    tree = FENCE.search(section).group(2)
    listed = [line.split()[0].rstrip("/").removesuffix(".py") for line in tree.splitlines() if line.strip()]
    assert tuple(listed) == test_architecture.STAGES
    for stage in listed:
        core = REPO / "cliff_terrain"
        assert (core / stage).is_dir() or (core / f"{stage}.py").is_file(), stage
    shared = re.search(r"Shared by all: (.*?)\. Each stage", section, flags=re.S).group(1)
    named = {m.removesuffix(".py") for m in re.findall(r"`(\w+\.py)`", shared)}
    assert named == test_architecture.SHARED


def test_the_layout_names_what_is_there():
    text = (DOCS / "development.md").read_text()
    tree = FENCE.search(text.split("## The layout\n", 1)[1]).group(2)
    for line in tree.splitlines():
        if line and not line.startswith(" "):
            assert (REPO / line.split()[0]).exists(), line.split()[0]


def test_the_readme_is_a_front_page_whose_figures_stand_on_the_pages_it_links():
    text = (REPO / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    section = text.split("## Key figures\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and "](" in line]
    assert len(rows) >= 6
    for row in rows:
        _, figure, where = [c.strip() for c in row.strip().strip("|").split("|")]
        page = (REPO / re.search(r"\]\(([^)#]+)", where).group(1)).read_text()
        for number in re.findall(r"[−+]?\d+\.\d+(?:-\d+(?:\.\d+)?)?", figure):
            assert number in page, f"README's {number!r} is not on {where}"
    # Every page the README links to exists.
    for link in re.findall(r"\]\(((?:docs/|CHANGES)[^)#]*)", text):
        assert (REPO / link).exists(), link


def test_the_docs_and_the_changelog_stay_out_of_the_extension_zip(tmp_path):
    import tomllib
    import zipfile

    manifest = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    patterns = manifest["build"]["paths_exclude_pattern"]
    # Blender's builder leaves these out ...
    assert {"/docs/", "/CHANGES.md", "/requirements*.txt", "/.venv*/"} <= set(patterns)
    # ... and tools/build_extension.py refuses a zip that holds them all the same.
    tool = load_script(REPO / "tools" / "build_extension.py", "_build_extension")
    for leaked in ("docs/index.md", "CHANGES.md"):
        archive_path = tmp_path / f"{leaked.replace('/', '_')}.zip"
        with zipfile.ZipFile(archive_path, "w") as archive:
            archive.writestr("blender_manifest.toml", 'id = "cliff_terrain"\nblender_version_min = "4.2.0"\n')
            for name in (
                "__init__.py",
                "cliff_terrain/__init__.py",
                "operators/__init__.py",
                "scene/__init__.py",
                "panels/__init__.py",
                leaked,
            ):
                archive.writestr(name, "")
        with pytest.raises(tool.BuildError, match=f"must be excluded, e.g. {leaked}"):
            tool.check_zip(archive_path, {"3.11": []}, "cliff_terrain", packages=())


def _table_names(text, header, pattern=r"`([^`]+)`"):
    """The backticked names in the first column of the Markdown table under `header`."""
    section = text.split(header + "\n", 1)[1].split("\n\n", 1)[0]
    names = set()
    for line in section.splitlines()[1:]:
        if line.startswith("| "):
            names |= set(re.findall(pattern, line.strip().strip("|").split("|")[0]))
    return names


def test_the_render_views_tables_name_its_options_and_outputs():
    sys.path.insert(0, str(REPO))
    try:
        import render_views
    finally:
        sys.path.remove(str(REPO))
    from cliff_terrain.figures.writer import OUTPUTS

    text = (DOCS / "cli.md").read_text()
    parser = render_views.build_parser()
    options = {o for a in parser._actions for o in a.option_strings if o.startswith("--")} - {"--help"}
    assert _table_names(text, "| option | default | meaning |", r"`(--[a-z-]+)") == options
    assert _table_names(text, "| file | what |") == set(OUTPUTS)


def test_the_index_table_is_the_indices_the_code_defines():
    from cliff_terrain.photo_heights.indices import INDICES

    text = (DOCS / "concepts" / "multispectral.md").read_text()
    section = text.split("| index | formula | bands | reference |\n", 1)[1].split("\n\n", 1)[0]
    listed = {line.split("|")[1].strip() for line in section.splitlines()[1:] if line.startswith("| ")}
    assert listed == set(INDICES)


def test_the_definitions_table_names_every_key_figure():
    from cliff_terrain import build_relief, synthetic_field
    from cliff_terrain.measure.key_figures import key_figures

    image, _ = synthetic_field(shape=(120, 160), seed=1)
    figures = key_figures(build_relief(image, max_size=160, gsd=0.01, mesh=None))
    text = (DOCS / "concepts" / "ground.md").read_text()
    assert _table_names(text, "| key | definition |") == set(figures) - {"units"}


def _table_rows(text, header):
    """{first cell: [other cells]} of the Markdown table under `header`."""
    section = text.split(header + "\n", 1)[1].split("\n\n", 1)[0]
    rows = {}
    for line in section.splitlines()[1:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def test_the_ground_pages_real_field_figures_are_the_validation_records():
    # The concept page quotes the validation record by hand; it drifted once (day 90 and soybean
    # kept figures of an earlier record), so each quoted r / RMSE is checked against it.
    import json

    record = json.loads((REPO / "bench" / "validation_record.json").read_text())

    def figure(key, field, date, against, who):
        (row,) = [f for f in record[key] if f["field"] == field and f["date"] == date]
        m = row["against"][against][who]
        return f"{m['r']:.3f} / {m['rmse_cm']:.1f} cm"

    text = (DOCS / "concepts" / "ground.md").read_text()
    d = "potato_fieldimager_d55_d90"
    quoted = {
        "potato, day 40 (open rows on ridges)": ("potato_fieldimager", "40", "aligned"),
        "potato, day 55": (d, "55", "aligned"),
        "potato, day 90 (closed canopy)": (d, "90", "aligned"),
        "potato, day 100": ("potato_fieldimager", "100", "aligned"),
        "second potato trial, surface model alone": ("potato_fieldimager_ex1", "vegetative", "aligned"),
        "soybean, vegetative (pliman's example; against DSM minus its DTM, aligned on the soil)": (
            "soybean_pliman",
            "vegetative",
            "aligned",
        ),
        "soybean, the same against DSM minus its DTM as published (the DTM lies 4.5 cm below the soil)": (
            "soybean_pliman",
            "vegetative",
            "raw",
        ),
    }
    rows = _table_rows(text, "| field, date | ours | naive baseline |")
    assert set(rows) == set(quoted)
    for label, where in quoted.items():
        assert rows[label] == [figure("fields", *where, "ours"), figure("fields", *where, "baseline")], label
    recoloured = _table_rows(
        text, "| date | straw, now | straw, before | golden, now | golden, before | naive baseline |"
    )
    dates = {
        "day 40": ("potato_fieldimager", "40"),
        "day 55": (d, "55"),
        "day 90 (closed canopy)": (d, "90"),
        "day 100": ("potato_fieldimager", "100"),
    }
    assert set(recoloured) == set(dates)
    for label, (field, date) in dates.items():
        straw, _, golden, _, baseline = recoloured[label]
        assert straw == figure("fields_straw", field, date, "aligned", "ours"), label
        assert golden == figure("fields_golden", field, date, "aligned", "ours"), label
        assert baseline == figure("fields", field, date, "aligned", "baseline"), label
    # The README's table row quotes each potato date's r / RMSE / bias, ours then the baseline's.
    line = next(x for x in (REPO / "README.md").read_text().splitlines() if "single-flight per-plot p90" in x)
    quoted = re.findall(r"day (\d+): ([^(]+?) \(naive baseline|day (\d+): ([^(]+?) \(baseline", line)
    baselines = re.findall(r"baseline ([0-9.]+ / [0-9.]+ cm / [−+][0-9.]+ cm)", line)
    assert len(quoted) == len(baselines) == 4
    for (d1, ours1, d2, ours2), theirs in zip(quoted, baselines, strict=True):
        date, ours = d1 or d2, ours1 or ours2
        (row,) = [
            f for f in record["fields"] if f["date"] == date and f["field"].startswith("potato_fieldimager")
        ]

        def full(m):
            return f"{m['r']:.3f} / {m['rmse_cm']:.1f} cm / {m['bias_cm']:+.1f} cm".replace("-", "−")

        assert ours.strip().rstrip(";").strip() == full(row["against"]["aligned"]["ours"]), date
        assert theirs == full(row["against"]["aligned"]["baseline"]), date
