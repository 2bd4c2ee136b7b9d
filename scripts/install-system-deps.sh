#!/usr/bin/env bash
# Debian (bookworm) packages for livetrack's camera sources; quiet and quick when they are all present.
#   bash scripts/install-system-deps.sh [EXTRA_PACKAGE ...]     # also installs the extra packages if missing
#
# - gir1.2-aravis-0.8          Aravis 0.8 (GigE Vision / USB3 Vision) and its GObject introspection data
# - aravis-tools-cli           arv-tool-0.8: list cameras, read and write their features
# - libgirepository1.0-dev libcairo2-dev pkg-config gcc python3-dev
#                              to build PyGObject<3.51 and pycairo from source into the venv (pip does that:
#                              PyGObject 3.51+ needs girepository-2.0, which bookworm does not have, and
#                              Debian's python3-gi only serves Debian's own /usr/bin/python3)
# V4L2 webcams need nothing more (OpenCV's wheel has its V4L2 backend built in).
# Needs apt-get, as root or with sudo.
set -euo pipefail

PACKAGES=(gir1.2-aravis-0.8 aravis-tools-cli libgirepository1.0-dev libcairo2-dev pkg-config gcc python3-dev "$@")

missing=()
for pkg in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
[ ${#missing[@]} -eq 0 ] && exit 0

if ! command -v apt-get >/dev/null; then
  echo "install-system-deps.sh: missing ${missing[*]} and no apt-get: install them by hand" >&2
  exit 1
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-system-deps.sh: need root or sudo for apt-get" >&2; exit 1; }
  sudo="sudo"
fi
echo "install-system-deps.sh: apt-get install ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
