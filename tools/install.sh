#!/usr/bin/env bash
# Installs photorecon into .venv/ on a fresh Debian/Ubuntu machine with Python >= 3.10:
# the system library Open3D's wheel needs (libusb-1.0-0), Chromium (the tests look at report.html and
# 'photorecon view' in a headless browser), then the package with its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
APT=()
if ! ldconfig -p 2>/dev/null | grep -q "libusb-1.0.so.0"; then APT+=(libusb-1.0-0); fi
if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then APT+=(chromium); fi
if [ ${#APT[@]} -gt 0 ]; then
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq "${APT[@]}"
fi
PY="${PYTHON:-python3}"
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
.venv/bin/python -c "import open3d, pycolmap, cv2, onnxruntime, trimesh, viser; print('photorecon installed in .venv')"
# compile the numba kernels now, into numba's cache next to the sources, so the first run does not compile them
.venv/bin/photorecon warmup
