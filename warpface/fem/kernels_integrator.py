"""The Newmark-β state update (SPEC §2), written once for both solvers, and its kernels.

:func:`newmark_advance` is the update of one node's velocity and acceleration from its new
displacement (its constants one struct argument, :func:`newmark_constants`, named as in
:class:`~warpface.fem.newmark.NewmarkCoefficients`).
:data:`newmark_update` applies it to a whole state after a direct solve; the CG solver's fused
end-of-step kernel (:data:`cg_newmark_update`) calls the same function. Both are generic over the
float type (vec3f/vec3d with matching scalars and constants), never allocate or read back to the host, and so can
be captured in a graph.
"""

import functools
from typing import Any

import warp as wp

from .kernels_cg import RR, START, slot_total

__all__ = [
    "cg_newmark_update",
    "interpolate_control",
    "newmark_advance",
    "newmark_constants",
    "newmark_constants_type",
    "newmark_update",
]


@functools.lru_cache(maxsize=None)
def newmark_constants_type(scalar_type):
    """The ``wp.struct`` of the state update's constants in ``scalar_type`` (``wp.float32`` or ``wp.float64``),
    fields named as in :class:`~warpface.fem.newmark.NewmarkCoefficients`."""

    @wp.struct
    class NewmarkConstants:
        mass_displacement: scalar_type
        mass_velocity: scalar_type
        mass_acceleration: scalar_type
        velocity_old_acceleration: scalar_type
        velocity_new_acceleration: scalar_type
        dt: scalar_type
        half_dt_squared: scalar_type

    return NewmarkConstants


def newmark_constants(coefficients, scalar_type):
    """The update constants of ``coefficients`` (a :class:`~warpface.fem.newmark.NewmarkCoefficients`) as an
    instance of :func:`newmark_constants_type` (one kernel argument)."""
    struct_type = newmark_constants_type(scalar_type)
    constants = struct_type()
    for name in struct_type.vars:
        setattr(constants, name, scalar_type(getattr(coefficients, name)))
    return constants


@wp.func
def newmark_advance(d_new: Any, d: Any, v: Any, a: Any, c: Any):
    """``(a', v')`` of a node whose displacement goes from ``d`` to ``d_new`` (velocity ``v``, acceleration ``a``),
    ``c`` the :func:`newmark_constants`: ``a' = c0 (d_new − d) − c1 v − c2 a`` and ``v' = v + c6 a + c7 a'``."""
    a_new = c.mass_displacement * (d_new - d) - c.mass_velocity * v - c.mass_acceleration * a
    v_new = v + c.velocity_old_acceleration * a + c.velocity_new_acceleration * a_new
    return a_new, v_new


@wp.kernel
def newmark_update(
    solution: wp.array(dtype=Any),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    driven: wp.array(dtype=Any),
    d_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    a_in: wp.array(dtype=Any),
    constants: Any,
    d_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
    a_out: wp.array(dtype=Any),
):
    """Per node: the new displacement (``solution[free_index]`` for free nodes, ``driven[driven_slot]``
    for driven ones, zero for fixed ones) and its Newmark acceleration and velocity.
    ``*_out`` may be the same arrays as ``*_in``."""
    i = wp.tid()
    di = d_in[i]
    dn = type(di)()
    o = free_index[i]
    s = driven_slot[i]
    if o >= 0:
        dn = solution[o]
    elif s >= 0:
        dn = driven[s]
    an, vn = newmark_advance(dn, di, v_in[i], a_in[i], constants)
    d_out[i] = dn
    v_out[i] = vn
    a_out[i] = an


@wp.kernel
def interpolate_control(start: wp.array(dtype=Any), end: wp.array(dtype=Any), fraction: Any, out: wp.array(dtype=Any)):
    """``out = start + fraction (end − start)`` per driven node (sub-steps between two camera frames)."""
    i = wp.tid()
    out[i] = start[i] + fraction * (end[i] - start[i])


@wp.kernel
def cg_newmark_update(
    correction: wp.array2d(dtype=Any),
    history: wp.array3d(dtype=Any),
    guess: wp.array2d(dtype=Any),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    trajectory: wp.array3d(dtype=Any),
    ring: wp.array(dtype=wp.int32),
    constants: Any,
    slots: wp.array4d(dtype=wp.float64),
    cg_iter: wp.array2d(dtype=wp.int32),
    tol_sq: wp.float64,
    chunk: int,
    d_in: wp.array2d(dtype=Any),
    v_in: wp.array2d(dtype=Any),
    a_in: wp.array2d(dtype=Any),
    d_out: wp.array2d(dtype=Any),
    v_out: wp.array2d(dtype=Any),
    a_out: wp.array2d(dtype=Any),
    record: wp.array3d(dtype=Any),
    step_count: wp.array(dtype=wp.int32),
    status: wp.array2d(dtype=wp.int32),
    failure: wp.array2d(dtype=wp.float64),
):
    """End of a CG step, per (model, node) of a batch of B models (one model: B = 1): new displacement,
    then :func:`newmark_advance`; thread ``(b, 0)`` books model ``b``'s step.

    The new displacement is the predictor ``d + dt v + dt²/2 a`` plus the CG ``correction[b]``
    (free nodes), ``trajectory[ring[1], b, slot]`` (driven) or zero (fixed); it is also written to
    ``record[ring[1], b, node]``. For free node ``o`` the last two increments are kept in
    ``history[0, b, o]``, ``history[1, b, o]`` and ``guess[b, o]`` becomes the next step's cubic
    extrapolation ``4 d − 6 d₋₁ + 4 d₋₂ − d₋₃`` minus its predictor. ``*_out`` may be ``*_in``.

    Thread ``(b, 0)`` records model ``b``'s CG convergence from its ``slots[b]`` and ``cg_iter[b]``
    (``status[b] = [failed steps, first failed step, max iterations, last iterations, total
    iterations]``, ``failure[b] = [residual, tolerance]`` of the first failed step, NaN counting as a
    failure) and counts its steps in ``step_count[b]``; thread (0, 0) advances the ring slot ``ring[0]``
    (read by the next step; this kernel reads only ``ring[1]``).
    """
    b, i = wp.tid()
    slot = ring[1]
    di = d_in[b, i]
    vi = v_in[b, i]
    ai = a_in[b, i]
    dn = type(di)()
    o = free_index[i]
    s = driven_slot[i]
    if o >= 0:
        dn = di + constants.dt * vi + constants.half_dt_squared * ai + correction[b, o]
    elif s >= 0:
        dn = trajectory[slot, b, s]
    an, vn = newmark_advance(dn, di, vi, ai, constants)
    d_out[b, i] = dn
    a_out[b, i] = an
    v_out[b, i] = vn
    record[slot, b, i] = dn
    if o >= 0:
        increment = dn - di
        previous = history[0, b, o]
        three = type(constants.dt)(3.0)
        extrapolated = three * (increment - previous) + history[1, b, o]
        guess[b, o] = extrapolated - constants.dt * vn - constants.half_dt_squared * an
        history[1, b, o] = previous
        history[0, b, o] = increment
    if i == 0:
        it = cg_iter[b, 0]
        model_slots = slots[b]
        status[b, 2] = wp.max(status[b, 2], it)
        status[b, 3] = it
        status[b, 4] = status[b, 4] + it
        if not (slot_total(model_slots, RR, it) <= tol_sq * slot_total(model_slots, START, 0)):
            if status[b, 0] == 0:
                status[b, 1] = step_count[b]
                failure[b, 0] = wp.sqrt(slot_total(model_slots, RR, it))
                failure[b, 1] = wp.sqrt(tol_sq * slot_total(model_slots, START, 0))
            status[b, 0] = status[b, 0] + 1
        step_count[b] = step_count[b] + 1
        if b == 0:
            ring[0] = (slot + 1) % chunk


@wp.kernel
def single_precision(values: wp.array2d(dtype=Any), out: wp.array2d(dtype=wp.vec3f)):
    """``out = values`` rounded to float32 (round to nearest, as NumPy's ``astype``), over (rows, nodes)."""
    i, j = wp.tid()
    out[i, j] = wp.vec3f(values[i, j])
