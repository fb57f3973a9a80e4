"""``SolverFace``: warpface's tissue FEM as a Newton solver (docs/NEWTON.md).

One :meth:`SolverFace.step` is: the rig's controls (``control.warpface.activation``) -> expression model ->
displacements of the driven nodes -> one Newmark-β step of :class:`~warpface.fem.TissueSimulation` (direct or CG
solver) in the head body's frame, with the inertial body force of the head's motion on its right-hand side
(``TissueSimulation.step(force=...)``) -> the soft contacts, added to the same step by superposition (the step is
linear: ``d = d_step + A_oo⁻¹ f_contact``) -> the nodes written back as Newton particles in the world
(``x = p + R (X + d)``).
"""

from __future__ import annotations

import dataclasses
import warnings

import newton
import numpy as np
import warp as wp

from ..fem import TissueMaterial, TissueSimulation
from ..fem.options import as_cg_options
from ..fem.solver_direct import factorize_spd, node_dofs
from .capturable import CapturablePath
from .contact import ContactReport, gather_contacts, solve_contacts, upright_scale
from .face import NAMESPACE, ROLE_DRIVEN, ROLE_FIXED, ROLE_FREE, NewtonFace, register_face_attributes
from .frame import HeadMotion, body_force, head_motion
from .kernels import Frame, TissueNodes, place_nodes

__all__ = ["SolverFace"]


def _model_gravity(model) -> np.ndarray:
    gravity = np.asarray(model.gravity.numpy(), dtype=np.float64).reshape(-1, 3)
    return gravity[0]


def _namespace(obj):
    return getattr(obj, NAMESPACE, None) if obj is not None else None


class SolverFace(newton.solvers.SolverBase):
    """warpface's face (expression model + viscoelastic tissue FEM) as a Newton solver.

    Step it after the solver that moves the rigid bodies (or after writing a prescribed head motion into
    ``state_out``), with the soft contacts Newton's ``CollisionPipeline`` found on ``state_in``: it overwrites
    the face's particles in ``state_out``. The tissue's displacement, velocity and acceleration live in the solver
    (:attr:`simulation`), like the internal buffers of Newton's own solvers; :meth:`reset` restarts them.

    Args:
        model: The finalized Newton model that :func:`~warpface.newton.add_face` put ``face`` into.
        face: The :class:`~warpface.newton.NewtonFace` that :func:`~warpface.newton.add_face` returned.
        dt: Time step [s]; default: the first :meth:`step`'s (the FEM's factorisation is built for one dt; a
            step with another rebuilds it).
        gravity: Gravity [m/s²] the tissue feels; default the model's. Kato's "hyper-expression": another gravity.
        rest_gravity: Gravity [m/s²] in the head frame that the rest shape already balances; default the model's
            gravity in the head frame at :meth:`reset` (or at the first step).
        inertia: Apply the head's inertial body force (docs/NEWTON.md §2); off: the tissue only rides along.
        formulation, solver, beta, gamma, cg: As :class:`~warpface.fem.TissueSimulation`.
        graph_capturable: Step on the host-free path (docs/NEWTON.md §5): kernel launches and device copies only,
            so ``wp.ScopedCapture`` can capture :meth:`step`; default on CUDA devices. It steps the tissue with the
            CG solver (``solver`` "auto" or "cg"; float64) and takes contacts as penalty forces; its errors are raised
            by :meth:`synchronize`.
        contact_stiffness: The host-free path's contact penalty, in multiples of the node's diagonal stiffness
            ``nᵀ A_oo[i, i] n`` (a closed gap is left at about ``1 / (1 + contact_stiffness)`` of its depth).
        contact_passes: The host-free path's active-set passes of the contact solve per step.
        step_graphs: On the host-free path, replay :meth:`step` from graphs of its own when the caller is not
            capturing (one per combination of states, control and contacts; the first step with them runs eagerly,
            the second is captured; :meth:`reset`, a gravity change and :meth:`notify_model_changed` drop them;
            docs/NEWTON.md §5); default on CUDA devices (Warp's CPU graphs work too).

    Raises:
        TypeError: ``face`` is not a NewtonFace.
        ValueError: ``model`` was not built with ``add_face`` for this face (no ``warpface`` attributes, or
            other particle roles), the face's head body is not in the model, ``graph_capturable`` with the direct
            solver or a float32 CG, or a contact option that is not positive.
    """

    def __init__(
        self,
        model,
        face: NewtonFace,
        *,
        dt: float | None = None,
        gravity=None,
        rest_gravity=None,
        inertia: bool = True,
        formulation: str = "linear",
        solver: str = "auto",
        beta: float = 0.25,
        gamma: float = 0.5,
        cg=None,
        graph_capturable: bool | None = None,
        contact_stiffness: float = 100.0,
        contact_passes: int = 3,
        step_graphs: bool | None = None,
    ):
        super().__init__(model)
        if not isinstance(face, NewtonFace):
            raise TypeError(f"SolverFace: face must be the NewtonFace add_face returned, got {type(face).__name__}")
        _check_model(model, face)
        self.face = face
        """The face."""
        self.material = face.material
        """The tissue's material (the model's ``warpface:*`` per-tet values after :meth:`notify_model_changed`)."""
        self.graph_capturable = _capturable(graph_capturable, solver, cg, model.device)
        """Whether :meth:`step` is the host-free path (docs/NEWTON.md §5): kernel launches only, capturable."""
        if self.graph_capturable:
            solver, cg = "cg", dataclasses.replace(as_cg_options(cg), use_graph=False)
        self._capturable_options = dict(
            contact_stiffness=_positive(contact_stiffness, "contact_stiffness"),
            contact_passes=int(_positive(contact_passes, "contact_passes", whole=True)),
            own_graphs=_flag(step_graphs, "step_graphs", model.device.is_cuda),
        )
        self._capturable: CapturablePath | None = None
        self._options = dict(formulation=formulation, solver=solver, beta=beta, gamma=gamma, cg=cg)
        self._gravity_override = None if gravity is None else _vector(gravity, "gravity")
        self._rest_gravity = None if rest_gravity is None else _vector(rest_gravity, "rest_gravity")
        self.inertia = bool(inertia)
        """Whether the head's inertial body force is applied."""
        self.gravity = _model_gravity(model) if gravity is None else self._gravity_override
        """Gravity the tissue feels [m/s²], shape (3,)."""
        self.expression = face.rig.model(device=model.device)
        """The rig's :class:`~warpface.ExpressionModel`."""
        self.simulation: TissueSimulation | None = None
        """The tissue FEM (built at the first step, or here when ``dt`` is given)."""
        self.contact_report = ContactReport()
        self._clamped_steps = 0
        n = face.tetmesh.node_count
        self._rest = np.ascontiguousarray(face.tetmesh.points, dtype=np.float64)
        self._rest_wp = wp.array(self._rest, dtype=wp.vec3d, device=model.device)
        self._contact_mask = np.zeros(n, dtype=bool)
        self._contact_mask[face.contact_nodes] = True
        self._rest_volumes = face.tetmesh.volumes
        self._last_controls = None
        self._driven = np.zeros((face.driven_nodes.size, 3))
        self._skin_rest = np.asarray(face.rig.mesh.points, dtype=np.float64)
        self._launches: dict = {}
        self._launch_pose: dict = {}
        if dt is not None:
            self._build(dt)

    # ------------------------------------------------------------------ Newton's solver interface
    @classmethod
    def register_custom_attributes(cls, builder) -> None:
        """Declare warpface's ``warpface:*`` custom attributes on ``builder`` (``add_face`` does it too)."""
        register_face_attributes(builder)

    def notify_model_changed(self, flags) -> None:
        """Re-read what the model changed: ``MODEL_PROPERTIES`` -> gravity and the face's per-tet material
        (``warpface:youngs_modulus``, ``poisson_ratio``, ``viscosity``); a changed material rebuilds the FEM. Any
        change drops the step's own graphs (``step_graphs``)."""
        if self._capturable is not None:
            self._capturable.drop_graphs()
        if not int(flags) & int(newton.ModelFlags.MODEL_PROPERTIES):
            return
        if self._gravity_override is None:
            self.gravity = _model_gravity(self.model)
            if self._capturable is not None:
                self._capturable.set_gravity(self.gravity)
        attrs, face = _namespace(self.model), self.face
        tets = slice(face.tet_start, face.tet_start + face.tetmesh.tet_count)
        E, nu, eta = (getattr(attrs, name).numpy()[tets] for name in ("youngs_modulus", "poisson_ratio", "viscosity"))
        old = self.material.per_tet(face.tetmesh.tet_count)
        if not np.allclose([E, nu, eta], [old["E"], old["nu"], old["eta"]], rtol=1e-6):
            self.material = TissueMaterial(E, nu, eta, old["rho"], damping=self.material.damping)
            dt = None if self.simulation is None else self.simulation.dt
            self.simulation = None
            if dt is not None:
                self._build(dt)

    def reset(self, state, world_mask=None, flags=None) -> None:
        """Restart the tissue at rest in the head frame of ``state`` (its head pose), writing the face's
        particles into ``state``; the rest gravity is taken again unless it was given."""
        self._normalize_reset_world_mask(world_mask)
        motion = head_motion(self.model, state, state, self.face.head_body, 1.0)
        if self._rest_gravity is None or getattr(self, "_rest_gravity_auto", False):
            self._rest_gravity = motion.rotation.T @ _model_gravity(self.model)
            self._rest_gravity_auto = True
        if self.simulation is not None:
            self.simulation.reset()
        if self._capturable is not None:
            self._capturable.reset()
            self._capturable.set_rest_gravity(self._rest_gravity)
        self._last_controls = None
        self.contact_report = ContactReport()
        self._write_particles(state, motion)

    @property
    def contact_report(self) -> ContactReport:
        """What the last step did with its contacts (:class:`~warpface.newton.contact.ContactReport`; on the
        host-free path read from the device)."""
        return self._contact_report if self._capturable is None else self._capturable.report()

    @contact_report.setter
    def contact_report(self, report: ContactReport) -> None:
        self._contact_report = report

    @property
    def clamped_steps(self) -> int:
        """Steps whose contact forces were scaled back to keep every tet upright."""
        return self._clamped_steps + (0 if self._capturable is None else self._capturable.clamped_count())

    def synchronize(self) -> None:
        """Wait for the queued steps and raise what they booked on the device (the host-free path raises nothing
        inside :meth:`step`): ValueError for a non-finite control (the steps held the last good ones),
        FloatingPointError for a non-finite correction (skipped), :class:`~warpface.errors.ConvergenceError` for a
        CG solve above its tolerance."""
        if self.simulation is not None:
            self.simulation.synchronize()
        if self._capturable is not None:
            self._capturable.raise_errors()

    def step(self, state_in, state_out, control, contacts, dt: float, *, observables=None) -> None:
        """Advance the face one time step ``dt`` [s] (module docstring).

        Raises:
            ValueError: a non-finite control (naming it), driven displacements beyond the FEM's limit.
            FloatingPointError: a non-finite body force (the head's motion; before the step) or contact correction
                (the state is left as the tissue step made it). The host-free path raises neither here:
                :meth:`synchronize` does.
        """
        sim = self._build(dt)
        if self._capturable is not None:
            self._capturable.advance(state_in, state_out, control, contacts)
            return
        face = self.face
        if self._rest_gravity is None:
            self._rest_gravity = head_motion(self.model, state_in, state_in, face.head_body, 1.0).rotation.T @ (
                _model_gravity(self.model)
            )
            self._rest_gravity_auto = True
        motion = head_motion(self.model, state_in, state_out, face.head_body, dt)
        driven = self._driven_displacements(control)
        sim.step(driven, force=self._body_force(motion) if self.inertia else None)
        correction = None if contacts is None else self._contact_correction(contacts, state_out, motion)
        if correction is not None and np.any(correction):
            if not np.all(np.isfinite(correction)):
                raise FloatingPointError("SolverFace: the contact forces gave non-finite displacements")
            self._apply(correction)
        self._write_particles(state_out, motion)

    # ------------------------------------------------------------------ parts of a step
    def _build(self, dt) -> TissueSimulation:
        sim = self.simulation
        if sim is not None and (dt is None or float(dt) == sim.dt):
            return sim
        face = self.face
        sim = TissueSimulation(
            face.tetmesh,
            self.material,
            dt,
            fixed=face.fixed_nodes,
            driven=face.driven_nodes,
            device=self.model.device,
            **self._options,
        )
        K, M, C = sim.matrices.to_scipy()
        self._mass = M.tocsr()
        state = sim.state.d  # the body force's array, the tissue state's type and device (a kernel input of the step)
        self._force = wp.zeros(face.tetmesh.node_count, dtype=state.dtype, device=state.device)
        self._force_view = self._force.numpy() if state.device.is_cpu else None
        self._force_host_dtype = np.float64 if state.dtype == wp.vec3d else np.float32
        self._free_dofs = node_dofs(sim.free_nodes)
        self._free_index = np.full(face.tetmesh.node_count, -1, dtype=np.int64)
        self._free_index[sim.free_nodes] = np.arange(sim.free_nodes.size)
        if sim.solver_kind == "direct":
            self._solve = sim.solver.solve
        else:  # the CG solver keeps A_oo on the device: contact solves use a host factor, made when first needed
            c = sim.coefficients
            dofs = self._free_dofs
            factor = []

            def solve(rhs):
                if not factor:
                    A = (K + c.mass_displacement * M + c.damping_displacement * C).tocsr()[dofs][:, dofs]
                    factor.append(factorize_spd(A))
                return factor[0].solve(rhs)

            self._solve = solve
        self.simulation = sim
        if self.graph_capturable:
            previous, self._capturable = self._capturable, CapturablePath(self, sim, **self._capturable_options)
            if self._rest_gravity is not None:
                self._capturable.set_rest_gravity(self._rest_gravity)
            elif previous is not None:  # a rebuild (another dt) keeps the rest gravity its first step took
                self._capturable.keep_rest_gravity(previous)
        self._last_controls = None
        self._launches.clear()
        self._launch_pose.clear()
        return sim

    def _tissue(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d, v, a)`` (N, 3) of the tissue: zero-copy views on the CPU, copies elsewhere."""
        state = self.simulation.state
        if state.d.device.is_cpu:
            return state.d.numpy(), state.v.numpy(), state.a.numpy()
        return state.numpy()

    def _apply(self, correction: np.ndarray) -> None:
        """Add a free-dof displacement correction (3F,) to the step just taken: ``δa = c0 δd``, ``δv = c7 δa``."""
        sim = self.simulation
        c = sim.coefficients
        delta = correction.reshape(-1, 3)
        free = sim.free_nodes
        d, v, a = self._tissue()
        d[free] += delta
        a[free] += c.mass_displacement * delta
        v[free] += c.velocity_new_acceleration * c.mass_displacement * delta
        if not sim.state.d.device.is_cpu:
            sim.state.assign(d, v, a)

    def _driven_displacements(self, control) -> np.ndarray:
        face = self.face
        names = face.rig.control_names
        if not face.driven_nodes.size or not names:
            return self._driven
        attrs = _namespace(control) or _namespace(self.model)
        rows = slice(face.control_start, face.control_start + len(names))
        values = np.zeros(len(names)) if attrs is None else np.asarray(attrs.activation.numpy()[rows], np.float64)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise ValueError(f"SolverFace: control {NAMESPACE}:activation of {names[bad[0]]!r} is not finite")
        if self._last_controls is None or not np.array_equal(values, self._last_controls):
            skin = np.asarray(self.expression.evaluate(values), dtype=np.float64)
            self._driven = skin[face.driven_vertices] - self._skin_rest[face.driven_vertices]
            self._last_controls = values
        return self._driven

    def _body_force(self, motion: HeadMotion) -> wp.array | None:
        """``f = M b`` (N,) at the start of the step in the tissue's force array, or None when the head feels nothing
        (the tissue's state is read only then: on a device that is a copy).

        Raises:
            FloatingPointError: a non-finite force (the head's motion), before the step is taken.
        """
        still = not (np.any(motion.angular_velocity) or np.any(motion.angular_acceleration))
        uniform = motion.rotation.T @ (self.gravity - motion.acceleration) - self._rest_gravity
        if still and not np.any(uniform):
            return None
        d, v, _ = self._tissue() if not still else (0.0, 0.0, None)
        b = body_force(motion, self.gravity, self._rest_gravity, self._rest + d, np.broadcast_to(v, self._rest.shape))
        force = (self._mass @ b.ravel()).reshape(-1, 3)
        if not np.all(np.isfinite(force[self.simulation.free_nodes])):
            raise FloatingPointError("SolverFace: the head's motion gave a non-finite body force (step not taken)")
        if self._force_view is not None:
            self._force_view[:] = force
        else:
            self._force.assign(force.astype(self._force_host_dtype))
        return self._force

    def _contact_correction(self, contacts, state_out, motion: HeadMotion) -> np.ndarray | None:
        """The contact forces' displacement correction (3F,) on top of the step (or None: no contact)."""
        face = self.face
        found = gather_contacts(self.model, contacts, state_out, face.particle_start, self._contact_mask, motion)
        if not found.nodes.size:
            self.contact_report = ContactReport()
            return None
        moved = self._tissue()[0].copy()
        lam, extra, _ = solve_contacts(found, self._rest, moved, face.contact_radius, self._free_index, self._solve)
        full = np.zeros_like(moved)
        full[self.simulation.free_nodes] = extra.reshape(-1, 3)
        scale = upright_scale(face.tetmesh.tets, self._rest_volumes, self._rest + moved, full)
        self.contact_report = ContactReport(
            count=int(found.nodes.size), active=int((lam > 0).sum()), total_force=float(lam.sum() * scale), scale=scale
        )
        if scale < 1.0:
            self._clamped_steps += 1
            warnings.warn(
                f"SolverFace: contact forces scaled to {scale:.3f} so that no tet is squashed below its volume limit",
                RuntimeWarning,
                stacklevel=3,
            )
        return scale * extra

    def _write_particles(self, state, motion: HeadMotion) -> None:
        """Launch :func:`~warpface.newton.kernels.place_nodes` into ``state`` (recorded once per pair of arrays)."""
        sim, face = self.simulation, self.face
        device = self.model.device
        if sim is None:
            d = v = wp.zeros(face.tetmesh.node_count, dtype=wp.vec3d, device=device)
        else:
            d, v = sim.state.d, sim.state.v
            if d.dtype != wp.vec3d or d.device != device:  # a float32 CG state: a float64 copy for the kernel
                host = sim.state.numpy()
                d = wp.array(host[0], dtype=wp.vec3d, device=device)
                v = wp.array(host[1], dtype=wp.vec3d, device=device)
        key = (state.particle_q.ptr, d.ptr, v.ptr)
        launch = self._launches.get(key)
        if launch is None:
            attrs = _namespace(state)
            nodes = TissueNodes()
            nodes.rest, nodes.d, nodes.v, nodes.start = self._rest_wp, d, v, face.particle_start
            out = getattr(attrs, "displacement", None) if attrs is not None else None
            out = wp.zeros(0, dtype=wp.vec3, device=device) if out is None else out
            launch = wp.launch(
                place_nodes,
                dim=face.tetmesh.node_count,
                inputs=[Frame(), nodes, state.particle_q, state.particle_qd, out],
                device=device,
                record_cmd=True,
            )
            if sim is not None and d is sim.state.d:
                self._launches[key] = launch
        pose = (motion.position.tobytes(), motion.rotation.tobytes(), motion.velocity.tobytes())
        pose += (motion.angular_velocity.tobytes(),)
        if self._launch_pose.get(key) != pose:  # a still head (the world) keeps the recorded frame
            frame = Frame()
            frame.head = wp.transformd(wp.vec3d(*motion.position), wp.quatd(*_rotation_quat(motion.rotation)))
            frame.origin_velocity = wp.vec3d(*motion.velocity)
            frame.omega = wp.vec3d(*motion.angular_velocity)
            launch.set_param_by_name("frame", frame)
            self._launch_pose[key] = pose
        launch.launch()


def _rotation_quat(R: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix (Shepperd's method)."""
    trace = np.trace(R)
    if trace > 0.0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = ((R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s)
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
        q = tuple(q)
    return tuple(float(c) for c in q)


def _flag(requested, name: str, default: bool) -> bool:
    """``requested`` (a bool) or ``default`` (None); TypeError otherwise."""
    if requested is not None and not isinstance(requested, (bool, np.bool_)):
        raise TypeError(f"SolverFace: {name} must be a bool or None, got {type(requested).__name__}")
    return default if requested is None else bool(requested)


def _capturable(requested, solver, cg, device) -> bool:
    """Whether the host-free path is taken (``requested``, or a CUDA device); ValueError where it cannot be."""
    on = _flag(requested, "graph_capturable", device.is_cuda)
    if on and solver == "direct":
        raise ValueError("SolverFace: graph_capturable steps the tissue with solver='cg', not 'direct'")
    if on and as_cg_options(cg).dtype != wp.float64:
        raise ValueError("SolverFace: graph_capturable needs a float64 CG state (CGOptions(dtype=wp.float64))")
    return on


def _positive(value, name: str, *, whole: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"SolverFace: {name} must be a number, got {type(value).__name__}")
    number = float(value)
    if not (np.isfinite(number) and number > 0.0) or (whole and number != round(number)):
        raise ValueError(f"SolverFace: {name} must be a positive {'whole ' if whole else ''}number, got {value!r}")
    return number


def _vector(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"SolverFace: {name} must be three finite numbers [m/s^2], got {value!r}")
    return arr


def _check_model(model, face: NewtonFace) -> None:
    """ValueError unless ``model`` holds ``face`` as add_face put it (its warpface attributes and node roles)."""
    attrs = _namespace(model)
    role = getattr(attrs, "node_role", None) if attrs is not None else None
    if role is None:
        raise ValueError("SolverFace: the model was not built with warpface.newton.add_face (no warpface:node_role)")
    n, start = face.tetmesh.node_count, face.particle_start
    roles = role.numpy()
    if start + n > roles.shape[0]:
        raise ValueError(f"SolverFace: the model has {roles.shape[0]} particles, the face needs {start + n}")
    expected = np.full(n, ROLE_FREE)
    expected[face.fixed_nodes], expected[face.driven_nodes] = ROLE_FIXED, ROLE_DRIVEN
    if not np.array_equal(roles[start : start + n], expected):
        raise ValueError("SolverFace: the model's warpface:node_role differs from this face: another builder's face")
    if face.head_body >= model.body_count:
        raise ValueError(f"SolverFace: head body {face.head_body} is not in the model ({model.body_count} bodies)")
