"""Docs that work when pasted: every core docstring example, and the README's Python example."""

from __future__ import annotations

import doctest
import importlib
import pkgutil
import re

import numpy as np
import pytest
from conftest import REPO

import cliff_terrain

# Modules whose examples need the command-line extras (Dask, matplotlib) import them lazily, so
# every module imports here; examples that need files of the user's are marked +SKIP in place.
MODULES = sorted(
    name
    for _, name, _ in pkgutil.walk_packages(cliff_terrain.__path__, "cliff_terrain.")
    if not name.endswith("__main__")
)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(
        module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (see above)"


def test_the_readme_python_example_runs(capsys):
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    api = [b for b in blocks if "from cliff_terrain import build_relief, synthetic_field" in b]
    assert len(api) == 1
    namespace = {}
    exec(compile(api[0], "README.md", "exec"), namespace)
    relief, truth = namespace["relief"], namespace["truth"]
    out = capsys.readouterr().out
    assert f"{relief.n_regions} plants, {truth.n_plants} drawn" in out
    assert relief.n_regions == pytest.approx(truth.n_plants, rel=0.2)
    assert np.isfinite(relief.heights).all()
