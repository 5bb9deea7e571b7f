"""Build the Cliff Terrain Blender extension: one zip per platform and Python, with the wheels it needs.

This is ``make extension``. Steps:

1. Keep ``blender_manifest.toml``'s ``version`` equal to ``cliff_terrain.__version__``.
2. Download binary wheels (``pip download --only-binary=:all: --no-deps``) of scikit-image, its
   runtime dependencies and OpenCV for every target platform and for both of Blender's Pythons into
   ``wheels/``: Python 3.11 (Blender 4.2-5.0, numpy 1.26; pins from ``requirements.txt``) and Python
   3.13 (Blender 5.1+ and Linux distributions' Blender, numpy 2.x; ``requirements-cp313.txt``
   overrides the packages whose wheels are Python-specific). Blender's builder derives a zip's
   Python version from the wheels it holds, so each zip holds one Python's wheels (see BLENDER_MIN
   for why not both). Never numpy: Blender ships its own and a second copy would shadow it. Downloads are cached in
   ``wheels/index.json`` so a rebuild asks the package index nothing.
3. For each Python, stage the extension's files (the manifest's ``[build]`` exclusions, as Blender's
   builder applies them) with a manifest listing that Python's wheels, then build with Blender's own
   builder (shipped in the ``bpy`` wheel) using ``--split-platforms``: ``dist/cliff_terrain-0.1.0-
   linux_x64-python3.11.zip`` and so on.
4. ``validate`` each zip, then open it and check it holds every wheel its platform and Python need,
   exactly one per package: the builder silently leaves out wheels whose platform tag it does not
   match.

A full build (all platforms) also rewrites the ``wheels = [...]`` list of the repository's manifest
(every wheel of both Pythons);
a build of some platforms or Pythons only (``--platform linux-x64``, ``--python 3.13``, used by the
tests) leaves it untouched.

Usage::

    python tools/build_extension.py [--platform linux-x64 ...] [--python 3.13 ...] [--output-dir dist]
                                    [--wheels-dir wheels]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = "blender_manifest.toml"

# Blender platform -> pip platform tags, preferred first. pip widens macosx_13_0 to older macOS
# tags itself but takes manylinux_2_28 literally, so the older glibc tags are listed. glibc 2.28 is
# Blender 4.2's own floor; OpenCV 4.11 has no macOS wheel older than 13.0.
TARGETS = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_13_0_arm64",),
    "macos-x64": ("macosx_13_0_x86_64",),
}
# Blender's Python versions -> the requirements files whose pins their wheels follow (later files
# override earlier ones).
PYTHONS = {
    "3.11": ("requirements.txt",),
    "3.13": ("requirements.txt", "requirements-cp313.txt"),
}
# One zip per platform and Python, not one holding both: Blender 4.2's installer ignores a wheel's
# Python tag and keeps the highest version of each package, so it would install SciPy's cp313 wheel
# into its Python 3.11. Blender 4.3 and newer check the tag and refuse a zip for another Python with
# their own message; 4.2 (always Python 3.11) is kept from the 3.13 zip by its minimum Blender version.
BLENDER_MIN = {"3.11": "4.2.0", "3.13": "4.3.0"}

# scikit-image 0.25.2's runtime requirements (its METADATA) without numpy, plus OpenCV.
PACKAGES = (
    "scikit-image",
    "scipy",
    "networkx",
    "imageio",
    "tifffile",
    "lazy-loader",
    "packaging",
    "pillow",
    "opencv-python-headless",
    # Surface models and orthophotos (LZW/Deflate GeoTIFFs) and plot polygons (ESRI Shapefiles).
    "imagecodecs",
    "pyshp",
    # The adaptive mesh (Garland-Heckbert greedy insertion); it needs numpy only.
    "pydelatin",
)
# Versions of the packages requirements.txt does not pin (the ones pip resolved for the .venv).
EXTRA_PINS = {
    "networkx": "3.6.1",
    "imageio": "2.38.1",
    "lazy-loader": "0.6",
    "packaging": "26.3",
}
NEVER = ("numpy",)


class BuildError(RuntimeError):
    """A step failed; the message says which and why."""


def log(message):
    print(f"[build_extension] {message}", flush=True)


def normalize(name):
    """PEP 503 name normalisation (wheel file names use underscores)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def wheel_name_version(filename):
    """(normalised distribution name, version) of a wheel file name."""
    parts = Path(filename).name.split("-")
    if len(parts) < 5 or not filename.endswith(".whl"):
        raise BuildError(f"not a wheel file name: {filename!r}")
    return normalize(parts[0]), parts[1]


def read_pins(root=ROOT, files=("requirements.txt",)):
    """Pinned versions for PACKAGES: the requirements `files` in order, EXTRA_PINS for the rest."""
    pins = {}
    for file in files:
        for line in (root / file).read_text().splitlines():
            line = line.split("#", 1)[0].strip()
            if "==" in line:
                name, version = line.split("==", 1)
                pins[normalize(name)] = version.strip()
    out = {}
    for package in PACKAGES:
        key = normalize(package)
        version = pins.get(key) or EXTRA_PINS.get(package)
        if version is None:
            raise BuildError(f"no pinned version for {package!r}: pin it in {files[0]}")
        out[key] = version
    return out


def python_tag_matches(filename, python):
    """Whether a wheel file installs on CPython `python` ("3.13"): its python and ABI tags."""
    parts = Path(filename).name[: -len(".whl")].split("-")
    python_tags, abi_tags = parts[-3].split("."), parts[-2].split(".")
    major, minor = (int(v) for v in python.split("."))
    for tag in python_tags:
        if tag in ("py3", f"py{major}{minor}", f"cp{major}{minor}"):
            return True
        digits = tag[2:]
        if tag.startswith("cp") and "abi3" in abi_tags and digits.isdigit():
            if (int(digits[0]), int(digits[1:] or 0)) <= (major, minor):
                return True
    return False


def core_version(root=ROOT):
    """``cliff_terrain.__version__`` read from the source (importing the core would pull in SciPy)."""
    text = (root / "cliff_terrain" / "__init__.py").read_text()
    match = re.search(r"^__version__\s*=\s*[\"']([^\"']+)[\"']", text, flags=re.MULTILINE)
    if match is None:
        raise BuildError("cliff_terrain/__init__.py defines no __version__ = '...'")
    return match.group(1)


def blender_ext_path():
    """Blender's extension builder as shipped in the bpy wheel (found without importing bpy)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise BuildError("the bpy wheel is not installed in this Python (run `make venv`)")
    for location in spec.submodule_search_locations:
        found = sorted(Path(location).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
        if found:
            return found[-1]
    raise BuildError("bpy is installed but its extension builder (bl_pkg/cli/blender_ext.py) is missing")


def load_blender_ext(path):
    spec = importlib.util.spec_from_file_location("_cliff_terrain_blender_ext", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# Manifest text: rewrite single fields in place so comments and layout stay as written.


def set_manifest_field(text, key, value_toml):
    """Replace the top-level ``key = ...`` (a string or a possibly multi-line list)."""
    pattern = re.compile(rf"^{re.escape(key)}\s*=\s*(\[[^\]]*\]|\"[^\"\n]*\")", flags=re.MULTILINE)
    if not pattern.search(text):
        raise BuildError(f"{MANIFEST} has no top-level `{key} = ...` line to rewrite")
    return pattern.sub(lambda _m: f"{key} = {value_toml}", text, count=1)


def toml_list(items):
    if not items:
        return "[]"
    return "[\n" + "".join(f'  "{item}",\n' for item in items) + "]"


def manifest_text(text, *, version, wheels, platforms=None, blender_version_min=None):
    text = set_manifest_field(text, "version", f'"{version}"')
    if blender_version_min is not None:
        text = set_manifest_field(text, "blender_version_min", f'"{blender_version_min}"')
    text = set_manifest_field(text, "wheels", toml_list([f"./wheels/{w}" for w in wheels]))
    if platforms is not None:
        text = set_manifest_field(text, "platforms", "[" + ", ".join(f'"{p}"' for p in platforms) + "]")
    tomllib.loads(text)  # fail here, not in Blender's builder, if the rewrite broke the TOML
    return text


# Wheels.


def download_wheels(targets, pins_by_python, wheels_dir):
    """Download (or reuse) each target's wheels for every Python.

    Returns {target: {python: sorted wheel file names}}.
    """
    wheels_dir.mkdir(parents=True, exist_ok=True)
    index_path = wheels_dir / "index.json"
    index = json.loads(index_path.read_text()) if index_path.exists() else {}
    selected = {}
    for target in targets:
        tags = TARGETS[target]
        selected[target] = {}
        for python, pins in pins_by_python.items():
            files = _download(target, tags, python, pins, wheels_dir, index, index_path)
            for name in NEVER:
                if name in files:
                    raise BuildError(f"{name} must never be bundled (Blender ships it), got {files[name]}")
            selected[target][python] = sorted(files.values())
    stray = sorted(p.name for p in wheels_dir.glob("*.whl") if wheel_name_version(p.name)[0] in NEVER)
    if stray:
        raise BuildError(f"{wheels_dir} holds {', '.join(stray)}: remove it, Blender ships its own numpy")
    return selected


def _download(target, tags, python, pins, wheels_dir, index, index_path):
    """{package: wheel file name} of one target and Python, downloading what the cache lacks."""
    keys = {name: f"{target}|{'+'.join(tags)}|py{python}|{name}=={version}" for name, version in pins.items()}
    files = {}
    missing = []
    for name, key in keys.items():
        cached = index.get(key)
        if cached and (wheels_dir / cached).is_file():
            files[name] = cached
        else:
            missing.append(name)
    if not missing:
        log(f"{target}, Python {python}: {len(files)} wheels already in {wheels_dir.name}/")
        return files
    requirements = [f"{name}=={pins[name]}" for name in missing]
    log(f"{target}, Python {python}: downloading {', '.join(requirements)}")
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:"]
    cmd += ["--python-version", python, "--dest", str(wheels_dir)]
    for tag in tags:
        cmd += ["--platform", tag]
    proc = subprocess.run(cmd + requirements, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(
            f"pip download failed for {target} ({' '.join(tags)}), Python {python}:\n{proc.stdout[-2000:]}"
            f"{proc.stderr[-4000:]}"
        )
    for path in re.findall(r"(\S+\.whl)\b", proc.stdout):
        name, version = wheel_name_version(Path(path).name)
        if name in missing and version == pins[name]:
            files[name] = Path(path).name
    lost = [name for name in missing if name not in files]
    if lost:
        raise BuildError(
            f"pip download for {target}, Python {python} reported no wheel for {', '.join(lost)}"
        )
    for name in missing:
        index[keys[name]] = files[name]
    index_path.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    return files


# Staging and building.


def stage_sources(root, stage, blender_ext, exclude_patterns):
    """Copy the files Blender's builder would take from `root` (same exclusions, no symlinks)."""
    matcher = blender_ext.PathPatternMatch(exclude_patterns)

    def keep(relpath, is_dir):
        relpath = relpath.replace(os.sep, "/")
        return not matcher.test_path(relpath + "/" if is_dir else relpath)

    count = 0
    for src, rel in blender_ext.scandir_recursive(str(root), filter_fn=keep):
        if Path(rel).name == MANIFEST and Path(rel).parent == Path("."):
            continue
        dst = stage / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
        count += 1
    return count


def link_or_copy(src, dst):
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def run_builder(blender_ext_file, args):
    proc = subprocess.run([sys.executable, str(blender_ext_file), *args], capture_output=True, text=True)
    output = (proc.stdout + proc.stderr).strip()
    return proc.returncode, output


def check_zip(zip_path, expected_by_python, manifest_id, *, blender_version_min="4.2.0", packages=PACKAGES):
    """Check a built zip: manifest, add-on entry points, every Python's wheels, no numpy, no tests.

    `expected_by_python` is {python: wheel file names}. For each Python, every package must have
    exactly one wheel in the zip that installs there (Blender picks the highest version otherwise).
    """
    with zipfile.ZipFile(zip_path) as archive:
        names = set(archive.namelist())
        manifest = tomllib.loads(archive.read(MANIFEST).decode()) if MANIFEST in names else None
    if manifest is None or manifest.get("id") != manifest_id:
        raise BuildError(f"{zip_path.name}: no {MANIFEST} for id {manifest_id!r}")
    if manifest.get("blender_version_min") != blender_version_min:
        raise BuildError(f"{zip_path.name}: blender_version_min is not {blender_version_min}")
    for required in (
        "__init__.py",
        "cliff_terrain/__init__.py",
        "operators/__init__.py",
        "scene/__init__.py",
        "panels/__init__.py",
    ):
        if required not in names:
            raise BuildError(f"{zip_path.name}: {required} is missing")
    wheels = {Path(n).name for n in names if n.startswith("wheels/") and n.endswith(".whl")}
    expected = {w for files in expected_by_python.values() for w in files}
    missing = sorted(expected - wheels)
    if missing:
        raise BuildError(
            f"{zip_path.name}: Blender's builder left out {len(missing)} wheel(s) (platform tag not "
            f"matched): {', '.join(missing)}"
        )
    extra = sorted(wheels - expected)
    if extra:
        raise BuildError(f"{zip_path.name}: unexpected wheels {', '.join(extra)}")
    for python in expected_by_python:
        for package in packages:
            usable = [
                w
                for w in wheels
                if wheel_name_version(w)[0] == normalize(package) and python_tag_matches(w, python)
            ]
            if len(usable) != 1:
                raise BuildError(
                    f"{zip_path.name}: Python {python} needs exactly one {package} wheel, the zip has "
                    f"{', '.join(usable) or 'none'}"
                )
    leaked = sorted(
        n
        for n in names
        if n.split("/", 1)[0] in ("tests", "bench", "tools", ".venv", "dist", "docs", "CHANGES.md")
    )
    if leaked:
        raise BuildError(f"{zip_path.name}: holds files that must be excluded, e.g. {leaked[0]}")
    if any(wheel_name_version(w)[0] in NEVER for w in wheels):
        raise BuildError(f"{zip_path.name}: holds a numpy wheel")
    return len(names)


def build(*, targets, output_dir, wheels_dir, pythons=tuple(PYTHONS), root=ROOT):
    """Build and check one zip per target and Python; return {(target, python): zip path}."""
    version = core_version(root)
    pins_by_python = {python: read_pins(root, PYTHONS[python]) for python in pythons}
    blender_ext_file = blender_ext_path()
    blender_ext = load_blender_ext(blender_ext_file)
    log(f"Cliff Terrain {version}; Blender builder {blender_ext_file}")

    manifest_path = root / MANIFEST
    repo_text = manifest_path.read_text()
    manifest = tomllib.loads(repo_text)
    unknown = sorted(set(targets) - set(manifest.get("platforms", ())))
    if unknown:
        raise BuildError(f"{MANIFEST} does not declare platform(s) {', '.join(unknown)}")

    per_target = download_wheels(targets, pins_by_python, wheels_dir)
    all_wheels = sorted(
        {w for by_python in per_target.values() for files in by_python.values() for w in files}
    )

    if set(targets) == set(manifest["platforms"]) and set(pythons) == set(PYTHONS):
        new_text = manifest_text(repo_text, version=version, wheels=all_wheels)
        if new_text != repo_text:
            manifest_path.write_text(new_text)
            log(f"rewrote {MANIFEST}: version {version}, {len(all_wheels)} wheels")
    elif manifest.get("version") != version:
        log(f"note: {MANIFEST} says version {manifest.get('version')!r}; building {version}")

    output_dir.mkdir(parents=True, exist_ok=True)
    exclude = manifest.get("build", {}).get("paths_exclude_pattern", [])
    zips = {}
    for python in pythons:
        wheels = sorted({w for target in targets for w in per_target[target][python]})
        with tempfile.TemporaryDirectory(prefix="cliff_terrain_stage_") as tmp:
            stage = Path(tmp) / "cliff_terrain"
            built = Path(tmp) / "built"
            stage.mkdir()
            built.mkdir()
            n_files = stage_sources(root, stage, blender_ext, exclude)
            (stage / "wheels").mkdir()
            for wheel in wheels:
                link_or_copy(wheels_dir / wheel, stage / "wheels" / wheel)
            (stage / MANIFEST).write_text(
                manifest_text(
                    repo_text,
                    version=version,
                    wheels=wheels,
                    platforms=list(targets),
                    blender_version_min=BLENDER_MIN[python],
                )
            )
            log(
                f"Python {python}: staged {n_files} source files and {len(wheels)} wheels; building "
                f"{', '.join(targets)}"
            )
            code, output = run_builder(
                blender_ext_file,
                ["build", "--source-dir", str(stage), "--output-dir", str(built), "--split-platforms"],
            )
            if code != 0:
                raise BuildError(f"Blender's builder failed (exit {code}):\n{output}")
            for target in targets:
                platform = target.replace("-", "_")
                made = built / f"{manifest['id']}-{version}-{platform}.zip"
                if not made.is_file():
                    raise BuildError(f"the builder did not write {made.name}")
                zip_path = output_dir / zip_name(manifest["id"], version, target, python)
                shutil.move(made, zip_path)
                zips[target, python] = zip_path

    for (target, python), zip_path in zips.items():
        code, output = run_builder(blender_ext_file, ["validate", str(zip_path)])
        if code != 0 or "error" in output.lower():
            raise BuildError(f"{zip_path.name} does not validate:\n{output}")
        expected = {python: per_target[target][python]}
        n_entries = check_zip(zip_path, expected, manifest["id"], blender_version_min=BLENDER_MIN[python])
        size_mb = zip_path.stat().st_size / 1e6
        log(
            f"{zip_path.name}: {size_mb:.1f} MB, {n_entries} entries, {len(expected[python])} wheels for "
            f"Python {python}, Blender {BLENDER_MIN[python]} or newer, valid"
        )
    return zips


def zip_name(extension_id, version, target, python):
    """``cliff_terrain-0.1.0-linux_x64-python3.13.zip``: Blender's own name plus the Python version."""
    return f"{extension_id}-{version}-{target.replace('-', '_')}-python{python}.zip"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    parser.add_argument(
        "--platform",
        action="append",
        choices=sorted(TARGETS),
        help="build this platform only (repeatable; default: every platform in the manifest)",
    )
    parser.add_argument(
        "--python",
        action="append",
        choices=sorted(PYTHONS),
        help="bundle wheels for this Python only (repeatable; default: every Python Blender uses)",
    )
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    parser.add_argument("--wheels-dir", type=Path, default=ROOT / "wheels")
    args = parser.parse_args(argv)
    if args.platform:
        targets = list(dict.fromkeys(args.platform))
    else:
        targets = tomllib.loads((ROOT / MANIFEST).read_text()).get("platforms", list(TARGETS))
    try:
        zips = build(
            targets=targets,
            output_dir=args.output_dir.resolve(),
            wheels_dir=args.wheels_dir.resolve(),
            pythons=tuple(dict.fromkeys(args.python or PYTHONS)),
        )
    except BuildError as exc:
        print(f"build_extension: error: {exc}", file=sys.stderr)
        return 1
    for (target, python), path in zips.items():
        log(f"ok {target}, Python {python}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
