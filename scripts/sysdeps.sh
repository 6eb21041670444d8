#!/usr/bin/env bash
# Installs the Debian packages citylod's tests and GUI need, only when something is missing:
# xvfb (Qt windows without a display), Mesa EGL/GL (VTK off-screen), the X/xcb libraries Qt loads, and
# proj-data (the EGM96 geoid: heights in a vertical datum such as NAP placed on the WGS84 ellipsoid).
set -euo pipefail
pkgs=(xvfb xauth libegl1 libgl1 libopengl0 libegl-mesa0 libgl1-mesa-dri libglu1-mesa libxkbcommon-x11-0 libxcb-cursor0
      libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-randr0 libxcb-render-util0 libxcb-shape0 libxcb-xinerama0
      libxcb-xkb1 libdbus-1-3 libfontconfig1 libglib2.0-0 libxrender1 libxi6 libsm6 libice6 libxtst6
      proj-data)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "installing system packages: ${missing[*]}"
sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
