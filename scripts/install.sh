#!/usr/bin/env bash
# Install livetrack into ./.venv (created if missing), with the Debian packages it needs.
#   bash scripts/install.sh          # the application
#   bash scripts/install.sh --test   # the application and the test tools
# Needs Python >= 3.11 (Debian bookworm's python3). System packages come from apt-get (root or sudo).
set -euo pipefail
cd "$(dirname "$0")/.."

extras=""
for arg in "$@"; do
  case "$arg" in
    --test) extras="[test]" ;;
    *) echo "install.sh: unknown option $arg (use --test)" >&2; exit 2 ;;
  esac
done

PYTHON=${PYTHON:-python3}

apt_install() {
  # Install the Debian packages in "$@" that are missing; quiet when all are present.
  local missing=()
  for pkg in "$@"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  if ! command -v apt-get >/dev/null; then
    echo "install.sh: missing system packages ${missing[*]} and no apt-get: install them by hand" >&2
    return 1
  fi
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  echo "install.sh: apt-get install ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

# Debian's python3 ships without venv/ensurepip unless python3-venv is installed.
if ! "$PYTHON" -c 'import venv, ensurepip' 2>/dev/null; then
  apt_install python3-venv
fi

# Aravis (GigE Vision / USB3 Vision) and what building PyGObject into the venv needs.
if [ "${LIVETRACK_SKIP_SYSTEM_DEPS:-0}" != "1" ]; then
  bash scripts/install-system-deps.sh
fi

if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".${extras}"
echo "install.sh: livetrack installed in $(pwd)/.venv"
