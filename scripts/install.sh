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

# Debian's python3 ships without venv/ensurepip unless python3-venv is installed; Aravis (GigE Vision / USB3
# Vision) and what building PyGObject into the venv needs come from scripts/install-system-deps.sh.
extra_packages=()
if ! "$PYTHON" -c 'import venv, ensurepip' 2>/dev/null; then
  extra_packages+=(python3-venv)
fi
# --test: the test of the real Rerun viewer runs it headless, on a virtual display (xvfb) with Mesa's Vulkan driver
# (lavapipe; with Mesa's OpenGL alone the viewer exits: no R32Float render target); it is skipped without them.
test_packages=()
if [ -n "$extras" ]; then
  test_packages+=(xvfb mesa-vulkan-drivers)
fi
if [ "${LIVETRACK_SKIP_SYSTEM_DEPS:-0}" != "1" ]; then
  bash scripts/install-system-deps.sh "${extra_packages[@]}" "${test_packages[@]}"
elif [ ${#extra_packages[@]} -gt 0 ]; then
  echo "install.sh: LIVETRACK_SKIP_SYSTEM_DEPS=1 but ${extra_packages[*]} is missing" >&2
  exit 1
fi

if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".${extras}"
# compile every numba kernel of the package (edge LM and the work around it, pose, surround, the detector's) into
# numba's cache now (~30-60 s), not during the first frame of the first run (tests/test_warm_up.py checks the
# warm-up reaches them all)
.venv/bin/python -c "from livetrack.estimator import warm; print(f'install.sh: kernels compiled in {warm.warm_up():.1f} s')"
echo "install.sh: livetrack installed in $(pwd)/.venv"
