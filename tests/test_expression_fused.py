"""Every launch plan of the model — the fused two- and three-kernel frames (kernels_fused, CUDA's), five
(the CPU's) — equals the five-kernel sequence of kernels.py (launched by expression_plans) bit for bit, on the default rig (jaw and
wrinkles) and on a rig without a jaw, single frames and batches."""

import numpy as np
import pytest
import warp as wp
from expression_plans import build_model, fan_rig, five_kernel_frames, random_controls
from helpers import small_face_rig

from warpface import ExpressionModel
from warpface.expression.kernels_fused import RING_SLOTS

DEVICE = "cpu"


@pytest.fixture(
    scope="module",
    params=[
        ("default rig", 2),
        ("default rig", 3),
        ("default rig", 5),
        ("small rig without jaw", 2),
        ("small rig without jaw", 3),
    ],
    ids=["default-2", "default-3", "default-5", "small-2", "small-3"],
)
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
    np.testing.assert_array_equal(
        model.evaluate_batch(contractions, wrinkle_depths=depths, frames_per_launch=frames_per_launch), expected
    )
    out = wp.empty((5, model.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate_batch_into(
        out,
        wp.array(contractions.astype(np.float32), device=DEVICE),
        wrinkle_depths=wp.array(depths.astype(np.float32), device=DEVICE),
        frames_per_launch=frames_per_launch,
    )
    np.testing.assert_array_equal(out.numpy(), expected)


@pytest.mark.parametrize("frames_per_thread", [2, 3])
@pytest.mark.parametrize(
    "rig_name, launches",
    [("default rig", 2), ("default rig", 3), ("small rig without jaw", 2), ("small rig without jaw", 3)],
)
def test_several_frames_per_thread_equal_one(rig_name, launches, rng, frames_per_thread):
    """The kernels' frame loop (used on CUDA for large launches) writes the same bits as one frame per thread."""
    from warpface.expression.kernels_fused import (
        bulge_from_ring,
        muscle_points_over_frames,
        muscles_and_bulge_from_ring,
        wrinkles_from_ring,
    )

    model = build_model(rig_name, launches=launches)
    frames = 5
    contractions, depths = random_controls(model, rng, frames)
    expected = five_kernel_frames(model, contractions, depths)["final"]
    buffers = model._frame_buffers(frames)
    buffers.upload_controls(contractions, depths)
    looped = 0
    for kernel, dim, inputs, outputs in model._launch_args(
        buffers, frames, buffers.contraction, buffers.depth, buffers.final_points, False
    ):
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
    assert (
        np.abs(expected["final"] - expected["bulge"]).max() > 0 and np.abs(expected["stretch"][:, 0] - 1).max() > 1e-3
    )
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
    ring = ring_table(
        triangles,
        np.array([1.0, 0.0], np.float32),
        np.array([0.5, 1.0], np.float32),
        np.array([0, 1, 3, 5, 6]),
        np.array([0, 0, 1, 0, 1, 1]),
        device=DEVICE,
    ).numpy()
    assert ring.dtype == RingTriangle.numpy_dtype() and ring.shape == (int(RING_SLOTS) * 4,)
    by_slot = ring.reshape(int(RING_SLOTS), 4)
    np.testing.assert_array_equal(by_slot["corners"][1, 2], [2, 1, 3])  # vertex 2's second triangle
    assert by_slot["weight"][1, 2] == 0.0 and by_slot["rest_length"][0, 0] == 0.5
    np.testing.assert_array_equal(by_slot["corners"][2, 1], [1, 1, 1])  # vertex 1 has two: slot 2 is padding
    assert by_slot["weight"][2, 1] == 0.0 and by_slot["rest_length"][2, 1] == 1.0
