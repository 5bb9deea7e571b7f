"""The core's shape, checked from its source: no import cycle, no private name imported across
modules, small modules, no Blender schedule in the core, and each stage importing only the stages
before it (the README's architecture section)."""

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[1] / "cliff_terrain"
MAX_LINES = 500

# Each subpackage may import the shared modules and the stages listed before it, never after.
STAGES = ("io", "data", "relief", "mesh", "evaluate", "measure", "build", "figures", "season", "commands")
SHARED = {"errors", "settings", "_validate", "_deps", "_memory", "_threads", "_progress", "params"}


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
