"""Newton-style stepping: solver.step(state_in, state_out, control) on device state, both solvers."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warpface.fem import CGOptions, TissueControl, TissueMaterial, TissueSimulation, TissueState, box_tet_mesh
from warpface.fem.newmark import newmark_coefficients

MATERIAL = TissueMaterial(1e5, 0.45, 20.0, 1000.0)


@pytest.fixture(scope="module")
def beam():
    mesh = box_tet_mesh((0.06, 0.02, 0.02), (6, 2, 2))
    return mesh, np.flatnonzero(mesh.points[:, 0] < 1e-12), np.flatnonzero(mesh.points[:, 0] > 0.06 - 1e-12)


def _trajectory(steps: int, driven: int) -> np.ndarray:
    out = np.zeros((steps, driven, 3))
    out[:, :, 1] = 2e-3 * np.sin(np.linspace(0.1, 1.5, steps))[:, None]
    out[7:, :, 2] = 1e-3  # a jump
    return out


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_ping_pong_states_match_run(beam, solver):
    mesh, fixed, driven = beam
    options = dict(fixed=fixed, driven=driven, device="cpu", solver=solver, cg=CGOptions(tolerance=1e-12))
    reference = TissueSimulation(mesh, MATERIAL, 1e-3, **options).run(_trajectory(20, driven.size))
    sim = TissueSimulation(mesh, MATERIAL, 1e-3, **options)
    states = [TissueState(mesh.node_count, device="cpu"), TissueState(mesh.node_count, device="cpu")]
    control = TissueControl(driven.size, device="cpu")
    for t, row in enumerate(_trajectory(20, driven.size)):
        control.driven.assign(row)
        before = states[t % 2].numpy()
        sim.solver.step(states[t % 2], states[(t + 1) % 2], control)
        after = states[t % 2].numpy()
        for x, y in zip(before, after):
            np.testing.assert_array_equal(x, y)  # state_in is only read
        d = states[(t + 1) % 2].d.numpy()
        np.testing.assert_allclose(d, reference[t], atol=1e-9, rtol=0)
        np.testing.assert_array_equal(d[driven], row)
        assert np.all(d[fixed] == 0.0)
    if solver == "cg":
        sim.solver.synchronize()
        assert len(sim.solver._bindings) == 2  # two bindings (graphs on CUDA) reused, none per step


def test_state_update_is_newmark(beam):
    """One direct step: the acceleration and velocity written follow the Newmark update from the new d."""
    mesh, fixed, driven = beam
    sim = TissueSimulation(mesh, MATERIAL, 2e-3, fixed=fixed, driven=driven, device="cpu", beta=0.3, gamma=0.6)
    state = TissueState(mesh.node_count, device="cpu")
    rng = np.random.default_rng(3)
    d0, v0, a0 = (rng.normal(scale=1e-4, size=(mesh.node_count, 3)) for _ in range(3))
    for x in (d0, v0, a0):
        x[fixed] = 0.0
    state.assign(d0, v0, a0)
    out = TissueState(mesh.node_count, device="cpu")
    control = TissueControl(driven.size, device="cpu")
    control.driven.assign(np.full((driven.size, 3), 5e-4))
    sim.solver.step(state, out, control)
    d1, v1, a1 = out.numpy()
    c = newmark_coefficients(2e-3, 0.3, 0.6)
    a_expected = 1 / (0.3 * 4e-6) * (d1 - d0) - 1 / (0.3 * 2e-3) * v0 - (1 / 0.6 - 1) * a0
    v_expected = v0 + 2e-3 * 0.4 * a0 + 2e-3 * 0.6 * a_expected
    np.testing.assert_allclose(a1, a_expected, rtol=1e-12, atol=1e-12 * np.abs(a_expected).max())
    np.testing.assert_allclose(v1, v_expected, rtol=1e-12, atol=1e-12 * np.abs(v_expected).max())
    assert c.mass_displacement == pytest.approx(1 / (0.3 * 4e-6))


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_step_rejects_mismatched_state(beam, solver):
    mesh, fixed, driven = beam
    sim = TissueSimulation(mesh, MATERIAL, 1e-3, fixed=fixed, driven=driven, device="cpu", solver=solver)
    with pytest.raises(ValueError, match="state_in must hold"):
        sim.solver.step(TissueState(5, device="cpu"), sim.state, sim.control)
    with pytest.raises(ValueError, match="state_out must hold"):
        sim.solver.step(sim.state, TissueState(mesh.node_count, dtype=wp.float32, device="cpu"), sim.control)
    with pytest.raises(ValueError, match="control must hold"):
        sim.solver.step(sim.state, sim.state, TissueControl(driven.size + 1, device="cpu"))
