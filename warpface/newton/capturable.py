"""``SolverFace``'s host-free step: kernel launches and device copies only, so it can be captured in a graph.

:class:`CapturablePath` runs the step of docs/NEWTON.md on the device, reading nothing back: the head frame from
Newton's ``body_q``/``body_qd`` (:func:`~warpface.newton.kernels.head_body_force`), the controls from Newton's
``warpface:activation`` into the expression model's own kernels (its plan's launches on fixed buffers), the
driven displacements into the tissue simulation's control, the inertial body force into the tissue step's
right-hand side (``TissueSimulation.step(force=...)``), its CG step, the soft contacts as penalty forces found by a
fixed number of active-set passes solved by the tissue's preconditioned CG
(:class:`~warpface.newton.device_cg.FreeSystem`; docs/NEWTON.md §5), the upright clamp per tet, and the particles.
Errors (a non-finite control, a non-finite head motion or correction, a solve above its tolerance) are booked on
the device and raised by ``SolverFace.synchronize``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..expression.frame_buffers import FrameBuffers
from ..expression.plans import plan_launches
from .contact import MIN_VOLUME_FRACTION, ContactReport
from .device_cg import FreeSystem
from .kernels import (
    ERROR_CLAMPED,
    ERROR_CONTROL,
    ERROR_NON_FINITE,
    BlockRows,
    ContactSlots,
    Frame,
    HeadInputs,
    SoftContacts,
    TissueNodes,
    apply_correction,
    contact_penalty,
    contact_report,
    driven_from_skin,
    find_contacts,
    head_body_force,
    head_frame,
    non_finite,
    place_nodes_from,
    take_controls,
    upright_scale,
)

__all__ = ["CapturablePath"]


GRAPH_LIMIT = 8
"""Combinations of a step's objects whose graphs are kept (a ping-pong of two states needs two)."""


def _ints(values, device) -> wp.array:
    return wp.array(np.asarray(values, dtype=np.int32), dtype=wp.int32, device=device)


class CapturablePath:
    """The capturable step of one :class:`~warpface.newton.SolverFace` and its tissue simulation (module docstring).

    Args:
        solver: The SolverFace.
        simulation: Its :class:`~warpface.fem.TissueSimulation` (CG solver, float64 state, no graphs of its own).
        contact_stiffness: Penalty of a contact in multiples of its node's diagonal stiffness ``nᵀ A_oo[o, o] n``.
        contact_passes: Active-set passes of the contact solve per step.
    """

    def __init__(self, solver, simulation, *, contact_stiffness: float, contact_passes: int, own_graphs: bool):
        sim, face, model = simulation, solver.face, solver.model
        device = self.device = model.device
        self.solver, self.simulation, self.face = solver, sim, face
        self.system = FreeSystem(sim)
        self.penalty, self.passes = float(contact_stiffness), int(contact_passes)
        self.own_graphs = bool(own_graphs)
        self._graphs: dict = {}  # per (ids of the step's objects, inertia): [graph or None, their arrays, objects]
        n, free = face.tetmesh.node_count, sim.free_nodes
        self._free = _ints(free, device)
        free_index = np.full(n, -1, dtype=np.int32)
        free_index[free] = np.arange(free.size, dtype=np.int32)
        contact_free = np.full(n, -1, dtype=np.int32)
        contact_free[face.contact_nodes] = free_index[face.contact_nodes]
        self._free_index, self._contact_free = _ints(free_index, device), _ints(contact_free, device)
        self._tets = wp.array(face.tetmesh.tets.astype(np.int32), dtype=wp.vec4i, device=device)
        self._rest_volumes = wp.array(face.tetmesh.volumes, dtype=wp.float64, device=device)
        self._rest = wp.array(face.tetmesh.points, dtype=wp.vec3d, device=device)
        self.gravity = wp.zeros(1, dtype=wp.vec3d, device=device)
        self.rest_gravity = wp.zeros(1, dtype=wp.vec3d, device=device)
        self.rest_set = wp.zeros(1, dtype=wp.int32, device=device)
        self._frames = wp.zeros(1, dtype=Frame, device=device)
        self.errors = wp.zeros(3, dtype=wp.int32, device=device)
        """Device counters: first bad control + 1, skipped non-finite corrections, clamped contact steps."""
        self._flag = wp.zeros(1, dtype=wp.int32, device=device)
        self._scale = wp.ones(1, dtype=wp.float64, device=device)
        self._counts = wp.zeros(2, dtype=wp.int32, device=device)
        self._force = wp.zeros(1, dtype=wp.float64, device=device)
        self._body = wp.zeros(n, dtype=wp.vec3d, device=device)  # the body force (N,): free rows written, others 0
        self._f = self.system.vector()
        self._x_contact = self.system.vector()
        self._H = wp.zeros(free.size, dtype=wp.mat33d, device=device)
        M = sim.matrices.M
        self._mass = BlockRows()
        self._mass.offsets, self._mass.indices, self._mass.values = M.offsets, M.columns, M.values
        self._contact_arrays: dict = {}
        self._empty_q = (
            wp.empty(0, dtype=wp.transform, device=device),
            wp.empty(0, dtype=wp.spatial_vector, device=device),
        )
        self._empty_vec = wp.zeros(0, dtype=wp.vec3, device=device)
        c = sim.coefficients
        self._c0, self._c7c0 = (
            wp.float64(c.mass_displacement),
            wp.float64(c.velocity_new_acceleration * c.mass_displacement),
        )
        self.set_gravity(solver.gravity)
        self._expression = self._expression_launches() if face.driven_nodes.size and face.rig.control_names else None

    # ------------------------------------------------------------------ set-up (host, outside a step)
    def set_gravity(self, gravity) -> None:
        """The gravity the tissue feels [m/s²] (3,)."""
        self.gravity.assign(np.asarray(gravity, dtype=np.float64).reshape(1, 3))
        self.drop_graphs()

    def set_rest_gravity(self, rest_gravity) -> None:
        """The gravity the rest shape balances, head frame [m/s²] (3,)."""
        self.rest_gravity.assign(np.asarray(rest_gravity, dtype=np.float64).reshape(1, 3))
        self.rest_set.fill_(1)
        self.drop_graphs()

    def keep_rest_gravity(self, other: CapturablePath) -> None:
        """Take ``other``'s rest gravity (device copies: whatever its first step found)."""
        wp.copy(self.rest_gravity, other.rest_gravity)
        wp.copy(self.rest_set, other.rest_set)

    def reset(self) -> None:
        """Clear the warm start of the contact solves and the step's own graphs."""
        self._x_contact.zero_()
        self.drop_graphs()

    def _expression_launches(self):
        """The expression model's plan on buffers of one frame, recorded; the controls' buffer and the skin."""
        face, expression = self.face, self.solver.expression
        mesh = expression.mesh
        names = face.rig.control_names
        buffers = FrameBuffers(
            1,
            mesh.vertex_count,
            mesh.triangle_count,
            len(names),
            len(expression.wrinkles),
            device=self.device,
            per_triangle=expression.plan == "staged",
        )
        buffers.upload_controls(np.zeros((1, len(names))), expression.default_depths[None])
        wp.synchronize_device(self.device)
        plan = plan_launches(expression, buffers, 1, buffers.contraction, buffers.depth, buffers.final_points)
        options = dict(device=self.device, block_dim=expression.block_dim, record_cmd=True)
        launches = [wp.launch(k, dim=dim, inputs=ins, outputs=outs, **options) for k, dim, ins, outs in plan]
        skin_rest = wp.array(np.asarray(face.rig.mesh.points, dtype=np.float64), dtype=wp.vec3d, device=self.device)
        return buffers, launches, _ints(face.driven_vertices, self.device), skin_rest

    # ------------------------------------------------------------------ the step
    def advance(self, state_in, state_out, control, contacts) -> None:
        """:meth:`run`; with :attr:`own_graphs`, outside a capture, as a graph of its own per combination of
        ``state_in``, ``state_out``, ``control`` and ``contacts`` (the objects, held while cached, and inertia on or
        off): the first step with them runs eagerly (it loads every kernel: no module load inside the capture), the
        second is captured and launched, the later ones are one ``wp.capture_launch``. A state whose body or particle
        arrays were replaced is recorded again; arrays replaced inside a control, contacts or a state's ``warpface``
        namespace need :meth:`drop_graphs`. A capture the caller has open (``device.is_capturing``) gets the
        launches themselves."""
        if not self.own_graphs or self.device.is_capturing:
            self.run(state_in, state_out, control, contacts)
            return
        key = (id(state_in), id(state_out), id(control), id(contacts), bool(self.solver.inertia))
        arrays = (state_in.body_q, state_in.body_qd, state_out.body_q, state_out.body_qd, state_out.particle_q)
        arrays += (state_out.particle_qd,)
        entry = self._graphs.get(key)
        if entry is None or entry[1] != arrays:  # tuples of arrays compare by identity
            if entry is None and len(self._graphs) >= GRAPH_LIMIT:  # new objects every step: keep memory bounded
                self._graphs.clear()
            self.run(state_in, state_out, control, contacts)
            self._graphs[key] = [None, arrays, (state_in, state_out, control, contacts)]
            return
        if entry[0] is None:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self.run(state_in, state_out, control, contacts)  # counts the step (steps_taken) once
            entry[0] = capture.graph
        else:
            self.simulation.steps_taken += 1  # what the tissue's own step() does on the host
        wp.capture_launch(entry[0])

    def drop_graphs(self) -> None:
        """Forget the step's own graphs (the next steps record them again)."""
        self._graphs.clear()

    def _launch(self, kernel, dim: int, inputs: list, outputs: list) -> None:
        wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device)

    def _nodes(self) -> TissueNodes:
        nodes = TissueNodes()
        state = self.simulation.state
        nodes.rest, nodes.d, nodes.v, nodes.start = self._rest, state.d, state.v, self.face.particle_start
        return nodes

    def run(self, state_in, state_out, control, contacts) -> None:
        """One step from ``state_in`` to ``state_out`` (module docstring); queues device work only."""
        sim, face, system = self.simulation, self.face, self.system
        head = self._head(state_in, state_out, sim.dt)
        if self._expression is not None:
            self._driven(control)
        nodes = self._nodes()
        rest = [self.rest_gravity, self.rest_set]
        force = None
        if self.solver.inertia:  # the frame and the body force at the start of the step (r, ḋ), in the step's rhs
            inputs = [head, *rest, self._mass, self._free, nodes]
            self._launch(head_body_force, system.free_count, inputs, [self._frames, self.errors, self._body])
            force = self._body
        else:
            self._launch(head_frame, 1, [head, *rest], [self._frames])
        sim.step(sim.control, force=force)
        if contacts is not None:
            self._contacts(contacts, state_out, nodes)
        attrs = getattr(state_out, "warpface", None)
        out = getattr(attrs, "displacement", None) if attrs is not None else None
        inputs = [self._frames, nodes, state_out.particle_q, state_out.particle_qd]
        inputs.append(self._empty_vec if out is None else out)
        self._launch(place_nodes_from, face.tetmesh.node_count, inputs, [self.rest_set])

    def _head(self, state_in, state_out, dt: float) -> HeadInputs:
        """The head kernels' inputs: the head body's poses and twists at both ends of the step (empty: the world)."""
        model, head = self.solver.model, HeadInputs()
        if self.face.head_body >= 0:
            head.q_in, head.qd_in, head.body_com = state_in.body_q, state_in.body_qd, model.body_com
            head.q_out, head.qd_out = state_out.body_q, state_out.body_qd
        else:
            (head.q_in, head.qd_in), (head.q_out, head.qd_out) = self._empty_q, self._empty_q
            head.body_com = self._empty_vec
        head.body, head.dt = self.face.head_body, wp.float64(dt)
        head.gravity, head.model_gravity = self.gravity, model.gravity
        return head

    def _driven(self, control) -> None:
        face, solver = self.face, self.solver
        buffers, launches, vertices, skin_rest = self._expression
        attrs = getattr(control, "warpface", None) or getattr(solver.model, "warpface", None)
        if attrs is not None:
            inputs = [attrs.activation, face.control_start, len(face.rig.control_names)]
            self._launch(take_controls, 1, inputs, [buffers.contraction, self.errors])
        for launch in launches:
            launch.launch()
        driven = self.simulation.control.driven
        self._launch(driven_from_skin, face.driven_nodes.size, [buffers.final_points, vertices, skin_rest], [driven])

    def _correct(self, x, scale) -> None:
        """Add the contact correction ``scale[0] x`` to the step (skipped, and booked, when not finite)."""
        state, count = self.simulation.state, self.system.free_count
        self._flag.zero_()
        self._launch(non_finite, count, [x], [self._flag])
        inputs = [x, scale, self._free, self._c0, self._c7c0, self._flag, 1, self.errors]
        self._launch(apply_correction, count, inputs, [state.d, state.v, state.a])

    def _contact_slots(self, capacity: int) -> ContactSlots:
        slots = self._contact_arrays.get(capacity)
        if slots is None:
            slots = self._contact_arrays[capacity] = ContactSlots()
            slots.slot = wp.full(capacity, -1, dtype=wp.int32, device=self.device)
            slots.normals = wp.zeros(capacity, dtype=wp.vec3d, device=self.device)
            slots.gaps = wp.zeros(capacity, dtype=wp.float64, device=self.device)
            slots.stiffness = wp.zeros(capacity, dtype=wp.float64, device=self.device)
        return slots

    def _contacts(self, contacts, state_out, nodes: TissueNodes) -> None:
        """Find the face's contacts, solve the penalty contact in passes, clamp it to upright tets, apply it."""
        face, system = self.face, self.system
        capacity = contacts.soft_contact_particle.shape[0]
        self._counts.zero_()
        self._force.zero_()
        self._scale.fill_(1.0)
        if capacity == 0:
            return
        slots = self._contact_slots(capacity)
        found = SoftContacts()
        found.count, found.particle, found.shape = (
            contacts.soft_contact_count,
            contacts.soft_contact_particle,
            contacts.soft_contact_shape,
        )
        found.body_pos, found.normal = contacts.soft_contact_body_pos, contacts.soft_contact_normal
        body_q = state_out.body_q if state_out.body_q is not None else self._empty_q[0]
        inputs = [found, self.solver.model.shape_body, body_q, self._frames, self._contact_free, nodes]
        inputs += [wp.float64(face.contact_radius), wp.float64(self.penalty), system.diagonal_blocks]
        self._launch(find_contacts, capacity, inputs, [slots, self._counts])
        for _ in range(self.passes):
            self._H.zero_()
            self._f.zero_()
            self._launch(contact_penalty, capacity, [slots, self._x_contact], [self._H, self._f])
            system.penalise(self._H)
            system.solve(self._f, self._x_contact, penalised=True)
        self._launch(contact_report, capacity, [slots, self._x_contact], [self._counts, self._force])
        inputs = [self._tets, self._rest_volumes, wp.float64(MIN_VOLUME_FRACTION), nodes, self._x_contact]
        self._launch(upright_scale, face.tetmesh.tet_count, [*inputs, self._free_index], [self._scale])
        self._correct(self._x_contact, self._scale)

    # ------------------------------------------------------------------ reports (host reads, outside a step)
    def report(self) -> ContactReport:
        """The last step's contacts (reads the device)."""
        count, active = (int(c) for c in self._counts.numpy())
        scale = float(self._scale.numpy()[0])
        return ContactReport(count=count, active=active, total_force=float(self._force.numpy()[0]) * scale, scale=scale)

    def clamped_count(self) -> int:
        """Steps whose contact correction was scaled back (reads the device)."""
        return int(self.errors.numpy()[ERROR_CLAMPED])

    def raise_errors(self) -> None:
        """Raise what the steps booked since the last call (and clear it): ValueError for a non-finite control,
        FloatingPointError for a skipped non-finite head motion (its body force) or contact correction,
        ConvergenceError for a contact solve that did not reach its tolerance."""
        from ..errors import ConvergenceError

        errors, failed = self.errors.numpy(), int(self.system.failed.numpy()[0])
        bad, skipped = int(errors[ERROR_CONTROL]), int(errors[ERROR_NON_FINITE])
        self.errors.assign(np.array([0, 0, errors[ERROR_CLAMPED]], dtype=np.int32))
        self.system.failed.zero_()
        if bad:
            name = self.face.rig.control_names[bad - 1]
            raise ValueError(
                f"SolverFace: control warpface:activation of {name!r} is not finite (the steps held the last good ones)"
            )
        if skipped:
            raise FloatingPointError(
                f"SolverFace: {skipped} head motions or contact corrections were not finite and were skipped"
            )
        if failed:
            raise ConvergenceError(f"SolverFace: {failed} contact solves stopped above the CG tolerance")
