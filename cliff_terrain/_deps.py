"""The libraries the core needs, the versions it supports, and errors that name them.

Blender's Python may already hold a library the extension also bundles (pip-installed there, or
by another add-on), and Linux distributions build Blender against their own packages: the core
meets whatever versions it finds. Anything that goes wrong because of them is reported as what it
is, naming the package and its version, never as a fault of the user's photo.
"""

from __future__ import annotations

import importlib
import re
import sys

from .errors import DependencyError

# import name -> (distribution on PyPI, lowest supported version). Kept equal to pyproject.toml's
# `dependencies` (a test checks); the highest supported versions are the newest releases, tested.
REQUIRED = {
    "numpy": ("numpy", "1.26"),
    "scipy": ("scipy", "1.11"),
    "skimage": ("scikit-image", "0.22"),
    "cv2": ("opencv-python-headless", "4.8"),
    "PIL": ("pillow", "11.3"),
}
# Imported only by the features that need them.
OPTIONAL = {
    "tifffile": "tifffile",
    "imagecodecs": "imagecodecs",
    "shapefile": "pyshp",
    "pydelatin": "pydelatin",
}


def distribution(module):
    """The PyPI name of an import name (``cv2`` -> ``opencv-python-headless``)."""
    top = module.split(".", 1)[0]
    if top in REQUIRED:
        return REQUIRED[top][0]
    return OPTIONAL.get(top, top)


def installed_version(module):
    """The version of an imported (or importable) module, as it reports it; ``"unknown"`` if none."""
    top = module.split(".", 1)[0]
    loaded = sys.modules.get(top)
    version = getattr(loaded, "__version__", None)
    if isinstance(version, str):
        return version
    import importlib.metadata  # here: only messages need it, and it costs a fresh Blender 35 ms

    try:
        return importlib.metadata.version(distribution(top))
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def describe(module):
    """``"opencv-python-headless 4.10.0"``: the package and its version, for messages."""
    return f"{distribution(module)} {installed_version(module)}"


def version_tuple(text):
    """The leading numbers of a version string: ``"4.11.0.86"`` -> (4, 11, 0, 86)."""
    return tuple(int(part) for part in re.findall(r"\d+", re.match(r"[\d.]*", text).group(0)))


def import_required(name):
    """Import a required library, or raise :class:`DependencyError` naming it, its version and why."""
    dist, minimum = REQUIRED[name]
    try:
        module = importlib.import_module(name)
    except Exception as error:  # ImportError, or whatever a broken binary raises while loading
        raise DependencyError(
            f"Cliff Terrain cannot import {dist} (installed: {installed_version(name)}): "
            f"{type(error).__name__}: {error}; it needs {dist} >= {minimum}"
        ) from error
    version = installed_version(name)
    if version != "unknown" and version_tuple(version) < version_tuple(minimum):
        raise DependencyError(f"{dist} {version} is too old: Cliff Terrain needs {dist} >= {minimum}")
    return module


def check_required():
    """Import every required library once, raising :class:`DependencyError` for the first that fails."""
    if not _checked:
        for name in REQUIRED:
            import_required(name)
        _checked.append(True)


_checked = []


def import_optional(name, *, feature):
    """Import a library one feature needs, or raise :class:`DependencyError` saying how to get it."""
    try:
        return importlib.import_module(name)
    except Exception as error:
        dist = distribution(name)
        raise DependencyError(
            f"{feature} needs {dist}, which cannot be imported (installed: {installed_version(name)}): "
            f"{type(error).__name__}: {error}; install it with `pip install {dist}`"
        ) from error


def environment_error(error, *, doing):
    """A :class:`DependencyError` if `error` comes from the environment rather than the data, else None.

    Missing APIs (``AttributeError`` on a library module), failed imports, and decoders or codecs a
    library was built without are problems of the installation: the message names the library and
    its version. `doing` says what was being done (``"cannot read image 'x.jpg'"``).
    """
    if isinstance(error, DependencyError):
        return error
    text = str(error)
    module = None
    if isinstance(error, ImportError):
        module = error.name or _module_in(text) or "unknown"
        what = f"a library cannot be imported ({type(error).__name__}: {text})"
    elif isinstance(error, AttributeError):
        module = _module_in(text)
        if module is None:
            return None
        what = f"its API lacks what Cliff Terrain uses ({text})"
    elif isinstance(error, OSError) and re.search(r"(decoder|encoder) \S+ not available", text):
        module = "PIL"
        what = f"it was built without a codec the file needs ({text})"
    elif "imagecodecs" in text:
        module = "imagecodecs"
        what = f"a codec library is missing ({text})"
    else:
        return None
    return DependencyError(
        f"{doing}: not a fault of the file but of the installed {describe(module)}: {what}"
    )


def _module_in(text):
    match = re.search(r"module '([\w.]+)'", text)
    return match.group(1) if match else None


def require_extra(module, *, extra, needed_by):
    """Raise :class:`DependencyError` before any work when `module`, of the package's `extra`
    (``pip install 'cliff-terrain[season]'``), is not installed; `needed_by` says what needs it.

    Examples
    --------
    >>> require_extra("numpy", extra="season", needed_by="growth.png")
    """
    try:
        importlib.import_module(module)
    except ImportError:
        raise DependencyError(
            f"{needed_by} needs {distribution(module)}, which is not installed: pip install "
            f"'cliff-terrain[{extra}]' (from a checkout of the repository: pip install '.[{extra}]')"
        ) from None
