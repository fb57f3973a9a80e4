"""warpface's face as a Newton solver: closed loops against the standalone FEM, a pressed sphere, a 3 g head."""

from __future__ import annotations

import numpy as np
import pytest

newton = pytest.importorskip("newton", reason="the newton extra is not installed (pip install 'warpface[newton]')")

import warp as wp  # noqa: E402
from fem_reference import assemble_reference  # noqa: E402
from helpers import shell_face  # noqa: E402

from warpface.fem import TissueSimulation, kato_uniform_material  # noqa: E402
from warpface.newton import SolverFace, add_face  # noqa: E402

MATERIAL = kato_uniform_material()


def _world(builder, rig, tetmesh, fixed, device="cpu", **options):
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, **options)
    model = builder.finalize(device=device)
    return face, model


def _set_body(state, body: int, position, velocity) -> None:
    q = state.body_q.numpy()
    qd = state.body_qd.numpy()
    q[body, :3], q[body, 3:] = position, (0.0, 0.0, 0.0, 1.0)
    qd[body, :3], qd[body, 3:] = velocity, 0.0
    state.body_q.assign(q)
    state.body_qd.assign(qd)


CASES = [("world", False, "cpu"), ("body at rest", False, "cpu"), ("body at rest", True, "cpu")]
if wp.is_cuda_available():  # the CUDA default: host-free, replayed from SolverFace's own graphs
    CASES.append(("body at rest", None, "cuda:0"))


@pytest.mark.parametrize(("head", "capturable", "device"), CASES)
def test_fixed_head_without_contact_matches_the_standalone_simulation(head, capturable, device):
    """200 steps of a muscle pulling the driven nodes: SolverFace's particles equal TissueSimulation's nodes (the
    CPU's direct solver); also on the host-free path (CG tissue, the expression model on the device)."""
    rig, tetmesh, fixed, _ = shell_face(8, 2)
    builder = newton.ModelBuilder()
    head_body = -1 if head == "world" else builder.add_body(xform=wp.transform((0.1, 0.2, 0.3), wp.quat_identity()))
    face, model = _world(builder, rig, tetmesh, fixed, device, head_body=head_body)
    dt = 1.0e-3
    solver = SolverFace(model, face, graph_capturable=capturable)
    reference = TissueSimulation(tetmesh, MATERIAL, dt, fixed=face.fixed_nodes, driven=face.driven_nodes, device="cpu")
    expression = rig.model(device="cpu")
    state_in, state_out, control = model.state(), model.state(), model.control()
    offset = np.zeros(3) if head_body < 0 else np.array([0.1, 0.2, 0.3])
    worst = 0.0
    for k in range(200):
        value = np.float32(0.02 * np.sin(2.0 * np.pi * 4.0 * k * dt))
        control.warpface.activation.assign(np.array([value]))
        solver.step(state_in, state_out, control, None, dt)
        state_in, state_out = state_out, state_in
        skin = expression.evaluate(np.array([value], dtype=np.float64))
        reference.step(skin[face.driven_vertices] - rig.mesh.points[face.driven_vertices])
        particles = state_in.particle_q.numpy()[face.particles].astype(np.float64)
        worst = max(worst, float(np.abs(particles - offset - tetmesh.points - reference.d).max()))
    solver.synchronize()
    assert solver.simulation.solver_kind == ("direct" if capturable is False else "cg")
    assert np.abs(reference.d).max() > 1e-4  # the muscle moved the tissue
    assert worst < 1e-6


def _press(depth_at, steps: int, dt: float, radius: float, **options):
    """A cheek patch pressed by a kinematic sphere whose apex goes ``depth_at(t)`` [m] below the rest skin at the
    patch's centre node; returns (indentation of that node along the press per step, contact reports).
    ``options``: SolverFace's."""
    rig, tetmesh, fixed, outer = shell_face(10, 2, span_u=0.7, span_v=0.5)
    centre = int(outer[5, 5])
    normal = np.array([0.0, 0.0, 1.0])  # the patch's centre is the shell's apex, facing +z
    builder = newton.ModelBuilder()
    sphere = builder.add_body(xform=wp.transform((0.0, 0.0, 1.0), wp.quat_identity()))
    builder.add_shape_sphere(sphere, radius=radius)
    face, model = _world(builder, rig, tetmesh, fixed, contact_radius=1.0e-4, driven=[])
    solver = SolverFace(model, face, **options)
    pipeline = newton.CollisionPipeline(model, soft_contact_gap=0.003)
    contacts = pipeline.contacts()
    state_in, state_out, control = model.state(), model.state(), model.control()

    def centre_at(t):
        return tetmesh.points[centre] + normal * (radius - depth_at(t))

    _set_body(state_in, sphere, centre_at(0.0), (0.0, 0.0, 0.0))
    indentation, reports = [], []
    for k in range(steps):
        t0, t1 = k * dt, (k + 1) * dt
        _set_body(state_out, sphere, centre_at(t1), (centre_at(t1) - centre_at(t0)) / dt)
        pipeline.collide(state_in, contacts)
        solver.step(state_in, state_out, control, contacts, dt)
        state_in, state_out = state_out, state_in
        moved = state_in.particle_q.numpy()[face.particle_start + centre].astype(np.float64)
        indentation.append(float(-(moved - tetmesh.points[centre]) @ normal))
        reports.append(solver.contact_report)
        assert np.isfinite(state_in.particle_q.numpy()).all()
    return np.array(indentation), reports


def _depth(t):  # approach from 2 mm off, 5 mm in by 0.1 s, hold, back out by 0.3 s
    return -0.002 + 0.007 * np.clip(t / 0.1, 0.0, 1.0) - 0.007 * np.clip((t - 0.2) / 0.1, 0.0, 1.0)


def test_a_sphere_pushed_5_mm_into_the_cheek_indents_it_5_mm_and_the_tissue_returns():
    dt = 2.0e-3
    indentation, reports = _press(_depth, 200, dt, radius=0.03)
    held = indentation[75:100]
    assert np.all(np.abs(held - 0.005) < 0.001), held
    assert max(r.active for r in reports[75:100]) > 3  # a patch of nodes, not one
    assert abs(indentation[-1]) < 1e-4  # back at rest after release
    assert reports[-1].active == 0


def test_the_host_free_penalty_contact_indents_as_the_exact_contact():
    """The same press on the host-free (graph-capturable) path: its penalty contact (κ = 100, three active-set
    passes) holds 5 ± 1 mm within 0.02 mm of the exact complementarity solution (0.1 mm over the whole press), and
    the tissue returns to rest after release."""
    exact, _ = _press(_depth, 200, 2.0e-3, radius=0.03)
    penalty, reports = _press(_depth, 200, 2.0e-3, radius=0.03, graph_capturable=True)
    held = penalty[75:100]
    assert np.all(np.abs(held - 0.005) < 0.001), held
    assert np.abs(held - exact[75:100]).max() < 2.0e-5
    assert np.abs(penalty - exact).max() < 1.0e-4
    assert max(r.active for r in reports[75:100]) > 3
    assert abs(penalty[-1]) < 1e-4 and reports[-1].active == 0


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_a_head_accelerated_at_3g_lags_as_the_static_body_force_predicts(solver):
    """The head body accelerates smoothly to 3 g along x; once the tissue settles, each node lags behind the
    rigidly carried rest shape by K_oo⁻¹ (M b)_o with b = −3 g x̂ (an independent float64 assembly). The CG
    solver (CUDA's) runs on the CPU device here."""
    rig, tetmesh, fixed, outer = shell_face(6, 2)
    builder = newton.ModelBuilder()
    head = builder.add_body(xform=wp.transform((0.0, 0.0, 0.0), wp.quat_identity()))
    face, model = _world(builder, rig, tetmesh, fixed, head_body=head, driven=[])
    dt, steps, peak = 1.0e-3, 300, 3.0 * 9.81
    face_solver = SolverFace(model, face, solver=solver)
    state_in, state_out, control = model.state(), model.state(), model.control()

    def acceleration(t):
        s = np.clip(t / 0.05, 0.0, 1.0)
        return peak * s * s * (3.0 - 2.0 * s)

    position, velocity = np.zeros(3), np.zeros(3)
    lags = []
    for k in range(steps):
        velocity = velocity + np.array([acceleration((k + 0.5) * dt), 0.0, 0.0]) * dt
        position = position + velocity * dt
        _set_body(state_out, head, position, velocity)
        face_solver.step(state_in, state_out, control, None, dt)
        state_in, state_out = state_out, state_in
        particles = state_in.particle_q.numpy()[face.particles].astype(np.float64)
        lags.append(particles - position - tetmesh.points)
    lag = np.mean(lags[-50:], axis=0)

    K, M, _ = assemble_reference(tetmesh, MATERIAL.E, MATERIAL.nu, MATERIAL.eta, MATERIAL.rho)
    free = np.setdiff1d(np.arange(tetmesh.node_count), face.fixed_nodes)
    dofs = (3 * free[:, None] + np.arange(3)).ravel()
    force = M @ np.tile([-peak, 0.0, 0.0], tetmesh.node_count)
    import scipy.sparse.linalg as spla

    static = np.zeros((tetmesh.node_count, 3))
    static[free] = spla.spsolve(K.tocsc()[dofs][:, dofs], force[dofs]).reshape(-1, 3)
    skin = outer.ravel()
    assert np.abs(static[skin, 0]).max() > 1e-5  # the check measures something
    assert np.allclose(lag[skin, 0], static[skin, 0], rtol=0.2, atol=0.05 * np.abs(static[skin, 0]).max())
    assert np.abs(lag[face.fixed_nodes]).max() < 1e-6  # the skull side rides along exactly


def test_a_non_finite_head_motion_stops_the_host_step_before_it_is_taken():
    """A head body whose velocity went NaN: FloatingPointError before the tissue steps (state and step count as they
    were, the simulation still usable), and the next good step runs."""
    rig, tetmesh, fixed, _ = shell_face(6, 2)
    builder = newton.ModelBuilder()
    head = builder.add_body(xform=wp.transform((0.0, 0.0, 0.0), wp.quat_identity()))
    face, model = _world(builder, rig, tetmesh, fixed, head_body=head, driven=[])
    solver = SolverFace(model, face, dt=1.0e-3)
    state_in, state_out, control = model.state(), model.state(), model.control()
    _set_body(state_out, head, (1e-6, 0.0, 0.0), (1e-3, 0.0, 0.0))
    solver.step(state_in, state_out, control, None, 1.0e-3)
    before, taken = solver.simulation.d, solver.simulation.steps_taken
    _set_body(state_in, head, (1e-6, 0.0, 0.0), (np.nan, 0.0, 0.0))
    with pytest.raises(FloatingPointError, match="body force"):
        solver.step(state_in, state_out, control, None, 1.0e-3)
    assert np.array_equal(solver.simulation.d, before) and solver.simulation.steps_taken == taken
    _set_body(state_in, head, (1e-6, 0.0, 0.0), (1e-3, 0.0, 0.0))
    solver.step(state_in, state_out, control, None, 1.0e-3)
    assert np.isfinite(solver.simulation.d).all() and np.abs(solver.simulation.d).max() > 0.0
