"""The core's shape, checked from its source: no import cycle, no private name imported across
modules, small modules, no Blender schedule in the core, and each stage importing only the stages
before it (the architecture of docs/development.md)."""

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[1] / "cliff_terrain"
MAX_LINES = 500

# Each subpackage may import the shared modules and the stages listed before it, never after.
STAGES = (
    "io",
    "data",
    "photo_heights",
    "mesh",
    "evaluate",
    "measure",
    "build",
    "mosaic",
    "figures",
    "season",
    "commands",
)
SHARED = {
    "errors",
    "settings",
    "_validate",
    "_deps",
    "_lazy",
    "_memory",
    "_threads",
    "_dask",
    "_progress",
    "params",
}


def _modules():
    for path in sorted(CORE.rglob("*.py")):
        parts = list(path.relative_to(CORE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


MODULES = dict(_modules())


def _resolve(module, path, node):
    """Absolute module names one import statement brings in (inside the core only)."""
    if isinstance(node, ast.Import):
        return [(alias.name, None) for alias in node.names if alias.name.startswith("cliff_terrain")]
    if node.level == 0:
        base = node.module or ""
    else:
        package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
        package = package[: len(package) - node.level + 1]
        base = ".".join(package + ([node.module] if node.module else []))
    if not base.startswith("cliff_terrain"):
        return []
    found = []
    for alias in node.names:
        candidate = f"{base}.{alias.name}"
        found.append((candidate, None) if candidate in MODULES else (base, alias.name))
    return found


def _imports():
    """module -> [(imported module, imported name or None, line)] over every import, lazy ones too."""
    graph = {}
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        edges = []
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                edges += [(target, name, node.lineno) for target, name in _resolve(module, path, node)]
        graph[module] = edges
    return graph


GRAPH = _imports()


def _stage(module):
    parts = module.split(".")
    if len(parts) == 1:
        return None
    if parts[1] in SHARED:
        return None
    return "commands" if parts[1] in ("cli", "__main__") else parts[1]


def test_no_import_cycle():
    # The package's own __init__ loads public names lazily; its edges are the public API, not a layer.
    edges = {
        m: {t for t, _, _ in e if t in MODULES and t != m and t != "cliff_terrain"}
        for m, e in GRAPH.items()
        if m != "cliff_terrain"
    }
    cycles = _cycles(edges)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_no_private_name_crosses_modules():
    crossing = [
        f"{m} imports {t}.{name} (line {line})"
        for m, e in GRAPH.items()
        for t, name, line in e
        if name is not None and name.startswith("_") and not name.startswith("__") and t != m
    ]
    assert not crossing, "\n".join(crossing)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_is_small(module):
    lines = len(MODULES[module].read_text().splitlines())
    assert lines <= MAX_LINES, f"{MODULES[module].relative_to(CORE.parent)} has {lines} lines (> {MAX_LINES})"


PACKAGES = sorted(m for m, path in MODULES.items() if path.name == "__init__.py")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_names_its_public_api(package):
    """`__all__` in every package: each name a public module of it, or a name it loads (`_EXPORTS`)."""
    import importlib

    module = importlib.import_module(package)
    assert module.__all__, f"{package} has no __all__"
    folder = MODULES[package].parent
    for name in module.__all__:
        assert not name.startswith("_") or name == "__version__", f"{package}.__all__ names {name}"
        if (folder / f"{name}.py").is_file() or (folder / name / "__init__.py").is_file():
            continue
        value = getattr(module, name)  # a lazily loaded name: its module is imported
        where = getattr(value, "__module__", None)
        if where is not None and where.startswith(package + "."):
            assert hasattr(importlib.import_module(where), name), (package, name, where)


def test_core_knows_nothing_of_blenders_schedule():
    words = ("MeshSink", "before_watershed", "on_watershed", "mesh_sink")
    found = [
        f"{path.relative_to(CORE.parent)}: {word}"
        for path in MODULES.values()
        for word in words
        if word in path.read_text()
    ]
    assert not found, "\n".join(found)


def test_stages_import_only_earlier_stages():
    order = {name: i for i, name in enumerate(STAGES)}
    backwards = []
    for m, e in GRAPH.items():
        here = _stage(m)
        if here is None:
            continue
        for t, _, line in e:
            there = _stage(t)
            if there is not None and there != here and order[there] > order[here]:
                backwards.append(f"{m} (line {line}) imports {t}")
    assert not backwards, "\n".join(backwards)


def test_a_build_does_not_import_scipys_or_scikit_images_heavy_packages(tmp_path):
    """A fresh Blender pays for every import on its first Build. The default Build needs none of
    SciPy's `ndimage`, `optimize`, `interpolate` or `sparse`, nor scikit-image's `segmentation`,
    `morphology` or `filters` packages, whose eager imports cost it 0.35 s on a 2-core VM (README,
    "Big fields"): the watershed kernel is loaded on its own and Otsu's threshold is computed here."""
    import subprocess
    import sys

    code = (
        "import sys, cv2\n"
        "from cliff_terrain import build_relief, synthetic_field\n"
        f"path = {str(tmp_path / 'field.png')!r}\n"
        "cv2.imwrite(path, synthetic_field(shape=(300, 400))[0][..., ::-1])\n"
        "relief = build_relief(path)\n"
        "build_relief(path, mesh='adaptive')\n"
        "assert relief.n_regions > 10, relief.n_regions\n"
        "print(sorted(m for m in sys.modules if m.startswith(('scipy.', 'skimage.'))))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=CORE.parent, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    loaded = eval(done.stdout.strip().splitlines()[-1])  # a list of module names
    heavy = ("scipy.ndimage", "scipy.optimize", "scipy.interpolate", "scipy.sparse")
    heavy += ("skimage.segmentation", "skimage.morphology", "skimage.filters")
    assert [m for m in loaded if m in heavy] == [], loaded
    assert "skimage.segmentation._watershed_cy" in loaded  # the kernel, loaded on its own


# ---- the add-on: the bpy side over the core ----

ROOT = CORE.parent
# The repository root is the extension's package; render_views.py and the loader import it under this name.
ADDON_NAME = "cliff_terrain_addon"
# The bpy side in layers, each importing only its own and the layers after it: the sidebar draws the
# operators' settings, the operators put things into the scene, and the scene's functions run the core.
LAYERS = ("panels", "operators", "scene", "cliff_terrain")
# Top-level modules of the folder: the package's own __init__ (registration: it imports the operators and
# the panels) and the scripts, which may import the loader, scene/ and the core, never an operator or a
# panel (a script makes a scene; the operators are the user's buttons for the same functions).
SCRIPTS = ("render_views", "render_season")
SCRIPT_MAY_IMPORT = ("_loader", "scene", "cliff_terrain")


def _addon_modules():
    """module name (dotted path from the repository root; ``""`` for its __init__) -> path."""
    found = {}
    for path in sorted(ROOT.glob("*.py")):
        found["" if path.stem == "__init__" else path.stem] = path
    for layer in LAYERS:
        for path in sorted((ROOT / layer).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


ADDON_MODULES = _addon_modules()


def _addon_targets(module, path, node):
    """Modules of the add-on one import statement brings in (the deepest module each name names)."""
    if isinstance(node, ast.Import):
        names = [alias.name for alias in node.names]
    elif node.level == 0:
        names = [f"{node.module}.{alias.name}" for alias in node.names]
    else:
        package = module.split(".") if path.name == "__init__.py" or not module else module.split(".")[:-1]
        package = [p for p in package if p]
        package = package[: len(package) - node.level + 1]
        base = ".".join(package + ([node.module] if node.module else []))
        names = [f"{base}.{alias.name}" if base else alias.name for alias in node.names]
    targets = []
    for name in names:
        if name == ADDON_NAME or name.startswith(ADDON_NAME + "."):
            name = name[len(ADDON_NAME) + 1 :]
        parts = name.split(".")
        # `from x import name`: name is a submodule or an attribute of x; keep the deepest module.
        while parts and ".".join(parts) not in ADDON_MODULES:
            parts.pop()
        if parts and not (len(parts) == 1 and parts[0] not in (*LAYERS, *SCRIPTS, "_loader")):
            targets.append(".".join(parts))
    return targets


def _addon_imports():
    """module -> [(imported module, line)], lazy imports too; importing a module imports its packages."""
    graph = {}
    for module, path in ADDON_MODULES.items():
        edges = []
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target in _addon_targets(module, path, node):
                    parts = target.split(".")
                    for depth in range(1, len(parts) + 1):
                        package = ".".join(parts[:depth])
                        # A module's own packages are being imported already when it runs.
                        if package != module and not module.startswith(package + "."):
                            edges.append((package, node.lineno))
        graph[module] = sorted(set(edges))
    return graph


ADDON_GRAPH = _addon_imports()


def _layer(module):
    top = module.split(".")[0]
    return top if top in LAYERS else None


def _cycles(edges):
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for t in sorted(edges.get(m, ())):
            if state.get(t) == "open":
                cycles.append(stack[stack.index(t) :] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = "done"

    for m in sorted(edges):
        if m not in state:
            visit(m)
    return cycles


def test_the_addon_has_no_import_cycle():
    """Over every module of the extension (registration, scripts, panels, operators, scene and the
    core's package), lazy imports included: a cycle through a function's import still fails when that
    function first runs in a fresh Blender."""
    edges = {m: {t for t, _ in e if t != m} for m, e in ADDON_GRAPH.items()}
    cycles = _cycles(edges)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(m or "(root)" for m in c) for c in cycles)


def test_the_cycle_finder_finds_a_cycle_through_lazy_imports():
    """The check above on the cycle the add-on had (scene.probe imported mask_digest from
    operators.build inside a function), written as the modules' own lines."""
    sources = {
        "operators.build": "from .properties import ReliefParameters\n",
        "operators.properties": "def f():\n    from ..scene.colour_by import reliefs\n",
        "scene.colour_by": "def g():\n    from .probe import grid_cells\n",
        "scene.probe": "def h():\n    from ..operators.build import mask_digest\n",
    }
    edges = {}
    for module, text in sources.items():
        path = ROOT / (module.replace(".", "/") + ".py")
        edges[module] = {
            t
            for node in ast.walk(ast.parse(text))
            if isinstance(node, ast.ImportFrom)
            for t in _addon_targets(module, path, node)
        }
    assert _cycles(edges) == [
        ["operators.build", "operators.properties", "scene.colour_by", "scene.probe", "operators.build"]
    ]


def test_each_layer_imports_only_the_layers_after_it():
    order = {name: i for i, name in enumerate(LAYERS)}
    upwards = []
    for m, e in ADDON_GRAPH.items():
        here = _layer(m)
        for t, line in e:
            there = _layer(t)
            if here is not None and (there is None or order[there] < order[here]):
                upwards.append(f"{m} (line {line}) imports {t or '(the package root)'}")
    assert not upwards, "\n".join(upwards)


def test_the_scripts_import_only_the_loader_the_scene_and_the_core():
    wrong = [
        f"{m}.py (line {line}) imports {t or '(the package root)'}"
        for m in SCRIPTS
        for t, line in ADDON_GRAPH[m]
        if t.split(".")[0] not in SCRIPT_MAY_IMPORT
    ]
    assert not wrong, "\n".join(wrong)


def test_no_module_of_the_addon_imports_a_script():
    """render_views.py and render_season.py are scripts: what others need of them lives in the loader,
    scene/ or the core (render_views' own tests and benchmark, outside the add-on, may import it)."""
    found = [
        f"{m} (line {line}) imports {t}.py" for m, e in ADDON_GRAPH.items() for t, line in e if t in SCRIPTS
    ]
    assert not found, "\n".join(found)


def test_a_relief_record_is_read_and_written_in_scene_record_only():
    """The relief object's record (its ``cliff_terrain`` custom property) has one home: the other
    modules of the add-on go through scene/record.py (its Record, with the defaults of older records)."""
    import re

    direct = re.compile(
        r"""\[\s*["']cliff_terrain["']\s*\]|\.get\(\s*["']cliff_terrain["']|["']cliff_terrain["']\s+(?:not\s+)?in\s+\w"""
    )
    found = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for module, path in ADDON_MODULES.items()
        if module != "scene.record" and not module.startswith("cliff_terrain")
        for number, line in enumerate(path.read_text().splitlines(), start=1)
        if direct.search(line)
    ]
    assert not found, "\n".join(found)
