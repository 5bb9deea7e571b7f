"""The packaged extension: build the linux-x64 zip for this Blender's Python with
tools/build_extension.py (Blender's own builder), install it into Blender with a throw-away user
configuration, and run it on a real photo; and Blender's own refusal of a zip for another Python or
platform. This runs on every bpy the suite runs on (4.2, 4.5 and 5.0.1 on Python 3.11, 5.2.3 on 3.13).

The install runs in a subprocess: BLENDER_USER_RESOURCES must be set before bpy is imported, and
the interpreter starts with ``-S`` and sees only bpy and numpy, so SciPy, scikit-image, OpenCV and
Pillow can only come from the wheels inside the zip. Wheels are cached in ``wheels/`` (as for
``make extension``), so only the first run downloads them.
"""

import ast
import json
import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_UAV as UAV
from conftest import blender_only_site, load_script

pytestmark = [pytest.mark.blender, pytest.mark.slow]
bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[1]
MAIZE = UAV / "plantcv_dsm" / "rgb.tif"  # 261x284 RGBA GeoTIFF, 2.2 cm/px
PYTHON = f"{sys.version_info.major}.{sys.version_info.minor}"
OTHER_PYTHON = {"3.11": "3.13", "3.13": "3.11"}[PYTHON]


def load_tool():
    return load_script(ROOT / "tools" / "build_extension.py", "_build_extension")


@pytest.fixture(scope="module")
def tool():
    return load_tool()


def build_zip(out, platform, python):
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tools" / "build_extension.py"),
            "--platform",
            platform,
            "--python",
            python,
            "--output-dir",
            str(out),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, f"build_extension failed:\n{proc.stdout}\n{proc.stderr}"
    return sorted(out.glob("*.zip")), proc.stdout


@pytest.fixture(scope="module")
def linux_zip(tmp_path_factory, tool):
    zips, log = build_zip(tmp_path_factory.mktemp("dist"), "linux-x64", PYTHON)
    expected = f"cliff_terrain-{tool.core_version()}-linux_x64-python{PYTHON}.zip"
    assert [z.name for z in zips] == [expected], log
    return zips[0]


def test_zip_holds_the_linux_wheels_and_the_add_on_only(linux_zip, tool):
    with zipfile.ZipFile(linux_zip) as archive:
        names = archive.namelist()
        manifest = tomllib.loads(archive.read("blender_manifest.toml").decode())
    wheels = [Path(n).name for n in names if n.startswith("wheels/")]
    packages = sorted(tool.wheel_name_version(w)[0] for w in wheels)
    assert packages == sorted(tool.normalize(p) for p in tool.PACKAGES)
    assert "numpy" not in packages
    # Pure-Python or Linux x86-64 wheels, for this CPython (or the stable ABI).
    cp = "cp" + PYTHON.replace(".", "")
    for wheel in wheels:
        python, abi, platform = wheel[: -len(".whl")].split("-")[-3:]
        assert platform == "any" or ("linux" in platform and platform.endswith("x86_64")), wheel
        assert python in ("py3", "py2.py3", cp, "cp37") and abi in ("none", cp, "abi3"), wheel
    assert manifest["build"]["generated"]["platforms"] == ["linux-x64"]
    # Blender 4.2 cannot tell a 3.13 zip by its wheels: its minimum version keeps it away.
    assert manifest["blender_version_min"] == {"3.11": "4.2.0", "3.13": "4.3.0"}[PYTHON]
    for required in (
        "__init__.py",
        "cliff_terrain/build.py",
        "operators/build.py",
        "scene/mesh_data.py",
        "panels/sidebar.py",
    ):
        assert required in names
    tops = {n.split("/", 1)[0] for n in names}
    assert not tops & {
        "tests",
        "bench",
        "tools",
        "docs",
        "dist",
        ".ci",
        ".venv",
        "Makefile",
        "pyproject.toml",
    }
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    # The season's reader is shipped (the Season Animation button); its Dask runner and matplotlib
    # chart are command-line only.
    assert "cliff_terrain/season/reader.py" in names and "operators/season_animation.py" in names
    assert "cliff_terrain/season/runner.py" not in names and "cliff_terrain/season/charts.py" not in names
    # Mask quality and the synthetic surface serve the tests, benchmarks and tools, not the extension.
    assert "cliff_terrain/evaluate/mask_quality.py" not in names
    assert "cliff_terrain/data/synthetic_surface.py" not in names


def test_every_module_the_zip_imports_is_in_the_zip(linux_zip):
    """What the manifest leaves out is imported by nothing the zip holds (lazy imports too), so no
    button of the installed extension can fail on a missing module."""
    with zipfile.ZipFile(linux_zip) as archive:
        sources = {n: archive.read(n).decode() for n in archive.namelist() if n.endswith(".py")}
    modules = {n[: -len(".py")].removesuffix("/__init__").replace("/", ".") for n in sources}
    missing = []
    for name, text in sources.items():
        package = name[: -len(".py")].replace("/", ".").split(".")[:-1]
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, ast.ImportFrom) or node.level == 0:
                continue
            base = package[: len(package) - node.level + 1] + ([node.module] if node.module else [])
            for alias in node.names:
                target = ".".join([*base, alias.name])
                if ".".join(base) not in modules and target not in modules:
                    missing.append(f"{name}: {'.' * node.level}{node.module or ''} import {alias.name}")
    assert not missing, "\n".join(missing)


def test_zip_check_names_a_wheel_the_builder_left_out(tool, tmp_path):
    archive_path = tmp_path / "cliff_terrain-0.0.0-linux_x64-python3.11.zip"
    with zipfile.ZipFile(archive_path, "w") as archive:
        archive.writestr("blender_manifest.toml", 'id = "cliff_terrain"\nblender_version_min = "4.2.0"\n')
        for name in (
            "__init__.py",
            "cliff_terrain/__init__.py",
            "operators/__init__.py",
            "scene/__init__.py",
            "panels/__init__.py",
        ):
            archive.writestr(name, "")
        archive.writestr("wheels/kept-1.0-py3-none-any.whl", "")
    expected = ["kept-1.0-py3-none-any.whl", "dropped-2.0-cp311-cp311-manylinux_2_17_x86_64.whl"]
    packages = ("kept", "dropped")
    with pytest.raises(tool.BuildError, match=r"left out 1 wheel.*dropped-2\.0"):
        tool.check_zip(archive_path, {"3.11": expected}, "cliff_terrain", packages=packages)
    with pytest.raises(
        tool.BuildError, match=r"Python 3\.11 needs exactly one dropped wheel, the zip has none"
    ):
        tool.check_zip(archive_path, {"3.11": expected[:1]}, "cliff_terrain", packages=packages)
    assert tool.check_zip(archive_path, {"3.11": expected[:1]}, "cliff_terrain", packages=packages[:1]) == 7
    with pytest.raises(tool.BuildError, match=r"blender_version_min is not 4\.3\.0"):
        tool.check_zip(
            archive_path,
            {"3.11": expected[:1]},
            "cliff_terrain",
            packages=packages[:1],
            blender_version_min="4.3.0",
        )


def test_a_numpy_wheel_in_the_wheels_folder_stops_the_build(tool, linux_zip, tmp_path, capsys):
    # The cached linux wheels (the linux_zip build filled the cache), plus a stray numpy wheel.
    cache = ROOT / "wheels"
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    for path in [cache / "index.json", *cache.glob("*.whl")]:
        (wheels / path.name).symlink_to(path)
    (wheels / "numpy-1.26.4-cp311-cp311-manylinux_2_17_x86_64.whl").write_bytes(b"")
    code = tool.main(
        [
            "--platform",
            "linux-x64",
            "--python",
            PYTHON,
            "--wheels-dir",
            str(wheels),
            "--output-dir",
            str(tmp_path / "out"),
        ]
    )
    assert code == 1
    assert "numpy-1.26.4" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


INSTALL_AND_RUN = r"""
import json, sys
shim, zip_path, photo, res = sys.argv[1:5]
sys.path.insert(0, shim)
import bpy
import numpy as np

out = {"blender": bpy.app.version_string}
out["install"] = sorted(bpy.ops.extensions.package_install_files(
    filepath=zip_path, repo="user_default", enable_on_install=True))
module = sys.modules.get("bl_ext.user_default.cliff_terrain")
out["module_file"] = getattr(module, "__file__", None)
out["build"] = sorted(bpy.ops.cliff_terrain.build_relief(filepath=photo, max_size=300))
obj = bpy.context.active_object
mesh = obj.data
co = np.empty(len(mesh.vertices) * 3, np.float32)
mesh.vertices.foreach_get("co", co)
uv = np.empty(len(mesh.loops) * 2, np.float32)
mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv)
tex = [n for n in obj.active_material.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage"]
out.update(
    name=obj.name,
    n_vertices=len(mesh.vertices),
    n_faces=len(mesh.polygons),
    z_max=float(co[2::3].max()),
    uvs=uv.reshape(-1, 2).tolist(),
    material=obj.active_material.name,
    texture_size=list(tex[0].image.size) if tex else None,
    record=obj["cliff_terrain"].to_dict(),
)
import cv2, PIL, scipy, skimage
out["libraries"] = {m.__name__: m.__file__ for m in (scipy, skimage, cv2, PIL, np)}
print("RESULT " + json.dumps(out))
"""


@pytest.mark.skipif(not MAIZE.is_file(), reason=f"real UAV image not found at {MAIZE}")
def test_installed_zip_builds_a_relief_with_its_own_wheels(linux_zip, tmp_path):
    from cliff_terrain import build_relief, load_image

    resources = tmp_path / "blender_user"
    resources.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "BLENDER"))}
    env["BLENDER_USER_RESOURCES"] = str(resources)
    proc = subprocess.run(
        [
            sys.executable,
            "-S",
            "-c",
            INSTALL_AND_RUN,
            str(blender_only_site(tmp_path)),
            str(linux_zip),
            str(MAIZE),
        ]
        + [str(resources)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, (
        f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    out = json.loads(lines[-1][len("RESULT ") :])

    assert out["install"] == ["FINISHED"] and out["build"] == ["FINISHED"]
    assert Path(out["module_file"]).is_relative_to(resources)
    for name in ("scipy", "skimage", "cv2", "PIL"):
        assert Path(out["libraries"][name]).is_relative_to(resources), (name, out["libraries"][name])
    assert not Path(out["libraries"]["numpy"]).resolve().is_relative_to(resources)

    ref = build_relief(str(MAIZE), max_size=300)
    assert (out["n_vertices"], out["n_faces"]) == (ref.mesh.n_vertices, ref.mesh.n_faces)
    # Metres (GeoTIFF pixel scale, no rescaling); corner heights average pixels, so <= the peak.
    assert 0.0 < out["z_max"] <= ref.max_height
    assert out["z_max"] == pytest.approx(float(ref.mesh.vertices[:, 2].max()), rel=1e-6)
    # The same UVs as the core's: front in [0, 1], walls and base beyond u = 1.
    uvs = np.array(out["uvs"], dtype=np.float32)
    np.testing.assert_array_equal(uvs, ref.mesh.uvs)
    n_front = int(ref.mesh.face_sizes[: ref.mesh.n_front_faces].sum())  # grid quads or TIN triangles
    assert uvs[:n_front].min() >= 0.0 and uvs[:n_front].max() <= 1.0
    assert n_front < len(uvs) and uvs[n_front:, 0].min() >= 1.0
    assert out["name"] == MAIZE.stem and out["material"] == MAIZE.stem
    meta = load_image(str(MAIZE))[1]
    assert out["texture_size"] == [meta.width, meta.height]  # the photo at full resolution
    assert out["record"]["units"] == "m" and out["record"]["regions"] == ref.n_regions
    assert np.isclose(out["record"]["pixel_size"], ref.pixel_size)


# A fresh Blender installs a zip and says what it did: one JSON line.
INSTALL_ONLY = r"""
import contextlib, io, json, sys
import bpy

log = io.StringIO()
out = {"error": None}
try:
    with contextlib.redirect_stdout(log):
        bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default", enable_on_install=True)
except RuntimeError as error:
    out["error"] = str(error)
out["log"] = log.getvalue()
out["enabled"] = "bl_ext.user_default.cliff_terrain" in bpy.context.preferences.addons
print("RESULT " + json.dumps(out))
"""


def install_only(zip_path, tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "BLENDER"))}
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "blender_user")
    proc = subprocess.run(
        [sys.executable, "-c", INSTALL_ONLY, str(zip_path)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    out = json.loads(lines[-1][len("RESULT ") :])
    return out, (out["error"] or "") + out["log"]


def test_a_zip_for_the_other_python_is_refused_by_blender(tmp_path):
    (zip_path,), _ = build_zip(tmp_path / "dist", "linux-x64", OTHER_PYTHON)
    out, message = install_only(zip_path, tmp_path)
    assert not out["enabled"], out
    if bpy.app.version < (4, 3, 0):
        # Blender 4.2 does not read a wheel's Python tag: the 3.13 zip asks for Blender 4.3 or newer.
        assert "doesn't meet the minimum supported version (4.3.0)" in message, out
    else:
        assert f"This Python version ({PYTHON}) isn't compatible with ({OTHER_PYTHON})" in message, out


def test_a_zip_for_another_platform_is_refused_by_blender(tmp_path):
    (zip_path,), _ = build_zip(tmp_path / "dist", "windows-x64", PYTHON)
    out, message = install_only(zip_path, tmp_path)
    assert not out["enabled"], out
    assert "This platform (linux-x64) isn't one of (windows-x64)" in message, out


def test_the_operator_works_out_the_key_figures_beside_the_adaptive_mesh(addon, scene, monkeypatch):
    """With an adaptive mesh the core runs without one, then the mesh is built in the calling
    thread while a worker works out the record's figures: the same relief, the same figures."""
    import importlib
    import threading

    from conftest import ADDON

    build = importlib.import_module(f"{ADDON}.operators.build")
    core = importlib.import_module(f"{ADDON}.cliff_terrain")
    params = importlib.import_module(f"{ADDON}.cliff_terrain.params").ReliefParams(
        max_size=300, mesh="adaptive"
    )
    caller, threads = threading.get_ident(), []
    real_figures = build.record_figures

    def record_figures(relief):
        threads.append(threading.get_ident())
        assert relief.mesh is None  # the heights are enough
        return real_figures(relief)

    monkeypatch.setattr(build, "record_figures", record_figures)
    stages, created = [], []
    relief, mesh, figures = build.build_beside_the_mesh(
        core.build_relief, str(MAIZE), params, lambda f, s: stages.append((f, s)), created
    )
    assert mesh is None and created == [] and threads and threads[0] != caller
    assert [s for _, s in stages] == ["load", "resize", "filter", "segment", "heights", "mesh", "done"]
    assert [f for f, _ in stages] == sorted(f for f, _ in stages) and stages[-1][0] == 1.0
    ref = core.build_relief(str(MAIZE), max_size=300, mesh="adaptive")
    assert (relief.mesh_kind, relief.mesh_rule, relief.max_error, relief.max_error_rule) == (
        ref.mesh_kind,
        ref.mesh_rule,
        ref.max_error,
        ref.max_error_rule,
    )
    assert relief.params == ref.params
    np.testing.assert_array_equal(relief.mesh.vertices, ref.mesh.vertices)
    np.testing.assert_array_equal(relief.mesh.corner_verts, ref.mesh.corner_verts)
    assert figures == real_figures(ref)
    assert figures[1]["cover"] > 0.05, "plants in the figures"


def test_the_operator_fills_its_mesh_in_its_own_thread_while_the_core_runs_in_a_worker(
    addon, scene, monkeypatch
):
    """The core is a plain function; the operator runs it (without a mesh) in a worker thread and
    meanwhile makes the Blender mesh in the calling thread, to which the progress is relayed."""
    import importlib
    import threading

    from conftest import ADDON

    build = importlib.import_module(f"{ADDON}.operators.build")
    core = importlib.import_module(f"{ADDON}.cliff_terrain")
    params = importlib.import_module(f"{ADDON}.cliff_terrain.params").ReliefParams(max_size=300, mesh="grid")
    caller, allocated, calls = threading.get_ident(), threading.Event(), []
    real_allocate, real_fill = build.allocate_mesh, build.fill_topology

    def allocate(name, sizes):
        calls.append(("allocate", threading.get_ident()))
        mesh = real_allocate(name, sizes)
        allocated.set()
        return mesh

    def fill(mesh, topology):
        calls.append(("fill", threading.get_ident()))
        real_fill(mesh, topology)

    monkeypatch.setattr(build, "allocate_mesh", allocate)
    monkeypatch.setattr(build, "fill_topology", fill)

    def core_build(path, params, **kwargs):
        calls.append(("core", threading.get_ident(), params.mesh, kwargs.get("mesh")))
        assert allocated.wait(60)  # the mesh is made while the core runs
        return core.build_relief(path, params, **kwargs)

    stages, created = [], []
    relief, mesh, figures = build.build_beside_the_mesh(
        core_build, str(MAIZE), params, lambda f, s: stages.append((s, threading.get_ident())), created
    )
    assert figures is None  # build_record works them out
    worker = calls[0][1]
    assert calls[0] == ("core", worker, "grid", None) and worker != caller
    assert calls[1:] == [("allocate", caller), ("fill", caller)]
    assert created == [mesh]
    assert [s for s, _ in stages] == ["load", "resize", "filter", "segment", "heights", "mesh", "done"]
    assert {t for _, t in stages} == {caller}
    ref = core.build_relief(str(MAIZE), max_size=300, mesh="grid")
    assert relief.params["mesh"] == "grid" and relief.mesh_kind == "grid" and relief.mesh_rule == "given"
    np.testing.assert_array_equal(relief.mesh.vertices, ref.mesh.vertices)
    assert (len(mesh.vertices), len(mesh.polygons)) == (ref.mesh.n_vertices, ref.mesh.n_faces)
    bpy.data.meshes.remove(mesh)

    # The worker's error propagates once it has finished; the mesh made meanwhile is in `created`.
    def failing(path, params, **kwargs):
        raise core.CliffTerrainError("the core failed")

    created = []
    with pytest.raises(core.CliffTerrainError, match="the core failed"):
        build.build_beside_the_mesh(failing, str(MAIZE), params, None, created)
    assert len(created) == 1
    bpy.data.meshes.remove(created[0])
