"""Warp kernels: the expression pipeline and its forward-mode Jacobian on a target's neighbourhood (float64).

The chain rule of the model in :mod:`.local_model`'s docstring, one thread per (frame, element), with
one derivative column per basis column looped inside the thread (driven by
:class:`.local_kernels.LocalExpression`); every value and derivative formula is a function of
:mod:`warpface.expression.formulas`, shared with the expression model's kernels. Frames with ``frame_on``
0 are skipped (their outputs keep stale values; the solver reads only the frames it evaluates). Layouts
are flat, frame after frame: values ``(frames·n,)``, derivatives ``(frames·n·B,)`` (column fastest). A
column whose muscle does not reach an element is never written: the derivative buffers are zeroed once,
and each element loops over its ``active`` columns only (a CSR fixed by the rig: which muscles reach the
element's stencil), which is most of the work saved — each vertex feels a few of the muscles.
"""

import warp as wp

from ..expression import formulas as fm
from ..kernels_surface import frame_and_element, struct_of

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = [
    "Layout",
    "layout_of",
    "Rings",
    "PointRows",
    "rings_of",
    "muscle_stage",
    "first_ring_triangles",
    "bulge_stage",
    "second_ring_triangles",
    "wrinkle_stage",
    "normal_equations",
]


@wp.struct
class Layout:
    """A frame's block sizes: C controls, M muscles, B basis columns of the model's input, K variables."""

    control_count: int
    muscle_count: int
    basis_count: int
    size: int


def layout_of(control_count: int, muscle_count: int, basis_count: int, size: int) -> Layout:
    """A :class:`Layout`: ``B = C + 1`` with a jaw (``sin θ, 1 − cos θ``), ``K = C`` or ``C + 6`` with the pose."""
    return struct_of(Layout, control_count=control_count, muscle_count=muscle_count, basis_count=basis_count, size=size)


@wp.struct
class Rings:
    """The stages' element counts per frame, and whether they take derivatives (``jacobian`` 0 or 1).

    ``columns`` basis columns; the x1 points of the second ring (``points2``), the first ring's triangles and
    vertices (``triangles1``, ``points1``), the targets' triangles and vertices (``triangles0``, ``points0``);
    ``triangle_slots`` the first ring's active (triangle, column) slots plus the always-zero one.
    """

    columns: int
    points2: int
    triangles1: int
    points1: int
    triangles0: int
    points0: int
    triangle_slots: int
    jacobian: int


def rings_of(sizes: dict, columns: int, jacobian: bool) -> Rings:
    """A :class:`Rings` from a neighbourhood's counts (keys ``n2 t1 n1 t0 n0 t1_slots``)."""
    points = dict(points2=sizes["n2"], points1=sizes["n1"], points0=sizes["n0"])
    triangles = dict(triangles1=sizes["t1"], triangles0=sizes["t0"], triangle_slots=sizes["t1_slots"])
    return struct_of(Rings, columns=columns, **points, **triangles, jacobian=1 if jacobian else 0)


@wp.func
def _zero3() -> wp.vec3d:
    return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))


@wp.func
def _corners(points: wp.array(dtype=wp.vec3d), first: int, triangle: wp.vec3i):
    """A triangle's three corners in the frame whose points start at ``first``."""
    return points[first + triangle[0]], points[first + triangle[1]], points[first + triangle[2]]


@wp.kernel
def muscle_stage(
    frame_on: wp.array(dtype=wp.int32),
    controls: wp.array(dtype=wp.float64),
    rest: wp.array(dtype=wp.vec3d),
    slot_field: wp.array(dtype=wp.vec3d),
    active_offsets: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    rings: Rings,
    points: wp.array(dtype=wp.vec3d),
):
    """x1 = x_rest + W c over the neighbourhood's vertices (the muscles that reach each vertex).

    ``slot_field`` is ``W`` per active slot (the order of ``active``), so a vertex's columns are contiguous.
    """
    i = wp.tid()
    f, v = frame_and_element(i, rings.points2)
    if frame_on[f] == 0:
        return
    x = rest[v]
    for slot in range(active_offsets[v], active_offsets[v + 1]):
        x = fm.muscle_pull(x, controls[f * rings.columns + active[slot]], slot_field[slot])
    points[i] = x


@wp.kernel
def first_ring_triangles(
    frame_on: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3d),
    slot_edges: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    weight: wp.array(dtype=wp.float64),
    rest_length: wp.array(dtype=wp.float64),
    active_offsets: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    rings: Rings,
    area: wp.array(dtype=wp.vec3d),
    ratio: wp.array(dtype=wp.float64),
    darea: wp.array(dtype=wp.vec3d),
    dratio: wp.array(dtype=wp.float64),
):
    """Area vector ``w·(p1 − p0) × (p2 − p0)`` of x1, ratio S'/S, and their derivatives (derivative of x1 = W;
    ``slot_edges[2·slot], [2·slot + 1]`` are the edges' constant derivatives ``W1 − W0``, ``W2 − W0`` per active slot).

    The derivatives are stored per active slot, ``slots + 1`` per frame (the last one stays 0: the
    bulge stage reads it for a column that does not reach the triangle).
    """
    i = wp.tid()
    f, t = frame_and_element(i, rings.triangles1)
    if frame_on[f] == 0:
        return
    p0, p1, p2 = _corners(points, f * rings.points2, triangles[t])
    w = weight[t]
    a = fm.area_vector(p0, p1, p2, w)
    area[i] = a
    ratio[i] = fm.area_ratio(a, rest_length[t])
    if rings.jacobian == 0:
        return
    e1 = p1 - p0
    e2 = p2 - p0
    for slot in range(active_offsets[t], active_offsets[t + 1]):
        k = f * (active_offsets[rings.triangles1] + 1) + slot
        da = fm.d_area_vector(e1, e2, slot_edges[2 * slot], slot_edges[2 * slot + 1], w)
        darea[k] = da
        dratio[k] = fm.d_area_ratio(a, da, rest_length[t])


@wp.kernel
def bulge_stage(
    frame_on: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3d),
    area: wp.array(dtype=wp.vec3d),
    ratio: wp.array(dtype=wp.float64),
    darea: wp.array(dtype=wp.vec3d),
    dratio: wp.array(dtype=wp.float64),
    slot_own: wp.array(dtype=wp.vec3d),
    ring_vertex: wp.array(dtype=wp.int32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.float64),
    thickness: wp.array(dtype=wp.float64),
    floor: wp.float64,
    active_offsets: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    pair_offsets: wp.array(dtype=wp.int32),
    pair_slot: wp.array(dtype=wp.int32),
    rings: Rings,
    stretch: wp.array(dtype=wp.float64),
    bulged: wp.array(dtype=wp.vec3d),
    dstretch: wp.array(dtype=wp.float64),
    dbulged: wp.array(dtype=wp.vec3d),
):
    """r (mean S'/S), N(x1), x2 = x1 + (1/max(r, floor) − 1)·h·N and ∂r/∂c, ∂x2/∂c on the first ring.

    ``ring_vertex[v]`` is the vertex's index among the x1 points (``rings.points2`` per frame); ``slot_own`` is the
    vertex's own ``W`` per active slot (the derivative of its x1). The first ring's derivatives are per
    slot (``rings.triangle_slots`` per frame, see :func:`first_ring_triangles`): ``pair_slot`` lists, from
    ``pair_offsets[v]`` on, the slot of each (active column, incident triangle) pair of the vertex in loop order.
    """
    i = wp.tid()
    f, v = frame_and_element(i, rings.points1)
    if frame_on[f] == 0:
        return
    first = f * rings.triangles1
    zero = wp.float64(0.0)
    total = zero
    normal_sum = _zero3()
    begin = adjacency_offsets[v]
    end = adjacency_offsets[v + 1]
    for k in range(begin, end):
        total += ratio[first + adjacency[k]]
        normal_sum += area[first + adjacency[k]]
    count = counts[v]
    r = fm.stretch_ratio(total, count)
    h = thickness[v]
    source = f * rings.points2 + ring_vertex[v]
    stretch[i] = r
    bulged[i] = fm.bulge_point(points[source], normal_sum, r, h, floor)
    if rings.jacobian == 0:
        return
    growth = fm.bulge_growth(r, floor)
    n = fm.unit_or_zero(normal_sum)
    pair = pair_offsets[v]
    first_slot = f * rings.triangle_slots
    for slot in range(active_offsets[v], active_offsets[v + 1]):
        m = active[slot]
        dtotal = zero
        dsum = _zero3()
        for _k in range(begin, end):
            j = first_slot + pair_slot[pair]
            pair += 1
            dtotal += dratio[j]
            dsum += darea[j]
        dr = fm.d_stretch_ratio(dtotal, count)
        dn = fm.d_unit_or_zero(normal_sum, dsum)
        out = i * rings.columns + m
        dstretch[out] = dr
        dbulged[out] = slot_own[slot] + h * (fm.d_bulge_growth(r, dr, floor) * n + growth * dn)


@wp.kernel
def second_ring_triangles(
    frame_on: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3d),
    dpoints: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    weight: wp.array(dtype=wp.float64),
    active_offsets: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    rings: Rings,
    area: wp.array(dtype=wp.vec3d),
    darea: wp.array(dtype=wp.vec3d),
):
    """Area vectors of x2 (for the wrinkles' normal) and their derivatives."""
    i = wp.tid()
    columns = rings.columns
    f, t = frame_and_element(i, rings.triangles0)
    if frame_on[f] == 0:
        return
    tri = triangles[t]
    base = f * rings.points1
    p0, p1, p2 = _corners(points, base, tri)
    w = weight[t]
    area[i] = fm.area_vector(p0, p1, p2, w)
    if rings.jacobian == 0:
        return
    e1 = p1 - p0
    e2 = p2 - p0
    for slot in range(active_offsets[t], active_offsets[t + 1]):
        m = active[slot]
        w0 = dpoints[(base + tri[0]) * columns + m]
        de1 = dpoints[(base + tri[1]) * columns + m] - w0
        de2 = dpoints[(base + tri[2]) * columns + m] - w0
        darea[i * columns + m] = fm.d_area_vector(e1, e2, de1, de2, w)


@wp.func
def _store_column(out: wp.array(dtype=wp.float64), row: int, m: int, control_count: int, value: wp.vec3d):
    base = 3 * row * control_count + m
    out[base] = value[0]
    out[base + control_count] = value[1]
    out[base + 2 * control_count] = value[2]


@wp.kernel
def wrinkle_stage(
    frame_on: wp.array(dtype=wp.int32),
    bulged: wp.array(dtype=wp.vec3d),
    stretch: wp.array(dtype=wp.float64),
    dbulged: wp.array(dtype=wp.vec3d),
    dstretch: wp.array(dtype=wp.float64),
    area: wp.array(dtype=wp.vec3d),
    darea: wp.array(dtype=wp.vec3d),
    ring_vertex: wp.array(dtype=wp.int32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency: wp.array(dtype=wp.int32),
    profile_offsets: wp.array(dtype=wp.int32),
    profile_wrinkle: wp.array(dtype=wp.int32),
    profile_value: wp.array(dtype=wp.float64),
    kr: wp.array(dtype=wp.float64),
    rest_band: wp.float64,
    active_offsets: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    rings: Rings,
    final: wp.array(dtype=wp.vec3d),
    dfinal: wp.array(dtype=wp.float64),
):
    """x3 = x2 + Σ_w depth·s·C_w(r)·N(x2) and ∂x3/∂c on the target vertices (``r ≤ 1 + rest_band``: compressed side).

    ``dfinal`` is laid out (frames, vertices, 3, controls): a frame's Jacobian is one (3n, M) matrix.
    """
    i = wp.tid()
    columns = rings.columns
    f, v = frame_and_element(i, rings.points0)
    if frame_on[f] == 0:
        return
    source = f * rings.points1 + ring_vertex[v]
    x = bulged[source]
    begin = profile_offsets[v]
    end = profile_offsets[v + 1]
    zero = wp.float64(0.0)
    if begin == end:
        final[i] = x
        if rings.jacobian != 0:
            for slot in range(active_offsets[v], active_offsets[v + 1]):
                m = active[slot]
                _store_column(dfinal, i, m, columns, dbulged[source * columns + m])
        return
    r = stretch[source]
    knee = wp.float64(1.0) + rest_band  # within the band of rest: the compressed side (REST_STRETCH_BAND)
    height = zero
    slope = zero
    for k in range(begin, end):
        factor, dfactor = fm.contraction_factor_and_slope(r, kr[profile_wrinkle[k]], knee)
        height += profile_value[k] * factor  # profile_value: depth · s, so each term is fm.wrinkle_term's
        slope += profile_value[k] * dfactor
    first = f * rings.triangles0
    a_begin = adjacency_offsets[v]
    a_end = adjacency_offsets[v + 1]
    normal_sum = _zero3()
    for k in range(a_begin, a_end):
        normal_sum += area[first + adjacency[k]]
    final[i] = fm.wrinkle_point(x, height, normal_sum)
    if rings.jacobian == 0:
        return
    n = fm.unit_or_zero(normal_sum)
    for slot in range(active_offsets[v], active_offsets[v + 1]):
        m = active[slot]
        dsum = _zero3()
        for k in range(a_begin, a_end):
            dsum += darea[(first + adjacency[k]) * columns + m]
        dn = fm.d_unit_or_zero(normal_sum, dsum)
        dheight = slope * dstretch[source * columns + m]
        _store_column(dfinal, i, m, columns, dbulged[source * columns + m] + dheight * n + height * dn)


@wp.struct
class PointRows:
    """The observation ``P`` as CSR rows: target point ``n`` is ``Σ weight[k]·x[vertex[k]]`` over
    ``k`` in ``offsets[n] .. offsets[n + 1]`` (one vertex, or a triangle's three)."""

    offsets: wp.array(dtype=wp.int32)
    vertex: wp.array(dtype=wp.int32)
    weight: wp.array(dtype=wp.float64)


@wp.func
def _observed(
    x3: wp.array(dtype=wp.vec3d),
    frame_first: int,
    points: PointRows,
    n: int,
):
    """``(P x3)_n``: a target point as the weighted sum of its vertices (one vertex, or a triangle's three)."""
    p = _zero3()
    for k in range(points.offsets[n], points.offsets[n + 1]):
        p += points.weight[k] * x3[frame_first + points.vertex[k]]
    return p


@wp.func
def _column(
    dx3: wp.array(dtype=wp.float64),
    basis: wp.array(dtype=wp.float64),
    frame: int,
    frame_first: int,
    points: PointRows,
    n: int,
    c: int,
    layout: Layout,
    rotation: wp.mat33d,
    arm: wp.vec3d,
    unit: wp.float64,
):
    """Column ``c`` of the posed target point's Jacobian [mesh units per variable]: a control's
    ``R·(P ∂x3/∂c)``, then the rotation vector's ``−[R(x − o)]×`` and the translation's ``ℓ·I``.

    ``dx3`` holds the pipeline's derivatives per *basis* column (``basis_count`` per row). With a jaw
    (``basis_count = control_count + 1``) the angle's column is the chain rule
    ``cos θ · ∂x/∂(sin θ) + sin θ · ∂x/∂(1 − cos θ)`` (``local_model`` docstring), taken here rather than
    by a separate pass over every row, and the slides sit one basis column later.
    """
    control_count = layout.control_count
    muscle_count = layout.muscle_count
    basis_count = layout.basis_count
    if c < control_count:
        # Branch-free: every column is ``first·cosine + second·sine``, with (1, 0) for all but the angle
        # (exact: ``d·1 + d·0 = d``): a branch here makes the CPU build of this kernel much slower.
        jaw = basis_count > control_count
        angle = jaw and c == muscle_count
        source = c + wp.where(jaw and c > muscle_count, 1, 0)
        second = source + wp.where(angle, 1, 0)
        frame_basis = frame * basis_count
        sine = wp.where(angle, basis[frame_basis + wp.min(muscle_count, basis_count - 1)], wp.float64(0.0))
        one_minus_cos = basis[frame_basis + wp.min(muscle_count + 1, basis_count - 1)]
        cosine = wp.where(angle, wp.float64(1.0) - one_minus_cos, wp.float64(1.0))
        d = _zero3()
        for k in range(points.offsets[n], points.offsets[n + 1]):
            row = 3 * (frame_first + points.vertex[k]) * basis_count
            base = row + source
            other = row + second
            d += points.weight[k] * wp.vec3d(
                dx3[base] * cosine + dx3[other] * sine,
                dx3[base + basis_count] * cosine + dx3[other + basis_count] * sine,
                dx3[base + 2 * basis_count] * cosine + dx3[other + 2 * basis_count] * sine,
            )
        return rotation * d
    zero = wp.float64(0.0)
    axis = wp.vec3d(zero, zero, zero)
    if c < control_count + 3:
        axis[c - control_count] = wp.float64(1.0)
        return wp.cross(axis, arm)
    axis[c - control_count - 3] = unit
    return axis


@wp.kernel
def normal_equations(
    x3: wp.array(dtype=wp.vec3d),
    dx3: wp.array(dtype=wp.float64),
    basis: wp.array(dtype=wp.float64),
    points: PointRows,
    active_offsets: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=wp.vec3d),
    weights: wp.array(dtype=wp.float64),
    rotation: wp.array(dtype=wp.mat33d),
    translation: wp.array(dtype=wp.vec3d),
    frame_on: wp.array(dtype=wp.int32),
    origin: wp.vec3d,
    unit: wp.float64,
    layout: Layout,
    vertex_count: int,
    point_count: int,
    jacobian: int,
    hessian: wp.array(dtype=wp.float64),
    gradient: wp.array(dtype=wp.float64),
    misfit: wp.array(dtype=wp.float64),
):
    """Per frame: the data term ``Σ_n w_n |e_n|²`` with ``e = (R(Px3 − o) + o)/ℓ + t − y`` and, with
    ``jacobian``, ``Jᵀ W J`` and ``Jᵀ W e`` over each point's active variables (atomics into the frame's sums).
    Only the upper triangle of ``Jᵀ W J`` is summed (half the atomics); its readers mirror it.

    Columns are in mesh units per variable; the caller scales them to the solver's variables.
    """
    i = wp.tid()
    f, n = frame_and_element(i, point_count)
    w = weights[i]
    if w == wp.float64(0.0) or frame_on[f] == 0:
        return
    first = f * vertex_count
    p = _observed(x3, first, points, n)
    r = rotation[f]
    arm = r * (p - origin)
    e = (arm + origin) / unit + translation[f] - targets[i]
    wp.atomic_add(misfit, f, w * wp.dot(e, e))
    if jacobian == 0:
        return
    variable_count = layout.size
    begin = active_offsets[n]
    end = active_offsets[n + 1]
    for a in range(begin, end):
        ca = active[a]
        col_a = _zero3()
        for b in range(a, end):  # b = a first: that column is col_a
            cb = active[b]
            col_b = _column(dx3, basis, f, first, points, n, cb, layout, r, arm, unit)
            if b == a:
                col_a = col_b
                wp.atomic_add(gradient, f * variable_count + ca, w * wp.dot(col_a, e))
            wp.atomic_add(hessian, (f * variable_count + ca) * variable_count + cb, w * wp.dot(col_a, col_b))
