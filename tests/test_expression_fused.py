"""Every launch plan of the model — the fused two- and three-kernel frames (kernels_fused, CUDA's), five
(the CPU's) — equals the five-kernel sequence of kernels.py launched here bit for bit, on the default rig (jaw and
wrinkles) and on a rig without a jaw, single frames and batches."""

import numpy as np
import pytest
import warp as wp

from helpers import small_face_rig
from warpface import ExpressionModel
from warpface.expression.kernels import apply_jaw_and_muscles, apply_muscles, apply_wrinkles, stretch_and_bulge, triangle_stretch
from warpface.expression.kernels_fused import RING_SLOTS
from warpface.kernels_surface import triangle_area_vectors

DEVICE = "cpu"


def five_kernel_frames(model, controls: np.ndarray, depths: np.ndarray) -> dict:
    """The unfused sequence (muscles, triangle stretch, stretch and bulge, area vectors, wrinkles) over
    F frames at once, on the model's rig data; every stage as numpy, (F, V, ...)."""
    mesh, device = model._mesh_buffers, model.device
    frames, vertex_count, triangle_count = len(controls), model.mesh.vertex_count, model.mesh.triangle_count
    vertices, triangles = frames * vertex_count, frames * triangle_count
    width, wrinkle_width = max(controls.shape[1], 1), max(depths.shape[1], 1)
    control_array = wp.array(np.pad(controls, ((0, 0), (0, width - controls.shape[1]))).ravel().astype(np.float32), device=device)
    depth_array = wp.array(np.pad(depths, ((0, 0), (0, wrinkle_width - depths.shape[1]))).ravel().astype(np.float32), device=device)
    x1 = wp.empty(vertices, dtype=wp.vec3, device=device)
    terms = wp.empty(triangles, dtype=wp.vec4, device=device)
    stretch = wp.empty(vertices, dtype=wp.float32, device=device)
    x2 = wp.empty(vertices, dtype=wp.vec3, device=device)
    areas = wp.empty(triangles, dtype=wp.vec3, device=device)
    x3 = wp.empty(vertices, dtype=wp.vec3, device=device)
    counts = [vertex_count, triangle_count]
    if model.jaw is None:
        wp.launch(apply_muscles, dim=vertices, inputs=[mesh.rest_points, model._muscle_offsets, model._muscle_entries, control_array,
                                                       width, vertex_count], outputs=[x1], device=device)
    else:
        jaw = model.jaw
        wp.launch(apply_jaw_and_muscles, dim=vertices,
                  inputs=[mesh.rest_points, model._jaw_weight, wp.vec3(*jaw.pivot), wp.vec3(*jaw.axis), wp.vec3(*jaw.forward),
                          model._muscle_offsets, model._muscle_entries, control_array, width, len(model.muscles), vertex_count],
                  outputs=[x1], device=device)
    wp.launch(triangle_stretch, dim=triangles, inputs=[x1, mesh.triangles, mesh.triangle_weight, mesh.rest_area_lengths, *counts],
              outputs=[terms], device=device)
    wp.launch(stretch_and_bulge, dim=vertices, inputs=[x1, terms, model._counts, mesh.adjacency_offsets, mesh.adjacency_triangles,
                                                       model._thickness, *counts], outputs=[stretch, x2], device=device)
    wp.launch(triangle_area_vectors, dim=triangles, inputs=[x2, mesh.triangles, mesh.triangle_weight, *counts], outputs=[areas],
              device=device)
    wp.launch(apply_wrinkles, dim=vertices, inputs=[x2, areas, mesh.adjacency_offsets, mesh.adjacency_triangles, stretch,
                                                    model._wrinkle_offsets, model._wrinkle_entries, depth_array, wrinkle_width, *counts],
              outputs=[x3], device=device)
    shape = (frames, vertex_count)
    return {"muscle": x1.numpy().reshape(shape + (3,)), "stretch": stretch.numpy().reshape(shape),
            "bulge": x2.numpy().reshape(shape + (3,)), "final": x3.numpy().reshape(shape + (3,))}


def build_model(rig_name: str, launches: int):
    from warpface.assets import default_rig

    rig = default_rig() if rig_name == "default rig" else small_face_rig()
    return ExpressionModel(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=DEVICE, jaw=getattr(rig, "jaw", None), launches=launches)


def random_controls(model, rng, frames: int):
    contractions = rng.uniform(0.0, 0.6, (frames, len(model.muscles)))
    contractions[rng.uniform(size=contractions.shape) < 0.4] = 0.0
    scale = float(model.mesh.size)
    for index, muscle in enumerate(model.muscles):
        if type(muscle).__name__ == "LinearMuscle":
            contractions[:, index] *= 0.03 * scale
    if model.jaw is not None:
        jaw = rng.uniform(0.0, 1.0, (frames, 3)) * np.array([0.25, 0.02 * scale, 0.01 * scale])
        contractions = np.concatenate([contractions, jaw], axis=1)
    depths = rng.uniform(0.0, 2.0, (frames, len(model.wrinkles))) * model.default_depths
    return contractions, depths


@pytest.fixture(scope="module", params=[("default rig", 2), ("default rig", 3), ("default rig", 5), ("small rig without jaw", 2),
                                        ("small rig without jaw", 3)],
                ids=["default-2", "default-3", "default-5", "small-2", "small-3"])
def model(request):
    return build_model(*request.param)


def test_single_frame_and_stages_equal_the_five_kernel_sequence(model, rng):
    contractions, depths = random_controls(model, rng, 1)
    expected = five_kernel_frames(model, contractions, depths)
    moved = np.linalg.norm(expected["final"][0] - model.mesh.points, axis=1).max()
    assert moved > 1e-3 * model.mesh.size  # a real expression
    if model.wrinkles:
        assert np.abs(expected["final"] - expected["bulge"]).max() > 0  # wrinkles act
    stages = model.evaluate(contractions[0], wrinkle_depths=depths[0], stages=True)
    for name in ("muscle", "stretch", "bulge", "final"):
        np.testing.assert_array_equal(stages[name], expected[name][0], err_msg=name)
    np.testing.assert_array_equal(model.evaluate(contractions[0], wrinkle_depths=depths[0]), expected["final"][0])


@pytest.mark.parametrize("frames_per_launch", [None, 3])
def test_batches_equal_the_five_kernel_sequence(model, rng, frames_per_launch):
    contractions, depths = random_controls(model, rng, 5)
    expected = five_kernel_frames(model, contractions, depths)["final"]
    np.testing.assert_array_equal(model.evaluate_batch(contractions, wrinkle_depths=depths, frames_per_launch=frames_per_launch), expected)
    out = wp.empty((5, model.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate_batch_into(out, wp.array(contractions.astype(np.float32), device=DEVICE),
                              wrinkle_depths=wp.array(depths.astype(np.float32), device=DEVICE), frames_per_launch=frames_per_launch)
    np.testing.assert_array_equal(out.numpy(), expected)


@pytest.mark.parametrize("frames_per_thread", [2, 3])
@pytest.mark.parametrize("rig_name, launches", [("default rig", 2), ("default rig", 3), ("small rig without jaw", 2),
                                                ("small rig without jaw", 3)])
def test_several_frames_per_thread_equal_one(rig_name, launches, rng, frames_per_thread):
    """The kernels' frame loop (used on CUDA for large launches) writes the same bits as one frame per thread."""
    from warpface.expression.kernels_fused import bulge_from_ring, muscle_points_over_frames, muscles_and_bulge_from_ring, wrinkles_from_ring

    model = build_model(rig_name, launches=launches)
    frames = 5
    contractions, depths = random_controls(model, rng, frames)
    expected = five_kernel_frames(model, contractions, depths)["final"]
    buffers = model._frame_buffers(frames)
    buffers.upload_controls(contractions, depths)
    looped = 0
    for kernel, dim, inputs, outputs in model._launch_args(buffers, frames, buffers.contraction, buffers.depth,
                                                           buffers.final_points, False):
        inputs = list(inputs)
        if kernel in (muscles_and_bulge_from_ring, muscle_points_over_frames, bulge_from_ring, wrinkles_from_ring):
            inputs[-2 if kernel is muscles_and_bulge_from_ring else -1] = frames_per_thread
            dim = -(-frames // frames_per_thread) * model.mesh.vertex_count
            looped += 1
        wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=DEVICE)
    assert looped == launches
    np.testing.assert_array_equal(buffers.read_frames(buffers.final_points, frames), expected)


@pytest.mark.parametrize("bad", ["2", 4, True, 2.5])
def test_launches_must_be_a_known_plan(bad):
    rig = small_face_rig()
    with pytest.raises(ValueError, match="launches"):
        ExpressionModel(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=DEVICE, launches=bad)


def test_default_plan_by_device():
    rig = small_face_rig()
    assert ExpressionModel(rig.mesh, rig.muscles, device=DEVICE).launches_per_frame == 5  # the CPU's default


def fan_rig():
    """A wavy disc whose centre has 14 incident triangles (more than the ring table's slots) and two
    rings around it, with two linear muscles and a wrinkle across the centre."""
    import warpface as wf

    angles = np.linspace(0.0, 2 * np.pi, 14, endpoint=False)
    rings = [np.c_[radius * np.cos(angles + shift), radius * np.sin(angles + shift)] for radius, shift in ((0.03, 0.0), (0.06, 0.1))]
    flat = np.r_[[[0.0, 0.0]], *rings]
    points = np.c_[flat, 0.004 * np.sin(40 * flat[:, 0]) * np.cos(30 * flat[:, 1])]
    inner, outer = 1 + np.arange(14), 15 + np.arange(14)
    nxt = np.roll(np.arange(14), -1)
    triangles = np.r_[np.c_[np.zeros(14, int), inner, inner[nxt]], np.c_[inner, outer, outer[nxt]], np.c_[inner, outer[nxt], inner[nxt]]]
    mesh = wf.FaceMesh(points, triangles, name="fan")
    muscles = [wf.LinearMuscle("a", [0.08, 0.0, -0.01], [0.0, 0.01, 0.0], 40.0, 0.03, 0.09),
               wf.LinearMuscle("b", [-0.05, 0.07, -0.01], [0.01, -0.01, 0.0], 40.0, 0.03, 0.09)]
    projection = wf.PlanarProjection([0.0, 0.0, 0.0], [1, 0, 0], [0, 1, 0])
    control = np.array([[-0.05, 0.0], [-0.02, 0.004], [0.02, -0.004], [0.05, 0.0]])
    wrinkles = [wf.Wrinkle("w", control, projection, 0.004, 0.02, 0.0)]
    return mesh, muscles, wrinkles


@pytest.mark.parametrize("launches", [2, 3])
def test_ring_table_overflow_equals_the_five_kernel_sequence(rng, launches):
    """A vertex with more incident triangles than the ring table has slots continues over the CSR: the
    fused plans still equal the five-kernel sequence bit for bit, frame loop included."""
    mesh, muscles, wrinkles = fan_rig()
    assert np.diff(mesh.adjacency.offsets).max() > int(RING_SLOTS)
    model = ExpressionModel(mesh, muscles, wrinkles, 0.004, device=DEVICE, launches=launches)
    contractions = rng.uniform(0.005, 0.02, (4, 2))
    depths = rng.uniform(0.5, 2.0, (4, 1)) * model.default_depths
    expected = five_kernel_frames(model, contractions, depths)
    assert np.abs(expected["final"] - expected["bulge"]).max() > 0 and np.abs(expected["stretch"][:, 0] - 1).max() > 1e-3
    np.testing.assert_array_equal(model.evaluate_batch(contractions, wrinkle_depths=depths), expected["final"])
    model._frames_per_thread = lambda frames: 3  # two thread groups over 4 frames, the second partial
    out = wp.empty((4, mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate_batch_into(out, contractions, wrinkle_depths=depths, frames_per_launch=4)
    np.testing.assert_array_equal(out.numpy(), expected["final"])


def test_slot_tables_hold_each_rows_first_entries_then_zeros():
    """Slot j of row v sits at j·V + v: the row's j-th CSR entry while the row has one, a zero entry after;
    the ring table copies the incident triangle's corners, weight and rest length, and pads with (v, v, v)."""
    from warpface.expression.kernels import MuscleEntry
    from warpface.expression.kernels_fused import RingTriangle, ring_table, slot_table

    offsets = np.array([0, 3, 3, 8])  # rows of 3, 0 and 5 entries
    entries = np.zeros(8, dtype=MuscleEntry.numpy_dtype())
    entries["muscle"] = np.arange(8) + 10
    entries["weight"] = np.arange(24, dtype=np.float32).reshape(8, 3) + 1
    table = slot_table(MuscleEntry, offsets, entries, 4, device=DEVICE).numpy().reshape(4, 3)
    for row in range(3):
        count = offsets[row + 1] - offsets[row]
        for slot in range(4):
            got = table[slot, row]
            if slot < count:
                assert got["muscle"] == entries["muscle"][offsets[row] + slot]
                np.testing.assert_array_equal(got["weight"], entries["weight"][offsets[row] + slot])
            else:
                assert got["muscle"] == 0 and not np.any(got["weight"])

    triangles = np.array([[0, 1, 2], [2, 1, 3]], dtype=np.int32)
    ring = ring_table(triangles, np.array([1.0, 0.0], np.float32), np.array([0.5, 1.0], np.float32),
                      np.array([0, 1, 3, 5, 6]), np.array([0, 0, 1, 0, 1, 1]), device=DEVICE).numpy()
    assert ring.dtype == RingTriangle.numpy_dtype() and ring.shape == (int(RING_SLOTS) * 4,)
    by_slot = ring.reshape(int(RING_SLOTS), 4)
    np.testing.assert_array_equal(by_slot["corners"][1, 2], [2, 1, 3])  # vertex 2's second triangle
    assert by_slot["weight"][1, 2] == 0.0 and by_slot["rest_length"][0, 0] == 0.5
    np.testing.assert_array_equal(by_slot["corners"][2, 1], [1, 1, 1])  # vertex 1 has two: slot 2 is padding
    assert by_slot["weight"][2, 1] == 0.0 and by_slot["rest_length"][2, 1] == 1.0
