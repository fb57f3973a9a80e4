"""CPU ↔ device parity of the persistent CG loop (``cg_loop="persistent"``, the CUDA default): grid-wide
barriers across many blocks, and fewer blocks than row groups. Device selection and skipping as in
``tests/test_cuda_parity.py`` (``WARPFACE_PARITY_DEVICE``, default ``cuda:0``; run by ``scripts/gpu_check.sh``).
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from helpers import parity_device

DEVICE = parity_device()

CPU = wp.get_device("cpu")


def pulled_shell():
    """A 1.8k-node shell, its top 40 % fixed and its bottom 10 % driven: ``(mesh, fixed, driven)``."""
    from warpface.fem import shell_tet_mesh

    mesh = shell_tet_mesh(20, 20, 3)
    p = mesh.points
    fixed = np.flatnonzero(p[:, 1] > np.quantile(p[:, 1], 0.6))
    driven = np.flatnonzero(p[:, 1] < np.quantile(p[:, 1], 0.1))
    return mesh, fixed, driven


@pytest.mark.parametrize("blocks", [None, 7])
def test_persistent_cg_with_many_blocks_matches_direct(blocks):
    """The persistent CG kernel on a 1.8k-node shell: as many blocks as row groups (grid barriers across
    ~100 blocks on CUDA), or 7 blocks that each walk many row groups. Every step within 1e-9 m of the
    direct solver, the same iterations as the launched loop, the barrier counters cleared after each step."""
    from warpface.fem import CGOptions, TissueMaterial, TissueSimulation

    if blocks is not None and not DEVICE.is_cuda:
        pytest.skip("blocks that wait for each other need CUDA: on the CPU the kernel runs as one block")
    mesh, fixed, driven = pulled_shell()
    steps = 30
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = -5e-3 * np.sin(np.linspace(0.05, 1.5, steps))[:, None]
    trajectory[steps // 2 :, :, 2] = 1e-3  # a jump
    material = TissueMaterial(1e5, 0.45, 20.0, 1000.0)
    expected = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, solver="direct", device=CPU).run(
        trajectory
    )
    runs = {}
    for loop in ("persistent", "launched"):
        sim = TissueSimulation(
            mesh,
            material,
            1e-3,
            fixed=fixed,
            driven=driven,
            solver="cg",
            device=DEVICE,
            cg=CGOptions(tolerance=1e-12, maxiter=400, chunk=8, loop=loop),
        )
        if loop == "persistent" and blocks is not None:
            sim.solver._persistent_blocks = blocks  # before the first graph is captured
        runs[loop] = (sim.run(trajectory), sim.solver.total_iterations, sim.solver._barrier.numpy())
    got, iterations, barrier = runs["persistent"]
    assert np.abs(expected).max() > 1e-3
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert abs(iterations - runs["launched"][1]) <= 2  # reduction order differs: +-1 iteration at a step or two
    np.testing.assert_array_equal(barrier, 0)


@pytest.mark.parametrize("blocks_per_model, waves", [(None, None), (5, [(0, 2), (2, 1)])])
def test_batched_persistent_cg_matches_each_models_direct(blocks_per_model, waves):
    """TissueBatch on the 1.8k-node shell: three models in one launch of the persistent kernel, each model's
    blocks meeting at its own barrier (as many as the GPU gives each, or 5 that walk many row groups, the
    models split over two launches). Each model within 1e-9 m of its own direct run, every barrier cleared."""
    from warpface.fem import CGOptions, TissueBatch, TissueMaterial, TissueSimulation

    if blocks_per_model is not None and not DEVICE.is_cuda:
        pytest.skip("blocks that wait for each other need CUDA: on the CPU a model runs as one block")
    mesh, fixed, driven = pulled_shell()
    steps = 20
    trajectory = np.zeros((steps, 3, driven.size, 3))
    for b in range(3):
        trajectory[:, b, :, 1] = -(3.0 + b) * 1e-3 * np.sin(np.linspace(0.05, 1.5, steps))[:, None]
    trajectory[steps // 2 :, 1, :, 2] = 1e-3  # a jump in one model only
    materials = [
        TissueMaterial(1e5, 0.45, 20.0, 1000.0),
        TissueMaterial(5e4, 0.49, 5.0, 1100.0),
        TissueMaterial(2e5, 0.40, 60.0, 1000.0),
    ]
    batch = TissueBatch(
        mesh,
        materials,
        1e-3,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device=DEVICE,
        cg=CGOptions(tolerance=1e-12, maxiter=400, chunk=8),
    )
    if blocks_per_model is not None:  # before the first graph is captured
        batch.solver.blocks_per_model, batch.solver.waves = blocks_per_model, waves
    got = batch.run(trajectory)
    for b, material in enumerate(materials):
        expected = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, solver="direct", device=CPU).run(
            trajectory[:, b]
        )
        assert np.abs(expected).max() > 1e-3
        np.testing.assert_allclose(got[:, b], expected, rtol=0, atol=1e-9, err_msg=f"model {b}")
    np.testing.assert_array_equal(batch.solver._barrier.numpy(), 0)
    assert len(set(batch.cg_iterations[:, 2].tolist())) > 1  # each model stops at its own convergence
