"""The extension zips as Blender installs them: one zip per platform and Python (3.11 and 3.13).

Each test runs a fresh Blender (the bpy wheel of this environment: 4.2, 5.0.1 or 5.2.3) in a
subprocess with a throw-away user folder, installs a zip built by ``tools/build_extension.py`` with
Blender's own ``extensions.package_install_files``, and checks what a user would see: the add-on
enabled and building a relief from a real photo with the zip's own libraries, or Blender's own
refusal of a zip for another platform or Python.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest
from conftest import REPO, uav_image

pytestmark = [pytest.mark.blender, pytest.mark.slow]

PYTHON = f"{sys.version_info.major}.{sys.version_info.minor}"
OTHER_PYTHON = {"3.11": "3.13", "3.13": "3.11"}[PYTHON]


def build_zip(out_dir, *args):
    run = subprocess.run(
        [sys.executable, str(REPO / "tools" / "build_extension.py"), "--output-dir", str(out_dir), *args],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    (path,) = out_dir.glob("cliff_terrain-*.zip")
    return path


@pytest.fixture(scope="module")
def linux_zip(tmp_path_factory):
    pytest.importorskip("bpy")
    if not sys.platform.startswith("linux"):
        pytest.skip("these tests install the linux-x64 zip")
    return build_zip(tmp_path_factory.mktemp("zip"), "--platform", "linux-x64", "--python", PYTHON)


# Runs in a fresh process: installs ZIP into a temporary user folder, then prints one JSON line.
INSTALL = textwrap.dedent(
    """
    import glob, io, json, os, sys, tempfile, contextlib
    user = tempfile.mkdtemp(prefix="cliff_terrain_user_")
    os.environ["BLENDER_USER_RESOURCES"] = user
    import bpy
    zip_path, photo = sys.argv[1], sys.argv[2]
    out = {"error": None}
    log = io.StringIO()
    try:
        with contextlib.redirect_stdout(log):
            bpy.ops.extensions.package_install_files(
                filepath=zip_path, repo="user_default", enable_on_install=True
            )
    except RuntimeError as error:
        out["error"] = str(error)
    out["log"] = log.getvalue()
    out["enabled"] = "bl_ext.user_default.cliff_terrain" in bpy.context.preferences.addons
    if out["enabled"] and photo:
        # The zip's own wheels, not this environment's: its site-packages first on sys.path.
        (site,) = glob.glob(os.path.join(user, "extensions", ".local", "lib", "python*", "site-packages"))
        sys.path.remove(site)
        sys.path.insert(0, site)
        for name in [m for m in sys.modules if m.split(".")[0] in ("cv2", "scipy", "skimage", "PIL")]:
            del sys.modules[name]
        import numpy, cv2, scipy, skimage
        out["libraries"] = {
            m.__name__: [m.__version__, m.__file__.startswith(user)] for m in (numpy, cv2, scipy, skimage)
        }
        result = bpy.ops.cliff_terrain.build_relief(filepath=photo, max_size=300)
        obj = bpy.context.active_object
        out["build"] = sorted(result)
        out["object"] = obj.name if obj else None
        out["vertices"] = len(obj.data.vertices) if obj else 0
        out["image_users"] = [im.filepath for im in bpy.data.images]
    print("RESULT " + json.dumps(out))
    sys.stdout.flush()
    os._exit(0)  # bpy 4.2 may crash while the interpreter shuts down
    """
)


def install(zip_path, photo=""):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    run = subprocess.run(
        [sys.executable, "-c", INSTALL, str(zip_path), str(photo)],
        capture_output=True,
        text=True,
        timeout=900,
        env=env,
    )
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, run.stdout[-3000:] + run.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT ") :])


def test_the_zip_installs_and_builds_with_its_own_wheels(linux_zip):
    photo = uav_image("broccoli/01_clip_raw_test.jpg")
    out = install(linux_zip, photo)
    assert out["error"] is None and out["enabled"], out
    libraries = out["libraries"]
    # numpy is Blender's own; OpenCV, SciPy and scikit-image come from the zip's wheels.
    assert not libraries["numpy"][1]
    for name in ("cv2", "scipy", "skimage"):
        assert libraries[name][1], (name, libraries[name])
    assert out["build"] == ["FINISHED"] and out["object"] == "01_clip_raw_test"
    assert out["vertices"] > 300 * 300
    assert any(path.endswith("01_clip_raw_test.jpg") for path in out["image_users"])


def test_a_zip_for_the_other_python_is_refused_by_blender(tmp_path):
    pytest.importorskip("bpy")
    zip_path = build_zip(tmp_path, "--platform", "linux-x64", "--python", OTHER_PYTHON)
    out = install(zip_path)
    assert not out["enabled"]
    message = (out["error"] or "") + out["log"]
    import bpy

    if bpy.app.version < (4, 3, 0):
        # Blender 4.2 does not read a wheel's Python tag: the 3.13 zip asks for Blender 4.3 or newer.
        assert "doesn't meet the minimum supported version (4.3.0)" in message, out
    else:
        assert f"This Python version ({PYTHON}) isn't compatible with ({OTHER_PYTHON})" in message, out


def test_a_zip_for_another_platform_is_refused_by_blender(tmp_path):
    pytest.importorskip("bpy")
    zip_path = build_zip(tmp_path, "--platform", "windows-x64", "--python", PYTHON)
    out = install(zip_path)
    assert not out["enabled"]
    assert "This platform (linux-x64) isn't one of (windows-x64)" in (out["error"] or "") + out["log"], out
