"""Warp kernels: the projected Levenberg–Marquardt step of :class:`~warpface.solve.Solver`, one thread per frame.

The same iteration as the solver's host loop (see :mod:`.solver`), kept on the device so a batch of
frames makes no host round trip per frame: after the data term's normal equations (:mod:`.kernels`),
:func:`begin_iteration` adds the regularisation, holds the controls pushed against a bound, solves the
damped system on the free variables (Cholesky in the frame's global scratch) and proposes a trial;
after the trial's misfit, :func:`judge_trial` accepts it (less damping) or retries with more damping.
Layouts are flat and frame-major: a frame's K×K system is ``[f·K·K, (f+1)·K·K)``, K = C controls
(+ 6 pose variables: rotation vector, translation in face units). Variables are the scaled controls
``u`` (face units), so every frame's state stays on the device between launches.

With a jaw the C controls are M muscles then the jaw's three (opening angle θ, protrusion, slide), and
the model's input is its B = M + 4 column basis (``sin θ, 1 − cos θ`` for the angle, see
:mod:`.local_model`): the kernels that hand an iterate to the model write the basis with the same
function as the host upload (:func:`.local_kernels.write_model_input`).
The L1 term ``l1·Σ|u|`` is handled per orthant as in :mod:`.host_steps`: :func:`begin_iteration`
picks each control's side (the bounds of the iteration, ``lower``/``upper``), the trials stay in it.
"""

import warp as wp

from .kernels import Layout
from .local_kernels import write_model_input

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = ["load_current", "begin_iteration", "judge_trial"]

BOUND_SLACK = wp.constant(1e-12)
"""A scaled control this close to a bound counts as at it (the host loop's margin)."""
MAX_TRIES = wp.constant(8)
"""Rejected trials per iteration before a frame counts as stationary."""


@wp.struct
class Terms:
    """The regularisation's weights and mirrored pairs (flat ``left, right``), and the convergence tests."""

    pairs: wp.array(dtype=wp.int32)
    pair_count: int
    l2: wp.float64
    l1: wp.float64
    smooth: wp.float64
    symmetry: wp.float64
    tolerance: wp.float64
    step_tolerance: wp.float64
    energy_tolerance: wp.float64


@wp.struct
class Scaling:
    """The solver's constants: each variable's column scale (mesh units → ``∂e/∂u``), the box bounds of
    the scaled controls, and the control scale (``u = c·scale``)."""

    column: wp.array(dtype=wp.float64)
    low: wp.array(dtype=wp.float64)
    high: wp.array(dtype=wp.float64)
    scale: wp.array(dtype=wp.float64)


@wp.struct
class DataTerm:
    """The data term's output at the model's input: ``JᵀWJ`` (upper triangle summed), ``JᵀWe``, misfit."""

    hessian: wp.array(dtype=wp.float64)
    gradient: wp.array(dtype=wp.float64)
    misfit: wp.array(dtype=wp.float64)


@wp.struct
class ModelInput:
    """What the model evaluates next: its basis input per frame, the pose, and the frames to evaluate."""

    controls: wp.array(dtype=wp.float64)
    rotation: wp.array(dtype=wp.mat33d)
    translation: wp.array(dtype=wp.vec3d)
    frame_on: wp.array(dtype=wp.int32)


@wp.struct
class Iterate:
    """Per-frame iteration state and scratch (see :class:`.device_steps.DeviceSteps`)."""

    u: wp.array(dtype=wp.float64)
    previous: wp.array(dtype=wp.float64)
    rotation: wp.array(dtype=wp.mat33d)
    translation: wp.array(dtype=wp.vec3d)
    damping: wp.array(dtype=wp.float64)
    current: wp.array(dtype=wp.float64)
    misfit: wp.array(dtype=wp.float64)
    active: wp.array(dtype=wp.int32)
    converged: wp.array(dtype=wp.int32)
    iterations: wp.array(dtype=wp.int32)
    held: wp.array(dtype=wp.int32)
    lower: wp.array(dtype=wp.float64)
    upper: wp.array(dtype=wp.float64)
    tries: wp.array(dtype=wp.int32)
    system: wp.array(dtype=wp.float64)
    step: wp.array(dtype=wp.float64)
    trial_u: wp.array(dtype=wp.float64)
    trial_rotation: wp.array(dtype=wp.mat33d)
    trial_translation: wp.array(dtype=wp.vec3d)
    pending: wp.array(dtype=wp.int32)
    counter: wp.array(dtype=wp.int32)


@wp.func
def _regularisation(u: wp.array(dtype=wp.float64), state: Iterate, terms: Terms, base: int, control_count: int):
    """``l2·|u|² + l1·Σ|u| + smooth·|u − u_prev|² + symmetry·Σ (u_l − u_r)²`` of one frame."""
    value = wp.float64(0.0)
    for m in range(control_count):
        x = u[base + m]
        d = x - state.previous[base + m]
        value += terms.l2 * x * x + terms.l1 * wp.abs(x) + terms.smooth * d * d
    for p in range(terms.pair_count):
        d = u[base + terms.pairs[2 * p]] - u[base + terms.pairs[2 * p + 1]]
        value += terms.symmetry * d * d
    return value


@wp.func
def _orthant_slope(x: wp.float64, gradient: wp.float64, l1: wp.float64):
    """∂|u|/∂u in this iteration's orthant: the sign of ``u``; at 0 the side the smooth gradient descends to."""
    slope = wp.float64(1.0)
    if x < wp.float64(0.0):
        slope = wp.float64(-1.0)
    elif x == wp.float64(0.0) and gradient - wp.float64(0.5) * l1 > wp.float64(0.0):
        slope = wp.float64(-1.0)
    return slope


@wp.func
def _rotation_from_vector(omega: wp.vec3d):
    """Rodrigues' formula (series near zero, as :func:`.pose.rotation_from_vector`)."""
    angle = wp.length(omega)
    one = wp.float64(1.0)
    zero = wp.float64(0.0)
    k = wp.mat33d(zero, -omega[2], omega[1], omega[2], zero, -omega[0], -omega[1], omega[0], zero)
    a = one - angle * angle / wp.float64(6.0)
    b = wp.float64(0.5) - angle * angle / wp.float64(24.0)
    if angle >= wp.float64(1e-8):
        a = wp.sin(angle) / angle
        b = (one - wp.cos(angle)) / (angle * angle)
    return wp.identity(n=3, dtype=wp.float64) + a * k + b * (k * k)


@wp.func
def _damped_step(data: DataTerm, state: Iterate, f: int, size: int):
    """Solve ``(H + λ·diag(H)) s = −g`` on the free variables (held ones: ``s = 0``) into ``state.step``.

    The damped system is positive definite; a failed Cholesky pivot falls back to the diagonal step.
    """
    hessian = data.hessian
    gradient = data.gradient
    held = state.held
    system = state.system
    step = state.step
    damping = state.damping[f]
    hb = f * size * size
    vb = f * size
    zero = wp.float64(0.0)
    largest = zero
    for a in range(size):
        largest = wp.max(largest, hessian[hb + a * size + a])
    floor = wp.float64(1e-12) * wp.max(largest, wp.float64(1e-300))
    for a in range(size):
        for b in range(size):
            value = zero
            if held[vb + a] == 0 and held[vb + b] == 0:
                value = hessian[hb + a * size + b]
            system[hb + a * size + b] = value
        d = hessian[hb + a * size + a]
        diagonal = wp.float64(1.0)
        if held[vb + a] == 0:
            diagonal = d + damping * wp.max(d, floor)
        system[hb + a * size + a] = diagonal
    # Cholesky in place (lower triangle), then forward and back substitution.
    ok = int(1)
    for j in range(size):
        s = system[hb + j * size + j]
        for k in range(j):
            s -= system[hb + j * size + k] * system[hb + j * size + k]
        if not (s > zero) or not wp.isfinite(s):
            ok = 0
            break
        root = wp.sqrt(s)
        system[hb + j * size + j] = root
        for i in range(j + 1, size):
            t = system[hb + i * size + j]
            for k in range(j):
                t -= system[hb + i * size + k] * system[hb + j * size + k]
            system[hb + i * size + j] = t / root
    if ok == 1:
        for i in range(size):
            t = zero
            if held[vb + i] == 0:
                t = -gradient[vb + i]
            for k in range(i):
                t -= system[hb + i * size + k] * step[vb + k]
            step[vb + i] = t / system[hb + i * size + i]
        for r in range(size):
            i = size - 1 - r
            t = step[vb + i]
            for k in range(i + 1, size):
                t -= system[hb + k * size + i] * step[vb + k]
            step[vb + i] = t / system[hb + i * size + i]
    else:
        for a in range(size):
            t = zero
            if held[vb + a] == 0:
                d = hessian[hb + a * size + a]
                t = -gradient[vb + a] / (d + damping * wp.max(d, floor))
            step[vb + a] = t
    for a in range(size):
        if not wp.isfinite(step[vb + a]):
            step[vb + a] = zero


@wp.func
def _propose(f: int, layout: Layout, scaling: Scaling, state: Iterate, model: ModelInput):
    """The trial ``clip(u + s)`` to the iteration's bounds (and the composed pose), as the model's next input."""
    control_count = layout.control_count
    ub = f * control_count
    vb = f * layout.size
    step = state.step
    for m in range(control_count):
        moved = state.u[ub + m] + step[vb + m]
        state.trial_u[ub + m] = wp.min(wp.max(moved, state.lower[ub + m]), state.upper[ub + m])
    write_model_input(state.trial_u, scaling.scale, f, layout, model.controls)
    r = state.rotation[f]
    t = state.translation[f]
    if layout.size > control_count:
        c = vb + control_count
        r = _rotation_from_vector(wp.vec3d(step[c], step[c + 1], step[c + 2])) * r
        t = t + wp.vec3d(step[c + 3], step[c + 4], step[c + 5])
    state.trial_rotation[f] = r
    state.trial_translation[f] = t
    model.rotation[f] = r
    model.translation[f] = t
    model.frame_on[f] = 1
    state.pending[f] = 1
    wp.atomic_add(state.counter, 0, 1)


@wp.kernel
def load_current(layout: Layout, scaling: Scaling, state: Iterate, model: ModelInput):
    """The current iterate as the model's input; counts the frames still iterating."""
    f = wp.tid()
    write_model_input(state.u, scaling.scale, f, layout, model.controls)
    model.rotation[f] = state.rotation[f]
    model.translation[f] = state.translation[f]
    model.frame_on[f] = state.active[f]
    if state.active[f] != 0:
        wp.atomic_add(state.counter, 0, 1)


@wp.kernel
def begin_iteration(data: DataTerm, layout: Layout, scaling: Scaling, terms: Terms, state: Iterate, model: ModelInput):
    """From the data term's ``JᵀWJ``, ``JᵀWe`` [mesh-unit columns] at the current iterate: the frame's
    Gauss–Newton system of ½E in ``u``, its convergence tests, and the first damped trial."""
    f = wp.tid()
    state.pending[f] = 0
    model.frame_on[f] = 0
    if state.active[f] == 0:
        return
    state.iterations[f] = state.iterations[f] + 1
    size = layout.size
    control_count = layout.control_count
    hessian = data.hessian
    gradient = data.gradient
    column = scaling.column
    u = state.u
    hb = f * size * size
    vb = f * size
    ub = f * control_count
    for a in range(1, size):  # the data term sums the upper triangle only
        for b in range(a):
            hessian[hb + a * size + b] = hessian[hb + b * size + a]
    for a in range(size):
        gradient[vb + a] = gradient[vb + a] * column[a]
        for b in range(size):
            hessian[hb + a * size + b] = hessian[hb + a * size + b] * column[a] * column[b]
    half = wp.float64(0.5)
    for m in range(control_count):
        x = u[ub + m]
        hessian[hb + m * size + m] += terms.l2 + terms.smooth
        gradient[vb + m] += terms.l2 * x + terms.smooth * (x - state.previous[ub + m])
    symmetry = terms.symmetry
    for p in range(terms.pair_count):
        left = terms.pairs[2 * p]
        right = terms.pairs[2 * p + 1]
        d = u[ub + left] - u[ub + right]
        gradient[vb + left] += symmetry * d
        gradient[vb + right] -= symmetry * d
        hessian[hb + left * size + left] += symmetry
        hessian[hb + right * size + right] += symmetry
        hessian[hb + left * size + right] -= symmetry
        hessian[hb + right * size + left] -= symmetry
    value = data.misfit[f] + _regularisation(u, state, terms, ub, control_count)
    state.misfit[f] = data.misfit[f]
    state.current[f] = value
    zero = wp.float64(0.0)
    l1 = terms.l1
    largest = zero
    for a in range(size):
        h = int(0)
        g = gradient[vb + a]
        if a < control_count:
            x = u[ub + a]
            slope = _orthant_slope(x, g, l1)
            g = g + half * l1 * slope
            gradient[vb + a] = g
            lo = scaling.low[a]
            hi = scaling.high[a]
            if l1 > zero:
                if slope > zero:
                    lo = wp.max(lo, zero)
                else:
                    hi = wp.min(hi, zero)
            state.lower[ub + a] = lo
            state.upper[ub + a] = hi
            if (x <= lo + wp.float64(BOUND_SLACK) and g > zero) or (x >= hi - wp.float64(BOUND_SLACK) and g < zero):
                h = 1
                gradient[vb + a] = zero
        state.held[vb + a] = h
        if h == 0:
            largest = wp.max(largest, wp.abs(g))
    if largest < wp.float64(1e-14):
        state.converged[f] = 1
        state.active[f] = 0
        return
    _damped_step(data, state, f, size)
    # The quadratic model's predicted decrease; negligible → converged without a trial.
    step = state.step
    linear = zero
    curvature = zero
    for a in range(size):
        s = step[vb + a]
        linear += gradient[vb + a] * s
        row = zero
        for b in range(size):
            row += hessian[hb + a * size + b] * step[vb + b]
        curvature += s * row
    predicted = -(linear + half * curvature)
    if predicted <= terms.tolerance * value + terms.energy_tolerance:
        state.converged[f] = 1
        state.active[f] = 0
        return
    state.tries[f] = 0
    _propose(f, layout, scaling, state, model)


@wp.kernel
def judge_trial(data: DataTerm, layout: Layout, scaling: Scaling, terms: Terms, state: Iterate, model: ModelInput):
    """Accept a trial that does not raise E (less damping; convergence tests), else retry with 4× damping."""
    f = wp.tid()
    if state.pending[f] == 0:
        model.frame_on[f] = 0
        return
    control_count = layout.control_count
    ub = f * control_count
    trial_misfit = data.misfit[f]
    value = trial_misfit + _regularisation(state.trial_u, state, terms, ub, control_count)
    state.pending[f] = 0
    model.frame_on[f] = 0
    current = state.current[f]
    if wp.isfinite(value) and value <= current:
        decrease = current - value
        moved = wp.float64(0.0)
        for m in range(control_count):
            moved = wp.max(moved, wp.abs(state.trial_u[ub + m] - state.u[ub + m]))
            state.u[ub + m] = state.trial_u[ub + m]
        state.rotation[f] = state.trial_rotation[f]
        state.translation[f] = state.trial_translation[f]
        if decrease <= terms.tolerance * current + terms.energy_tolerance or moved < terms.step_tolerance:
            state.converged[f] = 1
            state.active[f] = 0
        state.current[f] = value
        state.misfit[f] = trial_misfit
        state.damping[f] = wp.max(state.damping[f] / wp.float64(10.0), wp.float64(1e-9))
        return
    state.damping[f] = state.damping[f] * wp.float64(4.0)
    state.tries[f] = state.tries[f] + 1
    if state.tries[f] >= MAX_TRIES:  # no decrease even with heavy damping: a (numerically) stationary point
        state.converged[f] = 1
        state.active[f] = 0
        return
    _damped_step(data, state, f, layout.size)
    _propose(f, layout, scaling, state, model)
