"""Newmark-β integrator: energy, damping balance, wave speed, CG path, constraints and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warpface.fem import (
    CGOptions,
    ConvergenceError,
    TetMesh,
    TissueMaterial,
    TissueSimulation,
    box_tet_mesh,
    shell_tet_mesh,
)

SOFT = TissueMaterial(1e5, 0.45, 0.0, 1000.0)


@pytest.fixture(scope="module")
def beam():
    mesh = box_tet_mesh((0.06, 0.02, 0.02), (6, 2, 2))
    return mesh, np.flatnonzero(mesh.points[:, 0] < 1e-12), np.flatnonzero(mesh.points[:, 0] > 0.06 - 1e-12)


def _initial_state(mesh):
    x = mesh.points[:, 0] / 0.06
    v = np.zeros((mesh.node_count, 3))
    v[:, 1] = 0.1 * x**2
    d = np.zeros_like(v)
    d[:, 2] = 1e-3 * x**2
    return d, v


def test_undamped_newmark_conserves_energy_over_1000_steps(beam):
    mesh, fixed, _ = beam
    sim = TissueSimulation(mesh, SOFT, 1e-3, fixed=fixed, device="cpu")
    sim.reset(*_initial_state(mesh))
    e0 = sum(sim.energy())
    assert e0 > 0
    energies = []
    for i in range(1000):
        sim.step()
        if i % 50 == 49:
            kinetic, strain = sim.energy()
            energies.append(kinetic + strain)
    assert np.max(np.abs(np.array(energies) / e0 - 1.0)) < 1e-6
    assert sim.steps_taken == 1000 and sim.time == pytest.approx(1.0)
    np.testing.assert_array_equal(sim.d[fixed], 0.0)


def test_damped_energy_drops_by_dt_vbar_C_vbar(beam):
    mesh, fixed, _ = beam
    sim = TissueSimulation(mesh, TissueMaterial(1e5, 0.45, 50.0, 1000.0), 1e-3, fixed=fixed, device="cpu")
    sim.reset(*_initial_state(mesh))
    C = sim.matrices.to_scipy()[2]
    for _ in range(5):
        e0, v0 = sum(sim.energy()), sim.v.ravel()
        sim.step()
        vbar = 0.5 * (v0 + sim.v.ravel())
        dissipated = 1e-3 * vbar @ (C @ vbar)
        assert dissipated > 0
        assert sum(sim.energy()) - e0 == pytest.approx(-dissipated, rel=1e-8)


def test_thin_bar_wave_speed():
    E, rho = 1e5, 1000.0
    mesh = box_tet_mesh((1.0, 0.01, 0.01), (100, 1, 1))
    x = mesh.points[:, 0]
    driven = np.flatnonzero(x < 1e-12)
    dt, steps, rise, amp = 2e-4, 450, 0.02, 1e-3
    sim = TissueSimulation(mesh, TissueMaterial(E, 0.0, 0.0, rho), dt, driven=driven, device="cpu")
    t = dt * np.arange(1, steps + 1)
    pulse = amp * np.where(t < rise, 0.5 * (1.0 - np.cos(np.pi * t / rise)), 1.0)
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 0] = pulse[:, None]
    out = sim.run(trajectory)
    np.testing.assert_allclose(out[:, driven], trajectory.astype(np.float32))

    def arrival(position):
        u = out[:, np.abs(x - position) < 1e-9, 0].mean(axis=1)
        k = np.flatnonzero(u >= amp / 2)[0]
        return t[k - 1] + (amp / 2 - u[k - 1]) / (u[k] - u[k - 1]) * dt

    speed = 0.4 / (arrival(0.7) - arrival(0.3))
    assert speed == pytest.approx(np.sqrt(E / rho), rel=0.02)


def test_run_matches_step_and_records_selected_nodes(beam):
    mesh, fixed, driven = beam
    steps = 20
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = 2e-3 * np.sin(np.linspace(0.1, 2.0, steps))[:, None]
    a = TissueSimulation(mesh, SOFT, 1e-3, fixed=fixed, driven=driven, device="cpu")
    b = TissueSimulation(mesh, SOFT, 1e-3, fixed=fixed, driven=driven, device="cpu")
    nodes = np.array([5, 17, 40])
    out = a.run(trajectory, nodes=nodes, progress=False)
    assert out.shape == (steps, 3, 3) and out.dtype == np.float32
    for t in range(steps):
        b.step(trajectory[t])
        np.testing.assert_allclose(out[t], b.d[nodes], rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(b.d[fixed], 0.0)
    np.testing.assert_array_equal(b.d[driven], trajectory[-1])
    assert np.abs(b.d).max() > 0.0


@pytest.mark.parametrize(
    "options",
    [
        dict(cg=CGOptions(use_graph=False, tolerance=1e-10, maxiter=60)),
        dict(cg=CGOptions(use_graph=True, tolerance=1e-10, maxiter=60, preconditioner="block_jacobi", chunk=4)),
        dict(cg=CGOptions(use_graph=True, tolerance=1e-5, maxiter=60, dtype=wp.float32, chunk=3)),
        dict(cg=CGOptions(use_graph=False, tolerance=1e-10, maxiter=60, loop="persistent")),
        dict(
            cg=CGOptions(use_graph=True, tolerance=1e-10, maxiter=60, preconditioner="diag", chunk=4, loop="persistent")
        ),
        dict(cg=CGOptions(use_graph=True, tolerance=1e-5, maxiter=60, dtype=wp.float32, chunk=3, loop="persistent")),
    ],
)
def test_cg_path_matches_direct_solver(beam, options):
    mesh, fixed, driven = beam
    steps = 8
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = np.linspace(1e-4, 2e-3, steps)[:, None]
    material = TissueMaterial(1e5, 0.45, 20.0, 1000.0)
    ref = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu")
    sim = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu", solver="cg", **options)
    assert sim.solver_kind == "cg" and ref.solver_kind == "direct"
    expected = ref.run(trajectory[:5])
    got = sim.run(trajectory[:5])
    for t in range(5, steps):  # queued single steps, through the trajectory ring
        ref.step(trajectory[t])
        sim.step(trajectory[t])
    rtol = 1e-7 if options["cg"].dtype == wp.float64 else 1e-4
    scale = np.abs(expected).max()
    np.testing.assert_allclose(got, expected, rtol=0, atol=rtol * scale)
    np.testing.assert_allclose(sim.d, ref.d, rtol=0, atol=rtol * scale)
    np.testing.assert_allclose(sim.v, ref.v, rtol=0, atol=rtol * 1e3 * scale)
    assert sim.cg_iterations[0] >= 1


def test_cg_block_kernels_match_direct_solver_on_rough_motion(beam, monkeypatch):
    """The kernels' CUDA block shape (many lanes and rows per block, a partial last block), run on
    CPU fibers, through smooth motion and jumps (where the extrapolated start must be rejected)."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    mesh, fixed, driven = beam
    steps = 24
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = 2e-3 * np.sin(np.linspace(0.1, 1.5, steps))[:, None]
    trajectory[[9, 17], :, 2] = 3e-3  # two jumps
    material = TissueMaterial(1e5, 0.45, 20.0, 1000.0)
    ref = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu")
    sim = TissueSimulation(
        mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu", solver="cg", cg=CGOptions(tolerance=1e-10)
    )
    assert sim.solver._kernels.block_dim > 1 and sim.free_nodes.size % sim.solver._kernels.rows != 0
    expected = ref.run(trajectory)
    got = sim.run(trajectory)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-7 * np.abs(expected).max())
    np.testing.assert_allclose(sim.v, ref.v, rtol=0, atol=1e-4 * np.abs(expected).max())


@pytest.mark.parametrize("preconditioner", ["fsai", "block_jacobi"])
def test_persistent_cg_loop_matches_launched_loop_and_direct(beam, preconditioner):
    """The persistent CG kernel (residual, start and every iteration in one launch) against the launched
    kernels and the direct solver through smooth motion and jumps: the same iterations per step, the
    same displacements to round-off, and its grid-barrier counters back at zero after every step."""
    mesh, fixed, driven = beam
    steps = 20
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = 2e-3 * np.sin(np.linspace(0.1, 1.5, steps))[:, None]
    trajectory[[7, 13], :, 2] = 3e-3  # jumps: the extrapolated start is rejected there
    material = TissueMaterial(1e5, 0.45, 20.0, 1000.0)
    ref = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu")
    expected = ref.run(trajectory)
    results = {}
    for loop in ("launched", "persistent"):
        sim = TissueSimulation(
            mesh,
            material,
            1e-3,
            fixed=fixed,
            driven=driven,
            device="cpu",
            solver="cg",
            cg=CGOptions(tolerance=1e-10, preconditioner=preconditioner, loop=loop),
        )
        assert sim.solver.loop == loop
        per_step = []
        for row in trajectory:
            sim.step(row)
            per_step.append(sim.cg_iterations[1])
        results[loop] = (sim.d, per_step, sim.solver._barrier.numpy())
    (launched, launched_iterations, _), (persistent, persistent_iterations, barrier) = results.values()
    assert persistent_iterations == launched_iterations and max(persistent_iterations) > 2
    np.testing.assert_allclose(persistent, launched, rtol=0, atol=1e-12 * np.abs(launched).max())
    np.testing.assert_allclose(persistent, expected[-1], rtol=0, atol=1e-7 * np.abs(expected).max())
    np.testing.assert_array_equal(barrier, 0)  # arrivals and departures cleared, never gave up


def test_persistent_cg_loop_reports_non_convergence(beam):
    mesh, fixed, driven = beam
    sim = TissueSimulation(
        mesh,
        SOFT,
        1e-3,
        fixed=fixed,
        driven=driven,
        device="cpu",
        solver="cg",
        cg=CGOptions(tolerance=1e-14, maxiter=2, preconditioner="diag", loop="persistent"),
    )
    with pytest.raises(ConvergenceError, match=r"step 0 .*after 2 iterations"):
        sim.run(np.full((2, driven.size, 3), 1e-3))
    assert sim.solver.iterations[0] == 2


def test_grid_capacity_is_one_block_on_the_cpu():
    from warpface.fem.kernels_persistent import grid_capacity, persistent_pcg_kernel

    kernels = persistent_pcg_kernel(wp.float64)
    assert grid_capacity(kernels.cg_step, kernels.block_dim, device=wp.get_device("cpu")) == 1
    with pytest.raises(ValueError, match="lanes must divide 32"):
        persistent_pcg_kernel(wp.float64, 12, 2)


def test_cg_extrapolated_start_saves_iterations_not_accuracy():
    """Quasi-static tissue motion (Kato's damping): the cubic extrapolation of past displacements
    starts CG far closer than the Newmark predictor, while the tolerance stays relative to the
    predictor's residual, so the result keeps its accuracy."""
    mesh = shell_tet_mesh(12, 12, 3)
    p = mesh.points
    fixed = np.flatnonzero(p[:, 1] > np.quantile(p[:, 1], 0.6))
    driven = np.flatnonzero(p[:, 1] < np.quantile(p[:, 1], 0.1))
    steps = 100
    ramp = 0.5 * (1.0 - np.cos(np.pi * np.arange(1, steps + 1) / 150.0))
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = -5e-3 * ramp[:, None]
    material = TissueMaterial(192.4e3, 0.495, 476.8, 1100.0)
    ref = TissueSimulation(mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu")
    sim = TissueSimulation(
        mesh, material, 1e-3, fixed=fixed, driven=driven, device="cpu", solver="cg", cg=CGOptions(tolerance=1e-6)
    )
    expected = ref.run(trajectory)
    got = sim.run(trajectory[:3])
    first = sim.cg_iterations[0]
    got = np.r_[got, sim.run(trajectory[3:-4])]
    history = []
    for row in trajectory[-4:]:
        sim.step(row)
        history.append(sim.d)
    most, last = sim.cg_iterations
    assert most == first  # the first steps, without a history to extrapolate from, need the most
    assert last <= 0.6 * most and sim.cg_mean_iterations < 0.8 * most
    np.testing.assert_allclose(got, expected[:-4], rtol=0, atol=1e-6 * np.abs(expected).max())
    np.testing.assert_allclose(sim.d, ref.d, rtol=0, atol=1e-6 * np.abs(expected).max())
    # the next step's start: cubic extrapolation, stored relative to the Newmark predictor
    d3, d2, d1, d = history
    predictor = d + 1e-3 * sim.v + 0.5e-6 * sim.a
    free = sim.free_nodes
    guess = sim.solver._guess.numpy()
    np.testing.assert_allclose(
        guess, (4 * d - 6 * d1 + 4 * d2 - d3 - predictor)[free], rtol=0, atol=1e-9 * np.abs(d - d1).max()
    )
    assert np.abs(guess).max() > 1e-3 * np.abs(d - d1).max()


def test_pipelined_chunks_queue_the_next_chunk_before_finishing_one():
    from warpface.fem.chunks import pipelined_chunks

    calls = []

    def queue(start, stop, parity):
        calls.append(("queue", start, stop, parity))
        return start, stop

    def finish(queued):
        calls.append(("finish", *queued))
        return queued

    got = list(pipelined_chunks(10, 4, queue, finish, device=wp.get_device("cpu")))
    assert got == [(0, 4), (4, 8), (8, 10)]
    assert calls == [
        ("queue", 0, 4, 0),
        ("queue", 4, 8, 1),
        ("finish", 0, 4),
        ("queue", 8, 10, 0),
        ("finish", 4, 8),
        ("finish", 8, 10),
    ]
    assert list(pipelined_chunks(0, 4, queue, finish, device=wp.get_device("cpu"))) == []


def test_cg_run_returns_the_state_rounded_to_float32(beam):
    """run() copies each chunk out in float32 (rounded on the device): every step's row is the float64 state of
    that step rounded to nearest, the same bits as NumPy's astype; chunks of 2 alternate the staging buffers."""
    mesh, fixed, driven = beam
    sim = TissueSimulation(
        mesh, SOFT, 1e-3, fixed=fixed, driven=driven, device="cpu", solver="cg", cg=CGOptions(chunk=2)
    )
    trajectory = np.linspace(0.0, 1e-3, 5)[:, None, None] * np.ones((1, driven.size, 3))
    states = []
    for row in trajectory:
        sim.step(row)
        states.append(sim.d.copy())
    sim.reset()
    out = sim.run(trajectory)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, np.asarray(states).astype(np.float32))


def test_cg_non_convergence_raises_with_residual(beam):
    mesh, fixed, driven = beam
    sim = TissueSimulation(
        mesh,
        SOFT,
        1e-3,
        fixed=fixed,
        driven=driven,
        device="cpu",
        solver="cg",
        cg=CGOptions(tolerance=1e-14, maxiter=1, preconditioner="diag"),
    )
    trajectory = np.full((2, driven.size, 3), 1e-3)
    with pytest.raises(ConvergenceError, match=r"step 0 .*residual [0-9.e+-]+ > tolerance"):
        sim.run(trajectory)
    with pytest.raises(RuntimeError, match="reset"):
        sim.step(trajectory[0])
    sim.reset()
    assert sim.steps_taken == 0


def test_reset_gives_consistent_acceleration(beam):
    mesh, fixed, _ = beam
    sim = TissueSimulation(mesh, TissueMaterial(1e5, 0.45, 30.0, 1000.0), 1e-3, fixed=fixed, device="cpu")
    d, v = _initial_state(mesh)
    sim.reset(d, v)
    K, M, C = sim.matrices.to_scipy()
    residual = (M @ sim.a.ravel() + C @ v.ravel() + K @ d.ravel()).reshape(-1, 3)
    free = sim.free_nodes
    assert np.abs(residual[free]).max() < 1e-9 * np.abs(K @ d.ravel()).max()
    with pytest.raises(ValueError, match="fixed node"):
        sim.reset(np.ones((mesh.node_count, 3)))
    with pytest.raises(ValueError, match="shape"):
        sim.reset(np.zeros((3, 3)))


def test_bad_input_is_rejected(beam):
    mesh, fixed, driven = beam
    n = mesh.node_count
    ok = dict(fixed=fixed, driven=driven, device="cpu")
    for kwargs, message in [
        (dict(dt=0.0), "dt must be in"),
        (dict(dt=-1e-3), "dt must be"),
        (dict(dt=float("nan")), "dt must be"),
        (dict(beta=0.0), "beta"),
        (dict(fixed=fixed, driven=np.r_[driven, fixed[:1]]), f"node {fixed[0]} is both fixed and driven"),
        (dict(driven=np.r_[driven, driven[:1]]), "listed more than once"),
        (dict(fixed=np.r_[fixed, n]), f"fixed node index {n}"),
        (dict(driven=[-1]), "out of range"),
        (dict(fixed=None, driven=None), "no fixed or driven node"),
        (dict(fixed=np.ones(3, dtype=bool)), "mask has shape"),
        (dict(fixed=[0.5]), "integer node indices"),
        (dict(solver="lu"), "solver must be"),
        (dict(formulation="q2"), "formulation"),
        (dict(cg=dict(preconditioner="ilu")), "preconditioner"),
        (dict(cg=dict(loop="unrolled")), "loop must be one of"),
        (dict(fixed=np.arange(n), driven=None), "nothing to simulate"),
    ]:
        args = dict(ok, dt=1e-3) | kwargs
        dt = args.pop("dt")
        with pytest.raises(ValueError, match=message):
            if "cg" in args:
                args["cg"] = CGOptions(**args["cg"])
            TissueSimulation(mesh, SOFT, dt, **args)
    with pytest.raises(TypeError, match="TetMesh"):
        TissueSimulation("mesh", SOFT, 1e-3, **ok)
    with pytest.raises(ValueError, match="per-tet values"):
        TissueSimulation(mesh, TissueMaterial(np.full(2, 1e5), 0.3, 0.0, 1e3), 1e-3, **ok)

    sim = TissueSimulation(mesh, SOFT, 1e-3, **ok)
    bad = np.zeros((4, driven.size, 3))
    bad[2, 3, 1] = np.nan
    with pytest.raises(ValueError, match=f"step 2, driven node {driven[3]}"):
        sim.run(bad)
    with pytest.raises(ValueError, match="shape"):
        sim.run(np.zeros((4, driven.size + 1, 3)))
    with pytest.raises(ValueError, match="shape"):
        sim.step(np.zeros((driven.size, 2)))
    with pytest.raises(ValueError, match="need displacements"):
        sim.step()
    step = np.zeros((driven.size, 3))
    step[0, 0] = np.inf
    with pytest.raises(ValueError, match=f"node {driven[0]} is not finite"):
        sim.step(step)
    with pytest.raises(ValueError, match="nodes node index"):
        sim.run(np.zeros((1, driven.size, 3)), nodes=[n + 5])


def test_every_connected_part_needs_a_constraint():
    a = box_tet_mesh((1.0, 1.0, 1.0), (1, 1, 1))
    points = np.r_[a.points, a.points + [3.0, 0.0, 0.0]]
    mesh = TetMesh(points, np.r_[a.tets, a.tets + a.node_count])
    with pytest.raises(ValueError, match=r"part containing node 8 has no fixed or driven node"):
        TissueSimulation(mesh, SOFT, 1e-3, fixed=[0, 1, 2], device="cpu")
    TissueSimulation(mesh, SOFT, 1e-3, fixed=[0, 1, 2], driven=[8], device="cpu")
