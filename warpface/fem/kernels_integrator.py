"""Warp kernels of one Newmark-β step with a Dirichlet partition (SPEC §2), device-resident.

Generic over the float type (vec3f/vec3d state with a matching scalar ``coeffs`` array), so
the same kernels run the float32 and float64 CG paths. None of them allocates or reads back
to the host, so the whole step can be captured in one graph. The step's right-hand side and
its linear solve are in :mod:`warpface.fem.kernels_cg`.

``coeffs`` holds the Newmark constants for time step ``dt``:
``[c0, c1, c2, c3, c4, c5, c6, c7, dt, dt^2 / 2]`` with
``c0 = 1/(β dt²)``, ``c1 = 1/(β dt)``, ``c2 = 1/(2β) − 1``, ``c3 = γ/(β dt)``, ``c4 = γ/β − 1``,
``c5 = dt (γ/(2β) − 1)``, ``c6 = dt (1 − γ)``, ``c7 = dt γ``.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from .kernels_cg import RR, START, slot_total

__all__ = ["newmark_update"]


@wp.kernel
def newmark_update(
    correction: wp.array(dtype=Any),
    history: wp.array2d(dtype=Any),
    guess: wp.array(dtype=Any),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    trajectory: wp.array2d(dtype=Any),
    ring: wp.array(dtype=wp.int32),
    coeffs: wp.array(dtype=Any),
    slots: wp.array3d(dtype=wp.float64),
    cg_iter: wp.array(dtype=wp.int32),
    tol_sq: wp.float64,
    chunk: int,
    d: wp.array(dtype=Any),
    v: wp.array(dtype=Any),
    a: wp.array(dtype=Any),
    record: wp.array2d(dtype=Any),
    step_count: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    failure: wp.array(dtype=wp.float64),
):
    """Per node: new displacement, then Newmark a and v in place; thread 0 books the step.

    The new displacement is the predictor ``d + dt v + dt²/2 a`` plus the CG ``correction``
    (free nodes), ``trajectory[ring[1], slot]`` (driven) or zero (fixed); it is also written to
    ``record[ring[1], node]``. For free node ``o`` the last two increments are kept in
    ``history[0, o]``, ``history[1, o]`` and ``guess[o]`` becomes the next step's cubic
    extrapolation ``4 d − 6 d₋₁ + 4 d₋₂ − d₋₃`` minus its predictor.

    Thread 0 records CG convergence (``status = [failed steps, first failed step, max iterations,
    last iterations, total iterations]``, ``failure = [residual, tolerance]`` of the first failed
    step, NaN counting as a failure), counts the step and advances the ring slot ``ring[0]``
    (read by the next step; this kernel reads only ``ring[1]``).
    """
    i = wp.tid()
    slot = ring[1]
    dn = type(d[i])()
    di = d[i]
    vi = v[i]
    ai = a[i]
    o = free_index[i]
    s = driven_slot[i]
    if o >= 0:
        dn = di + coeffs[8] * vi + coeffs[9] * ai + correction[o]
    elif s >= 0:
        dn = trajectory[slot, s]
    an = coeffs[0] * (dn - di) - coeffs[1] * vi - coeffs[2] * ai
    vn = vi + coeffs[6] * ai + coeffs[7] * an
    d[i] = dn
    a[i] = an
    v[i] = vn
    record[slot, i] = dn
    if o >= 0:
        step = dn - di
        previous = history[0, o]
        three = type(coeffs[0])(3.0)
        guess[o] = three * (step - previous) + history[1, o] - coeffs[8] * vn - coeffs[9] * an
        history[1, o] = previous
        history[0, o] = step
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
