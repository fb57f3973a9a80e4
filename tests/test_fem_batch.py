"""TissueBatch: B material models on one mesh, each against its own single-model direct simulation."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.fem import (
    CGOptions,
    ConvergenceError,
    TissueBatch,
    TissueMaterial,
    TissueSimulation,
    box_tet_mesh,
    shell_tet_mesh,
)


@pytest.fixture(scope="module")
def shell():
    mesh = shell_tet_mesh(8, 8, 2)
    p = mesh.points
    fixed = np.flatnonzero(p[:, 1] > np.quantile(p[:, 1], 0.7))
    driven = np.flatnonzero(p[:, 1] < np.quantile(p[:, 1], 0.1))
    return mesh, fixed, driven


def _materials(mesh):
    rng = np.random.default_rng(3)
    per_tet_e = 150e3 * (1.0 + 0.5 * rng.random(mesh.tet_count))  # a heterogeneous model
    return [
        TissueMaterial(192.4e3, 0.495, 476.8, 1100.0),
        TissueMaterial(60e3, 0.45, 50.0, 1000.0),
        TissueMaterial(per_tet_e, 0.49, 300.0, 1100.0),
    ]


def _trajectories(steps, models, driven_count):
    """Own trajectory per model (T, B, D, 3): a smooth pull with a jump at step 7 for model 1."""
    t = np.arange(1, steps + 1) / steps
    traj = np.zeros((steps, models, driven_count, 3))
    for b in range(models):
        traj[:, b, :, 1] = -(2.0 + b) * 1e-3 * np.sin(0.5 * np.pi * t)[:, None]
        traj[:, b, :, 2] = 1e-3 * b * t[:, None]
    if models > 1:
        traj[7:, 1, :, 0] += 1e-3
    return traj


@pytest.mark.parametrize(
    "formulation, preconditioner", [("linear", "fsai"), ("anp", "fsai"), ("anp", "fsai_each"), ("anp", "block_jacobi")]
)
def test_batched_cg_matches_each_models_direct_simulation(shell, formulation, preconditioner):
    mesh, fixed, driven = shell
    materials = _materials(mesh)
    steps = 12
    traj = _trajectories(steps, len(materials), driven.size)
    batch = TissueBatch(
        mesh,
        materials,
        1e-3,
        fixed=fixed,
        driven=driven,
        formulation=formulation,
        solver="cg",
        device="cpu",
        cg=CGOptions(tolerance=1e-10, preconditioner=preconditioner, chunk=5),
    )
    assert batch.solver_kind == "cg" and batch.model_count == 3
    got = batch.run(traj[:8], nodes=np.arange(0, mesh.node_count, 3))
    for t in range(8, steps):  # queued single steps through the host ring (wraps at chunk = 5)
        batch.step(traj[t])
    for b, material in enumerate(materials):
        ref = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, formulation=formulation, device="cpu")
        expected = ref.run(traj[:8, b])
        for t in range(8, steps):
            ref.step(traj[t, b])
        assert np.abs(got[:, b] - expected[:, ::3]).max() < 1e-9 + 1e-7 * np.abs(expected).max()
        assert np.abs(batch.d[b] - ref.d).max() < 1e-9, f"model {b}"
    most, last, total = batch.cg_iterations.T
    assert np.all(most >= 1) and np.all(total >= steps)
    assert len(set(total.tolist())) > 1  # each model converges on its own


def test_batched_direct_equals_single_simulations_and_shared_trajectory_broadcasts(shell):
    mesh, fixed, driven = shell
    materials = _materials(mesh)[:2]
    shared = _trajectories(6, 1, driven.size)[:, 0]
    batch = TissueBatch(mesh, materials, 1e-3, fixed=fixed, driven=driven, device="cpu")
    assert batch.solver_kind == "direct"
    out = batch.run(shared)
    cg = TissueBatch(
        mesh, materials, 1e-3, fixed=fixed, driven=driven, solver="cg", device="cpu", cg=CGOptions(tolerance=1e-10)
    )
    cg_out = cg.run(shared)
    for b, material in enumerate(materials):
        ref = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu")
        np.testing.assert_array_equal(out[:, b], ref.run(shared))
        assert np.abs(cg.d[b] - ref.d).max() < 1e-9
    assert np.abs(out[:, 0] - out[:, 1]).max() > 1e-5  # the materials differ
    assert np.abs(cg_out - out).max() < 1e-9 + 1e-7 * np.abs(out).max()
    batch.reset()
    cg.reset()
    assert batch.steps_taken == 0 and np.all(cg.d == 0.0)


def test_batch_bad_input_and_non_convergence():
    mesh = box_tet_mesh((0.06, 0.02, 0.02), (4, 2, 2))
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-12)
    driven = np.flatnonzero(mesh.points[:, 0] > 0.06 - 1e-12)
    soft = TissueMaterial(1e5, 0.45, 0.0, 1000.0)
    with pytest.raises(ValueError, match="non-empty"):
        TissueBatch(mesh, [], 1e-3, fixed=fixed, device="cpu")
    with pytest.raises(TypeError, match="model 1"):
        TissueBatch(mesh, [soft, "steel"], 1e-3, fixed=fixed, device="cpu")
    with pytest.raises(ValueError, match="both fixed and driven"):
        TissueBatch(mesh, [soft], 1e-3, fixed=fixed, driven=fixed, device="cpu")
    batch = TissueBatch(
        mesh,
        [soft, soft],
        1e-3,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device="cpu",
        cg=CGOptions(tolerance=1e-14, maxiter=1),
    )
    for bad in (np.zeros((3, driven.size, 3)), np.full((driven.size, 3), np.nan), np.full((driven.size, 3), 1e3)):
        with pytest.raises(ValueError):
            batch.step(bad)
    with pytest.raises(ConvergenceError, match=r"model 0: CG did not converge at step 0"):
        batch.run(np.full((2, driven.size, 3), 1e-3))


def test_per_model_fsai_fits_each_model_on_one_support(shell):
    """``fsai_each``: every model's factor on the reference model's support, refitted to its own values
    (closer to its inverse: fewer CG iterations in total than the one shared factor)."""
    mesh, fixed, driven = shell
    materials = _materials(mesh)
    steps = 10
    traj = _trajectories(steps, len(materials), driven.size)
    totals = {}
    for preconditioner in ("fsai", "fsai_each"):
        batch = TissueBatch(
            mesh,
            materials,
            1e-3,
            fixed=fixed,
            driven=driven,
            formulation="linear",
            solver="cg",
            device="cpu",
            cg=CGOptions(tolerance=1e-10, preconditioner=preconditioner),
        )
        batch.run(traj)
        totals[preconditioner] = batch.cg_iterations[:, 2]
        lower = batch.solver._factor[0].values.numpy()
        assert lower.shape[0] == (1 if preconditioner == "fsai" else len(materials))
        if preconditioner == "fsai_each":
            assert all(np.abs(lower[b] - lower[(b + 1) % len(materials)]).max() > 0 for b in range(len(materials)))
    assert totals["fsai_each"].sum() < totals["fsai"].sum(), totals


@pytest.mark.parametrize("preconditioner", ["fsai", "fsai_each"])
def test_fsai_of_the_median_model_keeps_every_model_near_its_own_iterations(preconditioner):
    """A sweep of E (0.5-2x) against eta (2-0.5x), as in benchmarks/fem.py: the factor comes from the model
    of median system diagonal (here the middle one of the sweep), and the batch's slowest model needs
    about the CG iterations the slowest needs alone with its own FSAI (the support of an arbitrary model,
    picked by a measure that sums to about zero, cost up to 1.9x more before)."""
    mesh = shell_tet_mesh(8, 8, 2)
    p = mesh.points
    fixed = np.flatnonzero(p[:, 1] > p[:, 1].min() + 0.62 * np.ptp(p[:, 1]))
    driven = np.flatnonzero(p[:, 1] < np.quantile(p[:, 1], 0.1))
    scale = np.linspace(0.5, 2.0, 5)
    materials = [TissueMaterial(192.4e3 * e, 0.495, 476.8 * eta, 1100.0) for e, eta in zip(scale, scale[::-1])]
    steps = 24
    traj = np.zeros((steps, driven.size, 3))
    traj[:, :, 1] = -4e-3 * np.sin(0.5 * np.pi * np.arange(1, steps + 1) / steps)[:, None]
    batch = TissueBatch(
        mesh,
        materials,
        1e-3,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device="cpu",
        cg=CGOptions(preconditioner=preconditioner),
    )
    assert batch.solver.reference_model == 2  # E and eta sweep opposite ways; the diagonal follows E here
    batch.run(traj)
    batched = batch.cg_iterations[:, 2] / steps
    alone = []
    for material in materials:
        sim = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, solver="cg", device="cpu")
        sim.run(traj)
        alone.append(sim.cg_mean_iterations)
    # the batch steps as long as its slowest model: that one needs about what the slowest needs alone
    assert batched.max() <= 1.25 * max(alone), (batched, alone)
    if preconditioner == "fsai_each":
        assert np.all(batched <= 1.15 * np.asarray(alone) + 0.5), (batched, alone)


def test_batch_in_waves_equals_one_launch_and_the_single_model_solver(shell):
    """The batched CG step is the single-model persistent kernel with a model index: models launched in
    separate waves give the same bits as one launch, and each model the same bits as a CGSolver alone
    (the same FSAI factor: each model's own, so the shared ``"fsai"`` is not used here)."""
    mesh, fixed, driven = shell
    materials = _materials(mesh)
    traj = _trajectories(6, len(materials), driven.size)
    runs = []
    for waves in (None, [(0, 1), (1, 2)]):
        batch = TissueBatch(
            mesh,
            materials,
            1e-3,
            fixed=fixed,
            driven=driven,
            solver="cg",
            device="cpu",
            cg=CGOptions(tolerance=1e-10, preconditioner="block_jacobi"),
        )
        assert batch.solver.waves == [(0, 3)]
        if waves is not None:
            batch.solver.waves = waves
        runs.append(batch.run(traj))
    np.testing.assert_array_equal(runs[0], runs[1])
    for b, material in enumerate(materials):
        sim = TissueSimulation(
            mesh,
            material,
            1e-3,
            fixed=fixed,
            driven=driven,
            solver="cg",
            device="cpu",
            cg=CGOptions(tolerance=1e-10, preconditioner="block_jacobi", loop="persistent"),
        )
        np.testing.assert_array_equal(runs[0][:, b], sim.run(traj[:, b]), err_msg=f"model {b}")
