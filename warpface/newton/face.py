"""``add_face``: a face's tissue into a Newton ``ModelBuilder``, with its rig data as namespaced custom attributes.

The tissue's nodes become Newton particles and its tets Newton tetrahedra (Lamé parameters and density of the
tissue's material, so Newton's viewers and its own soft-body solvers see the same body); the rig's data goes into
custom attributes of the ``warpface`` namespace (:func:`register_face_attributes`):

=============================  ==========  ====================  ===============================================
attribute                      assignment  frequency             meaning
=============================  ==========  ====================  ===============================================
``warpface:activation``        CONTROL     ``warpface:control``  muscle contractions, then the jaw controls
``warpface:control_name``      MODEL       ``warpface:control``  the rig's control names (str)
``warpface:node_role``         MODEL       particle              -1 not a face node, 0 free, 1 fixed, 2 driven
``warpface:rest``              MODEL       particle              rest position in the head body's frame [m]
``warpface:displacement``      STATE       particle              tissue displacement in the head frame [m]
``warpface:youngs_modulus``    MODEL       tetrahedron           E [Pa] (0 for tets that are not the face's)
``warpface:poisson_ratio``     MODEL       tetrahedron           nu
``warpface:viscosity``         MODEL       tetrahedron           eta [Pa s]
``warpface:skin_rest``         MODEL       ``warpface:skin``     render-skin rest vertex, head frame [m]
``warpface:skin_tet``          MODEL       ``warpface:skin``     tet (Newton index) embedding the vertex
``warpface:skin_weights``      MODEL       ``warpface:skin``     its barycentric weights (vec4)
``warpface:skin_thickness``    MODEL       ``warpface:skin``     subcutaneous thickness at the vertex [m]
=============================  ==========  ====================  ===============================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import newton
import numpy as np
import warp as wp

from ..fem import TetMesh, TissueMaterial, embed_points
from ..fem.embedding import Embedding
from ..rig import FaceRig

__all__ = ["NAMESPACE", "NewtonFace", "add_face", "register_face_attributes"]

NAMESPACE = "warpface"
"""Namespace of every custom attribute and frequency warpface adds to a Newton model."""

ROLE_NONE, ROLE_FREE, ROLE_FIXED, ROLE_DRIVEN = -1, 0, 1, 2

_Freq = newton.Model.AttributeFrequency
_Assign = newton.Model.AttributeAssignment


def _attributes() -> list:
    """The custom attributes of :func:`register_face_attributes` (name, dtype, frequency, assignment, default)."""
    control, skin = f"{NAMESPACE}:control", f"{NAMESPACE}:skin"
    return [
        ("activation", wp.float32, control, _Assign.CONTROL, 0.0),
        ("control_name", str, control, _Assign.MODEL, ""),
        ("node_role", wp.int32, _Freq.PARTICLE, _Assign.MODEL, ROLE_NONE),
        ("rest", wp.vec3, _Freq.PARTICLE, _Assign.MODEL, None),
        ("displacement", wp.vec3, _Freq.PARTICLE, _Assign.STATE, None),
        ("youngs_modulus", wp.float32, _Freq.TETRAHEDRON, _Assign.MODEL, 0.0),
        ("poisson_ratio", wp.float32, _Freq.TETRAHEDRON, _Assign.MODEL, 0.0),
        ("viscosity", wp.float32, _Freq.TETRAHEDRON, _Assign.MODEL, 0.0),
        ("skin_rest", wp.vec3, skin, _Assign.MODEL, None),
        ("skin_tet", wp.int32, skin, _Assign.MODEL, -1),
        ("skin_weights", wp.vec4, skin, _Assign.MODEL, None),
        ("skin_thickness", wp.float32, skin, _Assign.MODEL, 0.0),
    ]


def register_face_attributes(builder) -> None:
    """Declare warpface's custom frequencies and attributes on ``builder`` (idempotent; module docstring)."""
    for name in ("control", "skin"):
        builder.add_custom_frequency(newton.ModelBuilder.CustomFrequency(name=name, namespace=NAMESPACE))
    for name, dtype, frequency, assignment, default in _attributes():
        builder.add_custom_attribute(
            newton.ModelBuilder.CustomAttribute(
                name=name,
                dtype=dtype,
                frequency=frequency,
                assignment=assignment,
                namespace=NAMESPACE,
                default=default,
                references="tetrahedron" if name == "skin_tet" else None,
            )
        )


@dataclass(frozen=True, eq=False)
class NewtonFace:
    """What :func:`add_face` put into a builder: the face's parts and where they sit in the Newton model."""

    rig: FaceRig
    """The rig (expression model source), in metres."""
    tetmesh: TetMesh
    """The tissue, in the head body's frame [m]."""
    material: TissueMaterial
    """The tissue's material (uniform or per tet)."""
    embedding: Embedding
    """The render skin's vertices bound to the tissue's tets."""
    head_body: int
    """The Newton body the skull is attached to (-1: the world)."""
    particle_start: int
    """Newton index of tissue node 0; nodes are ``particle_start + arange(N)``."""
    tet_start: int
    """Newton index of tissue tet 0."""
    control_start: int
    """Row of the first control in the ``warpface:control`` frequency."""
    skin_start: int
    """Row of the first render-skin vertex in the ``warpface:skin`` frequency."""
    fixed_nodes: np.ndarray
    """Tissue nodes on the skull (held in the head frame), sorted, int64."""
    driven_nodes: np.ndarray
    """Tissue nodes that follow the expression model, int64."""
    driven_vertices: np.ndarray
    """The render-skin vertex each driven node follows, int64."""
    contact_nodes: np.ndarray
    """Free tissue nodes on the skin side that take contact forces, sorted, int64."""
    contact_radius: float
    """Particle radius of the face's nodes [m] (Newton's soft-contact distance)."""

    @property
    def particles(self) -> np.ndarray:
        """Newton particle indices of the tissue nodes, shape (N,), int64."""
        return self.particle_start + np.arange(self.tetmesh.node_count, dtype=np.int64)


def _as_rig_and_tissue(rig_or_stage, tissue, skin_path):
    """``(rig, tetmesh, material)`` from a FaceRig (tissue required) or a rig stage (tissue read from it)."""
    from_stage = None
    if isinstance(rig_or_stage, FaceRig):
        rig = rig_or_stage
    elif isinstance(rig_or_stage, (str, Path)) or type(rig_or_stage).__name__ == "Stage":
        from ..usd import open_stage, read_rig

        from_stage = open_stage(rig_or_stage)
        rig = read_rig(from_stage, skin_path=skin_path)
    else:
        raise TypeError(
            f"add_face: rig_or_stage must be a FaceRig, a Usd.Stage or a file, got {type(rig_or_stage).__name__}"
        )
    if tissue is None:
        if from_stage is None:
            raise ValueError(f"add_face: rig {rig.name!r} has no tissue; pass tissue=(TetMesh, TissueMaterial)")
        from ..usd import read_tissue_mesh

        try:
            tissue = read_tissue_mesh(from_stage)
        except ValueError as exc:
            raise ValueError(f"add_face: the rig stage has no usable tissue TetMesh ({exc})") from None
    if hasattr(tissue, "tetmesh") and hasattr(tissue, "material"):
        return rig, tissue.tetmesh, tissue.material
    if isinstance(tissue, tuple) and len(tissue) == 2:
        tetmesh, material = tissue
        if isinstance(tetmesh, TetMesh) and isinstance(material, TissueMaterial):
            return rig, tetmesh, material
    raise TypeError(
        f"add_face: tissue must be a (TetMesh, TissueMaterial) pair or warpface.usd's TissueMeshData, "
        f"got {type(tissue).__name__}"
    )


def _node_indices(name: str, nodes, count: int) -> np.ndarray:
    arr = np.asarray(nodes)
    if arr.dtype == bool:
        if arr.shape != (count,):
            raise ValueError(f"add_face: {name} mask has shape {arr.shape}, expected ({count},)")
        return np.flatnonzero(arr).astype(np.int64)
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"add_face: {name} must be node indices or a boolean mask, got dtype {arr.dtype}")
    arr = arr.astype(np.int64).ravel()
    if arr.size and (arr.min() < 0 or arr.max() >= count):
        raise ValueError(f"add_face: {name} holds a node index outside [0, {count})")
    return arr


def _default_fixed(tetmesh: TetMesh, rig: FaceRig) -> np.ndarray:
    from ..pipelines.tissue_drive import bone_side_nodes

    return bone_side_nodes(tetmesh, rig.mesh.points, float(np.median(rig.thickness)))


def add_face(
    builder,
    rig_or_stage,
    *,
    tissue=None,
    head_body: int = -1,
    fixed=None,
    driven=None,
    contact_radius: float = 5.0e-4,
    max_embedding_distance: float | None = None,
    skin_path: str | None = None,
) -> NewtonFace:
    """Put a face's tissue into a Newton ``ModelBuilder``; returns the :class:`NewtonFace` to build a solver with.

    Args:
        builder: A ``newton.ModelBuilder`` (the head body, if any, already added).
        rig_or_stage: A :class:`~warpface.FaceRig` [m], or a warpface rig stage (``Usd.Stage`` or file) whose
            tissue TetMesh (``warpface.usd.write_tissue_mesh``) is read unless ``tissue`` is given.
        tissue: ``(TetMesh, TissueMaterial)`` or a ``TissueMeshData``, in the rig's frame [m].
        head_body: The Newton body the skull is attached to; -1 (default) attaches it to the world. The rig's
            frame is the body's frame: the tissue is placed at the body's current transform.
        fixed: Tissue nodes on the skull (indices or a boolean mask); default the boundary nodes deeper than half
            the rig's median thickness below the skin.
        driven: Tissue nodes that follow the expression model; default the nodes standing for the rig's landmark
            vertices (brows, eyes, nose, lips, jaw line), so the cheeks stay free to jiggle and be pressed.
        contact_radius: Particle radius of the face's nodes [m]: Newton detects a soft contact within it.
        max_embedding_distance: How far off the tissue a render-skin vertex may lie [m] (see
            :func:`~warpface.fem.embed_points`).
        skin_path: The rig stage's skin mesh (default: the only one).

    Raises:
        TypeError: ``builder`` is not a ModelBuilder, ``rig_or_stage`` or ``tissue`` of the wrong type,
            ``head_body`` not an integer.
        ValueError: a rig without tissue, ``head_body`` out of range, bad node sets, a contact radius that is
            not a positive length (one line each, naming the argument).
    """
    if not isinstance(builder, newton.ModelBuilder):
        raise TypeError(f"add_face: builder must be a newton.ModelBuilder, got {type(builder).__name__}")
    if isinstance(head_body, bool) or not isinstance(head_body, (int, np.integer)):
        raise TypeError(f"add_face: head_body must be an int body index, got {type(head_body).__name__}")
    head_body = int(head_body)
    if not -1 <= head_body < builder.body_count:
        raise ValueError(f"add_face: head_body {head_body} is out of range [-1, {builder.body_count}) of the builder")
    if isinstance(contact_radius, bool) or not isinstance(contact_radius, (int, float, np.integer, np.floating)):
        raise TypeError(f"add_face: contact_radius must be a number [m], got {type(contact_radius).__name__}")
    radius = float(contact_radius)
    if not (np.isfinite(radius) and radius > 0.0):
        raise ValueError(f"add_face: contact_radius must be a positive length [m], got {contact_radius!r}")
    rig, tetmesh, material = _as_rig_and_tissue(rig_or_stage, tissue, skin_path)
    material.per_tet(tetmesh.tet_count)  # size check, one line
    n = tetmesh.node_count
    embedding = embed_points(tetmesh, rig.mesh, max_distance=max_embedding_distance, device="cpu")

    fixed_nodes = np.unique(_default_fixed(tetmesh, rig) if fixed is None else _node_indices("fixed", fixed, n))
    if driven is None:
        landmarks = np.zeros(0, dtype=np.int64) if rig.landmarks is None else rig.landmarks
        nodes = embedding.nodes_for(landmarks).astype(np.int64) if len(landmarks) else np.zeros(0, np.int64)
        keep = ~np.isin(nodes, fixed_nodes)
        driven_nodes, first = np.unique(nodes[keep], return_index=True)
        driven_vertices = np.asarray(landmarks, dtype=np.int64)[keep][first]
    else:
        driven_nodes = _node_indices("driven", driven, n)
        if len(np.unique(driven_nodes)) != len(driven_nodes):
            raise ValueError("add_face: driven lists a node more than once")
        if np.isin(driven_nodes, fixed_nodes).any():
            raise ValueError("add_face: a node is both fixed and driven")
        from scipy.spatial import cKDTree

        driven_vertices = cKDTree(rig.mesh.points).query(tetmesh.points[driven_nodes])[1].astype(np.int64)
    constrained = np.union1d(fixed_nodes, driven_nodes)
    if constrained.size == 0:
        raise ValueError("add_face: no fixed or driven node: the tissue would float free of the skull")
    contact_nodes = np.setdiff1d(np.unique(tetmesh.boundary_faces), np.union1d(constrained, _deep(tetmesh, rig)))

    register_face_attributes(builder)
    particle_start, tet_start = builder.particle_count, builder.tet_count
    head = wp.transform_identity() if head_body < 0 else builder.body_q[head_body]
    fields = material.per_tet(tetmesh.tet_count)
    lam, mu = material.lame(tetmesh.tet_count)
    builder.add_soft_mesh(
        pos=wp.transform_get_translation(head),
        rot=wp.transform_get_rotation(head),
        scale=1.0,
        vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=tetmesh.points.astype(np.float32),
        indices=tetmesh.tets.astype(np.int32).ravel(),
        density=float(np.average(fields["rho"], weights=tetmesh.volumes)),
        k_mu=mu,
        k_lambda=lam,
        k_damp=fields["eta"],
        particle_radius=radius,
        label=f"{rig.name}_tissue",
    )
    # lumped masses of the tissue's own (possibly per-tet) density: a quarter of each tet's mass per node
    masses = np.zeros(n)
    np.add.at(masses, tetmesh.tets.ravel(), np.repeat(fields["rho"] * tetmesh.volumes / 4.0, 4))
    builder.particle_mass[particle_start : particle_start + n] = masses.tolist()

    attrs = builder.custom_attributes
    key = f"{NAMESPACE}:"
    role = np.full(n, ROLE_FREE, dtype=np.int32)
    role[fixed_nodes], role[driven_nodes] = ROLE_FIXED, ROLE_DRIVEN
    for i in range(n):
        attrs[key + "node_role"].values[particle_start + i] = int(role[i])
        attrs[key + "rest"].values[particle_start + i] = wp.vec3(*tetmesh.points[i])
        attrs[key + "displacement"].values[particle_start + i] = wp.vec3(0.0, 0.0, 0.0)
    for t in range(tetmesh.tet_count):
        attrs[key + "youngs_modulus"].values[tet_start + t] = float(fields["E"][t])
        attrs[key + "poisson_ratio"].values[tet_start + t] = float(fields["nu"][t])
        attrs[key + "viscosity"].values[tet_start + t] = float(fields["eta"][t])
    rows = [{key + "activation": 0.0, key + "control_name": name} for name in rig.control_names]
    control_start = _append_rows(builder, rows, key + "activation")
    thickness = np.broadcast_to(rig.thickness, (rig.mesh.vertex_count,))
    skin_rows = [
        {
            key + "skin_rest": wp.vec3(*rig.mesh.points[v]),
            key + "skin_tet": int(tet_start + embedding.tets[v]),
            key + "skin_weights": wp.vec4(*embedding.weights[v]),
            key + "skin_thickness": float(thickness[v]),
        }
        for v in range(rig.mesh.vertex_count)
    ]
    skin_start = _append_rows(builder, skin_rows, key + "skin_rest")
    return NewtonFace(
        rig=rig,
        tetmesh=tetmesh,
        material=material,
        embedding=embedding,
        head_body=head_body,
        particle_start=particle_start,
        tet_start=tet_start,
        control_start=control_start,
        skin_start=skin_start,
        fixed_nodes=fixed_nodes,
        driven_nodes=driven_nodes,
        driven_vertices=driven_vertices,
        contact_nodes=contact_nodes,
        contact_radius=radius,
    )


def _append_rows(builder, rows: list[dict], key: str) -> int:
    """Append custom-frequency rows; returns the index of the first (the current count when there are none)."""
    start = len(builder.custom_attributes[key].values or [])
    builder.add_custom_values_batch(rows)
    return start


def _deep(tetmesh: TetMesh, rig: FaceRig) -> np.ndarray:
    """Boundary nodes farther from the render skin than its largest thickness: the skull side and walls, which
    take no contact."""
    from scipy.spatial import cKDTree

    boundary = np.unique(tetmesh.boundary_faces)
    depth = cKDTree(rig.mesh.points).query(tetmesh.points[boundary])[0]
    reach = 0.5 * float(np.max(rig.thickness)) if np.max(rig.thickness) > 0 else np.inf
    return boundary[depth > reach]
