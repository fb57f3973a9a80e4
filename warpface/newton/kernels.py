"""Warp kernels of ``SolverFace``'s step: placing the tissue in the world, and the host-free (capturable) path.

Every kernel has a fixed launch shape and reads the step's device data where it lies (Newton's body and contact
arrays, the tissue's state), so a step made of them can be captured in a graph (docs/NEWTON.md §5). Shapes: N tissue
nodes, F free nodes, T tets, K the contact capacity (``soft_contact_max``), D driven nodes.
"""

from __future__ import annotations

import warp as wp

__all__ = [
    "Frame",
    "TissueNodes",
    "apply_correction",
    "body_force",
    "contact_penalty",
    "contact_report",
    "driven_from_skin",
    "find_contacts",
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

    rest: wp.array(dtype=wp.vec3d)
    d: wp.array(dtype=wp.vec3d)
    v: wp.array(dtype=wp.vec3d)
    start: int


@wp.func
def _f32(x: wp.vec3d):
    return wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))


@wp.func
def _f64(x: wp.vec3):
    return wp.vec3d(wp.float64(x[0]), wp.float64(x[1]), wp.float64(x[2]))


@wp.func
def _place(
    frame: Frame,
    nodes: TissueNodes,
    i: int,
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
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
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
):
    """World position ``q`` and velocity ``qd`` of each tissue node: ``x = p + R (X + d)``, ``ẋ = v_O + ω × R (X + d)
    + R ḋ``; ``out`` the ``warpface:displacement`` state attribute (empty when the state has none)."""
    _place(frame, nodes, wp.tid(), q, qd, out)


@wp.kernel
def place_nodes_from(
    frames: wp.array(dtype=Frame),
    nodes: TissueNodes,
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
):
    """:func:`place_nodes` with the frame read from the device (``frames[0]``, written by :func:`head_frame`)."""
    _place(frames[0], nodes, wp.tid(), q, qd, out)


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


@wp.kernel
def head_frame(
    q_in: wp.array(dtype=wp.transform),
    qd_in: wp.array(dtype=wp.spatial_vector),
    q_out: wp.array(dtype=wp.transform),
    qd_out: wp.array(dtype=wp.spatial_vector),
    body_com: wp.array(dtype=wp.vec3),
    body: int,
    dt: wp.float64,
    gravity: wp.array(dtype=wp.vec3d),
    model_gravity: wp.array(dtype=wp.vec3),
    rest_gravity: wp.array(dtype=wp.vec3d),
    rest_set: wp.array(dtype=wp.int32),
    frames: wp.array(dtype=Frame),
    inertia: wp.array(dtype=wp.vec3d),
):
    """One thread: the head body's frame at the end of the step into ``frames[0]``, and in the head frame
    ``inertia = [Rᵀ (g − a_O) − b_rest, Rᵀ ω, Rᵀ α]`` (``frame.head_motion``'s finite differences); the rest gravity
    ``b_rest = R_inᵀ g_model`` is taken here when ``rest_set[0]`` is 0. ``body`` -1: the world, at rest."""
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
    if rest_set[0] == 0:
        rest_gravity[0] = wp.quat_rotate_inv(r_in, _f64(model_gravity[0]))
        rest_set[0] = 1
    frame = Frame()
    frame.head = wp.transformd(p, r)
    frame.origin_velocity = v
    frame.omega = omega
    frames[0] = frame
    inertia[0] = wp.quat_rotate_inv(r, gravity[0] - accel) - rest_gravity[0]
    inertia[1] = wp.quat_rotate_inv(r, omega)
    inertia[2] = wp.quat_rotate_inv(r, alpha)


@wp.kernel
def take_controls(
    activation: wp.array(dtype=wp.float32),
    start: int,
    count: int,
    contraction: wp.array(dtype=wp.float32),
    errors: wp.array(dtype=wp.int32),
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
def driven_from_skin(
    skin: wp.array(dtype=wp.vec3),
    vertices: wp.array(dtype=wp.int32),
    skin_rest: wp.array(dtype=wp.vec3d),
    driven: wp.array(dtype=wp.vec3d),
):
    """Per driven node: ``d = skin[vertex] − rest[vertex]`` (the expression model's output, float64)."""
    k = wp.tid()
    v = vertices[k]
    driven[k] = _f64(skin[v]) - skin_rest[v]


@wp.kernel
def body_force(
    inertia: wp.array(dtype=wp.vec3d),
    M_offsets: wp.array(dtype=wp.int32),
    M_columns: wp.array(dtype=wp.int32),
    M_values: wp.array(dtype=wp.mat33d),
    free: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=wp.vec3d),
    d: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    f: wp.array(dtype=wp.vec3d),
):
    """Per free node ``o``: ``f_o = (M b)_o`` with ``b = u − α × r − ω × (ω × r) − 2 ω × ḋ``, ``r = X + d``
    (docs/NEWTON.md §2; ``inertia = [u, ω, α]``, head frame)."""
    o = wp.tid()
    i = free[o]
    u, omega, alpha = inertia[0], inertia[1], inertia[2]
    acc = wp.vec3d()
    for e in range(M_offsets[i], M_offsets[i + 1]):
        j = M_columns[e]
        r = rest[j] + d[j]
        b = u - wp.cross(alpha, r) - wp.cross(omega, wp.cross(omega, r)) - wp.float64(2.0) * wp.cross(omega, v[j])
        acc += M_values[e] * b
    f[o] = acc


@wp.kernel
def non_finite(x: wp.array(dtype=wp.vec3d), flag: wp.array(dtype=wp.int32)):
    """``flag[0] = 1`` when an entry of ``x`` is not finite."""
    o = wp.tid()
    if not (wp.isfinite(x[o][0]) and wp.isfinite(x[o][1]) and wp.isfinite(x[o][2])):
        flag[0] = 1


@wp.kernel
def apply_correction(
    x: wp.array(dtype=wp.vec3d),
    scale: wp.array(dtype=wp.float64),
    free: wp.array(dtype=wp.int32),
    c0: wp.float64,
    c7c0: wp.float64,
    flag: wp.array(dtype=wp.int32),
    count_clamp: int,
    errors: wp.array(dtype=wp.int32),
    d: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    a: wp.array(dtype=wp.vec3d),
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
    count: wp.array(dtype=wp.int32),
    particle: wp.array(dtype=wp.int32),
    shape: wp.array(dtype=wp.int32),
    body_pos: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    shape_body: wp.array(dtype=wp.int32),
    body_q: wp.array(dtype=wp.transform),
    frames: wp.array(dtype=Frame),
    start: int,
    contact_free: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=wp.vec3d),
    d: wp.array(dtype=wp.vec3d),
    radius: wp.float64,
    penalty: wp.float64,
    diagonal: wp.array(dtype=wp.mat33d),
    slot: wp.array(dtype=wp.int32),
    normals: wp.array(dtype=wp.vec3d),
    gaps: wp.array(dtype=wp.float64),
    stiffness: wp.array(dtype=wp.float64),
    counts: wp.array(dtype=wp.int32),
):
    """Per contact record ``k`` (to Newton's fixed capacity; those past ``count[0]`` do nothing): a contact on one
    of the face's contact nodes gets its free node ``slot[k]`` (else -1), the shape's normal ``n`` in the head frame,
    its gap ``g⁰ = n·(X + d − s) − ρ`` with the current ``d`` and its penalty ``k = penalty · nᵀ A_oo[o, o] n``."""
    k = wp.tid()
    slot[k] = -1
    if k >= count[0]:
        return
    i = particle[k] - start
    if i < 0 or i >= contact_free.shape[0]:
        return
    o = contact_free[i]
    if o < 0:
        return
    world = _f64(body_pos[k])
    b = shape_body[shape[k]]
    if b >= 0:
        p, r = _pose(body_q[b])
        world = p + wp.quat_rotate(r, world)
    head = frames[0].head
    rotation = wp.transform_get_rotation(head)
    s = wp.quat_rotate_inv(rotation, world - wp.transform_get_translation(head))
    n = wp.quat_rotate_inv(rotation, _f64(normal[k]))
    slot[k] = o
    normals[k] = n
    gaps[k] = wp.dot(n, rest[i] + d[i] - s) - radius
    stiffness[k] = penalty * wp.dot(n, diagonal[o] * n)
    wp.atomic_add(counts, 0, 1)


@wp.kernel
def contact_penalty(
    slot: wp.array(dtype=wp.int32),
    normals: wp.array(dtype=wp.vec3d),
    gaps: wp.array(dtype=wp.float64),
    stiffness: wp.array(dtype=wp.float64),
    x: wp.array(dtype=wp.vec3d),
    H: wp.array(dtype=wp.mat33d),
    rhs: wp.array(dtype=wp.vec3d),
):
    """One active-set pass: a contact whose gap ``g⁰ + n·x_o`` is closed adds ``k n nᵀ`` to ``H_o`` and
    ``−k g⁰ n`` to the right-hand side (``H``, ``rhs`` zeroed before)."""
    k = wp.tid()
    o = slot[k]
    if o < 0:
        return
    n = normals[k]
    if gaps[k] + wp.dot(n, x[o]) < wp.float64(0.0):
        wp.atomic_add(H, o, stiffness[k] * wp.outer(n, n))
        wp.atomic_add(rhs, o, -stiffness[k] * gaps[k] * n)


@wp.kernel
def contact_report(
    slot: wp.array(dtype=wp.int32),
    normals: wp.array(dtype=wp.vec3d),
    gaps: wp.array(dtype=wp.float64),
    stiffness: wp.array(dtype=wp.float64),
    x: wp.array(dtype=wp.vec3d),
    counts: wp.array(dtype=wp.int32),
    force: wp.array(dtype=wp.float64),
):
    """The contacts that push after the passes (``counts[1]``) and their force ``Σ λ``, ``λ = −k (g⁰ + n·x_o)``."""
    k = wp.tid()
    o = slot[k]
    if o < 0:
        return
    g = gaps[k] + wp.dot(normals[k], x[o])
    if g < wp.float64(0.0):
        wp.atomic_add(counts, 1, 1)
        wp.atomic_add(force, 0, -stiffness[k] * g)


@wp.func
def _volume(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, p3: wp.vec3d):
    return wp.dot(wp.cross(p1 - p0, p2 - p0), p3 - p0) / wp.float64(6.0)


@wp.func
def _node_correction(x: wp.array(dtype=wp.vec3d), free_index: wp.array(dtype=wp.int32), node: int):
    o = free_index[node]
    c = wp.vec3d()
    if o >= 0:
        c = x[o]
    return c


@wp.kernel
def upright_scale(
    tets: wp.array(dtype=wp.vec4i),
    rest_volumes: wp.array(dtype=wp.float64),
    fraction: wp.float64,
    rest: wp.array(dtype=wp.vec3d),
    d: wp.array(dtype=wp.vec3d),
    x: wp.array(dtype=wp.vec3d),
    free_index: wp.array(dtype=wp.int32),
    scale: wp.array(dtype=wp.float64),
):
    """Per tet: the largest ``s`` in [0, 1] keeping its volume at ``X + d + s x`` above ``fraction`` of its rest
    volume (bisection to 1e-3, as ``contact.upright_scale``), folded into ``scale[0]`` by ``atomic_min``."""
    t = wp.tid()
    tet = tets[t]
    p0, p1 = rest[tet[0]] + d[tet[0]], rest[tet[1]] + d[tet[1]]
    p2, p3 = rest[tet[2]] + d[tet[2]], rest[tet[3]] + d[tet[3]]
    c0, c1 = _node_correction(x, free_index, tet[0]), _node_correction(x, free_index, tet[1])
    c2, c3 = _node_correction(x, free_index, tet[2]), _node_correction(x, free_index, tet[3])
    limit = fraction * rest_volumes[t]
    if _volume(p0 + c0, p1 + c1, p2 + c2, p3 + c3) > limit:
        return
    low = wp.float64(0.0)
    high = wp.float64(1.0)
    while high - low > wp.float64(1.0e-3):
        mid = wp.float64(0.5) * (low + high)
        if _volume(p0 + mid * c0, p1 + mid * c1, p2 + mid * c2, p3 + mid * c3) > limit:
            low = mid
        else:
            high = mid
    wp.atomic_min(scale, 0, low)
