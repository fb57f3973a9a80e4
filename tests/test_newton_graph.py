"""SolverFace's host-free step (graph_capturable): the same results as the host path, no host read inside the step,
and a step captured in a graph replays as eager steps do (CPU graphs here, CUDA where present)."""

from __future__ import annotations

import numpy as np
import pytest

newton = pytest.importorskip("newton", reason="the newton extra is not installed (pip install 'warpface[newton]')")

import warp as wp  # noqa: E402
from helpers import shell_face  # noqa: E402

from warpface.fem import kato_uniform_material  # noqa: E402
from warpface.newton import SolverFace, add_face  # noqa: E402

MATERIAL = kato_uniform_material()
DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


def _set_body(state, body: int, position, velocity) -> None:
    q, qd = state.body_q.numpy(), state.body_qd.numpy()
    q[body, :3], q[body, 3:] = position, (0.0, 0.0, 0.0, 1.0)
    qd[body, :3], qd[body, 3:] = velocity, 0.0
    state.body_q.assign(q)
    state.body_qd.assign(qd)


def _shaken(graph_capturable: bool, steps: int = 120, device: str = "cpu"):
    """A head accelerated smoothly to 3 g with a rotation starting; the tissue's displacement per step."""
    rig, tetmesh, fixed, _ = shell_face(6, 2)
    builder = newton.ModelBuilder()
    head = builder.add_body(xform=wp.transform((0.0, 0.0, 0.0), wp.quat_identity()))
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, head_body=head, driven=[])
    model = builder.finalize(device=device)
    dt = 1.0e-3
    solver = SolverFace(model, face, graph_capturable=graph_capturable, solver="cg")
    state_in, state_out, control = model.state(), model.state(), model.control()
    position, velocity, out = np.zeros(3), np.zeros(3), []
    for k in range(steps):
        s = np.clip((k + 0.5) * dt / 0.05, 0.0, 1.0)
        velocity = velocity + np.array([3.0 * 9.81 * s * s * (3.0 - 2.0 * s), 0.0, 0.0]) * dt
        position = position + velocity * dt
        q, qd = state_out.body_q.numpy(), state_out.body_qd.numpy()
        angle = 0.5 * 2.0 * (k + 1) * dt * (k + 1) * dt  # ω = 2 rad/s² t about z
        q[head, :3], q[head, 3:] = position, (0.0, 0.0, np.sin(angle / 2.0), np.cos(angle / 2.0))
        qd[head, :3], qd[head, 3:] = velocity, (0.0, 0.0, 2.0 * (k + 1) * dt)
        state_out.body_q.assign(q)
        state_out.body_qd.assign(qd)
        solver.step(state_in, state_out, control, None, dt)
        state_in, state_out = state_out, state_in
        out.append(solver.simulation.d)
    solver.synchronize()
    return np.array(out)


@pytest.mark.parametrize("device", DEVICES)
def test_host_free_body_force_matches_the_host_solve(device):
    """The inertial body force (3 g and a spinning head) on the tissue step's right-hand side: the host-free path's
    device kernels give the host path's NumPy force (CPU), the same displacements on each device."""
    host, device = _shaken(False), _shaken(True, device=device)
    scale = np.abs(host).max()
    assert scale > 1e-5
    assert np.abs(device - host).max() < 2e-5 * scale


def _graph_world(device: str, **options):
    """A head body with a hyper gravity, a sphere pressed into the cheek and a muscle control: every part of the
    host-free step at work; the states and contacts are set once (replays see the same inputs)."""
    rig, tetmesh, fixed, outer = shell_face(8, 2, span_u=0.7, span_v=0.5)
    builder = newton.ModelBuilder()
    head = builder.add_body(xform=wp.transform((0.0, 0.0, 0.0), wp.quat_identity()))
    sphere = builder.add_body(xform=wp.transform((0.0, 0.0, 1.0), wp.quat_identity()))
    builder.add_shape_sphere(sphere, radius=0.03)
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, head_body=head, contact_radius=1e-4)
    model = builder.finalize(device=device)
    gravity = (0.0, -3.0 * 9.81, 0.0)
    solver = SolverFace(model, face, dt=1.0e-3, gravity=gravity, graph_capturable=True, **options)
    pipeline = newton.CollisionPipeline(model, soft_contact_gap=0.003)
    contacts = pipeline.contacts()
    state_in, state_out, control = model.state(), model.state(), model.control()
    apex = tetmesh.points[int(outer[4, 4])] + np.array([0.0, 0.0, 0.03 - 0.002])
    for state in (state_in, state_out):
        _set_body(state, sphere, apex, (0.0, 0.0, 0.0))
        _set_body(state, head, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    _set_body(state_out, head, (0.001, 0.0, 0.0), (1.0, 0.0, 0.0))
    control.warpface.activation.assign(np.array([0.01], dtype=np.float32))
    pipeline.collide(state_in, contacts)
    return solver, (state_in, state_out, control, contacts)


def test_the_host_free_step_reads_nothing_back(monkeypatch):
    """No .numpy(), no synchronisation inside step (moving head, contacts, a muscle control), once set up."""
    solver, args = _graph_world("cpu")
    solver.step(*args, 1.0e-3)  # the first step binds the arrays

    def refuse(*_args, **_kwargs):
        raise AssertionError("the host-free step read the device")

    for name in ("numpy", "list"):
        monkeypatch.setattr(wp.array, name, refuse)
    for name in ("synchronize", "synchronize_device", "synchronize_stream", "synchronize_event"):
        monkeypatch.setattr(wp, name, refuse)
    for _ in range(3):
        solver.step(*args, 1.0e-3)
    monkeypatch.undo()
    solver.synchronize()
    assert solver.contact_report.active > 0
    assert np.isfinite(args[1].particle_q.numpy()).all()


@pytest.mark.parametrize("device", DEVICES)
def test_a_captured_step_replays_as_eager_steps(device):
    """wp.ScopedCapture of two ping-pong steps (s0 -> s1 -> s0), replayed N times, gives the 2N eager steps'
    tissue and particles."""
    replays = 3

    def two_steps(solver, args):
        state_a, state_b, control, contacts = args
        solver.step(state_a, state_b, control, contacts, 1.0e-3)
        solver.step(state_b, state_a, control, contacts, 1.0e-3)

    eager, args = _graph_world(device)
    for _ in range(replays):
        two_steps(eager, args)
    expected_d, expected_q = eager.simulation.d, args[0].particle_q.numpy().copy()
    eager.synchronize()

    captured, args = _graph_world(device)
    captured.step(*args, 1.0e-3)  # an eager step: builds the solver, loads the kernels; then back to the start
    captured.reset(args[0])
    with wp.ScopedCapture(device=device) as capture:
        two_steps(captured, args)
    for _ in range(replays):
        wp.capture_launch(capture.graph)
    captured.synchronize()
    assert np.abs(expected_d).max() > 1e-5 and captured.contact_report.active > 0
    # the CPU replays the eager arithmetic exactly; on CUDA the order of atomic sums may move a CG stop by one
    # iteration (a 1e-5 relative tolerance)
    exact = device == "cpu"
    tolerance = 1e-12 if exact else 1e-5 * np.abs(expected_d).max()
    assert np.allclose(captured.simulation.d, expected_d, rtol=0.0, atol=tolerance)
    assert np.allclose(args[0].particle_q.numpy(), expected_q, rtol=0.0, atol=1e-7 if exact else 1e-6)


def test_a_non_finite_control_is_held_and_raised_by_synchronize():
    solver, args = _graph_world("cpu")
    state_in, state_out, control, contacts = args
    solver.step(*args, 1.0e-3)
    control.warpface.activation.assign(np.array([np.nan], dtype=np.float32))
    solver.step(*args, 1.0e-3)
    with pytest.raises(ValueError, match="levator.*not finite"):
        solver.synchronize()
    assert np.isfinite(solver.simulation.d).all() and np.isfinite(state_out.particle_q.numpy()).all()
    solver.synchronize()  # raised once


def test_a_non_finite_head_motion_gives_no_body_force_and_is_raised_by_synchronize():
    solver, args = _graph_world("cpu")
    state_in, state_out, control, contacts = args
    solver.step(*args, 1.0e-3)
    _set_body(state_out, 0, (0.001, 0.0, 0.0), (np.nan, 0.0, 0.0))  # body 0: the head
    solver.step(*args, 1.0e-3)
    assert np.isfinite(solver.simulation.d).all()
    with pytest.raises(FloatingPointError, match="head motions"):
        solver.synchronize()
    solver.synchronize()  # raised once


def test_without_inertia_the_tissue_rides_along_the_turning_head():
    """``inertia=False`` on the host-free path (its head-frame kernel alone): no force, the tissue stays at rest in
    the head frame, the particles are ``p + R X``."""
    rig, tetmesh, fixed, _ = shell_face(6, 2)
    builder = newton.ModelBuilder()
    head = builder.add_body(xform=wp.transform((0.0, 0.0, 0.0), wp.quat_identity()))
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, head_body=head, driven=[])
    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face, dt=1.0e-3, graph_capturable=True, inertia=False)
    state_in, state_out, control = model.state(), model.state(), model.control()
    for k in range(1, 6):
        angle = 0.1 * k
        q, qd = state_out.body_q.numpy(), state_out.body_qd.numpy()
        q[head] = (0.01 * k, 0.0, 0.0, 0.0, 0.0, np.sin(angle / 2.0), np.cos(angle / 2.0))
        qd[head] = (10.0, 0.0, 0.0, 0.0, 0.0, 100.0)
        state_out.body_q.assign(q)
        state_out.body_qd.assign(qd)
        solver.step(state_in, state_out, control, None, 1.0e-3)
        state_in, state_out = state_out, state_in
    solver.synchronize()
    assert np.abs(solver.simulation.d).max() < 1e-12
    c, s = np.cos(0.5), np.sin(0.5)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    expected = np.array([0.05, 0.0, 0.0]) + tetmesh.points @ rotation.T
    assert np.abs(state_in.particle_q.numpy()[face.particles] - expected).max() < 1e-6


def test_capturable_options_are_checked():
    rig, tetmesh, fixed, _ = shell_face(6, 2)
    builder = newton.ModelBuilder()
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed)
    model = builder.finalize(device="cpu")
    with pytest.raises(ValueError, match="cg"):
        SolverFace(model, face, graph_capturable=True, solver="direct")
    with pytest.raises(TypeError, match="graph_capturable"):
        SolverFace(model, face, graph_capturable="yes")
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="contact_stiffness"):
            SolverFace(model, face, graph_capturable=True, contact_stiffness=bad)
    with pytest.raises(ValueError, match="contact_passes"):
        SolverFace(model, face, graph_capturable=True, contact_passes=1.5)
    assert SolverFace(model, face).graph_capturable is False  # the CPU default: the host path


def _counting(function, name: str, calls: dict):
    def counted(*args, **kwargs):
        calls[name] += 1
        return function(*args, **kwargs)

    return counted


@pytest.mark.parametrize("device", DEVICES)
def test_a_solver_replaying_its_own_step_graphs_steps_as_eagerly(device, monkeypatch):
    """``step_graphs``: ping-pong steps (two sets of arrays) give the eager steps' tissue, particles and contacts;
    once both graphs exist a step is one graph launch and no kernel launch; reset drops them (an eager step again)."""
    steps = 6

    def ping_pong(solver, args, count):
        state_a, state_b, control, contacts = args
        for k in range(count):
            solver.step(*((state_a, state_b) if k % 2 == 0 else (state_b, state_a)), control, contacts, 1.0e-3)

    eager, eager_args = _graph_world(device, step_graphs=False)
    graphs, args = _graph_world(device, step_graphs=True)
    assert graphs._capturable.own_graphs and not eager._capturable.own_graphs
    ping_pong(eager, eager_args, steps)
    ping_pong(graphs, args, 4)  # eager, eager, captured, captured
    calls = {"launch": 0, "capture_launch": 0}
    for name in calls:
        monkeypatch.setattr(wp, name, _counting(getattr(wp, name), name, calls))
    ping_pong(graphs, args, steps - 4)
    monkeypatch.undo()
    assert calls == {"launch": 0, "capture_launch": steps - 4}
    assert graphs.simulation.steps_taken == eager.simulation.steps_taken == steps
    exact = device == "cpu"
    scale = np.abs(eager.simulation.d).max()
    assert scale > 1e-5 and graphs.contact_report.active > 0
    assert graphs.contact_report == eager.contact_report or not exact
    np.testing.assert_allclose(graphs.simulation.d, eager.simulation.d, rtol=0, atol=1e-12 if exact else 1e-5 * scale)
    q, q_eager = args[0].particle_q.numpy(), eager_args[0].particle_q.numpy()
    np.testing.assert_allclose(q, q_eager, rtol=0, atol=1e-7 if exact else 1e-6)
    fresh = wp.zeros_like(args[1].particle_q)  # a state's array replaced: that step is recorded again
    args[1].particle_q = fresh
    calls["launch"] = 0
    monkeypatch.setattr(wp, "launch", _counting(wp.launch, "launch", calls))
    graphs.step(args[0], args[1], args[2], args[3], 1.0e-3)
    monkeypatch.undo()
    assert calls["launch"] > 0 and np.abs(fresh.numpy()).max() > 0.0
    graphs.reset(args[0])
    assert not graphs._capturable._graphs
    graphs.synchronize()
    eager.synchronize()
