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


def test_every_solver_has_one_step_contract(beam):
    """direct, CG (both loops) and the batched solvers: ``step(state_in, state_out, control, dt)`` with the
    solver's own dt gives what the simulation's run() gives; another dt, or arguments of the wrong type, are
    refused before anything is stepped."""
    from warpface.fem import CGOptions, TissueBatch

    mesh, fixed, driven = beam
    trajectory = _trajectory(12, driven.size)
    reference = TissueSimulation(mesh, MATERIAL, 1e-3, fixed=fixed, driven=driven, device="cpu").run(trajectory)
    solvers = [
        TissueSimulation(mesh, MATERIAL, 1e-3, fixed=fixed, driven=driven, device="cpu", solver=kind, cg=options)
        for kind, options in [
            ("direct", None),
            ("cg", CGOptions(tolerance=1e-12, loop="launched")),
            ("cg", CGOptions(tolerance=1e-12, loop="persistent")),
        ]
    ]
    batches = [
        TissueBatch(mesh, [MATERIAL] * 2, 1e-3, fixed=fixed, driven=driven, device="cpu", solver=kind, cg=options)
        for kind, options in [("direct", None), ("cg", CGOptions(tolerance=1e-12))]
    ]
    for owner in solvers + batches:
        solver, state, control = owner.solver, owner.state, owner.control
        models = state.model_count
        with pytest.raises(ValueError, match="dt must be the solver's time step"):
            solver.step(state, state, control, 2e-3)
        with pytest.raises(TypeError, match="TissueState"):
            solver.step(state.d, state, control)
        for t, row in enumerate(trajectory):
            control.driven.assign(row if models is None else np.stack([row] * models))
            solver.step(state, state, control, 1e-3)
            d = state.d.numpy()
            np.testing.assert_allclose(d if models is None else d[-1], reference[t], atol=1e-9, rtol=0)
        solver.reset(state)  # a new trajectory: the next step starts from the predictor again
        assert solver.kind in ("direct", "cg")


def test_batched_state_and_control_views():
    state = TissueState(4, models=3, device="cpu")
    control = TissueControl(0, models=3, device="cpu")
    assert state.d.shape == (3, 4) and state.model_count == 3 and state.node_count == 4
    assert control.driven.shape == (3, 1) and TissueState(4, device="cpu").model_count is None
    values = np.arange(36.0).reshape(3, 4, 3)
    state.assign(values, -values, 2 * values)
    one = state.model(1)
    np.testing.assert_array_equal(one.d.numpy(), values[1])
    one.v.zero_()  # a view: writes reach the batch
    np.testing.assert_array_equal(state.v.numpy()[1], 0.0)
    np.testing.assert_array_equal(state.v.numpy()[2], -values[2])
    with pytest.raises(ValueError, match="models"):
        TissueState(4, models=0, device="cpu")


def test_cg_options_are_checked():
    from warpface.fem import CGOptions

    assert CGOptions().maxiter == 200 and CGOptions().chunk == 64 and CGOptions(maxiter=7.0).maxiter == 7
    for options, error, message in [
        (dict(tolerance="1e-5"), TypeError, "CGOptions.tolerance must be a number"),
        (dict(tolerance=0.0), ValueError, "CGOptions.tolerance"),
        (dict(maxiter=2.5), ValueError, "CGOptions.maxiter must be a whole number"),
        (dict(maxiter=True), TypeError, "CGOptions.maxiter"),
        (dict(chunk=0), ValueError, "CGOptions.chunk"),
        (dict(preconditioner=3), TypeError, "CGOptions.preconditioner must be a string"),
        (dict(preconditioner="ilu"), ValueError, "CGOptions.preconditioner must be one of"),
        (dict(loop="unrolled"), ValueError, "CGOptions.loop must be one of"),
        (dict(dtype=np.float64), ValueError, "CGOptions.dtype"),
        (dict(use_graph="yes"), TypeError, "CGOptions.use_graph"),
    ]:
        with pytest.raises(error, match=message):
            CGOptions(**options)


def test_each_solver_refuses_options_it_does_not_implement(beam):
    from warpface.fem import CGOptions, TissueBatch

    mesh, fixed, driven = beam
    options = dict(fixed=fixed, driven=driven, device="cpu", solver="cg")
    with pytest.raises(ValueError, match="preconditioner of CGSolver"):
        TissueSimulation(mesh, MATERIAL, 1e-3, cg=CGOptions(preconditioner="fsai_each"), **options)
    with pytest.raises(ValueError, match="preconditioner of BatchedCGSolver"):
        TissueBatch(mesh, [MATERIAL], 1e-3, cg=CGOptions(preconditioner="diag"), **options)
    with pytest.raises(ValueError, match="loop of BatchedCGSolver"):
        TissueBatch(mesh, [MATERIAL], 1e-3, cg=CGOptions(loop="launched"), **options)
    with pytest.raises(ValueError, match="dtype of BatchedCGSolver"):
        TissueBatch(mesh, [MATERIAL], 1e-3, cg=CGOptions(dtype=wp.float32), **options)
    with pytest.raises(TypeError, match="cg must be a CGOptions"):
        TissueSimulation(mesh, MATERIAL, 1e-3, cg=dict(tolerance=1e-6), **options)
    with pytest.raises(TypeError, match="materials must be a sequence"):
        TissueBatch(mesh, MATERIAL, 1e-3, **options)


class _FakeCuda:
    is_cuda, is_cpu, sm_count = True, False, 132


def test_loop_choice_follows_the_occupancy_query():
    """``auto`` runs the persistent kernel only where the occupancy query finds a resident block on every
    multiprocessor (its grid barrier needs all blocks co-resident), the launched loop otherwise; an explicit
    ``persistent`` where nothing fits is refused. The CPU never asks (one block, no barrier to wait at)."""
    from warpface.fem.solver_cg import choose_loop

    def never():
        raise AssertionError("the CPU must not query occupancy")

    cpu, cuda = wp.get_device("cpu"), _FakeCuda()
    assert (
        choose_loop("auto", device=cpu, capacity=never) == "launched"
        and choose_loop("persistent", device=cpu, capacity=never) == "persistent"
    )
    assert choose_loop("auto", device=cuda, capacity=lambda: 2 * 132) == "persistent"
    assert choose_loop("auto", device=cuda, capacity=lambda: 131) == "launched"  # not one block per multiprocessor
    assert choose_loop("auto", device=cuda, capacity=lambda: 0) == "launched"  # the query failed or nothing fits
    assert choose_loop("launched", device=cuda, capacity=never) == "launched"
    with pytest.raises(ValueError, match="occupancy"):
        choose_loop("persistent", device=cuda, capacity=lambda: 0)


def test_control_feed_rings_host_rows_into_the_control():
    from warpface.fem.state import ControlFeed

    control = TissueControl(2, models=3, device="cpu")
    feed = ControlFeed(control, 2)
    rows = np.arange(18.0).reshape(3, 2, 3)
    feed.put(rows)
    np.testing.assert_array_equal(control.driven.numpy(), rows)
    assert not feed.wrapped
    feed.put(-rows)
    assert feed.wrapped
    np.testing.assert_array_equal(control.driven.numpy(), -rows)
    queued = ControlFeed(TissueControl(2, device="cpu"), 3)
    queued._view = None  # the device path: host ring slots copied into the control
    for k in range(4):
        queued.put(k * rows[0])
        np.testing.assert_array_equal(queued.control.driven.numpy(), k * rows[0])
        assert queued.wrapped == (k == 2)
