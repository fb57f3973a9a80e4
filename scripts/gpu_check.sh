#!/usr/bin/env bash
# CPU <-> CUDA parity of every device path (tests/test_cuda_parity*.py), run on the GPU machine.
#
# Before: warp installed into /tmp/site; a pure-Python pytest carried in .gpu/site. numpy, scipy
# (and optionally torch) come from the machine's Python. Usage, from anywhere in the checkout:
#     bash scripts/gpu_check.sh [extra pytest arguments]
# WARPFACE_PARITY_DEVICE picks the device (default cuda:0). Fails, rather than skipping, when Warp
# cannot see that device, so a green run always means the parity tests ran.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3}"
export PYTHONPATH="/tmp/site:$PWD/.gpu/site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
export WARPFACE_PARITY_DEVICE="${WARPFACE_PARITY_DEVICE:-cuda:0}"

nvidia-smi -L
"$PYTHON" - <<'PY'
import os
import warp as wp

wp.init()
name = os.environ["WARPFACE_PARITY_DEVICE"]
try:
    device = wp.get_device(name)
except Exception as exc:  # noqa: BLE001
    raise SystemExit(f"gpu_check: Warp {wp.__version__} cannot use {name!r} ({exc}); devices: {[str(d) for d in wp.get_devices()]}")
print(f"warp {wp.__version__} on {device} ({device.name})")
PY
exec "$PYTHON" -m pytest -q -x -rs -p no:cacheprovider --durations=5 tests/test_cuda_parity.py tests/test_cuda_parity_plans.py tests/test_cuda_parity_cg.py "$@"
