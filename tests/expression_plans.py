"""Shared by the plan tests (test_expression_plans, test_expression_tiled): the five-kernel sequence
of kernels.py launched directly, the models under test, random controls, and a rig with a high-valence vertex."""

import numpy as np
import warp as wp
from helpers import small_face_rig

from warpface import ExpressionModel
from warpface.expression.kernels import (
    apply_jaw_and_muscles,
    apply_muscles,
    apply_wrinkles,
    stretch_and_bulge,
    triangle_stretch,
)
from warpface.kernels_surface import frame_sizes, triangle_area_vectors

DEVICE = "cpu"


def five_kernel_frames(model, controls: np.ndarray, depths: np.ndarray) -> dict:
    """The staged sequence (muscles, triangle stretch, stretch and bulge, area vectors, wrinkles) over
    F frames at once, on the model's rig data; every stage as numpy, (F, V, ...)."""
    mesh, device = model._mesh_buffers, model.device
    frames, vertex_count, triangle_count = len(controls), model.mesh.vertex_count, model.mesh.triangle_count
    vertices, triangles = frames * vertex_count, frames * triangle_count
    width, wrinkle_width = max(controls.shape[1], 1), max(depths.shape[1], 1)
    control_array = wp.array(
        np.pad(controls, ((0, 0), (0, width - controls.shape[1]))).ravel().astype(np.float32), device=device
    )
    depth_array = wp.array(
        np.pad(depths, ((0, 0), (0, wrinkle_width - depths.shape[1]))).ravel().astype(np.float32), device=device
    )
    x1 = wp.empty(vertices, dtype=wp.vec3, device=device)
    terms = wp.empty(triangles, dtype=wp.vec4, device=device)
    stretch = wp.empty(vertices, dtype=wp.float32, device=device)
    x2 = wp.empty(vertices, dtype=wp.vec3, device=device)
    areas = wp.empty(triangles, dtype=wp.vec3, device=device)
    x3 = wp.empty(vertices, dtype=wp.vec3, device=device)
    counts = frame_sizes(vertex_count, triangle_count)
    if model.jaw is None:
        wp.launch(
            apply_muscles,
            dim=vertices,
            inputs=[mesh.rest_points, model._muscle_offsets, model._muscle_entries, control_array, width, vertex_count],
            outputs=[x1],
            device=device,
        )
    else:
        jaw = model.jaw
        wp.launch(
            apply_jaw_and_muscles,
            dim=vertices,
            inputs=[
                mesh.rest_points,
                model._jaw_weight,
                wp.vec3(*jaw.pivot),
                wp.vec3(*jaw.axis),
                wp.vec3(*jaw.forward),
                model._muscle_offsets,
                model._muscle_entries,
                control_array,
                width,
                len(model.muscles),
                vertex_count,
            ],
            outputs=[x1],
            device=device,
        )
    wp.launch(
        triangle_stretch,
        dim=triangles,
        inputs=[x1, mesh.triangles, mesh.triangle_weight, mesh.rest_area_lengths, counts],
        outputs=[terms],
        device=device,
    )
    wp.launch(
        stretch_and_bulge,
        dim=vertices,
        inputs=[x1, terms, model._counts, mesh.adjacency_offsets, mesh.adjacency_triangles, model._thickness, counts],
        outputs=[stretch, x2],
        device=device,
    )
    wp.launch(
        triangle_area_vectors,
        dim=triangles,
        inputs=[x2, mesh.triangles, mesh.triangle_weight, counts],
        outputs=[areas],
        device=device,
    )
    wp.launch(
        apply_wrinkles,
        dim=vertices,
        inputs=[
            x2,
            areas,
            mesh.adjacency_offsets,
            mesh.adjacency_triangles,
            stretch,
            model._wrinkle_offsets,
            model._wrinkle_entries,
            depth_array,
            wrinkle_width,
            counts,
        ],
        outputs=[x3],
        device=device,
    )
    shape = (frames, vertex_count)
    return {
        "muscle": x1.numpy().reshape(shape + (3,)),
        "stretch": stretch.numpy().reshape(shape),
        "bulge": x2.numpy().reshape(shape + (3,)),
        "final": x3.numpy().reshape(shape + (3,)),
    }


def build_model(rig_name: str, plan: str):
    from warpface.assets import default_rig

    rig = default_rig() if rig_name == "default rig" else small_face_rig()
    return ExpressionModel(
        rig.mesh,
        rig.muscles,
        rig.wrinkles,
        rig.thickness,
        device=DEVICE,
        jaw=getattr(rig, "jaw", None),
        plan=plan,
    )


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


def fan_rig():
    """A wavy disc whose centre has 14 incident triangles (a high valence) and two
    rings around it, with two linear muscles and a wrinkle across the centre."""
    import warpface as wf

    angles = np.linspace(0.0, 2 * np.pi, 14, endpoint=False)
    rings = [
        np.c_[radius * np.cos(angles + shift), radius * np.sin(angles + shift)]
        for radius, shift in ((0.03, 0.0), (0.06, 0.1))
    ]
    flat = np.concatenate([[[0.0, 0.0]], *rings])
    points = np.c_[flat, 0.004 * np.sin(40 * flat[:, 0]) * np.cos(30 * flat[:, 1])]
    inner, outer = 1 + np.arange(14), 15 + np.arange(14)
    nxt = np.roll(np.arange(14), -1)
    triangles = np.r_[
        np.c_[np.zeros(14, int), inner, inner[nxt]],
        np.c_[inner, outer, outer[nxt]],
        np.c_[inner, outer[nxt], inner[nxt]],
    ]
    mesh = wf.FaceMesh(points, triangles, name="fan")
    muscles = [
        wf.LinearMuscle("a", [0.08, 0.0, -0.01], [0.0, 0.01, 0.0], 40.0, 0.03, 0.09),
        wf.LinearMuscle("b", [-0.05, 0.07, -0.01], [0.01, -0.01, 0.0], 40.0, 0.03, 0.09),
    ]
    projection = wf.PlanarProjection([0.0, 0.0, 0.0], [1, 0, 0], [0, 1, 0])
    control = np.array([[-0.05, 0.0], [-0.02, 0.004], [0.02, -0.004], [0.05, 0.0]])
    wrinkles = [wf.Wrinkle("w", control, projection, 0.004, 0.02, 0.0)]
    return mesh, muscles, wrinkles
