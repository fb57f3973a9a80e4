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

from .local_kernels import write_model_input

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = ["load_current", "begin_iteration", "judge_trial"]

BOUND_SLACK = wp.constant(1e-12)
"""A scaled control this close to a bound counts as at it (the host loop's margin)."""
MAX_TRIES = wp.constant(8)
"""Rejected trials per iteration before a frame counts as stationary."""


@wp.func
def _regularisation(
    u: wp.array(dtype=wp.float64),
    base: int,
    previous: wp.array(dtype=wp.float64),
    control_count: int,
    l2: wp.float64,
    l1: wp.float64,
    smooth: wp.float64,
    symmetry: wp.float64,
    pairs: wp.array(dtype=wp.int32),
    pair_count: int,
):
    """``l2·|u|² + l1·Σ|u| + smooth·|u − u_prev|² + symmetry·Σ (u_l − u_r)²`` of one frame."""
    value = wp.float64(0.0)
    for m in range(control_count):
        x = u[base + m]
        d = x - previous[base + m]
        value += l2 * x * x + l1 * wp.abs(x) + smooth * d * d
    for p in range(pair_count):
        d = u[base + pairs[2 * p]] - u[base + pairs[2 * p + 1]]
        value += symmetry * d * d
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
def _damped_step(
    hessian: wp.array(dtype=wp.float64),
    gradient: wp.array(dtype=wp.float64),
    held: wp.array(dtype=wp.int32),
    damping: wp.float64,
    f: int,
    size: int,
    system: wp.array(dtype=wp.float64),
    step: wp.array(dtype=wp.float64),
):
    """Solve ``(H + λ·diag(H)) s = −g`` on the free variables (held ones: ``s = 0``) into ``step``.

    The damped system is positive definite; a failed Cholesky pivot falls back to the diagonal step.
    """
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
def _propose(
    f: int,
    control_count: int,
    muscle_count: int,
    basis_count: int,
    size: int,
    step: wp.array(dtype=wp.float64),
    u: wp.array(dtype=wp.float64),
    rotation: wp.array(dtype=wp.mat33d),
    translation: wp.array(dtype=wp.vec3d),
    lower: wp.array(dtype=wp.float64),
    upper: wp.array(dtype=wp.float64),
    scale: wp.array(dtype=wp.float64),
    trial_u: wp.array(dtype=wp.float64),
    trial_rotation: wp.array(dtype=wp.mat33d),
    trial_translation: wp.array(dtype=wp.vec3d),
    controls_out: wp.array(dtype=wp.float64),
    rotation_out: wp.array(dtype=wp.mat33d),
    translation_out: wp.array(dtype=wp.vec3d),
    frame_on: wp.array(dtype=wp.int32),
    pending: wp.array(dtype=wp.int32),
    counter: wp.array(dtype=wp.int32),
):
    """The trial ``clip(u + s)`` to the iteration's bounds (and the composed pose), as the model's next input."""
    ub = f * control_count
    vb = f * size
    for m in range(control_count):
        trial_u[ub + m] = wp.min(wp.max(u[ub + m] + step[vb + m], lower[ub + m]), upper[ub + m])
    write_model_input(trial_u, scale, f, control_count, muscle_count, basis_count, controls_out)
    r = rotation[f]
    t = translation[f]
    if size > control_count:
        c = control_count
        r = _rotation_from_vector(wp.vec3d(step[vb + c], step[vb + c + 1], step[vb + c + 2])) * r
        t = t + wp.vec3d(step[vb + c + 3], step[vb + c + 4], step[vb + c + 5])
    trial_rotation[f] = r
    trial_translation[f] = t
    rotation_out[f] = r
    translation_out[f] = t
    frame_on[f] = 1
    pending[f] = 1
    wp.atomic_add(counter, 0, 1)


@wp.kernel
def load_current(
    u: wp.array(dtype=wp.float64),
    rotation: wp.array(dtype=wp.mat33d),
    translation: wp.array(dtype=wp.vec3d),
    active: wp.array(dtype=wp.int32),
    scale: wp.array(dtype=wp.float64),
    control_count: int,
    muscle_count: int,
    basis_count: int,
    controls_out: wp.array(dtype=wp.float64),
    rotation_out: wp.array(dtype=wp.mat33d),
    translation_out: wp.array(dtype=wp.vec3d),
    frame_on: wp.array(dtype=wp.int32),
    counter: wp.array(dtype=wp.int32),
):
    """The current iterate as the model's input; counts the frames still iterating."""
    f = wp.tid()
    write_model_input(u, scale, f, control_count, muscle_count, basis_count, controls_out)
    rotation_out[f] = rotation[f]
    translation_out[f] = translation[f]
    frame_on[f] = active[f]
    if active[f] != 0:
        wp.atomic_add(counter, 0, 1)


@wp.kernel
def begin_iteration(
    hessian: wp.array(dtype=wp.float64),
    gradient: wp.array(dtype=wp.float64),
    data_misfit: wp.array(dtype=wp.float64),
    column: wp.array(dtype=wp.float64),
    low: wp.array(dtype=wp.float64),
    high: wp.array(dtype=wp.float64),
    scale: wp.array(dtype=wp.float64),
    previous: wp.array(dtype=wp.float64),
    pairs: wp.array(dtype=wp.int32),
    pair_count: int,
    l2: wp.float64,
    l1: wp.float64,
    smooth: wp.float64,
    symmetry: wp.float64,
    tolerance: wp.float64,
    energy_tolerance: wp.float64,
    control_count: int,
    muscle_count: int,
    basis_count: int,
    size: int,
    u: wp.array(dtype=wp.float64),
    rotation: wp.array(dtype=wp.mat33d),
    translation: wp.array(dtype=wp.vec3d),
    damping: wp.array(dtype=wp.float64),
    current: wp.array(dtype=wp.float64),
    misfit: wp.array(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    converged: wp.array(dtype=wp.int32),
    iterations: wp.array(dtype=wp.int32),
    held: wp.array(dtype=wp.int32),
    lower: wp.array(dtype=wp.float64),
    upper: wp.array(dtype=wp.float64),
    tries: wp.array(dtype=wp.int32),
    system: wp.array(dtype=wp.float64),
    step: wp.array(dtype=wp.float64),
    trial_u: wp.array(dtype=wp.float64),
    trial_rotation: wp.array(dtype=wp.mat33d),
    trial_translation: wp.array(dtype=wp.vec3d),
    controls_out: wp.array(dtype=wp.float64),
    rotation_out: wp.array(dtype=wp.mat33d),
    translation_out: wp.array(dtype=wp.vec3d),
    frame_on: wp.array(dtype=wp.int32),
    pending: wp.array(dtype=wp.int32),
    counter: wp.array(dtype=wp.int32),
):
    """From the data term's ``JᵀWJ``, ``JᵀWe`` [mesh-unit columns] at the current iterate: the frame's
    Gauss–Newton system of ½E in ``u``, its convergence tests, and the first damped trial."""
    f = wp.tid()
    pending[f] = 0
    frame_on[f] = 0
    if active[f] == 0:
        return
    iterations[f] = iterations[f] + 1
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
        hessian[hb + m * size + m] += l2 + smooth
        gradient[vb + m] += l2 * x + smooth * (x - previous[ub + m])
    for p in range(pair_count):
        left = pairs[2 * p]
        right = pairs[2 * p + 1]
        d = u[ub + left] - u[ub + right]
        gradient[vb + left] += symmetry * d
        gradient[vb + right] -= symmetry * d
        hessian[hb + left * size + left] += symmetry
        hessian[hb + right * size + right] += symmetry
        hessian[hb + left * size + right] -= symmetry
        hessian[hb + right * size + left] -= symmetry
    value = data_misfit[f] + _regularisation(
        u, ub, previous, control_count, l2, l1, smooth, symmetry, pairs, pair_count
    )
    misfit[f] = data_misfit[f]
    current[f] = value
    zero = wp.float64(0.0)
    largest = zero
    for a in range(size):
        h = int(0)
        g = gradient[vb + a]
        if a < control_count:
            x = u[ub + a]
            slope = _orthant_slope(x, g, l1)
            g = g + half * l1 * slope
            gradient[vb + a] = g
            lo = low[a]
            hi = high[a]
            if l1 > zero:
                if slope > zero:
                    lo = wp.max(lo, zero)
                else:
                    hi = wp.min(hi, zero)
            lower[ub + a] = lo
            upper[ub + a] = hi
            if (x <= lo + wp.float64(BOUND_SLACK) and g > zero) or (x >= hi - wp.float64(BOUND_SLACK) and g < zero):
                h = 1
                gradient[vb + a] = zero
        held[vb + a] = h
        if h == 0:
            largest = wp.max(largest, wp.abs(g))
    if largest < wp.float64(1e-14):
        converged[f] = 1
        active[f] = 0
        return
    _damped_step(hessian, gradient, held, damping[f], f, size, system, step)
    # The quadratic model's predicted decrease; negligible → converged without a trial.
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
    if predicted <= tolerance * value + energy_tolerance:
        converged[f] = 1
        active[f] = 0
        return
    tries[f] = 0
    _propose(
        f,
        control_count,
        muscle_count,
        basis_count,
        size,
        step,
        u,
        rotation,
        translation,
        lower,
        upper,
        scale,
        trial_u,
        trial_rotation,
        trial_translation,
        controls_out,
        rotation_out,
        translation_out,
        frame_on,
        pending,
        counter,
    )


@wp.kernel
def judge_trial(
    hessian: wp.array(dtype=wp.float64),
    gradient: wp.array(dtype=wp.float64),
    data_misfit: wp.array(dtype=wp.float64),
    lower: wp.array(dtype=wp.float64),
    upper: wp.array(dtype=wp.float64),
    scale: wp.array(dtype=wp.float64),
    previous: wp.array(dtype=wp.float64),
    pairs: wp.array(dtype=wp.int32),
    pair_count: int,
    l2: wp.float64,
    l1: wp.float64,
    smooth: wp.float64,
    symmetry: wp.float64,
    tolerance: wp.float64,
    step_tolerance: wp.float64,
    energy_tolerance: wp.float64,
    control_count: int,
    muscle_count: int,
    basis_count: int,
    size: int,
    u: wp.array(dtype=wp.float64),
    rotation: wp.array(dtype=wp.mat33d),
    translation: wp.array(dtype=wp.vec3d),
    damping: wp.array(dtype=wp.float64),
    current: wp.array(dtype=wp.float64),
    misfit: wp.array(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    converged: wp.array(dtype=wp.int32),
    held: wp.array(dtype=wp.int32),
    tries: wp.array(dtype=wp.int32),
    system: wp.array(dtype=wp.float64),
    step: wp.array(dtype=wp.float64),
    trial_u: wp.array(dtype=wp.float64),
    trial_rotation: wp.array(dtype=wp.mat33d),
    trial_translation: wp.array(dtype=wp.vec3d),
    controls_out: wp.array(dtype=wp.float64),
    rotation_out: wp.array(dtype=wp.mat33d),
    translation_out: wp.array(dtype=wp.vec3d),
    frame_on: wp.array(dtype=wp.int32),
    pending: wp.array(dtype=wp.int32),
    counter: wp.array(dtype=wp.int32),
):
    """Accept a trial that does not raise E (less damping; convergence tests), else retry with 4× damping."""
    f = wp.tid()
    if pending[f] == 0:
        frame_on[f] = 0
        return
    ub = f * control_count
    trial_misfit = data_misfit[f]
    value = trial_misfit + _regularisation(
        trial_u, ub, previous, control_count, l2, l1, smooth, symmetry, pairs, pair_count
    )
    pending[f] = 0
    frame_on[f] = 0
    if wp.isfinite(value) and value <= current[f]:
        decrease = current[f] - value
        moved = wp.float64(0.0)
        for m in range(control_count):
            moved = wp.max(moved, wp.abs(trial_u[ub + m] - u[ub + m]))
            u[ub + m] = trial_u[ub + m]
        rotation[f] = trial_rotation[f]
        translation[f] = trial_translation[f]
        if decrease <= tolerance * current[f] + energy_tolerance or moved < step_tolerance:
            converged[f] = 1
            active[f] = 0
        current[f] = value
        misfit[f] = trial_misfit
        damping[f] = wp.max(damping[f] / wp.float64(10.0), wp.float64(1e-9))
        return
    damping[f] = damping[f] * wp.float64(4.0)
    tries[f] = tries[f] + 1
    if tries[f] >= MAX_TRIES:  # no decrease even with heavy damping: a (numerically) stationary point
        converged[f] = 1
        active[f] = 0
        return
    _damped_step(hessian, gradient, held, damping[f], f, size, system, step)
    _propose(
        f,
        control_count,
        muscle_count,
        basis_count,
        size,
        step,
        u,
        rotation,
        translation,
        lower,
        upper,
        scale,
        trial_u,
        trial_rotation,
        trial_translation,
        controls_out,
        rotation_out,
        translation_out,
        frame_on,
        pending,
        counter,
    )
