"""Warp kernels of ``SolverFace``'s step: placing the tissue in the world, and the host-free (capturable) path.

Every kernel has a fixed launch shape and reads the step's device data where it lies (Newton's body and contact
arrays, the tissue's state), so a step made of them can be captured in a graph (docs/NEWTON.md §5). Shapes: N tissue
nodes, F free nodes, T tets, K the contact capacity (``soft_contact_max``), D driven nodes.
"""

from __future__ import annotations

import warp as wp

from ..fem.kernels_cg_rows import cg_matrix_types

BlockRows = cg_matrix_types(wp.float64).BlockRows
"""A BSR matrix of 3x3 float64 blocks as one kernel argument (``offsets``, ``indices``, ``values``)."""

Vectors = wp.array(dtype=wp.vec3d)
"""Annotation: an array of float64 3-vectors."""
Vectors32 = wp.array(dtype=wp.vec3)
"""Annotation: an array of float32 3-vectors (Newton's particles, the expression model's points)."""
Indices = wp.array(dtype=wp.int32)
"""Annotation: an array of int32."""
Scalars = wp.array(dtype=wp.float64)
"""Annotation: an array of float64."""
Blocks = wp.array(dtype=wp.mat33d)
"""Annotation: an array of 3x3 float64 blocks."""
Poses = wp.array(dtype=wp.transform)
"""Annotation: Newton's body poses."""
Twists = wp.array(dtype=wp.spatial_vector)
"""Annotation: Newton's body twists (COM linear velocity, angular velocity)."""

__all__ = [
    "BlockRows",
    "Blocks",
    "Indices",
    "Poses",
    "Twists",
    "Scalars",
    "Vectors",
    "Vectors32",
    "ContactSlots",
    "SoftContacts",
    "Frame",
    "HeadInputs",
    "TissueNodes",
    "apply_correction",
    "contact_penalty",
    "contact_report",
    "driven_from_skin",
    "find_contacts",
    "head_body_force",
    "head_frame",
    "non_finite",
    "place_nodes",
    "place_nodes_from",
    "take_controls",
    "upright_scale",
]

ERROR_CONTROL, ERROR_NON_FINITE, ERROR_CLAMPED = 0, 1, 2
"""Slots of the capturable step's status counters: first bad control + 1, skipped non-finite corrections,
clamped contact steps."""


@wp.struct
class Frame:
    """The head frame at the end of a step: pose, origin velocity [m/s] and angular velocity [rad/s] (world)."""

    head: wp.transformd
    origin_velocity: wp.vec3d
    omega: wp.vec3d


@wp.struct
class TissueNodes:
    """The tissue in the head frame (rest positions, displacement [m], velocity [m/s]) and its first particle."""

    rest: Vectors
    d: Vectors
    v: Vectors
    start: int


@wp.struct
class SoftContacts:
    """Newton's soft-contact arrays (``newton.Contacts``): count (1,), then per record (K,) the particle, the shape,
    the contact point in the shape's body frame [m] and the shape's outward normal."""

    count: Indices
    particle: Indices
    shape: Indices
    body_pos: Vectors32
    normal: Vectors32


@wp.struct
class ContactSlots:
    """The face's contacts per Newton record (K,): free node (-1: none), normal and gap ``g⁰`` [m] in the head frame,
    penalty stiffness [N/m]."""

    slot: Indices
    normals: Vectors
    gaps: Scalars
    stiffness: Scalars


@wp.func
def _f32(x: wp.vec3d):
    return wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))


@wp.func
def _f64(x: wp.vec3):
    return wp.vec3d(wp.float64(x[0]), wp.float64(x[1]), wp.float64(x[2]))


@wp.func
def _finite(x: wp.vec3d):
    return wp.isfinite(x[0]) and wp.isfinite(x[1]) and wp.isfinite(x[2])


@wp.func
def _place(
    frame: Frame,
    nodes: TissueNodes,
    i: int,
    q: Vectors32,
    qd: Vectors32,
    out: Vectors32,
):
    arm = wp.transform_vector(frame.head, nodes.rest[i] + nodes.d[i])
    x = wp.transform_get_translation(frame.head) + arm
    xd = frame.origin_velocity + wp.cross(frame.omega, arm) + wp.transform_vector(frame.head, nodes.v[i])
    j = nodes.start + i
    q[j] = _f32(x)
    qd[j] = _f32(xd)
    if out.shape[0] > 0:
        out[j] = _f32(nodes.d[i])


@wp.kernel
def place_nodes(
    frame: Frame,
    nodes: TissueNodes,
    q: Vectors32,
    qd: Vectors32,
    out: Vectors32,
):
    """World position ``q`` and velocity ``qd`` of each tissue node: ``x = p + R (X + d)``, ``ẋ = v_O + ω × R (X + d)
    + R ḋ``; ``out`` the ``warpface:displacement`` state attribute (empty when the state has none)."""
    _place(frame, nodes, wp.tid(), q, qd, out)


@wp.kernel
def place_nodes_from(
    frames: wp.array(dtype=Frame),
    nodes: TissueNodes,
    q: Vectors32,
    qd: Vectors32,
    out: Vectors32,
    rest_set: Indices,
):
    """:func:`place_nodes` with the frame read from the device (``frames[0]``, written by :func:`head_frame` or
    :func:`head_body_force`); thread 0 marks the rest gravity as taken (``rest_set[0] = 1``)."""
    _place(frames[0], nodes, wp.tid(), q, qd, out)
    if wp.tid() == 0:
        rest_set[0] = 1


@wp.func
def _pose(q: wp.transform):
    t = wp.transform_get_translation(q)
    r = wp.transform_get_rotation(q)
    return _f64(t), wp.quatd(wp.float64(r[0]), wp.float64(r[1]), wp.float64(r[2]), wp.float64(r[3]))


@wp.func
def _origin_twist(q: wp.transform, qd: wp.spatial_vector, com: wp.vec3):
    # (v_origin, ω) from Newton's twist (COM linear velocity, then angular velocity; world frame)
    p, r = _pose(q)
    omega = wp.vec3d(wp.float64(qd[3]), wp.float64(qd[4]), wp.float64(qd[5]))
    v = wp.vec3d(wp.float64(qd[0]), wp.float64(qd[1]), wp.float64(qd[2])) - wp.cross(
        omega, wp.quat_rotate(r, _f64(com))
    )
    return v, omega


@wp.func
def _head_motion(
    q_in: Poses, qd_in: Twists, q_out: Poses, qd_out: Twists, body_com: Vectors32, body: int, dt: wp.float64
):
    # (p, R, R_in, v_O, ω, a_O, α) of the head body over the step (world frame); the world at rest for body -1
    p = wp.vec3d()
    r = wp.quatd(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0), wp.float64(1.0))
    r_in = r
    v = wp.vec3d()
    omega = wp.vec3d()
    accel = wp.vec3d()
    alpha = wp.vec3d()
    if body >= 0:
        com = body_com[body]
        p, r = _pose(q_out[body])
        p_in, r_in = _pose(q_in[body])
        v, omega = _origin_twist(q_out[body], qd_out[body], com)
        v_in, omega_in = _origin_twist(q_in[body], qd_in[body], com)
        accel = (v - v_in) / dt
        alpha = (omega - omega_in) / dt
    return p, r, r_in, v, omega, accel, alpha


@wp.func
def _frame(p: wp.vec3d, r: wp.quatd, v: wp.vec3d, omega: wp.vec3d):
    frame = Frame()
    frame.head = wp.transformd(p, r)
    frame.origin_velocity = v
    frame.omega = omega
    return frame


@wp.func
def _inertia(r: wp.quatd, gravity: wp.vec3d, rest: wp.vec3d, accel: wp.vec3d, omega: wp.vec3d, alpha: wp.vec3d):
    # [Rᵀ (g − a_O) − b_rest, Rᵀ ω, Rᵀ α] in the head frame, all zero (and False) when one is not finite
    u = wp.quat_rotate_inv(r, gravity - accel) - rest
    w = wp.quat_rotate_inv(r, omega)
    dw = wp.quat_rotate_inv(r, alpha)
    finite = _finite(u) and _finite(w) and _finite(dw)
    if not finite:
        u = wp.vec3d()
        w = wp.vec3d()
        dw = wp.vec3d()
    return u, w, dw, finite


@wp.struct
class HeadInputs:
    """What the head's motion over a step is read from: Newton's body poses and twists at both ends, the bodies' COM
    offsets, the head body (-1: the world), dt [s], the tissue's gravity (1,) and the model's (1,) [m/s²]."""

    q_in: Poses
    qd_in: Twists
    q_out: Poses
    qd_out: Twists
    body_com: Vectors32
    body: int
    dt: wp.float64
    gravity: Vectors
    model_gravity: Vectors32


@wp.func
def _head_motion_of(head: HeadInputs):
    return _head_motion(head.q_in, head.qd_in, head.q_out, head.qd_out, head.body_com, head.body, head.dt)


@wp.kernel
def head_frame(head: HeadInputs, rest_gravity: Vectors, rest_set: Indices, frames: wp.array(dtype=Frame)):
    """One thread: the head body's frame at the end of the step into ``frames[0]`` (``frame.head_motion``'s finite
    differences; ``body`` -1: the world, at rest), and the rest gravity ``b_rest = R_inᵀ g_model`` when
    ``rest_set[0]`` is 0. The step without inertia; with it, :func:`head_body_force` does this."""
    p, r, r_in, v, omega, accel, alpha = _head_motion_of(head)
    if rest_set[0] == 0:
        rest_gravity[0] = wp.quat_rotate_inv(r_in, _f64(head.model_gravity[0]))
        rest_set[0] = 1
    frames[0] = _frame(p, r, v, omega)


@wp.kernel
def head_body_force(
    head: HeadInputs,
    rest_gravity: Vectors,
    rest_set: Indices,
    M: BlockRows,
    free: Indices,
    nodes: TissueNodes,
    frames: wp.array(dtype=Frame),
    errors: Indices,
    f: Vectors,
):
    """The head frame and the inertial body force in one launch, per free node ``o`` (node ``i = free[o]``):
    ``f[i] = (M b)_i`` with ``b = u − α × r − ω × (ω × r) − 2 ω × ḋ``, ``r = X + d`` (docs/NEWTON.md §2;
    ``[u, ω, α] = [Rᵀ (g − a_O) − b_rest, Rᵀ ω, Rᵀ α]`` in the head frame, ``M`` the consistent mass, N x N blocks);
    ``f`` (N,) is the tissue step's external force, its other rows left as they are (zero). Every thread finds the
    head's motion itself (a few quaternion products); thread 0 writes ``frames[0]``, the rest gravity
    ``b_rest = R_inᵀ g_model`` when ``rest_set[0]`` is 0, and books a non-finite ``[u, ω, α]`` (a head motion gone
    bad: no body force) in ``errors[ERROR_NON_FINITE]``. With ``[u, ω, α] = 0`` (a still head in its rest gravity) ``f``
    is 0 without reading the mass row. ``rest_set`` is only read here, so every thread sees one
    value: the step's last kernel (:func:`place_nodes_from`) sets it."""
    o = wp.tid()
    p, r, r_in, v, omega, accel, alpha = _head_motion_of(head)
    taken = rest_set[0] != 0
    rest = wp.quat_rotate_inv(r_in, _f64(head.model_gravity[0]))
    if taken:
        rest = rest_gravity[0]
    u, w, dw, finite = _inertia(r, head.gravity[0], rest, accel, omega, alpha)
    if o == 0:
        frames[0] = _frame(p, r, v, omega)
        if not taken:
            rest_gravity[0] = rest
        if not finite:
            errors[ERROR_NON_FINITE] = errors[ERROR_NON_FINITE] + 1
    i = free[o]
    if wp.length_sq(u) + wp.length_sq(w) + wp.length_sq(dw) == wp.float64(0.0):
        f[i] = wp.vec3d()  # a head at rest in its rest gravity: b = 0 exactly, no pass over the mass row
    else:
        f[i] = _mass_times_body(u, w, dw, M, i, nodes)


@wp.kernel
def take_controls(
    activation: wp.array(dtype=wp.float32),
    start: int,
    count: int,
    contraction: wp.array(dtype=wp.float32),
    errors: Indices,
):
    """One thread: the face's rows of Newton's ``warpface:activation`` into the expression model's input; a
    non-finite one keeps the last good controls and books its index (+1) in ``errors[ERROR_CONTROL]``."""
    bad = int(-1)
    for c in range(count):
        if bad < 0 and not wp.isfinite(activation[start + c]):
            bad = c
    if bad >= 0:
        if errors[ERROR_CONTROL] == 0:
            errors[ERROR_CONTROL] = bad + 1
        return
    for c in range(count):
        contraction[c] = activation[start + c]


@wp.kernel
def driven_from_skin(skin: Vectors32, vertices: Indices, skin_rest: Vectors, driven: Vectors):
    """Per driven node: ``d = skin[vertex] − rest[vertex]`` (the expression model's output, float64)."""
    k = wp.tid()
    v = vertices[k]
    driven[k] = _f64(skin[v]) - skin_rest[v]


@wp.func
def _mass_times_body(u: wp.vec3d, omega: wp.vec3d, alpha: wp.vec3d, M: BlockRows, i: int, nodes: TissueNodes):
    # (M b)_i, b = u − α × r − ω × (ω × r) − 2 ω × ḋ at each node j of row i, r = X + d
    acc = wp.vec3d()
    for e in range(M.offsets[i], M.offsets[i + 1]):
        j = M.indices[e]
        r = nodes.rest[j] + nodes.d[j]
        b = u - wp.cross(alpha, r) - wp.cross(omega, wp.cross(omega, r))
        acc += M.values[e] * (b - wp.float64(2.0) * wp.cross(omega, nodes.v[j]))
    return acc


@wp.kernel
def non_finite(x: Vectors, flag: Indices):
    """``flag[0] = 1`` when an entry of ``x`` is not finite."""
    if not _finite(x[wp.tid()]):
        flag[0] = 1


@wp.kernel
def apply_correction(
    x: Vectors,
    scale: Scalars,
    free: Indices,
    c0: wp.float64,
    c7c0: wp.float64,
    flag: Indices,
    count_clamp: int,
    errors: Indices,
    d: Vectors,
    v: Vectors,
    a: Vectors,
):
    """Add ``s x`` (``s = scale[0]``) to the free nodes' displacement of the step just taken, with ``δa = c0 δd``,
    ``δv = c7 c0 δd``; nothing when ``flag[0]`` says ``x`` is not finite (booked in ``errors``)."""
    o = wp.tid()
    s = scale[0]
    if o == 0:
        if flag[0] != 0:
            errors[ERROR_NON_FINITE] = errors[ERROR_NON_FINITE] + 1
        elif count_clamp != 0 and s < wp.float64(1.0):
            errors[ERROR_CLAMPED] = errors[ERROR_CLAMPED] + 1
    if flag[0] != 0:
        return
    delta = s * x[o]
    i = free[o]
    d[i] = d[i] + delta
    a[i] = a[i] + c0 * delta
    v[i] = v[i] + c7c0 * delta


@wp.kernel
def find_contacts(
    found: SoftContacts,
    shape_body: Indices,
    body_q: Poses,
    frames: wp.array(dtype=Frame),
    contact_free: Indices,
    nodes: TissueNodes,
    radius: wp.float64,
    penalty: wp.float64,
    diagonal: Blocks,
    out: ContactSlots,
    counts: Indices,
):
    """Per contact record ``k`` (to Newton's fixed capacity; those past ``found.count[0]`` do nothing): a contact
    on one of the face's contact nodes gets its free node (else -1), the shape's normal ``n`` in the head frame, its
    gap ``g⁰ = n·(X + d − s) − ρ`` with the current ``d`` and its penalty ``k = penalty · nᵀ A_oo[o, o] n``;
    ``counts[0]`` counts them. ``contact_free``: free index of each contact node, -1 for the other nodes."""
    k = wp.tid()
    out.slot[k] = -1
    if k >= found.count[0]:
        return
    i = found.particle[k] - nodes.start
    if i < 0 or i >= contact_free.shape[0]:
        return
    o = contact_free[i]
    if o < 0:
        return
    world = _f64(found.body_pos[k])
    b = shape_body[found.shape[k]]
    if b >= 0:
        p, r = _pose(body_q[b])
        world = p + wp.quat_rotate(r, world)
    head = frames[0].head
    rotation = wp.transform_get_rotation(head)
    s = wp.quat_rotate_inv(rotation, world - wp.transform_get_translation(head))
    n = wp.quat_rotate_inv(rotation, _f64(found.normal[k]))
    out.slot[k] = o
    out.normals[k] = n
    out.gaps[k] = wp.dot(n, nodes.rest[i] + nodes.d[i] - s) - radius
    out.stiffness[k] = penalty * wp.dot(n, diagonal[o] * n)
    wp.atomic_add(counts, 0, 1)


@wp.func
def _gap(contacts: ContactSlots, k: int, x: Vectors):
    # the gap of contact k (of free node o >= 0) after the correction x
    return contacts.gaps[k] + wp.dot(contacts.normals[k], x[contacts.slot[k]])


@wp.kernel
def contact_penalty(contacts: ContactSlots, x: Vectors, H: Blocks, rhs: Vectors):
    """One active-set pass: a contact whose gap ``g⁰ + n·x_o`` is closed adds ``k n nᵀ`` to ``H_o`` and
    ``−k g⁰ n`` to the right-hand side (``H``, ``rhs`` zeroed before)."""
    k = wp.tid()
    o = contacts.slot[k]
    if o >= 0:
        if _gap(contacts, k, x) < wp.float64(0.0):
            n, stiffness = contacts.normals[k], contacts.stiffness[k]
            wp.atomic_add(H, o, stiffness * wp.outer(n, n))
            wp.atomic_add(rhs, o, -stiffness * contacts.gaps[k] * n)


@wp.kernel
def contact_report(
    contacts: ContactSlots,
    x: Vectors,
    counts: Indices,
    force: Scalars,
):
    """The contacts that push after the passes (``counts[1]``) and their force ``Σ λ``, ``λ = −k (g⁰ + n·x_o)``."""
    k = wp.tid()
    if contacts.slot[k] >= 0:
        g = _gap(contacts, k, x)
        if g < wp.float64(0.0):
            wp.atomic_add(counts, 1, 1)
            wp.atomic_add(force, 0, -contacts.stiffness[k] * g)


@wp.func
def _volume(p: wp.mat44d):
    # signed volume of the tet whose corners are the rows of p (the fourth column unused)
    p0 = wp.vec3d(p[0, 0], p[0, 1], p[0, 2])
    e1 = wp.vec3d(p[1, 0], p[1, 1], p[1, 2]) - p0
    e2 = wp.vec3d(p[2, 0], p[2, 1], p[2, 2]) - p0
    e3 = wp.vec3d(p[3, 0], p[3, 1], p[3, 2]) - p0
    return wp.dot(wp.cross(e1, e2), e3) / wp.float64(6.0)


@wp.kernel
def upright_scale(
    tets: wp.array(dtype=wp.vec4i),
    rest_volumes: Scalars,
    fraction: wp.float64,
    nodes: TissueNodes,
    x: Vectors,
    free_index: Indices,
    scale: Scalars,
):
    """Per tet: the largest ``s`` in [0, 1] keeping its volume at ``X + d + s x`` above ``fraction`` of its rest
    volume (bisection to 1e-3, as ``contact.upright_scale``), folded into ``scale[0]`` by ``atomic_min``."""
    tet = tets[wp.tid()]
    p = wp.mat44d()
    c = wp.mat44d()
    for corner in range(4):
        node = tet[corner]
        o = free_index[node]
        for axis in range(3):
            p[corner, axis] = nodes.rest[node][axis] + nodes.d[node][axis]
            if o >= 0:
                c[corner, axis] = x[o][axis]
    limit = fraction * rest_volumes[wp.tid()]
    if _volume(p + c) > limit:
        return
    low = wp.float64(0.0)
    high = wp.float64(1.0)
    while high - low > wp.float64(1.0e-3):
        mid = wp.float64(0.5) * (low + high)
        if _volume(p + mid * c) > limit:
            low = mid
        else:
            high = mid
    wp.atomic_min(scale, 0, low)
