"""The external nodal force of a Newmark step (``TissueSimulation.step(force=...)``, every solver): an independent
float64 Newmark reference with the force on its right-hand side, a static load, the batch, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla
import warp as wp
from fem_reference import assemble_reference

from warpface.fem import CGOptions, TissueMaterial, TissueSimulation, TissueState, box_tet_mesh
from warpface.fem.newmark import newmark_coefficients
from warpface.fem.solver_batch import BatchedCGSolver
from warpface.fem.state import TissueControl

MATERIAL = TissueMaterial(1e5, 0.45, 20.0, 1000.0)
DT = 1.0e-3
DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])
LOOPS = [CGOptions(tolerance=1e-10, loop="launched"), CGOptions(tolerance=1e-10, loop="persistent")]
SOLVERS = [("direct", None, "cpu")] + [("cg", cg, device) for device in DEVICES for cg in LOOPS]


@pytest.fixture(scope="module")
def beam():
    mesh = box_tet_mesh((0.06, 0.02, 0.02), (6, 2, 2))
    x = mesh.points[:, 0]
    return mesh, np.flatnonzero(x < 1e-12), np.flatnonzero(x > 0.06 - 1e-12)


def _forces(mesh, steps: int) -> np.ndarray:
    """A load [N] per step (steps, N, 3) that grows and turns: a transverse pull rising with x, and a twist."""
    x = mesh.points[:, 0] / 0.06
    t = np.arange(1, steps + 1)[:, None] / steps
    f = np.zeros((steps, mesh.node_count, 3))
    f[:, :, 1] = 1e-2 * t * x
    f[:, :, 2] = 5e-3 * np.sin(3.0 * t) * x * (mesh.points[:, 1] - 0.01) / 0.01
    return f


def _reference(mesh, fixed, driven, forces, trajectory) -> np.ndarray:
    """Newmark-β (1/4, 1/2) in float64 on an independent assembly: ``A d_o = f_o + M(c0 d + c1 v + c2 a) + C(c3 d
    + c4 v + c5 a) − A_od d_driven`` per step; the displacements (steps, N, 3)."""
    K, M, C = assemble_reference(mesh, MATERIAL.E, MATERIAL.nu, MATERIAL.eta, MATERIAL.rho)
    c = newmark_coefficients(DT)
    A = (K + c.mass_displacement * M + c.damping_displacement * C).tocsr()
    free = np.setdiff1d(np.arange(mesh.node_count), np.r_[fixed, driven])
    o, dd = ((3 * nodes[:, None] + np.arange(3)).ravel() for nodes in (free, driven))
    solve = spla.factorized(A[o][:, o].tocsc())
    n3 = 3 * mesh.node_count
    d, v, a, out = np.zeros(n3), np.zeros(n3), np.zeros(n3), []
    for f, moved in zip(forces, trajectory):
        u = c.mass_displacement * d + c.mass_velocity * v + c.mass_acceleration * a
        w = c.damping_displacement * d + c.damping_velocity * v + c.damping_acceleration * a
        new = np.zeros(n3)
        new[dd] = moved.ravel()
        new[o] = solve((f.ravel() + M @ u + C @ w)[o] - A[o][:, dd] @ new[dd])
        a_new = c.mass_displacement * (new - d) - c.mass_velocity * v - c.mass_acceleration * a
        v = v + c.velocity_old_acceleration * a + c.velocity_new_acceleration * a_new
        d, a = new, a_new
        out.append(d.reshape(-1, 3).copy())
    return np.array(out)


@pytest.mark.parametrize(("solver", "cg", "device"), SOLVERS)
def test_the_force_enters_the_step_as_an_independent_newmark_reference_has_it(beam, solver, cg, device):
    """A turning load and moving driven nodes: the displacements of every solver equal the float64 reference's.
    The force array is written in place between steps (the step reads it where it lies)."""
    mesh, fixed, driven = beam
    steps = 12
    forces = _forces(mesh, steps)
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 2] = np.linspace(1e-5, 2e-4, steps)[:, None]
    expected = _reference(mesh, fixed, driven, forces, trajectory)
    sim = TissueSimulation(mesh, MATERIAL, DT, fixed=fixed, driven=driven, device=device, solver=solver, cg=cg)
    force = wp.zeros(mesh.node_count, dtype=wp.vec3d, device=device)
    got = []
    for f, moved in zip(forces, trajectory):
        force.assign(f)
        sim.step(moved, force=force)
        got.append(sim.d)
    scale = np.abs(expected).max()
    assert np.abs(expected[:, :, 1]).max() > 0.2 * scale  # the force moved the beam, not only the driven end
    np.testing.assert_allclose(np.array(got), expected, rtol=0, atol=1e-7 * scale)


@pytest.mark.parametrize("device", DEVICES)
def test_a_held_load_settles_at_the_static_solution(beam, device):
    """A constant load held on a damped beam: it settles at ``K_oo d = f_o`` (SciPy float64); the (N, 3) float64
    form of the force is accepted; a step without it afterwards releases the beam (the force is not kept)."""
    mesh, fixed, _ = beam
    heavy = TissueMaterial(1e5, 0.45, 1000.0, 1000.0)
    f = np.zeros((mesh.node_count, 3))
    f[:, 1] = -2e-3
    sim = TissueSimulation(mesh, heavy, DT, fixed=fixed, device=device, cg=CGOptions(tolerance=1e-10))
    force = wp.array(f, dtype=wp.float64, device=device)
    for _ in range(400):
        sim.step(force=force)
    K, _, _ = assemble_reference(mesh, heavy.E, heavy.nu, heavy.eta, heavy.rho)
    free = np.setdiff1d(np.arange(mesh.node_count), fixed)
    o = (3 * free[:, None] + np.arange(3)).ravel()
    static = np.zeros((mesh.node_count, 3))
    static[free] = spla.spsolve(K.tocsc()[o][:, o], f.ravel()[o]).reshape(-1, 3)
    assert np.abs(static).max() > 1e-5
    np.testing.assert_allclose(sim.d, static, rtol=0, atol=2e-3 * np.abs(static).max())
    held = sim.d
    sim.step(force=force)
    still = np.abs(sim.d - held).max()
    sim.step()  # no force: released, the beam springs back
    assert np.abs(sim.d - held).max() > 10.0 * still


def test_a_batch_takes_one_force_row_per_model(beam):
    """BatchedCGSolver with a (B, N) force: each model steps as its own simulation with its row."""
    mesh, fixed, _ = beam
    forces = _forces(mesh, 2)[:, None] * np.array([1.0, -2.0])[None, :, None, None]  # (steps, B, N, 3)
    sim = TissueSimulation(mesh, MATERIAL, DT, fixed=fixed, device="cpu", solver="cg", cg=CGOptions(tolerance=1e-10))
    options = CGOptions(tolerance=1e-10)
    batch = BatchedCGSolver([sim.matrices] * 2, sim.coefficients, sim.free_nodes, sim.driven_nodes, options)
    state, control = TissueState(mesh.node_count, models=2, device="cpu"), TissueControl(0, models=2, device="cpu")
    force = wp.zeros((2, mesh.node_count), dtype=wp.vec3d, device="cpu")
    expected = [_reference(mesh, fixed, np.zeros(0, int), forces[:, b], np.zeros((2, 0, 3)))[-1] for b in range(2)]
    for f in forces:
        force.assign(f)
        batch.step(state, state, control, force=force)
    got = state.d.numpy()
    for b in range(2):
        np.testing.assert_allclose(got[b], expected[b], rtol=0, atol=1e-7 * np.abs(expected[b]).max())


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_a_bad_force_is_rejected_naming_it(beam, solver):
    mesh, fixed, _ = beam
    sim = TissueSimulation(mesh, MATERIAL, DT, fixed=fixed, device="cpu", solver=solver)
    n = mesh.node_count
    with pytest.raises(TypeError, match="force"):
        sim.step(force=np.zeros((n, 3)))
    for bad in (
        wp.zeros(n + 1, dtype=wp.vec3d, device="cpu"),
        wp.zeros((n, 3), dtype=wp.float32, device="cpu"),
        wp.zeros((n, 3), dtype=wp.float64, device="cpu")[:, :2],
    ):
        with pytest.raises(ValueError, match="force"):
            sim.step(force=bad)
    assert sim.steps_taken == 0 and not np.any(sim.d)
