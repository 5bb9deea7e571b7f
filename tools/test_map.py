"""Which test files test each module of the core: the table ``tests/TEST_MAP.md``.

    python tools/test_map.py           # print the table
    python tools/test_map.py --write   # write tests/TEST_MAP.md

A test file tests a module when it imports it (``from cliff_terrain.io.raster.bands import read_bands``;
``from cliff_terrain import build_relief`` or ``from cliff_terrain.io.photo import load_image``, a
package's public name, counts for the module that defines it; the Blender tests' ``cliff_terrain_addon.cliff_terrain...`` and
``f"{ADDON}.cliff_terrain..."`` too). A module no test imports is reached through another entry point
(the command line, ``build_relief``): :data:`REACHED_THROUGH` names the test files that exercise it
and how. ``tests/test_test_map.py`` fails when the table is not this script's output, or when a core
module with code has no test file.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "cliff_terrain"
TESTS = ROOT / "tests"
MAP = TESTS / "TEST_MAP.md"

# Modules no test file imports, with the test files that run them and the way in.
REACHED_THROUGH = {
    "cliff_terrain._lazy": (
        ("test_environment.py",),
        "the package's and the io subpackages' names, loaded when first used",
    ),
    "cliff_terrain.commands.cluster_options": (
        ("test_windowed_heights.py", "test_season.py"),
        "`heights --windowed --workers/--scheduler`, `season --scheduler`",
    ),
    "cliff_terrain.commands.heights_windowed": (
        ("test_windowed_heights.py",),
        "`cliff-terrain heights --windowed` (and past the memory cap)",
    ),
    "cliff_terrain.measure.grid_search": (
        ("test_plot_fit_corners.py", "test_plot_grid.py"),
        "`fit_grid`'s search along each axis",
    ),
    "cliff_terrain._progress": (
        ("test_interrupted_outputs.py",),
        "the commands' progress bar on a terminal (`--no-progress`)",
    ),
    "cliff_terrain.commands.out_folder": (
        ("test_interrupted_outputs.py", "test_bad_input_table.py"),
        "an interrupted run's outputs replaced, a finished run's kept",
    ),
    "cliff_terrain.__main__": (("test_cli.py",), "`python -m cliff_terrain`"),
    "cliff_terrain._memory": (("test_mosaic.py",), "`peak_rss` of a mosaic's build"),
    "cliff_terrain._validate": (
        ("test_pipeline.py", "test_bad_input_table.py"),
        "every entry point's checks",
    ),
    "cliff_terrain.commands.index_options": (("test_multispectral.py",), "`--indices` of the commands"),
    "cliff_terrain.commands.plots": (
        ("test_plot_grid.py", "test_plot_fit_reference.py"),
        "`cliff-terrain plots`",
    ),
    "cliff_terrain.commands.relief": (("test_cli.py",), "`cliff-terrain relief`"),
    "cliff_terrain.commands.season": (("test_season.py",), "`cliff-terrain season`"),
    "cliff_terrain.commands.synthetic": (("test_cli.py",), "`cliff-terrain synthetic`"),
    "cliff_terrain.commands.traits": (("test_traits.py",), "`cliff-terrain traits`"),
    "cliff_terrain.io.photo._camera": (("test_image_io.py",), "a photo's metadata"),
    "cliff_terrain.io.raster._geokeys": (("test_measured_heights.py", "test_season.py"), "reading GeoTIFFs"),
    "cliff_terrain.io.photo._pillow_pixels": (("test_image_io.py",), "decoding photos"),
    "cliff_terrain.season.align": (("test_season.py",), "`cliff-terrain season`"),
    "cliff_terrain.season.charts": (("test_season.py",), "`cliff-terrain season` (growth.png)"),
    "cliff_terrain.season.security": (("test_season.py",), "`cliff-terrain season --scheduler`"),
    "cliff_terrain.season.task": (("test_season.py",), "`cliff-terrain season` (one date)"),
    "cliff_terrain.season.trait_charts": (("test_traits.py",), "`cliff-terrain traits`"),
}

_ADDON_STRING = re.compile(
    r"""(?:cliff_terrain_addon\.|\{ADDON\}\.|ADDON \+ ["']\.)(cliff_terrain(?:\.\w+)*)"""
)


def core_modules():
    """{module name: path} of every module of the core, packages' ``__init__`` included."""
    found = {}
    for path in sorted(CORE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _lazy_exports(tree):
    """A package ``__init__``'s ``_EXPORTS`` table (public name -> its module, relative), or {}."""
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "_EXPORTS" for t in node.targets):
            return ast.literal_eval(node.value)
    return {}


def has_code(path):
    """True unless the module is only a docstring, imports and ``__all__`` (a package's ``__init__``
    mostly), or a package's table of lazily loaded public names (``_EXPORTS``, ``__getattr__``)."""
    tree = ast.parse(path.read_text())
    if path.name == "__init__.py" and path.parent != CORE and _lazy_exports(tree):
        return False
    return any(
        not isinstance(n, (ast.Import, ast.ImportFrom, ast.Expr)) and not _names_all(n) for n in tree.body
    )


def _names_all(node):
    return isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["__all__"]


def public_names():
    """{dotted public name of a package: the module defining it}, e.g. ``cliff_terrain.build_relief`` ->
    ``cliff_terrain.build`` (the packages load their public names lazily, from ``_EXPORTS``)."""
    names = {}
    for module, path in core_modules().items():
        if path.name != "__init__.py":
            continue
        tree = ast.parse(path.read_text())
        names.update({f"{module}.{k}": f"{module}.{v}" for k, v in _lazy_exports(tree).items()})
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                names.update({f"{module}.{a.name}": f"{module}.{node.module}" for a in node.names})
    return names


def imported_names(path):
    """Dotted names a test file imports (statically, lazy imports included)."""
    text = path.read_text()
    names = set(_ADDON_STRING.findall(text))
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {name.removeprefix("cliff_terrain_addon.") for name in names}


def test_map():
    """{core module: (sorted test file names, how: "imports" or the entry point)}."""
    modules = core_modules()
    public = public_names()
    importers = {m: set() for m in modules}
    for test in sorted(TESTS.glob("test_*.py")):
        for name in imported_names(test):
            name = public.get(name, name)
            parts = name.split(".")
            while parts and ".".join(parts) not in modules:
                parts.pop()
            if parts:
                importers[".".join(parts)].add(test.name)
    table = {}
    for module, path in modules.items():
        if importers[module]:
            table[module] = (sorted(importers[module]), "imports")
        elif module in REACHED_THROUGH:
            files, how = REACHED_THROUGH[module]
            table[module] = (sorted(files), how)
        elif not has_code(path):
            table[module] = ([], "a package: see its modules")
        else:
            table[module] = ([], "")
    return table


def markdown(table):
    lines = [
        "# Which tests test which module of the core",
        "",
        "Generated by `python tools/test_map.py --write` (checked by `tests/test_test_map.py`). Run one",
        "module's tests with `python -m pytest tests/FILE.py`; the Blender ones need bpy (`.venv`).",
        "",
        "| module | test files | how |",
        "| --- | --- | --- |",
    ]
    for module, (files, how) in table.items():
        path = module.replace(".", "/") + (
            "/__init__.py" if (ROOT / module.replace(".", "/")).is_dir() else ".py"
        )
        tests = ", ".join(f"`{f}`" for f in files) or (
            "-" if how == "a package: see its modules" else "**none**"
        )
        lines.append(f"| `{path}` | {tests} | {how} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"write {MAP.relative_to(ROOT)}")
    args = parser.parse_args(argv)
    text = markdown(test_map())
    if args.write:
        MAP.write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
