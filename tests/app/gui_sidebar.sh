#!/usr/bin/env bash
# The sidebar's test in a real Blender window: Xvfb, then gui_driver.py (which starts Blender, clicks
# Build Relief with xdotool and saves the screenshot). Fails, never skips, without a display server.
#
#   tests/app/gui_sidebar.sh PHOTO SHOT.png [gui_driver.py options, e.g. --blender "blender" --source .]
#
# Needs on PATH: xvfb-run (xvfb, xauth), xdotool, xwd (x11-apps), convert (imagemagick), python3, blender.
set -euo pipefail
if [[ $# -lt 2 ]]; then
    echo "usage: $0 PHOTO SHOT.png [gui_driver.py options]" >&2
    exit 2
fi
for tool in xvfb-run Xvfb python3; do
    if ! command -v "$tool" >/dev/null; then
        echo "gui_sidebar.sh: FAIL: no display server can be started: $tool is missing (apt-get install xvfb xauth)" >&2
        exit 1
    fi
done
here="$(cd "$(dirname "$0")" && pwd)"
exec xvfb-run -a -s "-screen 0 ${GUI_WIDTH:-1600}x${GUI_HEIGHT:-1000}x24" \
    python3 "$here/gui_driver.py" --photo "$1" --shot "$2" \
    --width "${GUI_WIDTH:-1600}" --height "${GUI_HEIGHT:-1000}" "${@:3}"
