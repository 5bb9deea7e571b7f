#!/usr/bin/env bash
# The sidebar's test in a real Blender window: Xvfb, then gui_driver.py (which starts Blender, clicks
# Build Relief with xdotool, checks the relief from inside Blender, runs Render Views as a background
# job and cancels Evaluate with Esc, and saves the screenshot). Fails, never skips, without a display
# server.
#
#   tests/app/gui_sidebar.sh [PHOTO [SHOT.png [gui_driver.py options]]]
#
# PHOTO defaults to $PHOTO, SHOT to docs/images/sidebar.png. From tools/test_app.sh (`make test-app`):
#   RUN      command prefix that runs a program where Blender is (e.g. "chroot ROOTFS env -i HOME=/root
#            PATH=..."; the repository and $WORK are mounted at the same paths there); empty: here
#   BLENDER_USER_RESOURCES   the throw-away user folder with the extension installed
#   WORK     scratch folder (screenshots and Blender's log go to $WORK/gui)
#   ORTHO    a georeferenced orthophoto with dsm.tif beside it: the plot grid part runs on it
#
# Needs where Blender is: xvfb-run (xvfb, xauth), xdotool, xwd (x11-apps), convert (imagemagick),
# python3, blender.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
photo="${1:-${PHOTO:-}}"
shot="${2:-${SHOT:-$repo/docs/images/sidebar.png}}"
if [[ -z "$photo" ]]; then
    echo "usage: $0 PHOTO [SHOT.png [gui_driver.py options]]  (or PHOTO=... in the environment)" >&2
    exit 2
fi
read -r -a run <<<"${RUN:-}"
inside() { "${run[@]}" "$@"; }

for tool in xvfb-run Xvfb xauth python3; do
    if ! inside sh -c "command -v $tool" >/dev/null; then
        echo "gui_sidebar.sh: FAIL: no display server can be started: $tool is missing (apt-get install xvfb xauth python3)" >&2
        exit 1
    fi
done
options=()
if [[ -n "${WORK:-}" ]]; then
    options+=(--work "$WORK/gui" --keep)
fi
if [[ -n "${ORTHO:-}" && -f "${ORTHO}" ]]; then
    options+=(--ortho "$ORTHO")
fi
width="${GUI_WIDTH:-1600}"
height="${GUI_HEIGHT:-1000}"
inside env ${BLENDER_USER_RESOURCES:+BLENDER_USER_RESOURCES="$BLENDER_USER_RESOURCES"} \
    xvfb-run -a -s "-screen 0 ${width}x${height}x24" \
    python3 "$here/gui_driver.py" --photo "$photo" --shot "$shot" --width "$width" --height "$height" \
    "${options[@]}" "${@:3}"
