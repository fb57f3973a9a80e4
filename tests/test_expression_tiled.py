"""The tiled plan (``plan="tiled"``, kernels_tiled + kernels_resident + tiling): its tiles against an independent
per-tile set construction, and its frames against the five-kernel sequence of kernels.py bit for bit —
blocks of one thread (the CPU's) and of many (CPU blocks, as on CUDA), several frames per block."""

import numpy as np
import pytest
import warp as wp
from expression_plans import build_model, fan_rig, five_kernel_frames, random_controls

from warpface import ExpressionModel
from warpface.expression.kernels_resident import expression_tiles_resident
from warpface.expression.kernels_tiled import expression_tiles
from warpface.expression.plans import plan_launches
from warpface.expression.tiling import (
    TILE_OWNED,
    TILE_TRIANGLES,
    TILE_VERTICES,
    FrameBatch,
    mesh_tiles,
    morton_order,
    vertex_tiles,
)
from warpface.kernels_surface import struct_of

DEVICE = "cpu"


def tiles_of(mesh, **caps):
    buffers = mesh.device_buffers(device=DEVICE)
    return vertex_tiles(
        mesh.points,
        mesh.triangles,
        buffers.triangle_weight.numpy(),
        buffers.rest_area_lengths.numpy(),
        mesh.adjacency.offsets,
        mesh.adjacency.triangles,
        **caps,
    )


def check_tiles(mesh, tiles, max_owned, max_halo, max_triangles):
    """Each tile against sets built here vertex by vertex: owned vertices partition the mesh; the local
    vertices are owned, then the rest of their one-ring, then the rest of the two-ring; local triangles
    are those touching the one-ring, the ones touching an owned vertex first; local corners and each
    one-ring vertex's local incident triangles (in the CSR's order) name the right global items."""
    triangles = mesh.triangles
    offsets, incident = mesh.adjacency.offsets, mesh.adjacency.triangles
    neighbours = [set(triangles[incident[offsets[v] : offsets[v + 1]]].ravel()) | {v} for v in range(mesh.vertex_count)]
    touching = [set(incident[offsets[v] : offsets[v + 1]]) for v in range(mesh.vertex_count)]
    owners = np.zeros(mesh.vertex_count, dtype=int)
    for info in tiles.info:
        start, owned_count, ring_count, halo_count = (int(info[k]) for k in ("vertex_start", "owned", "ring", "halo"))
        local = tiles.vertices[start : start + halo_count]
        owned = set(local[:owned_count])
        ring = set().union(*(neighbours[v] for v in owned))
        halo = set().union(*(neighbours[v] for v in ring))
        assert len(owned) == owned_count <= max_owned and halo_count <= max_halo
        assert set(local[:ring_count]) == ring and set(local) == halo and len(local) == len(halo)
        tri_start, near_count, tri_count = (int(info[k]) for k in ("triangle_start", "near", "triangles"))
        local_triangles = tiles.triangles[tri_start : tri_start + tri_count]
        global_triangles = [tuple(local[c]) for c in local_triangles["corners"]]
        ring_triangles = set().union(*(touching[v] for v in ring))
        near = set().union(*(touching[v] for v in owned))
        assert tri_count == len(ring_triangles) <= max_triangles and near_count == len(near)
        assert {tuple(triangles[t]) for t in near} == set(global_triangles[:near_count])
        assert {tuple(triangles[t]) for t in ring_triangles} == set(global_triangles)
        for s in range(halo_count):
            rows = tiles.adjacency[tiles.adjacency_offsets[start + s] : tiles.adjacency_offsets[start + s + 1]]
            expected = (
                [tuple(triangles[t]) for t in incident[offsets[local[s]] : offsets[local[s] + 1]]]
                if s < ring_count
                else []
            )
            assert [global_triangles[t] for t in rows] == expected
        owners[list(owned)] += 1
    np.testing.assert_array_equal(owners, 1)


def test_tiles_of_the_default_face_hold_each_tiles_two_ring():
    from warpface.assets import default_face

    mesh = default_face()
    tiles = tiles_of(mesh)
    check_tiles(mesh, tiles, int(TILE_OWNED), int(TILE_VERTICES), int(TILE_TRIANGLES))
    assert tiles.info["owned"].mean() > 0.5 * int(TILE_OWNED)  # compact tiles: few are split


def grid_mesh(n: int):
    """A wavy n × n grid of two triangles per cell."""
    import warpface as wf

    x, y = np.meshgrid(np.linspace(0.0, 0.1, n), np.linspace(0.0, 0.1, n))
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    points = np.c_[x.ravel(), y.ravel(), 0.002 * np.sin(60 * x.ravel()) * np.cos(50 * y.ravel())]
    return wf.FaceMesh(points, np.r_[np.c_[a, b, d], np.c_[a, d, c]], name="grid")


def test_small_caps_split_tiles_until_they_fit():
    mesh = grid_mesh(20)
    tiles = tiles_of(mesh, max_owned=32, max_halo=40, max_triangles=60)
    assert tiles.count > -(-mesh.vertex_count // 32)  # tiles were halved
    check_tiles(mesh, tiles, 32, 40, 60)
    with pytest.raises(ValueError, match="two-ring has more than 20 vertices"):  # the fan: any vertex's two-ring is 29
        tiles_of(fan_rig()[0], max_owned=8, max_halo=20, max_triangles=100)


def test_a_mesh_that_cannot_be_tiled_is_an_error_only_when_the_tiled_plan_is_required():
    """The model's default plan on CUDA tiles meshes and falls back to the staged plan when a vertex cannot fit."""
    mesh = fan_rig()[0]
    caps = dict(max_owned=8, max_halo=20, max_triangles=100)
    assert mesh_tiles(mesh, mesh.device_buffers(device=DEVICE), device=DEVICE, required=False, **caps) is None
    with pytest.raises(ValueError, match='use plan="staged"'):
        mesh_tiles(mesh, mesh.device_buffers(device=DEVICE), device=DEVICE, **caps)
    tiles = mesh_tiles(mesh, mesh.device_buffers(device=DEVICE), device=DEVICE, required=False)
    assert len(tiles) == 5 and tiles[0].shape[0] >= 1


def test_morton_order_keeps_neighbours_close():
    rng = np.random.default_rng(0)
    points = rng.uniform(size=(4096, 3))
    order = morton_order(points)
    assert sorted(order) == list(range(4096))
    steps = np.linalg.norm(np.diff(points[order], axis=0), axis=1)
    assert np.median(steps) < 0.25 * np.median(np.linalg.norm(np.diff(points, axis=0), axis=1))


@pytest.mark.parametrize("rig_name", ["default rig", "small rig without jaw"])
def test_tiled_frames_equal_the_five_kernel_sequence(rig_name, rng):
    model = build_model(rig_name, "tiled")
    contractions, depths = random_controls(model, rng, 4)
    expected = five_kernel_frames(model, contractions, depths)
    np.testing.assert_array_equal(model.evaluate(contractions[0], wrinkle_depths=depths[0]), expected["final"][0])
    np.testing.assert_array_equal(model.evaluate(contractions, wrinkle_depths=depths), expected["final"])
    out = wp.empty((4, model.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate(contractions, out=out, wrinkle_depths=depths, frames_per_launch=3)
    np.testing.assert_array_equal(out.numpy(), expected["final"])


def launch_tiled_blocks(model, rng, kernel, block_dim, frames_per_block, frames=5):
    """``kernel`` over a batch of ``frames`` with ``block_dim`` threads per block (Warp's CPU blocks, as on
    CUDA) and ``frames_per_block``; returns the frames and the five-kernel sequence's."""
    contractions, depths = random_controls(model, rng, frames)
    expected = five_kernel_frames(model, contractions, depths)["final"]
    buffers = model.evaluator()._frame_buffers(frames)
    buffers.upload_controls(contractions, depths)
    ((_, dim, inputs, outputs),) = plan_launches(
        model, buffers, frames, buffers.contraction, buffers.depth, buffers.final_points
    )
    inputs = list(inputs)
    batch = inputs[-1]
    widths = dict(control_count=batch.control_count, wrinkle_count=batch.wrinkle_count)
    inputs[-1] = struct_of(FrameBatch, **widths, frame_count=batch.frame_count, frames_per_block=frames_per_block)
    saved = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = True
    try:
        wp.launch(
            kernel,
            dim=(-(-frames // frames_per_block), dim[1], block_dim),
            inputs=inputs,
            outputs=outputs,
            device=DEVICE,
            block_dim=block_dim,
        )
    finally:
        wp.config.enable_cpu_blocks = saved
    return buffers.read_frames(buffers.final_points, frames), expected


@pytest.mark.parametrize(
    "rig_name, block_dim, frames_per_block, frames_per_pass, slots",
    [
        ("default rig", 256, 5, 2, (3, 6, 4)),
        ("default rig", 64, 3, 1, (1, 2, 1)),
        ("small rig without jaw", 128, 4, 3, (2, 6, 6)),
        ("default rig", 512, 2, 1, (0, 0, 0)),
        ("default rig", 256, 1, 1, (4, 6, 8)),
    ],
)
def test_resident_rig_data_equals_the_five_kernel_sequence(
    rng, rig_name, block_dim, frames_per_block, frames_per_pass, slots
):
    """The CUDA kernel that reads each thread's rig data once per block (its fixed items in registers, rows
    cut after ``slots`` entries continuing over the CSR; slots of 0 walk every row over the CSR), over
    blocks of 64–512 threads, several frames per block and pass: the same bits as the five kernels."""
    model = build_model(rig_name, "tiled")
    got, expected = launch_tiled_blocks(
        model, rng, expression_tiles_resident(frames_per_pass, block_dim, slots=slots), block_dim, frames_per_block
    )
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("block_dim, frames_per_block, frames_per_pass", [(1, 5, 2), (1, 4, 3), (8, 3, 1), (64, 4, 2)])
def test_blocks_of_many_threads_equal_the_five_kernel_sequence(rng, block_dim, frames_per_block, frames_per_pass):
    """The kernel's strided passes and barriers with many threads per block (as on CUDA, 256), here as
    Warp's CPU blocks, several frames per block and per pass (the last pass partial): the same bits."""
    model = build_model("default rig", "tiled")
    got, expected = launch_tiled_blocks(model, rng, expression_tiles(frames_per_pass), block_dim, frames_per_block)
    np.testing.assert_array_equal(got, expected)


def test_tiled_plan_with_more_incident_triangles_than_ring_slots(rng):
    """The fan's centre (14 incident triangles): local adjacency has no fixed width, several frames per block."""
    mesh, muscles, wrinkles = fan_rig()
    model = ExpressionModel(mesh, muscles, wrinkles, 0.004, device=DEVICE, plan="tiled")
    contractions = rng.uniform(0.005, 0.02, (4, 2))
    depths = rng.uniform(0.5, 2.0, (4, 1)) * model.default_depths
    expected = five_kernel_frames(model, contractions, depths)["final"]
    np.testing.assert_array_equal(
        model.evaluate(contractions, wrinkle_depths=depths, frames_per_launch=4), expected
    )  # 4 per block
