"""CPU ↔ device parity of the expression model's two plans (tiled, staged) on the parity device of
``tests/test_cuda_parity.py`` (``WARPFACE_PARITY_DEVICE``, default ``cuda:0``; skipped without it)::

    WARPFACE_PARITY_DEVICE=cpu python -m pytest -q tests/test_cuda_parity_plans.py   # logic, no GPU
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from helpers import FLOAT32_FACE_TOLERANCE, expression_controls, parity_device

DEVICE = parity_device()

CPU = wp.get_device("cpu")


@pytest.fixture(scope="module")
def face_rig():
    from warpface.assets import default_rig

    return default_rig(device="cpu")


@pytest.fixture(scope="module")
def models(face_rig):
    return face_rig.model(device=CPU), face_rig.model(device=DEVICE)


def test_plans_agree_on_the_device(face_rig, models):
    """The device default (the tiled plan on CUDA) against the staged plan on the same device: the same formulas
    in the same order, so equal up to the compiler's choice of FMA contraction, and both against the CPU. A
    batch large enough for several frames per block and several chunks equals single frames."""
    from warpface import ExpressionModel

    cpu_model, default = models
    assert default.plan == ("tiled" if DEVICE.is_cuda else "staged")
    staged = ExpressionModel.from_rig(face_rig, device=DEVICE, plan="staged")
    contractions, depths = expression_controls(face_rig, 3, seed=4)
    tolerance = FLOAT32_FACE_TOLERANCE * face_rig.mesh.size
    for frame in range(3):
        got = default.evaluate(contractions[frame], wrinkle_depths=depths[frame])
        np.testing.assert_allclose(
            got, staged.evaluate(contractions[frame], wrinkle_depths=depths[frame]), rtol=0, atol=tolerance
        )
        # Against the CPU: float32 rounding amplified at a few points of the face (the compilers contract
        # multiply-adds differently), so: the tolerance at 99.9 % of the points, 4x it at the rest.
        off = np.linalg.norm(got - cpu_model.evaluate(contractions[frame], wrinkle_depths=depths[frame]), axis=1)
        assert np.mean(off > tolerance) < 1e-3 and off.max() < 4 * tolerance, (off.max(), np.sum(off > tolerance))
    frames = max(8, 4 * (1 << 20) // face_rig.mesh.vertex_count + 1)  # > 2^20 frame·vertices per launch
    many_c, many_d = (
        np.resize(contractions, (frames, contractions.shape[1])),
        np.resize(depths, (frames, depths.shape[1])),
    )
    for model in (default, staged):
        out = wp.empty((frames, face_rig.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
        model.evaluate(many_c, out=out, wrinkle_depths=many_d)
        batch = out.numpy()
        for frame in range(3):
            np.testing.assert_array_equal(
                batch[frame], model.evaluate(contractions[frame], wrinkle_depths=depths[frame])
            )
            np.testing.assert_array_equal(batch[frames - 3 + frame], batch[(frames - 3 + frame) % 3])


@pytest.mark.skipif(not DEVICE.is_cuda, reason="the tiled plan's CUDA kernels: the parity device is not CUDA")
def test_tiled_plan_on_the_device_equals_the_cpu_tiled_plan(face_rig, models):
    """The tiled plan's CUDA kernels (resident for batches and small frames, strided otherwise) against the same
    plan on the CPU (strided, blocks of one thread)."""
    from warpface import ExpressionModel

    cpu_tiled = ExpressionModel.from_rig(face_rig, device=CPU, plan="tiled")
    _, default = models
    contractions, depths = expression_controls(face_rig, 6, seed=5)
    tolerance = FLOAT32_FACE_TOLERANCE * face_rig.mesh.size
    off = np.linalg.norm(
        default.evaluate(contractions, wrinkle_depths=depths) - cpu_tiled.evaluate(contractions, wrinkle_depths=depths),
        axis=2,
    )
    assert np.mean(off > tolerance) < 1e-3 and off.max() < 4 * tolerance, (off.max(), np.sum(off > tolerance))
