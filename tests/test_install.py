"""`pip install .` gives the core with its declared ranges and the `cliff-terrain` command."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import tomllib
import venv
import zipfile
from email.parser import Parser
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from PIL import Image

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheel")
    run = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(REPO)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    (path,) = out.glob("cliff_terrain-*.whl")
    return path


def test_the_wheel_holds_the_core_only_with_the_declared_ranges(wheel):
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        (metadata,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        meta = Parser().parsestr(archive.read(metadata).decode())
        (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
        scripts = archive.read(entry_points).decode()
    tops = {n.split("/", 1)[0] for n in names if not n.split("/", 1)[0].endswith(".dist-info")}
    assert tops == {"cliff_terrain"}, tops  # not the Blender side, tests or tools
    from packaging.requirements import Requirement

    def parsed(requirements):
        return {(r.name, r.specifier) for r in map(Requirement, requirements) if r.marker is None}

    assert parsed(meta.get_all("Requires-Dist")) == parsed(project["dependencies"])
    assert "cliff-terrain = cliff_terrain.cli:main" in scripts
    from cliff_terrain import __version__

    assert meta["Version"] == __version__


def test_the_installed_command_runs_the_core(wheel, tmp_path):
    # A fresh environment that sees this one's libraries (a .pth file), with the wheel installed into it.
    env_dir = tmp_path / "env"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True,
        text=True,
    ).stdout.strip()
    (Path(site) / "outer.pth").write_text(sysconfig.get_path("purelib") + "\n")
    run = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps", str(wheel)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    command = env_dir / "bin" / "cliff-terrain"
    photo = tmp_path / "field.png"
    out = subprocess.run(
        [command, "synthetic", str(photo), "--size", "120x160"], capture_output=True, text=True, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert Image.open(photo).size == (160, 120)
    out = subprocess.run(
        [command, "relief", str(photo), "--out", str(tmp_path / "relief"), "--max-size", "100"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    import tifffile

    heights = tifffile.imread(tmp_path / "relief" / "height.tif")
    assert heights.shape == (75, 100) and heights.max() > 0 and np.isfinite(heights).all()
    # The installed package, not the repository's copy.
    where = subprocess.run(
        [python, "-c", "import cliff_terrain; print(cliff_terrain.__file__)"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert str(env_dir) in where.stdout, where.stdout
    # Bad input: exit 2 and one line.
    out = subprocess.run(
        [command, "relief", str(tmp_path / "missing.jpg"), "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and "no such file" in out.stderr
    assert not (tmp_path / "x").exists()
