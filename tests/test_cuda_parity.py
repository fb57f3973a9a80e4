"""CPU ↔ device parity of every device path: the same inputs on the CPU and on the *parity device*.

The project promises that every kernel runs on the CPU in tests and on CUDA unchanged. The rest of
the suite runs on the CPU; this module runs each device path — the expression model's graph-replayed
``evaluate(..., out=...)`` (a whole batch as one graph) with pinned control staging, the batched activation
solve, depth back-projection (quickselect kernel), the graph-captured CG tissue step on
``TissueState``/``TissueControl``, the tracking → tissue drive and ``geometry.closest_points`` — on
the parity device and compares it with the CPU.

Which device: ``WARPFACE_PARITY_DEVICE`` (default ``cuda:0``). Where that device does not exist (every
CPU-only machine, so the normal suite) the whole module is skipped with the reason. To test this
file's own logic without a GPU, run it CPU against CPU::

    WARPFACE_PARITY_DEVICE=cpu python -m pytest -q tests/test_cuda_parity.py

On the GPU machine: ``scripts/gpu_check.sh``. Needs warp, numpy, scipy (torch optional: the
zero-copy checks skip without it); nothing from usd-core, pytetwild, pyrender, hypothesis or
``../shared/data`` (meshes are procedural or the built-in face).

Comparisons:

* **On one device, bit-exact**: the device-resident paths (``evaluate(..., out=)`` into Warp arrays and
  torch tensors, device controls, graph replay) against the NumPy path on the same device — the same
  kernels on the same inputs.
* **Across devices, a stated tolerance**: CPU kernels are compiled by LLVM, CUDA ones by NVRTC with
  floating-point contraction (``fuse_fp``: a·b + c as one FMA) and libdevice's transcendental
  functions, so float results differ in the last bits (never more: both are IEEE with correctly
  rounded division and square root). Each tolerance below says why it bounds that difference;
  float64 atomics (solve, assembly) add order-dependent rounding on the GPU.
* **Against ground truth** where one exists (direct solver, float64 brute force, exact planes), so
  a path that is wrong the same way on both devices still fails.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from helpers import FLOAT32_FACE_TOLERANCE, expression_controls, grid_surface, parity_device

DEVICE = parity_device()

CPU = wp.get_device("cpu")


def torch_on(device):
    """``torch`` if importable and able to use ``device``, else skip."""
    torch = pytest.importorskip("torch", reason="torch is not installed: zero-copy checks skipped")
    if device.is_cuda and not torch.cuda.is_available():
        pytest.skip("torch has no CUDA here")
    return torch


# ---------------------------------------------------------------------------------------- expression
@pytest.fixture(scope="module")
def face_rig():
    from warpface.assets import default_rig

    return default_rig(device="cpu")


@pytest.fixture(scope="module")
def models(face_rig):
    """The same rig's expression model on the CPU and on the parity device."""
    return face_rig.model(device=CPU), face_rig.model(device=DEVICE)


def test_precomputed_fields_match(face_rig):
    """Muscle weight fields and wrinkle profiles (float64 kernels, once per rig) agree per vertex."""
    from warpface.expression.muscles import muscle_weights
    from warpface.expression.wrinkles import wrinkle_shapes

    points, vertex_count = face_rig.mesh.points, face_rig.mesh.vertex_count

    def dense(offsets, column, values, width):
        rows = np.repeat(np.arange(vertex_count), np.diff(offsets))
        out = np.zeros((vertex_count, width) + values.shape[1:])
        out[rows, column] = values
        return out

    m = len(face_rig.muscles)
    cpu = muscle_weights(points, face_rig.muscles, device=CPU)
    dev = muscle_weights(points, face_rig.muscles, device=DEVICE)
    w_cpu, w_dev = dense(cpu.offsets, cpu.muscle, cpu.weight, m), dense(dev.offsets, dev.muscle, dev.weight, m)
    assert np.abs(w_cpu).max() > 0.1  # the fields are there (weights are O(1) per unit contraction)
    # float64 cos/atan2/sqrt: libdevice and libm agree to a few ulps; 1e-12 leaves room for the
    # 1/D and angle-ratio roundings and is still 1e-12 of the largest weight.
    np.testing.assert_allclose(w_dev, w_cpu, rtol=0, atol=1e-12 * np.abs(w_cpu).max())

    w = len(face_rig.wrinkles)
    cpu = wrinkle_shapes(points, face_rig.wrinkles, device=CPU)
    dev = wrinkle_shapes(points, face_rig.wrinkles, device=DEVICE)
    s_cpu, s_dev = dense(cpu.offsets, cpu.wrinkle, cpu.shape, w), dense(dev.offsets, dev.wrinkle, dev.shape, w)
    assert np.abs(s_cpu).max() > 0.5
    # Entries are kept where |shape| ≥ 1e-7 (WRINKLE_SHAPE_CUTOFF): one device may keep an entry at the
    # cut-off that the other drops, so a kept-vs-dropped pair differs by at most the cut-off itself.
    np.testing.assert_allclose(s_dev, s_cpu, rtol=0, atol=2e-7)


def test_expression_frames_match_cpu(face_rig, models):
    cpu_model, dev_model = models
    contractions, depths = expression_controls(face_rig, 6, seed=1)
    expected = cpu_model.evaluate(contractions, wrinkle_depths=depths)
    got = dev_model.evaluate(contractions, wrinkle_depths=depths)
    moved = np.linalg.norm(expected - face_rig.mesh.points, axis=2).max()
    assert moved > 0.01 * face_rig.mesh.size  # real expressions, not the rest face
    tolerance = FLOAT32_FACE_TOLERANCE * face_rig.mesh.size
    np.testing.assert_allclose(got, expected, rtol=0, atol=tolerance)
    # every stage of a single frame (the staged plan's intermediates on each device)
    cpu_stages, dev_stages = (model.stages(contractions[0], wrinkle_depths=depths[0]) for model in models)
    for name in ("muscle", "bulge", "final"):
        np.testing.assert_allclose(dev_stages[name], cpu_stages[name], rtol=0, atol=tolerance, err_msg=name)
    # r is a float32 ratio of lengths the device sums in another order: 1.1e-5 relative measured (H200).
    np.testing.assert_allclose(dev_stages["stretch"], cpu_stages["stretch"], rtol=5e-5, atol=0)


def test_device_resident_paths_are_bit_identical_on_the_device(face_rig, models):
    """evaluate(..., out=...) (Warp arrays, device controls, chunked launches, one frame or a batch) writes the
    same bits as the NumPy path on the same device."""
    _, model = models
    contractions, depths = expression_controls(face_rig, 5, seed=2)
    vertex_count = face_rig.mesh.vertex_count
    expected = model.evaluate(contractions, wrinkle_depths=depths)
    single = model.evaluate(contractions[0], wrinkle_depths=depths[0])  # graph replay on CUDA
    np.testing.assert_array_equal(single, expected[0])  # graph replay == eager launches

    out = wp.empty(vertex_count, dtype=wp.vec3, device=DEVICE)
    assert model.evaluate(contractions[0], out=out, wrinkle_depths=depths[0]) is out
    np.testing.assert_array_equal(out.numpy(), expected[0])
    device_c = wp.array(contractions.astype(np.float32), dtype=wp.float32, device=DEVICE)
    device_d = wp.array(depths.astype(np.float32), dtype=wp.float32, device=DEVICE)
    flat = wp.empty((vertex_count, 3), dtype=wp.float32, device=DEVICE)
    model.evaluate(device_c[1], out=flat, wrinkle_depths=device_d[1])
    np.testing.assert_array_equal(flat.numpy(), model.evaluate(contractions[1], wrinkle_depths=depths[1]))

    for frames_per_launch in (None, 2):
        batch = wp.empty((5, vertex_count), dtype=wp.vec3, device=DEVICE)
        model.evaluate(device_c, out=batch, wrinkle_depths=device_d, frames_per_launch=frames_per_launch)
        np.testing.assert_array_equal(batch.numpy(), expected, err_msg=f"frames_per_launch={frames_per_launch}")
        model.evaluate(contractions, out=batch, wrinkle_depths=depths, frames_per_launch=frames_per_launch)
        np.testing.assert_array_equal(batch.numpy(), expected, err_msg=f"host controls, {frames_per_launch}")


def test_back_to_back_frames_without_sync_each_keep_their_controls(face_rig, models):
    """Queued graph replays with host controls: the pinned staging of frame f+1 must not overwrite
    frame f's controls before their copy ran. Nothing is read back until the end."""
    _, model = models
    contractions, depths = expression_controls(face_rig, 8, seed=3)
    expected = model.evaluate(contractions, wrinkle_depths=depths)
    out = wp.empty((8, face_rig.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    for f in range(8):
        model.evaluate(contractions[f], out=out[f], wrinkle_depths=depths[f])
    # Device-resident follow-up work on the results: a reduction by a kernel, no host round trip.
    moved = wp.zeros(1, dtype=wp.float32, device=DEVICE)
    rest = wp.array(face_rig.mesh.points.astype(np.float32), dtype=wp.vec3, device=DEVICE)
    wp.launch(_max_motion, dim=out.shape, inputs=[out, rest], outputs=[moved], device=DEVICE)
    np.testing.assert_array_equal(out.numpy(), expected)
    largest = np.linalg.norm(expected - face_rig.mesh.points.astype(np.float32), axis=2).max()
    assert moved.numpy()[0] == pytest.approx(largest, rel=1e-6)


@wp.kernel
def _max_motion(frames: wp.array2d(dtype=wp.vec3), rest: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    f, v = wp.tid()
    wp.atomic_max(out, 0, wp.length(frames[f, v] - rest[v]))


def test_torch_tensors_in_and_out(face_rig, models):
    """Torch tensors on the parity device as controls and outputs (DLPack, zero-copy), and a Warp
    result seen by torch through ``wp.to_torch``: same bits as the NumPy path."""
    _, model = models
    torch = torch_on(DEVICE)
    torch_device = wp.device_to_torch(DEVICE)
    contractions, depths = expression_controls(face_rig, 3, seed=4)
    expected = model.evaluate(contractions, wrinkle_depths=depths)
    vertex_count = face_rig.mesh.vertex_count
    out = torch.empty((vertex_count, 3), dtype=torch.float32, device=torch_device)
    controls = torch.tensor(contractions.astype(np.float32), device=torch_device)
    wrinkles = torch.tensor(depths.astype(np.float32), device=torch_device)
    batch = torch.zeros((3, vertex_count, 3), dtype=torch.float32, device=torch_device)
    # Warp and torch queue work on their own streams: hand over at synchronisation points, as the
    # model's docstring asks (torch's inputs ready before Warp reads them, Warp done before torch reads).
    synchronize_torch = torch.cuda.synchronize if DEVICE.is_cuda else (lambda: None)
    synchronize_torch()
    assert model.evaluate(controls[0], out=out, wrinkle_depths=wrinkles[0]) is out
    model.evaluate(controls, out=batch, wrinkle_depths=wrinkles)
    wp.synchronize_device(DEVICE)
    np.testing.assert_array_equal(out.cpu().numpy(), expected[0])
    np.testing.assert_array_equal(batch.cpu().numpy(), expected)
    warp_out = wp.empty((3, vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate(contractions, out=warp_out, wrinkle_depths=depths)
    wp.synchronize_device(DEVICE)
    shared = wp.to_torch(warp_out)  # a view, no copy
    assert shared.data_ptr() == warp_out.ptr
    assert torch.equal(shared, batch)


def test_batch_graph_replays_read_each_calls_controls(face_rig, models):
    """On CUDA a device batch is one captured graph, replayed while its arrays stay the same: every
    replay must read that call's controls (host ones restaged, device ones rewritten in place), with
    jaw controls and a partial last chunk, queued back to back with no sync in between."""
    _, model = models
    frames, vertex_count = 5, face_rig.mesh.vertex_count
    calls = [expression_controls(face_rig, frames, seed=seed) for seed in (6, 7, 8)]
    expected = [model.evaluate(c, wrinkle_depths=d, frames_per_launch=2) for c, d in calls]
    assert np.abs(expected[0] - expected[1]).max() > 1e-3 * face_rig.mesh.size  # the calls really differ
    # the host path's pinned double-buffered read-back: chunks of 2 (three copies in flight in turn) == one chunk
    np.testing.assert_array_equal(expected[0], model.evaluate(calls[0][0], wrinkle_depths=calls[0][1]))
    outs = [wp.empty((frames, vertex_count), dtype=wp.vec3, device=DEVICE) for _ in range(2)]
    for index, (controls, depths) in enumerate(calls):  # host controls: staged, same graph per output
        model.evaluate(controls, out=outs[index % 2], wrinkle_depths=depths, frames_per_launch=2)
        if index == 1:
            np.testing.assert_array_equal(outs[0].numpy(), expected[0])
    np.testing.assert_array_equal(outs[1].numpy(), expected[1])
    np.testing.assert_array_equal(outs[0].numpy(), expected[2])

    device_c, device_d = (wp.array(v.astype(np.float32), dtype=wp.float32, device=DEVICE) for v in calls[0])
    for index in (0, 1, 2):  # device controls rewritten in place between replays of one graph
        for target, values in zip((device_c, device_d), calls[index]):
            wp.copy(target, wp.array(values.astype(np.float32), dtype=wp.float32, device=DEVICE))
        model.evaluate(device_c, out=outs[0], wrinkle_depths=device_d)
        np.testing.assert_array_equal(outs[0].numpy(), expected[index], err_msg=f"device controls, call {index}")


# ------------------------------------------------------------------------------------------------ solve
def solve_inputs(rig, frames: int):
    """Target vertices (landmarks + every 16th vertex), (F, N, 3) targets from known controls, truths."""
    from warpface.assets import rig_scale

    rng = np.random.default_rng(5)
    vertices = np.union1d(rig.landmarks, np.arange(0, rig.mesh.vertex_count, 16))
    scale = rig_scale(rig)
    truths = np.zeros((frames, len(rig.muscles)))
    for f in range(frames):
        chosen = rng.choice(len(rig.muscles), 4, replace=False)
        truths[f, chosen] = rng.uniform(0.03, 0.12, 4)
    from warpface.expression import SphincterMuscle

    linear = np.array([not isinstance(m, SphincterMuscle) for m in rig.muscles])
    truths[:, linear] *= scale
    shapes = rig.model(device=CPU).evaluate(truths).astype(np.float64)
    targets = shapes[:, vertices]
    targets[1, :20] = np.nan  # missing points
    return vertices, targets, truths


def test_batched_solve_matches_cpu_and_truth():
    """Solver.solve_batch with its kernels on the parity device. The data term's per-frame sums are
    float64 atomics (their order differs on the GPU), so the Levenberg–Marquardt iterates differ in
    the last bits and may stop an iteration apart: controls then agree to the solver's own step
    tolerance (1e-7 face units per step, a few steps), residuals to 1e-7 face units."""
    from warpface.assets import default_rig, rig_scale
    from warpface.solve import Solver

    # One rig per device: the solver's operators are cached per rig, built on the first solver's device.
    # The classic rig: its 23 controls are determined by these points, so both devices can also be held to
    # the ground truth (the full rig's lid and lip muscles are nearly collinear at them).
    rig_cpu, rig_dev = (default_rig(device="cpu", anatomy="classic") for _ in range(2))
    vertices, targets, truths = solve_inputs(rig_cpu, 6)
    cpu = Solver(rig_cpu, vertices, device=CPU)
    dev = Solver(rig_dev, vertices, device=DEVICE)
    expected, got = cpu.solve_batch(targets), dev.solve_batch(targets)
    unit = rig_scale(rig_cpu)
    assert expected.converged.all() and got.converged.all()
    assert not got.skipped.any()
    scaled = cpu.control_scale  # control → face units of displacement
    np.testing.assert_allclose(got.controls * scaled, expected.controls * scaled, rtol=0, atol=1e-5)
    np.testing.assert_allclose(got.residual, expected.residual, rtol=0, atol=1e-7 * unit)
    # both against the ground truth (dense-enough targets determine the controls)
    for result in (expected, got):
        np.testing.assert_allclose(result.controls * scaled, truths * scaled, rtol=0, atol=1e-3)
        assert result.residual.max() < 1e-4 * unit

    # One frame through solve(): the fit's points come from the full model on the parity device.
    fit = dev.solve(targets[0])
    assert fit.model.device == DEVICE
    np.testing.assert_allclose(
        fit.points,
        rig_cpu.model(device=CPU).evaluate(fit.vector),
        rtol=0,
        atol=FLOAT32_FACE_TOLERANCE * rig_cpu.mesh.size,
    )


# ------------------------------------------------------------------------------------ back-projection
def depth_scene(rng):
    """A 320×240 depth image [m]: a noisy curved face-sized cap in front of a wall, holes, and an exact
    tilted plane in the bottom-right quarter. Returns (intrinsics, depth, plane depth function)."""
    from warpface.tracking.depth import CameraIntrinsics

    k = CameraIntrinsics(width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5)
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    x, y = (u - k.cx) / k.fx, (v - k.cy) / k.fy
    # sphere of radius 0.09 m centred 0.68 m away: the ray's first hit, else the wall at 0.9 m
    centre, radius = 0.68, 0.09
    norm2 = x * x + y * y + 1.0
    disc = centre**2 - norm2 * (centre**2 - radius**2)
    hit = disc > 0
    z = np.where(hit, (centre - np.sqrt(np.maximum(disc, 0.0))) / norm2, 0.9)
    z = z + rng.normal(0.0, 0.0008, z.shape)  # sensor noise
    z[rng.uniform(size=z.shape) < 0.05] = 0.0  # holes

    def plane(uu, vv):  # 1/Z affine in the pixel: a plane
        return 1.0 / (1.6 + 0.002 * (uu - 240) - 0.001 * (vv - 180))

    quarter = (u >= 200) & (v >= 140)
    z[quarter] = plane(u[quarter], v[quarter])
    return k, z.astype(np.float32), plane


def test_backprojection_matches_cpu():
    from warpface.tracking.depth import backproject

    rng = np.random.default_rng(6)
    k, depth, plane = depth_scene(rng)
    on_cap = np.c_[rng.uniform(110, 210, 150), rng.uniform(70, 170, 150)]
    on_plane = np.c_[rng.uniform(215, 305, 40), rng.uniform(155, 225, 40)]
    specials = np.array([[np.nan, 3.0], [-40.0, 10.0], [1e9, 5.0], [0.2, 0.3], [319.4, 239.4]])
    pixels = np.r_[on_cap, on_plane, specials]
    for model in ("quadric", "plane"):
        expected, expected_in = backproject(pixels, depth, k, model=model, device=CPU)
        got, got_in = backproject(pixels, depth, k, model=model, device=DEVICE)
        valid = np.isfinite(expected[:, 0])
        assert valid[:150].mean() > 0.8 and valid[150:190].all() and not valid[[190, 191, 192]].any()
        # Inlier sets come from comparisons of float32 residuals with gates: a pixel would have to sit
        # within float32 rounding of a gate for the devices to disagree (probability ~1e-4 per run).
        np.testing.assert_array_equal(got_in, expected_in, err_msg=model)
        np.testing.assert_array_equal(np.isfinite(got[:, 0]), valid, err_msg=model)
        # The fit runs in float32 per pixel (FMA-contracted on CUDA) with float64 normal equations:
        # positions agree far below the 0.8 mm noise.
        np.testing.assert_allclose(got[valid], expected[valid], rtol=0, atol=2e-6, err_msg=model)
        # exact on the plane (1/Z affine in the pixel), on both devices
        for points in (expected, got):
            truth_z = plane(pixels[150:190, 0], pixels[150:190, 1])
            np.testing.assert_allclose(points[150:190, 2], truth_z, rtol=1e-6, err_msg=model)  # float32 1/Z


# ------------------------------------------------------------------------------------ FEM: CG stepping
def tissue_material():
    from warpface.fem import TissueMaterial

    return TissueMaterial(1e5, 0.45, 20.0, 1000.0)


@pytest.fixture(scope="module")
def beam():
    from warpface.fem import box_tet_mesh

    mesh = box_tet_mesh((0.06, 0.02, 0.02), (9, 3, 3))
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-12)
    driven = np.flatnonzero(mesh.points[:, 0] > 0.06 - 1e-12)
    return mesh, fixed, driven


def beam_trajectory(steps: int, driven: int) -> np.ndarray:
    out = np.zeros((steps, driven, 3))
    out[:, :, 1] = 2e-3 * np.sin(np.linspace(0.1, 1.5, steps))[:, None]
    out[steps // 2 :, :, 2] = 1e-3  # a jump: CG has real work after it
    return out


@pytest.fixture(scope="module")
def direct_reference(beam):
    """Displacements (T, N, 3) of the direct (SuperLU, CPU) solver: the ground truth of the CG paths."""
    from warpface.fem import TissueSimulation

    mesh, fixed, driven = beam
    sim = TissueSimulation(mesh, tissue_material(), 1e-3, fixed=fixed, driven=driven, solver="direct", device=CPU)
    return sim.run(beam_trajectory(24, driven.size))


def test_cg_step_graph_on_device_state_matches_direct(beam, direct_reference):
    """CGSolver.step(state_in, state_out, control) ping-ponging two TissueStates, the control filled on
    the device, every step a (captured) graph launch, nothing read back until the end. CG to a 1e-12
    relative residual: the error left is far below the 1e-9 m tolerance (float32 reference rounding
    of 2 mm is 1e-10 m)."""
    from warpface.fem import CGOptions, TissueControl, TissueSimulation, TissueState

    mesh, fixed, driven = beam
    steps = len(direct_reference)
    sim = TissueSimulation(
        mesh,
        tissue_material(),
        1e-3,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device=DEVICE,
        cg=CGOptions(tolerance=1e-12, maxiter=400, use_graph=True),
    )
    trajectory = wp.array(beam_trajectory(steps, driven.size).reshape(-1, 3), dtype=wp.vec3d, device=DEVICE)
    states = [TissueState(mesh.node_count, device=DEVICE), TissueState(mesh.node_count, device=DEVICE)]
    control = TissueControl(driven.size, device=DEVICE)
    record = wp.zeros(steps * mesh.node_count, dtype=wp.vec3d, device=DEVICE)
    for t in range(steps):
        wp.copy(control.driven, trajectory, src_offset=t * driven.size, count=driven.size)  # device to device
        sim.solver.step(states[t % 2], states[(t + 1) % 2], control)
        wp.copy(record, states[(t + 1) % 2].d, dest_offset=t * mesh.node_count, count=mesh.node_count)
    sim.solver.synchronize()  # raises if a step did not converge
    assert len(sim.solver._graphs) == 2  # one graph per (state_in, state_out) pair, none per step
    got = record.numpy().reshape(steps, mesh.node_count, 3)
    assert np.abs(direct_reference).max() > 1e-3
    np.testing.assert_allclose(got, direct_reference, rtol=0, atol=1e-9)
    assert np.all(got[:, fixed] == 0.0)
    assert sim.solver.iterations[0] >= 1

    # the final state seen by torch without a copy
    try:
        torch = torch_on(DEVICE)
    except pytest.skip.Exception:
        return
    d = wp.to_torch(states[steps % 2].d)
    assert d.data_ptr() == states[steps % 2].d.ptr
    assert float(d.abs().max()) == pytest.approx(float(np.abs(got[-1]).max()), rel=1e-12)
    del torch


@pytest.mark.parametrize("loop", ["persistent", "launched"])
def test_cg_run_chunks_match_direct(beam, direct_reference, loop):
    """TissueSimulation.run on the device: driven inputs through the ring (several chunks), graph launches,
    the CG iterations in one persistent kernel or in launched kernels."""
    from warpface.fem import CGOptions, TissueSimulation

    mesh, fixed, driven = beam
    sim = TissueSimulation(
        mesh,
        tissue_material(),
        1e-3,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device=DEVICE,
        cg=CGOptions(tolerance=1e-12, maxiter=400, chunk=5, use_graph=True, loop=loop),
    )
    assert sim.solver.loop == loop
    got = sim.run(beam_trajectory(len(direct_reference), driven.size))
    np.testing.assert_allclose(got, direct_reference, rtol=0, atol=1e-9)
    assert sim.steps_taken == len(direct_reference)


@pytest.mark.parametrize("preconditioner", ["fsai", "fsai_each", "block_jacobi"])
def test_tissue_batch_graph_matches_per_model_direct(beam, direct_reference, preconditioner):
    """TissueBatch: three materials (the reference one first) stepped as one captured graph, each
    with its own trajectory, through run() (ring chunks) and queued step() calls; model 0 against the
    direct reference, the others against their own direct runs."""
    from warpface.fem import CGOptions, TissueBatch, TissueMaterial, TissueSimulation

    mesh, fixed, driven = beam
    steps = len(direct_reference)
    materials = [tissue_material(), TissueMaterial(6e4, 0.45, 30.0, 1000.0), TissueMaterial(2e5, 0.49, 5.0, 1100.0)]
    base = beam_trajectory(steps, driven.size)
    own = np.stack([base, 0.5 * base, -base], axis=1)  # (T, 3, D, 3)
    batch = TissueBatch(
        mesh,
        materials,
        1e-3,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device=DEVICE,
        cg=CGOptions(tolerance=1e-12, maxiter=400, preconditioner=preconditioner, chunk=5),
    )
    got = batch.run(own[: steps - 4])
    for t in range(steps - 4, steps):
        batch.step(own[t])
    final = batch.d
    np.testing.assert_allclose(got[:, 0], direct_reference[: steps - 4], rtol=0, atol=1e-9)
    np.testing.assert_allclose(final[0], direct_reference[-1], rtol=0, atol=1e-9)
    for b in (1, 2):
        ref = TissueSimulation(mesh, materials[b], 1e-3, fixed=fixed, driven=driven, solver="direct", device=CPU)
        ref.run(own[:, b])
        np.testing.assert_allclose(final[b], ref.d, rtol=0, atol=1e-9)


# ------------------------------------------------------------------------------- tracking → tissue drive
@pytest.fixture(scope="module")
def skin_patch():
    """A tissue slab 80 × 80 × 6 mm (skin on top, z = 0) and its top surface as the dense skin mesh."""
    from warpface.fem import TetMesh, box_tet_mesh

    n, size, thickness = 12, 0.08, 0.006
    box = box_tet_mesh((size, size, thickness), (n, n, 2))
    points = box.points - np.array([size / 2, size / 2, thickness])
    tetmesh = TetMesh(points, box.tets)
    top = np.flatnonzero(np.abs(points[:, 2]) < 1e-12)
    order = np.lexsort((points[top, 0], points[top, 1]))  # row-major grid: y rows, x columns
    skin = points[top[order]]
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return skin, triangles, tetmesh, thickness


def test_tissue_drive_matches_cpu(skin_patch):
    """The drive on the parity device (CG solver on CUDA, sub-step controls interpolated by a kernel)
    against the drive on the CPU (direct solver). The drive's simulation keeps the default CG
    tolerance (1e-5 of the Newmark predictor's residual), so the two solvers differ by CG's stopping
    error, not by rounding: 4.7e-7 m at most over these frames when the CG path runs on the CPU
    (0.02 % of the 2 mm lift); the tolerance is 2e-6 m (0.1 %)."""
    from warpface.fem import TissueMaterial
    from warpface.pipelines.tissue_drive import TissueDrive
    from warpface.tracking import adapter_for_face, vertex_landmark_names
    from warpface.tracking.sources import LandmarkFrame

    skin, _, tetmesh, thickness = skin_patch
    centre = np.flatnonzero(np.linalg.norm(skin[:, :2], axis=1) < 0.02)
    names = vertex_landmark_names(centre)
    adapter = adapter_for_face(skin, names, camera_to_model=np.eye(4), device=CPU)  # shared: isolates the drive
    adapter.bind(names)
    material = TissueMaterial(E=192.4e3, nu=0.495, eta=476.8, rho=1100.0)
    drives = [
        TissueDrive(adapter, tetmesh, material, fps=30.0, dt=1.0 / 90.0, thickness=thickness, device=device)
        for device in (CPU, DEVICE)
    ]
    assert drives[1].simulation.solver_kind == ("cg" if DEVICE.is_cuda else "direct")
    lift = np.array([0.0, 0.0, 0.002])
    for i in range(6):
        frame = LandmarkFrame(
            timestamp=i / 30.0, points=skin[centre] + lift * min(i, 3) / 3, confidence=np.ones(len(centre)), index=i
        )
        tracked = adapter.track_frame(frame)
        expected, got = (drive(frame, tracked) for drive in drives)
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-6, err_msg=f"frame {i}")
    driven = adapter.weights >= 1.0
    np.testing.assert_allclose(got[driven], tracked[driven], atol=1e-7)  # tracked skin stays tracked
    outside = adapter.weights == 0.0
    assert np.linalg.norm(got[outside] - skin[outside], axis=1).max() > 1e-5  # the tissue carried the rest
    state = drives[1].simulation.state.d
    assert state.device == DEVICE  # the tissue state never left the device


# ------------------------------------------------------------------------------------- closest points
def reference_closest(queries: np.ndarray, points: np.ndarray, triangles: np.ndarray):
    """Float64 brute force: distance from every query to every triangle, (Q, T)."""
    a, b, c = (points[triangles[:, i]][None] for i in range(3))
    p = queries[:, None, :]
    ab, ac = b - a, c - a
    normal = np.cross(ab, ac)
    n2 = np.einsum("...i,...i", normal, normal)
    # inside the prism: distance to the plane; else the nearest of the three edges
    ap = p - a
    gram = np.stack([np.einsum("...i,...i", ab, ab), np.einsum("...i,...i", ab, ac), np.einsum("...i,...i", ac, ac)])
    rhs_b, rhs_c = np.einsum("...i,...i", ap, ab), np.einsum("...i,...i", ap, ac)
    det = gram[0] * gram[2] - gram[1] ** 2
    v = (gram[2] * rhs_b - gram[1] * rhs_c) / det
    w = (gram[0] * rhs_c - gram[1] * rhs_b) / det
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)
    plane = np.abs(np.einsum("...i,...i", ap, normal)) / np.sqrt(n2)
    best = np.where(inside, plane, np.inf)
    for s, e in ((a, b), (a, c), (b, c)):
        se = e - s
        t = np.clip(np.einsum("...i,...i", p - s, se) / np.einsum("...i,...i", se, se), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - s - t[..., None] * se, axis=-1))
    return best


def test_closest_points_match_cpu_and_brute_force():
    from warpface.geometry import TriangleMeshIndex, closest_points

    points, triangles = grid_surface(20, size=0.2, height=0.03, seed=7)
    points = points + np.array([0.05, -0.02, 0.6])  # in front of a camera: the index recentres
    rng = np.random.default_rng(8)
    queries = np.r_[
        points[rng.choice(len(points), 200)] + rng.normal(0.0, 0.01, (200, 3)),  # near the surface
        rng.uniform(-0.3, 0.3, (100, 3)) + np.array([0.05, -0.02, 0.6]),  # around it
        np.array([[5.0, -3.0, 40.0], [0.05, -0.02, 0.6]]),  # far away; the box centre
    ]
    expected = closest_points(queries, points, triangles, device=CPU)
    got = closest_points(queries, points, triangles, device=DEVICE)
    reference = reference_closest(queries, points, triangles)
    true_distance = reference.min(axis=1)
    size = np.linalg.norm(np.ptp(points, axis=0))
    for tri, bary, dist in (expected, got):
        assert np.all((tri >= 0) & (tri < len(triangles)))
        # float32 search around the box centre: 1e-6 of the distance plus 1e-6 of the mesh size
        np.testing.assert_allclose(dist, true_distance, rtol=1e-6, atol=1e-6 * size)
        closest = np.einsum("qj,qjk->qk", bary.astype(np.float64), points[triangles[tri]])
        np.testing.assert_allclose(
            np.linalg.norm(closest - queries, axis=1), true_distance, rtol=1e-5, atol=2e-6 * size
        )
    # The same triangle wherever the runner-up is clearly farther; within float32 rounding of a tie
    # (closest point on a shared edge or vertex) FMA contraction may pick either neighbour.
    ranked = np.sort(reference, axis=1)
    clear = ranked[:, 1] - ranked[:, 0] > 1e-5 * size
    assert clear.mean() > 0.3
    np.testing.assert_array_equal(got[0][clear], expected[0][clear])
    np.testing.assert_allclose(got[2], expected[2], rtol=2e-6, atol=1e-6 * size)
    # a reused index gives the same answers as the one-shot call
    index = TriangleMeshIndex(points, triangles, device=DEVICE)
    for a, b in zip(index.query(queries), got):
        np.testing.assert_array_equal(a, b)
