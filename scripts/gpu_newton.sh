#!/usr/bin/env bash
# SolverFace on CUDA: the plug's overhead rows (benchmarks/newton.py --quick --overhead-only) and the Newton and
# external-force tests (tests/test_newton*.py, tests/test_fem_force.py, the persistent CG parity of
# tests/test_cuda_parity_cg.py) on the GPU machine.
#
# Set-up as scripts/gpu_check.sh (Warp in /tmp/site, pytest in .gpu/site), plus Newton importable from there
# (e.g. `pip install --no-deps --target /tmp/site newton`). Fails, rather than skipping, when Newton or the CUDA
# device is missing. With $OUT set, the benchmark's JSON and the tests' JUnit XML are written into it.
#     bash scripts/gpu_newton.sh [extra pytest arguments]
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3}"
export PYTHONPATH="/tmp/site:$PWD/.gpu/site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
export WARPFACE_PARITY_DEVICE="${WARPFACE_PARITY_DEVICE:-cuda:0}"
DEVICE="$WARPFACE_PARITY_DEVICE"
OUT_DIR="${OUT:-}"

"$PYTHON" - "$DEVICE" <<'PY'
import sys
import warp as wp
import newton

wp.init()
try:
    device = wp.get_device(sys.argv[1])
except Exception as exc:  # noqa: BLE001
    raise SystemExit(f"gpu_newton: Warp {wp.__version__} cannot use {sys.argv[1]!r} ({exc})")
if not device.is_cuda:
    raise SystemExit(f"gpu_newton: {device} is not a CUDA device")
print(f"warp {wp.__version__}, newton {newton.__version__} on {device} ({device.name})")
PY
"$PYTHON" -m benchmarks.newton --device "$DEVICE" --quick --overhead-only ${OUT_DIR:+--out "$OUT_DIR"}
exec "$PYTHON" -m pytest -q -x -rs -p no:cacheprovider --durations=5 \
    tests/test_newton.py tests/test_newton_graph.py tests/test_newton_io.py tests/test_fem_force.py \
    tests/test_cuda_parity_cg.py ${OUT_DIR:+--junitxml "$OUT_DIR/newton_tests.xml"} "$@"
