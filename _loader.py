"""The extension loaded from this folder, for what runs it outside Blender's extension system: the
tests, the benchmarks and the scripts (``render_views.py``, ``render_season.py``).

Blender imports an installed extension as a package (``bl_ext.user_default.cliff_terrain``), so
the relative imports of ``operators/``, ``scene/`` and ``panels/`` reach the core as
``..cliff_terrain``. This folder is imported the same way, as the package ``cliff_terrain_addon``
(:data:`PACKAGE`); after :func:`package` (or :func:`register`) its modules are plain imports::

    import _loader

    _loader.register()  # bpy needed; once per process (bpy keeps its state)
    from cliff_terrain_addon.scene import views
    from cliff_terrain_addon.cliff_terrain.params import ReliefParams

It is a module of its own, not part of a script, so a test or a benchmark loads the extension
without importing a script's arguments and run; and it sits at the top of the folder, outside the
package it loads, because it is what makes that package importable. It imports no bpy until
:func:`package` runs the package's ``__init__`` (``--help`` and bad arguments answer at once).
"""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
PACKAGE = "cliff_terrain_addon"
START = time.perf_counter()  # a script's start (it imports this module first)
# Inside Blender (blender -b -P SCRIPT) bpy is loaded before a script runs, and the script imports this
# module first; with the bpy wheel bpy is imported later.
INSIDE_BLENDER = "bpy" in sys.modules


class InputError(Exception):
    """Bad input the user can fix: a script reports it as one line on stderr and exits with status 2."""


def package(*, execute=True):
    """The repository root as the package :data:`PACKAGE`, as Blender imports an extension.

    With `execute` False the package's ``__init__`` (which imports bpy) has not run yet: enough to
    import its bpy-free modules, such as ``cliff_terrain_addon.cliff_terrain.settings``, while a
    script parses its arguments.
    """
    module = sys.modules.get(PACKAGE)
    if module is None:
        spec = importlib.util.spec_from_file_location(
            PACKAGE, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = module
    if execute and not hasattr(module, "register"):
        try:
            module.__spec__.loader.exec_module(module)
        except BaseException:
            del sys.modules[PACKAGE]
            raise
    return module


def register():
    """The package, registered in this process's Blender unless a Cliff Terrain is already (an
    installed extension registers the same classes); returns ``(package, registered_here)``."""
    import bpy

    module = package()
    registered_here = not hasattr(bpy.types.Scene, "cliff_terrain")
    if registered_here:
        module.register()
    return module, registered_here


def log(message):
    """A script's progress line: seconds since start, then `message`."""
    print(f"[{time.perf_counter() - START:6.1f} s] {message}", flush=True)


def start_blender(*, usage):
    """Import bpy, start from an empty scene and register the extension from this folder; returns
    ``(bpy, package, core)``.

    `usage` is the Blender command the error names when bpy is missing (each script's own). Raises
    :class:`InputError` without bpy or the core's libraries.
    """
    try:
        import bpy
    except ImportError:
        raise InputError(
            f"Blender's Python module is missing: run `{usage}` "
            "or install the bpy wheel (pip install -r requirements-dev.txt)"
        ) from None
    # An empty scene with factory settings; the preferences (and installed add-ons) stay untouched.
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    addon, _ = register()
    try:
        from cliff_terrain_addon import cliff_terrain as core
        from cliff_terrain_addon.cliff_terrain import _deps

        _deps.check_required()
    except ImportError as exc:
        raise InputError(
            f"Cliff Terrain's libraries are missing in this Python ({exc}): install the extension zip "
            "in Blender (Edit > Preferences > Get Extensions > Install from Disk), or pip-install "
            "requirements.txt into Blender's Python"
        ) from None
    return bpy, addon, core


def leave(code):
    """Exit a script with `code`.

    bpy 4.2-4.5 as a Python module segfaults while the interpreter shuts down once a PropertyGroup
    has been registered (even after unregistering it): there, flush, remove Blender's session
    folder and leave without the teardown, so the exit code is the script's.
    """
    bpy = sys.modules.get("bpy")
    if INSIDE_BLENDER or bpy is None or bpy.app.version >= (5, 0, 0):
        sys.exit(code)
    import shutil

    sys.stdout.flush()
    sys.stderr.flush()
    if bpy.app.tempdir:
        shutil.rmtree(bpy.app.tempdir, ignore_errors=True)
    os._exit(code)
