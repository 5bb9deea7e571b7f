"""Sphinx configuration of the Cliff Terrain docs (`make docs`: HTML into docs/_build/html, warnings as errors).

Pages are Markdown (MyST); the API reference is autodoc reading the core's numpydoc docstrings, so
the core is imported: it never imports bpy, and the docs' venv holds only its libraries and Sphinx.
"""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cliff_terrain  # noqa: E402

project = "Cliff Terrain"
author = "Cliff Terrain developers"
copyright = "Cliff Terrain developers, GPL-3.0-or-later"
release = cliff_terrain.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "numpydoc",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build"]

# MyST: heading anchors for links such as [the rules](adaptive-mesh.md#the-default-bound-...).
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence"]

# autodoc + numpydoc: the signature as written, members in source order, no class-member tables
# (they would document every dataclass field twice), and every docstring section checked by
# numpydoc's parser when the page is built.
autodoc_member_order = "bysource"
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "pydata_sphinx_theme"
html_title = f"Cliff Terrain {release}"
html_static_path = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    # Nothing fetched at build or view time: no external icons, no version switcher.
    "icon_links": [],
}
html_show_sourcelink = False
# The pages at the top have no sub-pages: no empty "Section Navigation" column beside them.
html_sidebars = {
    page: []
    for page in ("index", "blender", "cli", "api", "validation", "benchmarks", "development", "changes")
}
