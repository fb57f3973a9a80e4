"""Warp kernels of one Newmark-β step with a Dirichlet partition (SPEC §2), device-resident.

Generic over the float type (vec3f/vec3d state with a matching scalar ``coeffs`` array), so
the same kernels run the float32 and float64 CG paths. None of them allocates or reads back
to the host, so the whole step can be captured in one graph.

``coeffs`` holds the Newmark constants for time step ``dt``:
``[c0, c1, c2, c3, c4, c5, c6, c7, dt, dt^2 / 2]`` with
``c0 = 1/(β dt²)``, ``c1 = 1/(β dt)``, ``c2 = 1/(2β) − 1``, ``c3 = γ/(β dt)``, ``c4 = γ/β − 1``,
``c5 = dt (γ/(2β) − 1)``, ``c6 = dt (1 − γ)``, ``c7 = dt γ``.
"""

from __future__ import annotations

from typing import Any

import warp as wp

__all__ = ["newmark_predict", "newmark_update", "cg_status", "advance_counter"]


@wp.kernel
def newmark_predict(
    d: wp.array(dtype=Any),
    v: wp.array(dtype=Any),
    a: wp.array(dtype=Any),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    trajectory: wp.array2d(dtype=Any),
    counter: wp.array(dtype=wp.int32),
    coeffs: wp.array(dtype=Any),
    stacked: wp.array(dtype=Any),
    predicted: wp.array(dtype=Any),
):
    """Per node: the stacked right-hand-side input and the warm start of the free nodes.

    ``stacked = [c0 d + c1 v + c2 a ; c3 d + c4 v + c5 a ; d_driven(n+1)]`` (lengths N, N, D), the
    vector that ``[M_o*, C_o*, -A_od]`` multiplies; ``predicted[o] = d + dt v + dt²/2 a`` [m].
    """
    i = wp.tid()
    n = d.shape[0]
    di = d[i]
    vi = v[i]
    ai = a[i]
    stacked[i] = coeffs[0] * di + coeffs[1] * vi + coeffs[2] * ai
    stacked[n + i] = coeffs[3] * di + coeffs[4] * vi + coeffs[5] * ai
    o = free_index[i]
    if o >= 0:
        predicted[o] = di + coeffs[8] * vi + coeffs[9] * ai
    s = driven_slot[i]
    if s >= 0:
        stacked[2 * n + s] = trajectory[counter[0], s]


@wp.kernel
def newmark_update(
    predicted: wp.array(dtype=Any),
    correction: wp.array(dtype=Any),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    trajectory: wp.array2d(dtype=Any),
    counter: wp.array(dtype=wp.int32),
    coeffs: wp.array(dtype=Any),
    d: wp.array(dtype=Any),
    v: wp.array(dtype=Any),
    a: wp.array(dtype=Any),
    record: wp.array2d(dtype=Any),
):
    """Per node: new displacement (solved, driven, or zero if fixed), then Newmark a and v, in place.

    Also writes the new displacement to ``record[counter[0], node]``.
    """
    i = wp.tid()
    dn = type(d[i])()
    o = free_index[i]
    s = driven_slot[i]
    if o >= 0:
        dn = predicted[o] + correction[o]
    elif s >= 0:
        dn = trajectory[counter[0], s]
    di = d[i]
    vi = v[i]
    ai = a[i]
    an = coeffs[0] * (dn - di) - coeffs[1] * vi - coeffs[2] * ai
    d[i] = dn
    a[i] = an
    v[i] = vi + coeffs[6] * ai + coeffs[7] * an
    record[counter[0], i] = dn


@wp.kernel
def cg_status(
    iterations: wp.array(dtype=wp.int32),
    residual_sq: wp.array(dtype=Any),
    tolerance_sq: wp.array(dtype=Any),
    step_count: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    failure: wp.array(dtype=wp.float64),
):
    """Record CG convergence of this step without the host.

    ``status = [failed steps, first failed step, max iterations, last iterations]``;
    ``failure = [residual, tolerance]`` of the first failed step. NaN counts as a failure.
    """
    r = residual_sq[0]
    t = tolerance_sq[0]
    it = iterations[0]
    status[2] = wp.max(status[2], it)
    status[3] = it
    if not (r <= t):
        if status[0] == 0:
            status[1] = step_count[0]
            failure[0] = wp.sqrt(wp.float64(r))
            failure[1] = wp.sqrt(wp.float64(t))
        status[0] = status[0] + 1


@wp.kernel
def advance_counter(counter: wp.array(dtype=wp.int32), step_count: wp.array(dtype=wp.int32), ring: int):
    """Advance the slot in the ``ring``-step trajectory/record buffers and the global step count."""
    counter[0] = (counter[0] + 1) % ring
    step_count[0] = step_count[0] + 1
