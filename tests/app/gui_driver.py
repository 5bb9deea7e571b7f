"""Drive the sidebar's GUI test: start Blender in the current X display, answer its requests with
xdotool (scroll, click) and xwd + ImageMagick (screenshots), and report its verdict.

    python3 tests/app/gui_driver.py --photo PHOTO --shot docs/images/sidebar.png [--blender blender]
        [--source REPO] [--work DIR] [--width 1600 --height 1000]

Run it inside a display (``tests/app/gui_sidebar.sh`` starts Xvfb): without one it fails, it does
not skip. Exit status 0 when every check passed, 1 otherwise (the checks and notes are printed).
Standard library only: it runs with the system Python beside the Blender under test.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TOOLS = ("xdotool", "xwd", "convert")
TIMEOUT_S = 480
# Screenshots that go beside --shot (docs/images/) for the README.
README_SHOTS = ("probe.png", "color_by_height.png", "plots.png")


def fail(message):
    print(f"gui_driver.py: FAIL: {message}", file=sys.stderr, flush=True)
    sys.exit(1)


def run(*command):
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def screenshot(path):
    """The whole X screen as a PNG (Blender's own screen.screenshot is black under Xvfb)."""
    xwd = subprocess.run(["xwd", "-root", "-silent"], check=True, capture_output=True).stdout
    subprocess.run(["convert", "xwd:-", f"png:{path}"], input=xwd, check=True, capture_output=True)


def main():
    parser = argparse.ArgumentParser(prog="gui_driver.py")
    parser.add_argument("--photo", required=True)
    parser.add_argument("--shot", required=True, help="where the final screenshot goes (sidebar.png)")
    parser.add_argument(
        "--blender",
        default=os.environ.get("BLENDER", "blender"),
        help="the Blender command, with any options of its own (default $BLENDER or blender)",
    )
    parser.add_argument(
        "--source", help="register the add-on from this source folder instead of the installed zip"
    )
    parser.add_argument("--work", help="scratch folder (default: a temporary one)")
    parser.add_argument("--width", type=int, default=1600)
    parser.add_argument("--height", type=int, default=1000)
    parser.add_argument("--max-size", type=int, default=400)
    parser.add_argument(
        "--ortho", help="a georeferenced orthophoto with dsm.tif beside it (the plot grid part)"
    )
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder and Blender's log")
    args = parser.parse_args()

    if not os.environ.get("DISPLAY"):
        fail("no X display (DISPLAY is unset): run tests/app/gui_sidebar.sh, which starts Xvfb")
    blender_command = shlex.split(args.blender)
    missing = [tool for tool in (*TOOLS, blender_command[0]) if shutil.which(tool) is None]
    if missing:
        fail(f"missing programs: {', '.join(missing)} (apt-get install xdotool x11-apps imagemagick blender)")
    photo = Path(args.photo).resolve()
    if not photo.is_file():
        fail(f"photo not found: {photo}")
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="cliff_terrain_gui_"))
    work.mkdir(parents=True, exist_ok=True)
    for stale in ("state.json", "result.json"):
        (work / stale).unlink(missing_ok=True)

    command = [
        *blender_command,
        "-p", "0", "0", str(args.width), str(args.height),
        "--python", str(HERE / "gui_sidebar.py"),
        "--", "--work", str(work), "--photo", str(photo), "--max-size", str(args.max_size),
    ]  # fmt: skip
    if args.source:
        command += ["--source", str(Path(args.source).resolve())]
    if args.ortho:
        command += ["--ortho", str(Path(args.ortho).resolve())]
    log_path = work / "blender.log"
    print("starting:", " ".join(command), flush=True)
    with open(log_path, "w") as log:
        blender = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    try:
        verdict = drive(blender, work, Path(args.shot))
    finally:
        if blender.poll() is None:
            try:
                blender.wait(timeout=20)
            except subprocess.TimeoutExpired:
                blender.terminate()
                blender.wait(timeout=20)
    if verdict is None:
        print(log_path.read_text()[-4000:], file=sys.stderr)
        fail(f"Blender gave no verdict (exit status {blender.returncode}); log: {log_path}")
    for name, passed in verdict["checks"].items():
        print(f"  {'ok  ' if passed else 'FAIL'} {name}")
    for note in verdict["notes"]:
        print(f"  note: {note}")
    if verdict["error"]:
        print(verdict["error"], file=sys.stderr)
    if not verdict["passed"]:
        print(log_path.read_text()[-4000:], file=sys.stderr)
        fail("the sidebar test failed")
    print(f"passed; screenshot: {args.shot}")
    if not args.keep and not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def drive(blender, work, shot):
    """Answer Blender's requests until it publishes a verdict or exits."""
    state_path, result_path = work / "state.json", work / "result.json"
    seen = 0
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if result_path.exists() and blender.poll() is not None:
            break
        if blender.poll() is not None and not result_path.exists():
            return None
        try:
            state = json.loads(state_path.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            time.sleep(0.2)
            continue
        if state["seq"] == seen:
            time.sleep(0.1)
            continue
        seen = state["seq"]
        phase = state["phase"]
        if phase == "category":
            # The wheel over the sidebar's tab strip (its right edge) cycles its tabs.
            x, y = state["point"]
            run("xdotool", "mousemove", str(x), str(y))
            time.sleep(0.1)
            run("xdotool", "keydown", "ctrl", "click", "5", "keyup", "ctrl")
        elif phase == "shot":
            path = Path(state["path"])
            time.sleep(0.5)  # let the window finish drawing
            screenshot(path)
            if path.name == "sidebar.png":
                shot.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(path, shot)
            elif path.name in README_SHOTS:  # beside sidebar.png, for the README
                shutil.copyfile(path, shot.parent / path.name)
            Path(state["done"]).write_text("ok")
        elif phase == "click":
            x, y = state["point"]
            run("xdotool", "mousemove", str(x), str(y))
            time.sleep(0.3)
            run("xdotool", "click", "1")
            time.sleep(1.0)
            screenshot(work / "after_click.png")  # for the log when the build never comes
            # Move away so the final screenshot shows no hover highlight.
            run("xdotool", "mousemove", "200", "600")  # an empty part of the 3D view: no tooltip
        elif phase == "key":
            x, y = state["point"]
            run("xdotool", "mousemove", str(x), str(y))
            time.sleep(0.2)
            run("xdotool", "key", state["key"])
        elif phase == "done":
            deadline = min(deadline, time.monotonic() + 30)
    if not result_path.exists():
        return None
    text = result_path.read_text()
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        return {
            "passed": False,
            "checks": {},
            "notes": [text],
            "error": f"Blender's verdict is not JSON: {exc}",
        }


if __name__ == "__main__":
    sys.exit(main())
