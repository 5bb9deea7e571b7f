#!/usr/bin/env bash
# `make test-app`: the extension in a real Blender executable, as a user installs and runs it.
#
# 1. Uses the `blender` on PATH; where there is none, sets up Debian 13's Blender (4.3.2, Python 3.13,
#    numpy 2.2) in a debootstrap chroot cached outside the repository ($CLIFF_TERRAIN_CACHE, default
#    ~/.cache/cliff-terrain/debian13-blender; needs root, debootstrap and the Debian mirror).
# 2. Builds the linux-x64 zip for that Blender's Python and installs it into a throw-away user folder
#    with `blender --command extension install-file -r user_default -e ZIP`.
# 3. In background mode, runs the Build Relief operator on a real photo (tests/app/check_build.py).
# 4. Runs `blender -b -P render_views.py -- PHOTO --out DIR` with nothing on PYTHONPATH and checks the
#    outputs (tests/app/check_views.py).
# 5. Runs the sidebar test in a real window under Xvfb (tests/app/gui_sidebar.sh), when present.
# Any failure exits non-zero; nothing is skipped in silence.
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
SHARED=$(cd "$REPO/.." && pwd)/shared
PY=${PY:-$REPO/.venv/bin/python}
CACHE=${CLIFF_TERRAIN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/cliff-terrain}
ROOTFS=$CACHE/debian13-blender
CHROOT_PACKAGES="blender python3-numpy libegl-mesa0 libgl1-mesa-dri libglx-mesa0 xvfb xauth x11-apps imagemagick xdotool"

say() { echo "[test-app] $*"; }
fail() { echo "[test-app] FAILED: $*" >&2; exit 1; }

WORK=$(mktemp -d /tmp/cliff-terrain-app.XXXXXX)
MOUNTS=()
cleanup() {
  local i
  for ((i = ${#MOUNTS[@]} - 1; i >= 0; i--)); do umount -l "${MOUNTS[i]}" 2>/dev/null || true; done
  rm -rf "$WORK"
}
trap cleanup EXIT

bind() {  # bind DIR into the chroot at the same path
  local target=$ROOTFS$1
  mkdir -p "$target"
  if ! mountpoint -q "$target"; then
    mount --bind "$1" "$target"
    MOUNTS+=("$target")
  fi
}

setup_chroot() {
  [ "$(id -u)" -eq 0 ] || fail "no blender on PATH, and setting up Debian 13's Blender in a chroot needs root: run as root, or put Blender 4.2+ on PATH"
  command -v debootstrap >/dev/null || { say "installing debootstrap"; apt-get install -y -qq debootstrap >/dev/null; }
  if [ ! -f "$ROOTFS/.cliff-terrain-ready" ]; then
    say "setting up Debian 13 with Blender in $ROOTFS (a few minutes, once)"
    rm -rf "$ROOTFS"
    mkdir -p "$CACHE"
    debootstrap --variant=minbase trixie "$ROOTFS" http://deb.debian.org/debian >"$CACHE/debootstrap.log" 2>&1 \
      || fail "debootstrap failed, see $CACHE/debootstrap.log"
    cp /etc/resolv.conf "$ROOTFS/etc/resolv.conf"
    for d in proc sys dev; do bind "/$d"; done
    chroot "$ROOTFS" bash -c "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $CHROOT_PACKAGES" \
      >"$CACHE/apt.log" 2>&1 || fail "installing Blender in the chroot failed, see $CACHE/apt.log"
    touch "$ROOTFS/.cliff-terrain-ready"
  fi
  for d in proc sys dev; do bind "/$d"; done
  bind "$REPO"
  [ -d "$SHARED" ] && bind "$SHARED"
  bind "$WORK"
}

if command -v blender >/dev/null; then
  RUN=(env -u PYTHONPATH)
  say "using $(command -v blender)"
else
  setup_chroot
  RUN=(chroot "$ROOTFS" env -i HOME=/root PATH=/usr/local/bin:/usr/bin:/bin LANG=C.UTF-8)
  say "using Debian 13's Blender in $ROOTFS"
fi
blender_run() { "${RUN[@]}" BLENDER_USER_RESOURCES="$WORK/user" blender "$@"; }

VERSION=$(blender_run -b --factory-startup --python-expr 'import sys, bpy; print("CT-VERSION", bpy.app.version_string, "%d.%d" % sys.version_info[:2])' 2>/dev/null | sed -n 's/^CT-VERSION //p')
[ -n "$VERSION" ] || fail "blender does not start in background mode"
BLENDER_VERSION=${VERSION% *}
PYVER=${VERSION##* }
say "Blender $BLENDER_VERSION, Python $PYVER"

PHOTO=${CLIFF_TERRAIN_APP_PHOTO:-$SHARED/data/uav/broccoli/01_clip_raw_test.jpg}
if [ ! -f "$PHOTO" ]; then
  say "the shared photo $PHOTO is absent (../shared missing): using the synthetic demo field"
  PHOTO=$WORK/synthetic_field.png
  "$PY" -m cliff_terrain synthetic "$PHOTO" >/dev/null
fi

say "building the linux-x64 zip for Python $PYVER"
(cd "$REPO" && "$PY" tools/build_extension.py --platform linux-x64 --python "$PYVER" --output-dir "$WORK/dist") >"$WORK/build.log" 2>&1 \
  || { cat "$WORK/build.log"; fail "the extension zip did not build"; }
ZIP=$(ls "$WORK"/dist/cliff_terrain-*-linux_x64-python"$PYVER".zip)

say "installing $(basename "$ZIP") into a throw-away user folder"
blender_run --command extension install-file -r user_default -e "$ZIP" >"$WORK/install.log" 2>&1 \
  || { cat "$WORK/install.log"; fail "Blender refused the zip"; }

say "Build Relief in background mode on $(basename "$PHOTO")"
blender_run -b --python-exit-code 1 --python "$REPO/tests/app/check_build.py" -- "$PHOTO" "$WORK/build.json" \
  >"$WORK/check_build.log" 2>&1 || { tail -40 "$WORK/check_build.log"; fail "Build Relief in the real Blender"; }
cat "$WORK/build.json"; echo

say "render_views.py with nothing on PYTHONPATH"
blender_run -b --python-exit-code 1 -P "$REPO/render_views.py" -- "$PHOTO" --out "$WORK/views" --max-size 300 --samples 4 \
  >"$WORK/render_views.log" 2>&1 || { tail -40 "$WORK/render_views.log"; fail "render_views.py in the real Blender"; }
"$PY" "$REPO/tests/app/check_views.py" "$PHOTO" "$WORK/views" || fail "render_views.py's outputs"

if [ -f "$REPO/tests/app/gui_sidebar.sh" ]; then
  say "the sidebar in a real window under Xvfb"
  RUN="${RUN[*]}" BLENDER_USER_RESOURCES="$WORK/user" WORK="$WORK" PHOTO="$PHOTO" \
    ORTHO="$SHARED/data/dsm/fieldimager_ex2/odm_orthophoto.tif" bash "$REPO/tests/app/gui_sidebar.sh" \
    || fail "the sidebar test in a real window"
fi
say "all passed on Blender $BLENDER_VERSION (Python $PYVER)"
