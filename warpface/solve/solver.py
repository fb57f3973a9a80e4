"""Solve a rig's controls from captured points or shapes (SPEC §6.1): ``fit`` and ``Solver``.

Objective per frame, in scaled controls ``u_m = c_m·ρ_m/ℓ`` (``ρ_m`` the muscle's largest displacement
per unit contraction, ``ℓ`` the face's size unit, so every ``u`` is "displacement in face units")::

    E(u) = Σ_i ŵ_i |e_i|² + l2·|u|² + l1·Σ|u| + symmetry·Σ_(l,r) (u_l − u_r)² + smoothness·|u − u_prev|²

with ``e_i = (R(x_i(c) − o) + o + t − y_i)/ℓ`` (pose optional, else R = I, t = 0) and ``ŵ`` the point
weights normalised to sum to 1 over the frame's valid points. Every control has box bounds (a linear
muscle only pulls, ``c ≥ 0``; a sphincter ``0 ≤ K ≤ 1``: at K = 1 the innermost skin reaches the
centre), so the L1 term is the linear ``Σ u`` on the feasible set and E is smooth.

Method — projected Levenberg–Marquardt with the exact Jacobian (:mod:`.local_kernels`): per iteration the
Gauss–Newton normal equations (M×M, plus 6 with pose) are solved on the free controls (those not held at
a bound by their gradient), the step is projected onto the box, and accepted if E decreases, otherwise
the damping grows. Frames are independent and advance together (arrays over frames), so a batch is one
pass per iteration; the iteration itself runs on the device, one thread per frame (:mod:`.device_steps`),
so only a counter comes back per launch round (``device_steps=False``: the NumPy reference loop of
:mod:`.host_steps`). The jaw's controls are signed (its L1 term is ``Σ|u|``, smooth away from 0).
Chosen over SciPy's ``least_squares`` (trust-region reflective on the same objective, measured in
``benchmarks/solve.py``): the exact Jacobian restricted to the rows the targets touch, and the tiny
bounded system, make each iteration cheaper than one finite-difference Jacobian.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..assets.rig import BODY_CONTROL_NAMES
from ..errors import RigError
from ..expression.jaw import JAW_CONTROL_NAMES, JAW_RANGE
from ..expression.lids import LidMuscle
from ..expression.muscles import SphincterMuscle
from ..expression.seal import LipSeal
from ..rig import FaceRig
from .device_steps import DeviceSteps
from .host_steps import HostSteps
from .local_kernels import LocalExpression
from .local_model import RigOperators
from .objective import DeviceObjective
from .pose import rigid_alignment
from .targets import frame_targets, observation, point_weights

__all__ = ["SolveOptions", "Fit", "BatchFit", "Solver", "fit", "SPHINCTER_MAX", "FIT_RIDGE_POINTS"]

FIT_RIDGE_POINTS = 100000
"""``ridge_points`` of :func:`fit`: a Gaussian prior on the controls whose weight against the points' summed error is
that of ``l2`` against the mean over 10⁵ points, so a dense face (ICT's face region 9,409 vertices, the built-in face
11,492) gets ``l2·10.6`` (``l2·8.7``) and a 68-landmark fit ``l2·1471`` (docs/RIG.md §13: landmark reach on the
trained ICT shapes 43.5 → 44.4 % with 66 controls, 46.0 → 46.4 % with the lip slides; the dense reach unchanged)."""

SPHINCTER_MAX = 1.0
"""Upper bound of a sphincter's contraction: at K = 1 the skin at the centre reaches it (f·K ≤ 1)."""

_OPERATORS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_SOLVERS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_SOLVERS_PER_RIG = 4
_CUDA_PASS_BYTES, _CUDA_PASS_FRAMES = 16 << 30, 16384
"""Working memory and frame count of one batched pass on CUDA (see ``frames_per_pass``)."""
_COLD_DAMPING, _WARM_DAMPING = 1.0, 1e-2
"""Initial Levenberg–Marquardt damping (× the Hessian's diagonal) without and with a warm start. From
neutral a cautious start keeps a large expression's first step out of another basin; near the solution
a Gauss–Newton step is often cut back by the bounds, so a little damping wastes fewer trials (the
measurements behind both values: benchmarks/README.md, "Solving controls")."""


@dataclass(frozen=True)
class SolveOptions:
    """Weights and limits of the solve (all weights ≥ 0, dimensionless: see the module docstring).

    Attributes:
        l2: ridge weight on the scaled controls.
        l1: sparsity weight (on the feasible set the controls are ≥ 0, so it is linear).
        symmetry: pulls mirrored pairs ``name_L``/``name_R`` together.
        smoothness: pulls a frame toward the previous frame's controls (sequential :meth:`Solver.solve`).
        pose: also solve a rigid head pose (rotation about the observed points' centroid + translation).
        bounds: per-control ``{name: (low, high)}`` overriding the defaults (c ≥ 0, sphincters ≤ 1, jaw: JAW_RANGE).
        jaw: solve the jaw's controls too when the rig has a jaw (False: muscles only, the jaw at rest).
        lip_rolls: solve the lip hinges and slides and the mouth corners (``BODY_CONTROL_NAMES``, docs/RIG.md §15–17)
            too. Default False for a :class:`Solver`: the trackers see at most 68 points, from which a lip's roll in
            and out together (and its protrusion) trade against the jaw (a monocular solve's reprojection rose
            0.14 → 0.30 px with the hinges free); :func:`fit` frees them. ``bounds`` can free them either way.
        max_iterations: Levenberg–Marquardt iterations per frame.
        tolerance: stop when a step lowers E (or is predicted to) by less than this fraction …
        step_tolerance: … or moves no scaled control by more than this (face units) …
        energy_tolerance: … or lowers E by less than this: E is a mean squared distance in face units², so
            1e-10 is an RMS change of 1e-5 face units (0.6 µm on a face with a 62 mm inter-ocular distance).
        min_points: fewer valid (non-NaN, weighted) points keeps the previous controls and flags the frame.
        frames_per_pass: frames evaluated together (bounds the working memory of a batch); default 64 on
            the CPU; on CUDA as many as fit in 16 GiB, at most 16384 (converged frames cost little, so a
            larger pass keeps more of the GPU busy per launch).
        ridge_points: the count of target points at which ``l2`` holds; a fit to ``N`` fewer points uses
            ``l2·ridge_points/N``. The data term is a mean over the points (``ŵ`` sums to 1), so a fixed ridge would
            weigh 68 landmarks' evidence as much as a dense face's; a Gaussian prior on the controls against
            independent point errors keeps its weight against their *sum*, i.e. grows as 1/N against the mean.
            Dense faces (≥ ``ridge_points`` vertices) keep ``l2``. Default 1 (off) for a :class:`Solver`, whose
            trackers hold the controls with the previous frame and recover exact controls from exact landmarks;
            :func:`fit` uses :data:`FIT_RIDGE_POINTS` (docs/RIG.md §13).
        device_steps: run the iteration itself (damped bounded step, accept/reject, convergence) on the
            device, one thread per frame, reading back only a counter per launch round (default: fewer
            Python operations per iteration, on the CPU too); False: the NumPy loop. Results agree to
            rounding either way.
    """

    l2: float = 1e-6
    l1: float = 1e-6
    symmetry: float = 0.0
    smoothness: float = 0.0
    pose: bool = False
    bounds: dict | None = None
    jaw: bool = True
    lip_rolls: bool = False
    max_iterations: int = 50
    tolerance: float = 1e-5
    step_tolerance: float = 1e-7
    energy_tolerance: float = 1e-10
    min_points: int = 3
    ridge_points: int = 1
    frames_per_pass: int | None = None
    device_steps: bool | None = None

    @classmethod
    def from_keywords(cls, **options) -> "SolveOptions":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"unknown solve option {unknown[0]!r} (known: {', '.join(sorted(known))})")
        made = cls(**options)
        for name in ("l2", "l1", "symmetry", "smoothness", "tolerance", "step_tolerance", "energy_tolerance"):
            value = getattr(made, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise TypeError(f"{name}: expected a number, got {type(value).__name__}")
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name}: expected a finite number ≥ 0, got {value!r}")
        for name in ("max_iterations", "min_points", "ridge_points", "frames_per_pass"):
            value = getattr(made, name)
            if name == "frames_per_pass" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
            if value < 1:
                raise ValueError(f"{name}: expected a positive integer, got {value!r}")
        if made.device_steps is not None and not isinstance(made.device_steps, (bool, np.bool_)):
            raise TypeError(f"device_steps: expected True, False or None, got {made.device_steps!r}")
        if made.bounds is not None and not isinstance(made.bounds, dict):
            raise TypeError(f"bounds: expected a dict {{control name: (low, high)}}, got {type(made.bounds).__name__}")
        return replace(made, pose=bool(made.pose), jaw=bool(made.jaw), lip_rolls=bool(made.lip_rolls))


@dataclass
class Fit:
    """One solved frame.

    Attributes:
        controls: ``{control name: value}`` (muscle contractions; linear in mesh units, sphincters dimensionless).
        residual: weighted RMS distance between the (posed) model and the valid targets [mesh units]
            (the solver's float64 evaluation of the full pipeline at the targets).
        converged: the iteration met its tolerance (False: best iterate returned, or frame skipped).
        skipped: too few valid points; the previous controls were kept.
        valid_points: targets used (not NaN, weight > 0).
        iterations: Levenberg–Marquardt iterations taken.
        rotation, translation: solved head pose (identity/zero without ``pose``); posed = R(x − origin) + origin + t.
        origin: the pose's rotation centre [mesh units], (3,).
        vector: the controls in rig order, (M,) float64.
        points: the rig evaluated at the solution with the full model, (V, 3) float32 NumPy, rig space
            (evaluated on first access).
    """

    controls: dict
    residual: float
    converged: bool
    skipped: bool
    valid_points: int
    iterations: int
    rotation: np.ndarray
    translation: np.ndarray
    origin: np.ndarray
    vector: np.ndarray = field(repr=False)
    model: object = field(default=None, repr=False)
    _points: np.ndarray | None = field(default=None, repr=False)

    @property
    def points(self) -> np.ndarray:
        if self._points is None:
            self._points = self.model.evaluate(self.vector)
        return self._points

    @property
    def posed_points(self) -> np.ndarray:
        """:attr:`points` under the solved head pose, (V, 3) float64."""
        return (self.points - self.origin) @ self.rotation.T + self.origin + self.translation


@dataclass
class BatchFit:
    """Many frames solved together (arrays over frames, F first). ``controls[f]`` is in rig order."""

    names: list
    controls: np.ndarray
    residual: np.ndarray
    converged: np.ndarray
    skipped: np.ndarray
    iterations: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray

    def __len__(self) -> int:
        return len(self.controls)

    def mapping(self, frame: int) -> dict:
        """Controls of one frame as ``{name: value}``."""
        return dict(zip(self.names, map(float, self.controls[frame])))


def rig_operators(rig, device=None) -> RigOperators:
    """The rig's precomputed solver operators (cached per rig object)."""
    cached = _OPERATORS.get(rig)
    if cached is None:
        cached = _OPERATORS[rig] = RigOperators.from_rig(rig, device=device)
    return cached


def _face_unit(rig) -> float:
    """Inter-ocular (eye-centre) distance from the 68 iBUG landmarks, else a quarter of the mesh diagonal."""
    landmarks = rig.landmarks
    if landmarks is not None and len(landmarks) == 68:
        points = rig.mesh.points[landmarks]
        unit = float(np.linalg.norm(points[36:42].mean(axis=0) - points[42:48].mean(axis=0)))
        if unit > 0.0:
            return unit
    return 0.25 * rig.mesh.size


class Solver:
    """Solves controls frame after frame (warm-started) or many frames at once, for fixed target locations.

    Args:
        rig: a :class:`warpface.FaceRig` with at least one muscle.
        vertices: (N,) vertex indices of the targets; or ``triangles`` (N,) + ``barycentrics`` (N, 3)
            for surface points; neither: dense targets (V, 3) with the rig's topology.
        weights: per-point confidence (N,), ≥ 0 and finite (default 1).
        device: Warp device of the solve's kernels and of the full model behind :attr:`Fit.points`
            (default: Warp's preferred device).
        **options: :class:`SolveOptions` fields.

    Raises:
        RigError: the rig has no muscles. ValueError/TypeError: bad arguments, naming them.
    """

    def __init__(self, rig, vertices=None, *, triangles=None, barycentrics=None, weights=None, device=None, **options):
        if not isinstance(rig, FaceRig):
            raise TypeError(f"rig: expected a warpface.FaceRig, got {type(rig).__name__}")
        if not rig.muscles:
            raise RigError(f"rig {rig.name!r}: has no muscles, nothing to solve for")
        self.rig = rig
        self.options = SolveOptions.from_keywords(**options)
        self.muscle_count = len(rig.muscles)
        self.has_jaw = rig.jaw is not None and self.options.jaw
        self.names = rig.control_names if self.has_jaw else rig.muscle_names
        self.observation = observation(rig.mesh, vertices, triangles, barycentrics)
        self.weights = point_weights(weights, self.observation.count)
        self.ridge = self.options.l2 * max(1.0, self.options.ridge_points / self.observation.count)
        """The ridge weight of these targets (``l2`` scaled by ``ridge_points``/N)."""
        self._step_options = replace(self.options, l2=self.ridge)
        self.device = device
        self._model = None
        operators = rig_operators(rig, device)
        if not self.has_jaw:
            operators = replace(operators, jaw_field=None)
        self.local = LocalExpression(operators, self.observation.vertices, device=device)
        reach = operators.control_reach()
        self.unit = _face_unit(rig)
        self.reach = np.where(reach > 0.0, reach, 1.0)
        self.control_scale = self.reach / self.unit
        self.low, self.high = self._bounds()
        self._pairs = self._mirrored_pairs()
        self.origin = self.observation.apply(operators.rest).mean(axis=0)
        self.objective = DeviceObjective(
            self.local, self.observation, pose=self.options.pose, origin=self.origin, unit=self.unit
        )
        iteration = HostSteps if self.options.device_steps is False else DeviceSteps
        self.steps = iteration(
            self.objective,
            scale=self.control_scale,
            low=self.low * self.control_scale,
            high=self.high * self.control_scale,
            pairs=self._pairs,
            unit=self.unit,
        )
        """The Levenberg–Marquardt loop: :class:`~.device_steps.DeviceSteps` (default) or the NumPy
        :class:`~.host_steps.HostSteps`."""
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the warm start: the next frame starts from neutral (and re-aligns the pose)."""
        self.controls = np.zeros(len(self.names))
        self._earlier: np.ndarray | None = None
        """The controls of the frame before the last (for the constant-velocity first guess)."""
        self.rotation = np.eye(3)
        self.translation = np.zeros(3)
        self._pose_known = False
        self._solved_once = False
        """A frame has been solved since the last reset: later frames are warm starts."""

    def _bounds(self):
        low = np.zeros(len(self.names))
        high = np.array([_upper_bound(m) for m in self.rig.muscles] + [0.0] * (len(self.names) - self.muscle_count))
        for index, name in enumerate(JAW_CONTROL_NAMES if self.has_jaw else (), start=self.muscle_count):
            lo, hi = JAW_RANGE[name]
            unit = 1.0 if name == "jaw_open" else self.unit  # the slides' range is in face units
            low[index], high[index] = lo * unit, hi * unit
        if not self.options.lip_rolls:
            high[[i for i, name in enumerate(self.names) if name in BODY_CONTROL_NAMES]] = 0.0
        for name, pair in (self.options.bounds or {}).items():
            if name not in self.names:
                raise ValueError(f"bounds: unknown control {name!r}")
            try:
                lo, hi = (float(v) for v in pair)
            except TypeError:
                raise TypeError(f"bounds[{name!r}]: expected a pair of numbers (low, high)") from None
            except ValueError:
                raise ValueError(f"bounds[{name!r}]: expected a pair of numbers (low, high)") from None
            if np.isnan(lo) or np.isnan(hi) or lo > hi or lo == np.inf or hi == -np.inf:
                raise ValueError(f"bounds[{name!r}]: expected low ≤ high, got ({lo}, {hi})")
            if lo < 0.0 and name not in JAW_CONTROL_NAMES:  # muscles only pull; the L1 term is Σ c on this set
                raise ValueError(f"bounds[{name!r}]: a muscle's lower bound must be ≥ 0, got {lo}")
            index = self.names.index(name)
            low[index], high[index] = lo, hi
        return low, high

    def _mirrored_pairs(self) -> np.ndarray:
        index = {name: i for i, name in enumerate(self.names)}
        pairs = [
            (i, index[name[:-2] + "_R"])
            for i, name in enumerate(self.names)
            if name.endswith("_L") and name[:-2] + "_R" in index
        ]
        return np.array(pairs, dtype=np.int64).reshape(-1, 2)

    @property
    def model(self):
        if self._model is None:
            self._model = self.rig.model(device=self.device)
        return self._model

    # ------------------------------------------------------------------ public solves
    def solve(self, target, weights=None) -> Fit:
        """Solve one frame, warm-started from (and smoothed toward) the previous frame's solution.

        Args:
            target: (N, 3) points (NaN rows are missing), or (V, 3) for a dense solver.
            weights: optional per-point weights for this frame (N,), else the solver's.
        """
        targets = frame_targets(target, self.observation, batched=False)
        weight = self.weights if weights is None else point_weights(weights, self.observation.count)
        # First guess: the last two frames' motion continued (smooth motion starts one step closer);
        # the temporal term still pulls toward the last frame itself.
        guess = None if self._earlier is None else 2.0 * self.controls - self._earlier
        result = self._solve_frames(
            targets,
            weight,
            self.controls[None],
            temporal=True,
            cold=not self._solved_once,
            guess=None if guess is None else guess[None],
        )
        controls = result["controls"][0]
        self._earlier = None if result["skipped"][0] else self.controls
        self._solved_once = self._solved_once or not result["skipped"][0]
        self.controls = controls.copy()
        if not result["skipped"][0]:
            self.rotation, self.translation = result["rotation"][0], result["translation"][0]
            self._pose_known = self._pose_known or self.options.pose
        return Fit(
            controls=dict(zip(self.names, map(float, controls))),
            residual=float(result["residual"][0]),
            converged=bool(result["converged"][0]),
            skipped=bool(result["skipped"][0]),
            valid_points=int(result["valid"][0]),
            iterations=int(result["iterations"][0]),
            rotation=self.rotation.copy(),
            translation=self.translation.copy(),
            origin=self.origin.copy(),
            vector=controls,
            model=self.model,
        )

    def solve_sequence(self, targets, weights=None, *, progress: bool = False) -> BatchFit:
        """Solve F frames in order, each warm-started from (and smoothed toward) the one before, as
        :meth:`solve` would frame by frame; the solver's state advances to the last frame.

        ``targets`` is (F, N, 3) with NaN for missing points. For tracking: feed ``controls`` to
        :func:`warpface.usd.write_animation` as contractions, and keep ``residual`` per frame.
        """
        array = frame_targets(targets, self.observation, batched=True)
        frames = range(len(array))
        if progress:
            from tqdm import tqdm

            frames = tqdm(frames, desc="solve frames", unit="frame")
        fits = [self.solve(array[f], weights) for f in frames]
        names = list(self.names)
        if not fits:
            return BatchFit(
                names,
                np.zeros((0, len(names))),
                *(np.zeros(0) for _ in range(4)),
                np.zeros((0, 3, 3)),
                np.zeros((0, 3)),
            )
        return BatchFit(
            names=names,
            controls=np.stack([f.vector for f in fits]),
            residual=np.array([f.residual for f in fits]),
            converged=np.array([f.converged for f in fits]),
            skipped=np.array([f.skipped for f in fits]),
            iterations=np.array([f.iterations for f in fits]),
            rotation=np.stack([f.rotation for f in fits]),
            translation=np.stack([f.translation for f in fits]),
        )

    def solve_batch(self, targets, weights=None, *, progress: bool = False) -> BatchFit:
        """Solve F independent frames together, each started from the solver's current controls.

        The temporal term does not apply (frames are independent); the solver's state is unchanged.
        ``targets`` is (F, N, 3) with NaN for missing points; the residual is the solver's float64
        evaluation of the model (the same pipeline as :class:`~warpface.ExpressionModel`).
        """
        array = frame_targets(targets, self.observation, batched=True)
        weight = self.weights if weights is None else point_weights(weights, self.observation.count)
        frames = len(array)
        out = {
            key: [] for key in ("controls", "residual", "converged", "skipped", "iterations", "rotation", "translation")
        }
        chunk = self.options.frames_per_pass or self._default_pass()
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=frames, desc="solve frames", unit="frame")
        for start in range(0, frames, chunk):
            part = array[start : start + chunk]
            result = self._solve_frames(
                part, weight, np.tile(self.controls, (len(part), 1)), temporal=False, cold=not self._solved_once
            )
            for key in out:
                out[key].append(result[key])
            if bar is not None:
                bar.update(len(part))
        if bar is not None:
            bar.close()
        stacked = {key: (np.concatenate(v) if v else np.zeros((0,))) for key, v in out.items()}
        if frames == 0:
            stacked["controls"] = np.zeros((0, len(self.names)))
        return BatchFit(names=list(self.names), **stacked)

    def _default_pass(self) -> int:
        if not self.local.device.is_cuda:
            return 64
        k = self.objective.variable_count
        per_frame = self.local.bytes_per_frame + 3 * 8 * k * k + 8 * 8 * k + 4 * self.observation.count * 8
        return int(np.clip(_CUDA_PASS_BYTES // per_frame, 1, _CUDA_PASS_FRAMES))

    # ------------------------------------------------------------------ the solve
    def _solve_frames(
        self,
        targets: np.ndarray,
        weight: np.ndarray,
        start: np.ndarray,
        *,
        temporal: bool,
        cold: bool,
        guess: np.ndarray | None = None,
    ) -> dict:
        """Solve (F, N, 3) targets; ``start`` (F, M) is the temporal anchor and kept by skipped frames,
        ``guess`` (default ``start``) the first iterate; ``cold``: no earlier frame to start near."""
        opts = self._step_options
        frames, count = targets.shape[:2]
        valid = np.all(np.isfinite(targets), axis=2) & (weight[None] > 0.0)
        valid_count = valid.sum(axis=1)
        skipped = valid_count < max(opts.min_points, 3 if opts.pose else 1)
        wn = np.where(valid, weight[None], 0.0)
        wn = wn / np.where(skipped, 1.0, wn.sum(axis=1))[:, None]
        y = np.where(valid[..., None], targets, 0.0) / self.unit
        scale = self.control_scale
        low, high = self.low * scale, self.high * scale
        previous = np.clip(start * scale, low, high)
        u = previous.copy() if guess is None else np.clip(guess * scale, low, high)
        smooth = opts.smoothness if temporal else 0.0
        rotation = np.tile(self.rotation, (frames, 1, 1))
        translation = np.tile(self.translation / self.unit, (frames, 1))
        if opts.pose and not self._pose_known:
            x0 = self.observation.apply_frames(self.local.evaluate(u / scale, jacobian=False)[0])
            for f in np.flatnonzero(~skipped):
                r, t = rigid_alignment(x0[f], targets[f], wn[f], self.origin)
                rotation[f], translation[f] = r, t / self.unit

        self.objective.bind(y, wn)
        active = ~skipped
        # Without an earlier frame, start cautious (large damping): the first Gauss–Newton step of a large
        # expression can jump into another basin (a muscle pulled past its attachment); warm starts start near GN.
        damping = np.full(frames, _COLD_DAMPING if cold else _WARM_DAMPING)
        out = self.steps.run(u, rotation, translation, previous, active, damping, options=opts, smooth=smooth)
        u, rotation, translation, misfit = out["u"], out["rotation"], out["translation"], out["misfit"]
        return self._frames_result(
            u,
            rotation,
            translation,
            misfit,
            out["converged"],
            out["active"],
            out["iterations"],
            skipped,
            start,
            valid_count,
        )

    def _frames_result(
        self, u, rotation, translation, misfit, converged, active, iterations, skipped, start, valid_count
    ):
        scale = self.control_scale
        controls = u / scale
        controls[skipped] = start[skipped]
        rotation[skipped] = self.rotation
        translation[skipped] = self.translation / self.unit
        residual = np.sqrt(np.maximum(misfit, 0.0))
        return dict(
            controls=controls,
            residual=np.where(skipped, 0.0, residual * self.unit),
            converged=converged & ~skipped & ~active,
            skipped=skipped,
            iterations=iterations,
            valid=valid_count,
            rotation=rotation,
            translation=translation * self.unit,
        )


def fit(rig, target, *, vertices=None, weights=None, device=None, **options) -> Fit:
    """Solve the controls that make ``rig`` match ``target`` (SPEC §6.1); see :class:`Solver`.

    Args:
        rig: a :class:`warpface.FaceRig` with muscles.
        target: (V, 3) dense shape with the rig's topology, or (N, 3) points at ``vertices`` (NaN = missing).
            Surface points: pass ``triangles=`` (N,) and ``barycentrics=`` (N, 3) instead of ``vertices``.
        vertices: (N,) vertex indices of the target points.
        weights: per-point weights (N,), ≥ 0.
        device: Warp device of the solve's kernels and of :attr:`Fit.points`.
        **options: :class:`SolveOptions` fields (``l2``, ``l1``, ``symmetry``, ``pose``, ``bounds``, …);
            ``ridge_points`` defaults to :data:`FIT_RIDGE_POINTS` here: one shape solved from neutral has nothing
            but the prior to hold the controls its few points leave loose; ``lip_rolls`` to True.

    Returns:
        :class:`Fit`, solved from neutral. The solver built for these target locations is kept with the
        rig (a few per rig), so fitting many shapes at the same locations pays its setup once.
    """
    if not isinstance(rig, FaceRig):
        raise TypeError(f"rig: expected a warpface.FaceRig, got {type(rig).__name__}")
    surface = {key: options.pop(key) for key in ("triangles", "barycentrics") if key in options}
    options.setdefault("ridge_points", FIT_RIDGE_POINTS)
    options.setdefault("lip_rolls", True)
    key = (
        str(device),
        repr(sorted(options.items())),
        *(None if v is None else np.asarray(v).tobytes() for v in (vertices, *surface.values())),
    )
    solvers = _SOLVERS.setdefault(rig, {})
    solver = solvers.pop(key, None)
    if solver is None:
        solver = Solver(rig, vertices, device=device, **surface, **options)
    solvers[key] = solver  # most recently used last
    while len(solvers) > _SOLVERS_PER_RIG:
        solvers.pop(next(iter(solvers)))
    solver.reset()
    return solver.solve(target, weights=weights)


def _upper_bound(muscle) -> float:
    """A muscle's largest contraction in a fit: sphincters to SPHINCTER_MAX, a lid's turn to its ``fit_limit``
    (1, the full closure, unless the hinge allows more: docs/RIG.md §11), the lip seal's parting to 0 (it is the
    lips' constraint, not an expression: fits that used it traded it against jaw_open; ``bounds`` can free it),
    linear muscles unbounded."""
    if isinstance(muscle, LipSeal):
        return 0.0
    if isinstance(muscle, LidMuscle):
        return muscle.fit_limit
    return SPHINCTER_MAX if isinstance(muscle, SphincterMuscle) else np.inf
