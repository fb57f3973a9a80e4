"""warpface.newton's bad input (one clear line each) and its USD read/write paths."""

from __future__ import annotations

import numpy as np
import pytest

newton = pytest.importorskip("newton", reason="the newton extra is not installed (pip install 'warpface[newton]')")
pytest.importorskip("pxr", reason="usd-core is not installed")

import warp as wp  # noqa: E402
from helpers import shell_face  # noqa: E402

from warpface.fem import kato_uniform_material  # noqa: E402
from warpface.newton import SkinRecorder, SolverFace, add_face  # noqa: E402

MATERIAL = kato_uniform_material()


@pytest.fixture(scope="module")
def shell():
    return shell_face(6, 2)


def _one_line(excinfo) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    return message


def test_a_rig_without_tissue_is_refused(shell):
    rig, *_ = shell
    with pytest.raises(ValueError) as excinfo:
        add_face(newton.ModelBuilder(), rig)
    assert "no tissue" in _one_line(excinfo)


def test_a_rig_stage_without_tissue_is_refused(shell, tmp_path):
    from warpface.usd import write_rig

    rig, *_ = shell
    path = tmp_path / "rig.usda"
    write_rig(path, rig)
    with pytest.raises(ValueError) as excinfo:
        add_face(newton.ModelBuilder(), path)
    assert "tissue" in _one_line(excinfo)


@pytest.mark.parametrize("body", [1, 7, -2])
def test_a_head_body_out_of_range_is_refused(shell, body):
    rig, tetmesh, fixed, _ = shell
    builder = newton.ModelBuilder()
    builder.add_body()
    with pytest.raises(ValueError) as excinfo:
        add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, head_body=body)
    assert f"head_body {body}" in _one_line(excinfo)
    with pytest.raises(TypeError):
        add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, head_body=True)


def test_a_model_built_without_add_face_is_refused(shell):
    rig, tetmesh, fixed, _ = shell
    face = add_face(newton.ModelBuilder(), rig, tissue=(tetmesh, MATERIAL), fixed=fixed)
    plain = newton.ModelBuilder()
    plain.add_particle((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1.0)
    with pytest.raises(ValueError) as excinfo:
        SolverFace(plain.finalize(device="cpu"), face)
    assert "add_face" in _one_line(excinfo)
    with pytest.raises(TypeError):
        SolverFace(plain.finalize(device="cpu"), "face")


def test_nan_controls_are_refused_and_the_state_stays_finite(shell):
    rig, tetmesh, fixed, _ = shell
    builder = newton.ModelBuilder()
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed)
    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face)
    state_in, state_out, control = model.state(), model.state(), model.control()
    control.warpface.activation.assign(np.array([np.nan], dtype=np.float32))
    with pytest.raises(ValueError) as excinfo:
        solver.step(state_in, state_out, control, None, 1e-3)
    assert "levator" in _one_line(excinfo) and "not finite" in str(excinfo.value)
    assert np.isfinite(state_out.particle_q.numpy()).all() and np.isfinite(solver.simulation.d).all()
    control.warpface.activation.assign(np.array([0.01], dtype=np.float32))  # a good control steps on
    solver.step(state_in, state_out, control, None, 1e-3)
    assert np.isfinite(state_out.particle_q.numpy()).all()


@pytest.mark.parametrize("capturable", [False, True])
def test_a_contact_that_would_invert_a_tet_is_clamped_and_reported(capturable):
    """A big sphere driven 3 cm into an 8 mm tissue: the contact forces are scaled back, every tet stays
    upright, and the step says so (the host path warns; the host-free path reports it on the device)."""
    from warpface.fem.tetmesh import tet_signed_volumes

    rig, tetmesh, fixed, outer = shell_face(8, 1, span_u=0.6, span_v=0.5, thickness=0.008)
    builder = newton.ModelBuilder()
    sphere = builder.add_body(xform=wp.transform((0.0, 0.0, 0.09 + 0.05 - 0.03), wp.quat_identity()))
    builder.add_shape_sphere(sphere, radius=0.05)
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, driven=[], contact_radius=1e-4)
    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face, graph_capturable=capturable)
    pipeline = newton.CollisionPipeline(model, soft_contact_gap=0.003)
    contacts = pipeline.contacts()
    state_in, state_out, control = model.state(), model.state(), model.control()
    state_out.body_q.assign(state_in.body_q.numpy())
    pipeline.collide(state_in, contacts)
    if capturable:
        solver.step(state_in, state_out, control, contacts, 1e-3)
        solver.synchronize()
    else:
        with pytest.warns(RuntimeWarning, match="scaled"):
            solver.step(state_in, state_out, control, contacts, 1e-3)
    assert solver.contact_report.clamped and solver.clamped_steps == 1
    positions = state_out.particle_q.numpy()[face.particles].astype(np.float64)
    assert np.isfinite(positions).all()
    assert (tet_signed_volumes(positions, tetmesh.tets) > 0.0).all()


def _rig_stage(shell, path):
    """The shell's rig written to ``path`` with its tissue TetMesh; returns the skin's prim path."""
    from pxr import UsdGeom

    from warpface.usd import write_rig, write_tissue_mesh

    rig, tetmesh, *_ = shell
    stage = write_rig(path, rig)
    skin_path = str(next(p.GetPath() for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)))
    write_tissue_mesh(stage, "/Tissue", tetmesh, MATERIAL, skin_path=skin_path)
    stage.GetRootLayer().Save()
    return skin_path


def test_newton_add_usd_reads_the_tissue_tetmesh_warpface_writes(shell, tmp_path):
    pytest.importorskip("newton_usd_schemas", reason="Newton's add_usd needs newton[importers] (newton-usd-schemas)")
    rig, tetmesh, *_ = shell
    path = tmp_path / "face.usda"
    _rig_stage(shell, path)
    builder = newton.ModelBuilder(up_axis="Y")  # the stage's own frame (a Z-up builder turns the points)
    builder.add_usd(str(path))
    assert builder.tet_count == tetmesh.tet_count
    assert builder.particle_count == tetmesh.node_count
    assert np.allclose(np.array(builder.particle_q, dtype=np.float64), tetmesh.points, atol=1e-6)
    # the uniform material's physics material: Lamé parameters per tet and the mass rho V
    E, nu = MATERIAL.E, MATERIAL.nu
    lame = np.array([E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))])
    materials = np.array(builder.tet_materials, dtype=np.float64)[:, :2]
    np.testing.assert_allclose(materials, np.broadcast_to(lame, materials.shape), rtol=1e-5)
    np.testing.assert_allclose(sum(builder.particle_mass), MATERIAL.rho * tetmesh.volumes.sum(), rtol=1e-5)


def test_a_rig_stage_with_tissue_loads_into_newton_and_records_a_point_cache(shell, tmp_path):
    """add_face reads the rig stage's tissue; a run's skin goes into a time-sampled cache through warpface's bake
    writer and reads back."""
    from pxr import Usd

    from warpface.usd import open_stage, read_rig

    rig, tetmesh, fixed, _ = shell
    path = tmp_path / "face.usda"
    skin_path = _rig_stage(shell, path)

    builder = newton.ModelBuilder()
    face = add_face(builder, str(path), fixed=fixed)
    assert np.allclose(face.tetmesh.points, tetmesh.points, atol=1e-7)
    assert np.isclose(float(face.material.E), float(MATERIAL.E))

    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face)
    recorder = SkinRecorder(solver)
    state_in, state_out, control = model.state(), model.state(), model.control()
    for frame in range(1, 6):
        control.warpface.activation.assign(np.array([0.01 * frame], dtype=np.float32))
        solver.step(state_in, state_out, control, None, 1.0 / 30.0)
        state_in, state_out = state_out, state_in
        recorder.record(frame, state_in)
    cache = recorder.write(path)
    assert cache.exists()
    reopened = open_stage(str(path))
    points = reopened.GetPrimAtPath(skin_path).GetAttribute("points")
    assert points.GetTimeSamples() == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert np.allclose(np.asarray(points.Get(Usd.TimeCode(5.0))), recorder.frames[-1], atol=1e-6)
    moved = np.abs(recorder.frames[-1] - rig.mesh.points).max()
    assert moved > 1e-5
    assert read_rig(reopened).mesh.vertex_count == rig.mesh.vertex_count


@pytest.mark.parametrize("capturable", [False, True])
def test_reset_and_a_changed_material(shell, capturable):
    """reset puts the tissue back at rest at the state's head pose; notify_model_changed(MODEL_PROPERTIES) picks
    up the model's warpface:youngs_modulus and rebuilds the FEM with it (on either path)."""
    rig, tetmesh, fixed, _ = shell
    builder = newton.ModelBuilder()
    face = add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed)
    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face, dt=1e-3, graph_capturable=capturable)
    state_in, state_out, control = model.state(), model.state(), model.control()
    control.warpface.activation.assign(np.array([0.02], dtype=np.float32))
    for _ in range(5):
        solver.step(state_in, state_out, control, None, 1e-3)
        state_in, state_out = state_out, state_in
    assert np.abs(solver.simulation.d).max() > 1e-5
    solver.reset(state_in)
    assert np.abs(solver.simulation.d).max() == 0.0
    assert np.allclose(state_in.particle_q.numpy()[face.particles], tetmesh.points, atol=1e-7)

    before = solver.simulation
    stiffer = model.warpface.youngs_modulus.numpy()
    stiffer[face.tet_start : face.tet_start + tetmesh.tet_count] *= 2.0
    model.warpface.youngs_modulus.assign(stiffer)
    solver.notify_model_changed(newton.ModelFlags.MODEL_PROPERTIES)
    assert solver.simulation is not before
    assert np.allclose(solver.material.E, 2.0 * MATERIAL.E, rtol=1e-6)
    solver.notify_model_changed(newton.ModelFlags.SHAPE_PROPERTIES)  # nothing of the face's: nothing rebuilt
    assert solver.material.E.shape == (tetmesh.tet_count,)
    solver.step(state_in, state_out, control, None, 1e-3)  # the rebuilt solver steps on
    solver.synchronize()
    assert np.isfinite(state_out.particle_q.numpy()).all() and np.abs(solver.simulation.d).max() > 0.0


def test_add_face_arguments_fuzzed(shell):
    """Any head body or contact radius: a face, or a TypeError/ValueError of one line naming the argument."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    rig, tetmesh, fixed, _ = shell
    values = st.one_of(
        st.integers(-5, 5),
        st.floats(allow_nan=True, allow_infinity=True),
        st.text(max_size=3),
        st.none(),
        st.booleans(),
    )

    @settings(max_examples=30, deadline=None, database=None)
    @given(head_body=st.one_of(st.just(-1), values), radius=values)
    def check(head_body, radius):
        builder = newton.ModelBuilder()
        builder.add_body()
        try:
            add_face(builder, rig, tissue=(tetmesh, MATERIAL), fixed=fixed, head_body=head_body, contact_radius=radius)
        except (TypeError, ValueError) as exc:
            message = str(exc)
            assert "\n" not in message and ("head_body" in message or "contact_radius" in message), message

    check()
