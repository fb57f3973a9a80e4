"""The Newmark-β state update (SPEC §2), written once for both solvers, and its kernels.

:func:`newmark_advance` is the update of one node's velocity and acceleration from its new
displacement (constants by name in :class:`~warpface.fem.newmark.NewmarkCoefficients`).
:data:`newmark_update` applies it to a whole state after a direct solve; the CG solver's fused
end-of-step kernel (:data:`cg_newmark_update`) calls the same function. Both are generic over the
float type (vec3f/vec3d with matching scalars), never allocate or read back to the host, and so can
be captured in a graph.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from .kernels_cg import RR, START, slot_total

__all__ = ["cg_newmark_update", "interpolate_control", "newmark_advance", "newmark_update"]


@wp.func
def newmark_advance(
    d_new: Any, d: Any, v: Any, a: Any,
    mass_displacement: Any, mass_velocity: Any, mass_acceleration: Any,
    velocity_old_acceleration: Any, velocity_new_acceleration: Any,
):
    """``(a', v')`` of a node whose displacement goes from ``d`` to ``d_new`` (velocity ``v``, acceleration ``a``):
    ``a' = c0 (d_new − d) − c1 v − c2 a`` and ``v' = v + c6 a + c7 a'``."""
    a_new = mass_displacement * (d_new - d) - mass_velocity * v - mass_acceleration * a
    v_new = v + velocity_old_acceleration * a + velocity_new_acceleration * a_new
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
    mass_displacement: Any,
    mass_velocity: Any,
    mass_acceleration: Any,
    velocity_old_acceleration: Any,
    velocity_new_acceleration: Any,
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
    an, vn = newmark_advance(dn, di, v_in[i], a_in[i], mass_displacement, mass_velocity, mass_acceleration,
                             velocity_old_acceleration, velocity_new_acceleration)
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
    correction: wp.array(dtype=Any),
    history: wp.array2d(dtype=Any),
    guess: wp.array(dtype=Any),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    trajectory: wp.array2d(dtype=Any),
    ring: wp.array(dtype=wp.int32),
    mass_displacement: Any,
    mass_velocity: Any,
    mass_acceleration: Any,
    velocity_old_acceleration: Any,
    velocity_new_acceleration: Any,
    dt: Any,
    half_dt_squared: Any,
    slots: wp.array3d(dtype=wp.float64),
    cg_iter: wp.array(dtype=wp.int32),
    tol_sq: wp.float64,
    chunk: int,
    d_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    a_in: wp.array(dtype=Any),
    d_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
    a_out: wp.array(dtype=Any),
    record: wp.array2d(dtype=Any),
    step_count: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    failure: wp.array(dtype=wp.float64),
):
    """End of a CG step, per node: new displacement, then :func:`newmark_advance`; thread 0 books the step.

    The new displacement is the predictor ``d + dt v + dt²/2 a`` plus the CG ``correction``
    (free nodes), ``trajectory[ring[1], slot]`` (driven) or zero (fixed); it is also written to
    ``record[ring[1], node]``. For free node ``o`` the last two increments are kept in
    ``history[0, o]``, ``history[1, o]`` and ``guess[o]`` becomes the next step's cubic
    extrapolation ``4 d − 6 d₋₁ + 4 d₋₂ − d₋₃`` minus its predictor. ``*_out`` may be ``*_in``.

    Thread 0 records CG convergence (``status = [failed steps, first failed step, max iterations,
    last iterations, total iterations]``, ``failure = [residual, tolerance]`` of the first failed
    step, NaN counting as a failure), counts the step and advances the ring slot ``ring[0]``
    (read by the next step; this kernel reads only ``ring[1]``).
    """
    i = wp.tid()
    slot = ring[1]
    di = d_in[i]
    vi = v_in[i]
    ai = a_in[i]
    dn = type(di)()
    o = free_index[i]
    s = driven_slot[i]
    if o >= 0:
        dn = di + dt * vi + half_dt_squared * ai + correction[o]
    elif s >= 0:
        dn = trajectory[slot, s]
    an, vn = newmark_advance(dn, di, vi, ai, mass_displacement, mass_velocity, mass_acceleration,
                             velocity_old_acceleration, velocity_new_acceleration)
    d_out[i] = dn
    a_out[i] = an
    v_out[i] = vn
    record[slot, i] = dn
    if o >= 0:
        increment = dn - di
        previous = history[0, o]
        three = type(dt)(3.0)
        guess[o] = three * (increment - previous) + history[1, o] - dt * vn - half_dt_squared * an
        history[1, o] = previous
        history[0, o] = increment
    if i == 0:
        it = cg_iter[0]
        status[2] = wp.max(status[2], it)
        status[3] = it
        status[4] = status[4] + it
        if not (slot_total(slots, RR, it) <= tol_sq * slot_total(slots, START, 0)):
            if status[0] == 0:
                status[1] = step_count[0]
                failure[0] = wp.sqrt(slot_total(slots, RR, it))
                failure[1] = wp.sqrt(tol_sq * slot_total(slots, START, 0))
            status[0] = status[0] + 1
        step_count[0] = step_count[0] + 1
        ring[0] = (slot + 1) % chunk
