"""``x3(c)`` and its exact Jacobian ``∂x3/∂c`` on a target's neighbourhood, by the Warp kernels of :mod:`.kernels`.

The solver's one evaluation of the expression pipeline (SPEC §1, with the jaw's basis of
:mod:`.local_model`), in float64 on any Warp device: the rig's constant data per active (element,
column) slot is laid out once here, the five stages are recorded once per mode and replayed.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

from .._validate import MAX_COORDINATE, as_device, as_finite_array, expect_instance
from . import kernels
from .local_model import REST_STRETCH_BAND, STRETCH_FLOOR, Neighbourhood, RigOperators

__all__ = ["LocalExpression", "jaw_chain_rule_kernel", "write_model_input", "model_input_kernel"]


@wp.func
def write_model_input(
    values: wp.array(dtype=wp.float64),
    scale: wp.array(dtype=wp.float64),
    f: int,
    layout: kernels.Layout,
    out: wp.array(dtype=wp.float64),
):
    """Frame ``f``'s controls ``values/scale`` (C per frame) → the pipeline's input (B per frame).

    Muscles are copied; with a jaw (``B = C + 1``) the angle θ becomes ``sin θ, 1 − cos θ`` and the
    slides follow. One function for the host upload and the on-device iteration, so both hand the model
    the same bits (a muscle at rest next to a rigidly moved vertex sits on the wrinkle term's kink, where
    an ulp of ``sin θ`` picks the side of the derivative).
    """
    control_count = layout.control_count
    muscle_count = layout.muscle_count
    ub = f * control_count
    ob = f * layout.basis_count
    for m in range(muscle_count):
        out[ob + m] = values[ub + m] / scale[m]
    if layout.basis_count > control_count:
        angle = values[ub + muscle_count] / scale[muscle_count]
        out[ob + muscle_count] = wp.sin(angle)
        out[ob + muscle_count + 1] = wp.float64(1.0) - wp.cos(angle)
        for j in range(muscle_count + 1, control_count):
            out[ob + j + 1] = values[ub + j] / scale[j]
    else:
        for j in range(muscle_count, control_count):
            out[ob + j] = values[ub + j] / scale[j]


@wp.kernel
def model_input_kernel(
    controls: wp.array(dtype=wp.float64),
    ones: wp.array(dtype=wp.float64),
    layout: kernels.Layout,
    out: wp.array(dtype=wp.float64),
):
    """Per frame: controls (F·C) → the pipeline's basis (F·B), see :func:`write_model_input`."""
    write_model_input(controls, ones, wp.tid(), layout, out)


@wp.kernel
def jaw_chain_rule_kernel(
    dbasis: wp.array(dtype=wp.float64),
    basis: wp.array(dtype=wp.float64),
    rows_per_frame: int,
    layout: kernels.Layout,
    dcontrols: wp.array(dtype=wp.float64),
):
    """Per (frame, vertex, axis) row: basis derivatives → control derivatives (``local_model`` docstring).

    ``∂x/∂θ = cos θ · ∂x/∂(sin θ) + sin θ · ∂x/∂(1 − cos θ)``; muscle and slide columns are copied.
    """
    row = wp.tid()
    muscle_count = layout.muscle_count
    basis_count = layout.basis_count
    frame = row // rows_per_frame
    source = row * basis_count
    target = row * layout.control_count
    for m in range(muscle_count):
        dcontrols[target + m] = dbasis[source + m]
    sine = basis[frame * basis_count + muscle_count]
    cosine = wp.float64(1.0) - basis[frame * basis_count + muscle_count + 1]
    dcontrols[target + muscle_count] = dbasis[source + muscle_count] * cosine + dbasis[source + muscle_count + 1] * sine
    dcontrols[target + muscle_count + 1] = dbasis[source + muscle_count + 2]
    dcontrols[target + muscle_count + 2] = dbasis[source + muscle_count + 3]


class _Buffers:
    def __init__(self, frames: int, sizes: dict, controls: int, device, outputs: int | None = None):
        # Zeroed once: derivative entries outside an element's active controls are never written.
        def vec(n):
            return wp.zeros(max(n, 1), dtype=wp.vec3d, device=device)

        def scalar(n):
            return wp.zeros(max(n, 1), dtype=wp.float64, device=device)

        n2, t1, n1, t0, n0 = (sizes[k] for k in ("n2", "t1", "n1", "t0", "n0"))
        self.controls = wp.zeros(frames * controls, dtype=wp.float64, device=device)
        self.x1 = vec(frames * n2)
        self.area1, self.ratio1 = vec(frames * t1), scalar(frames * t1)
        self.darea1, self.dratio1 = vec(frames * sizes["t1_slots"]), scalar(frames * sizes["t1_slots"])
        """Per active (triangle, column) slot, ``t1_slots`` per frame (see :func:`.kernels.first_ring_triangles`)."""
        self.stretch, self.x2 = scalar(frames * n1), vec(frames * n1)
        self.dstretch, self.dx2 = scalar(frames * n1 * controls), vec(frames * n1 * controls)
        self.area0, self.darea0 = vec(frames * t0), vec(frames * t0 * controls)
        self.x3, self.dx3_basis = vec(frames * n0), scalar(frames * n0 * 3 * controls)
        """The pipeline's derivatives per basis column; with a jaw, :attr:`dx3` holds them per control."""
        self._dx3 = self.dx3_basis
        if outputs is not None and outputs != controls:
            self._dx3 = None  # allocated on first use: the solver's normal equations read dx3_basis
            self._dx3_size, self._device = max(frames * n0 * 3 * outputs, 1), device
        self.raw_controls = None
        """With a jaw: the controls as given (F·C), turned into ``controls`` (the basis) by a kernel."""
        if outputs is not None and outputs != controls:
            self.raw_controls = wp.zeros(frames * outputs, dtype=wp.float64, device=device)
        self.frame_on = wp.ones(frames, dtype=wp.int32, device=device)
        """Frames to evaluate (1) or skip (0): the solver turns off the frames that have converged."""
        self.recorded: dict[tuple, list] = {}
        """Launches recorded once per mode (with / without Jacobian; per control / per basis column) and
        replayed: argument packing is most of a small launch's cost on the CPU."""
        staged = self.controls if self.raw_controls is None else self.raw_controls
        self.staged = staged
        self.host_controls = staged.numpy() if device.is_cpu else None
        """CPU: a NumPy view sharing the uploaded controls' memory (written in place)."""
        self.basis_command = None
        """The recorded controls → basis launch (with a jaw)."""

    @property
    def dx3(self) -> wp.array:
        """``∂x3/∂c`` per control, (F·n·3·C,) (with a jaw: the chain rule of :attr:`dx3_basis`)."""
        if self._dx3 is None:
            self._dx3 = wp.zeros(self._dx3_size, dtype=wp.float64, device=self._device)
        return self._dx3


class LocalExpression:
    """``x3(c)`` and ``∂x3/∂c`` at a fixed set of vertices (the union of what the targets touch).

    Args:
        operators: the rig's :class:`~.local_model.RigOperators`.
        vertices: the vertices whose final positions are needed, (n,) int.
        device: Warp device of the evaluation (default: Warp's preferred device).
    """

    def __init__(self, operators: RigOperators, vertices, *, device=None):
        expect_instance(operators, RigOperators, "operators")
        self.device = as_device(device)
        self.neighbourhood = local = Neighbourhood(operators, vertices)
        """The two rings around the vertices and the rig's data on them (host, float64)."""
        self.vertices, self.count, self.control_count = local.vertices, local.count, local.control_count
        self.basis_count, self.muscle_count, self.has_jaw = local.basis_count, local.muscle_count, local.has_jaw
        self.layout = kernels.layout_of(self.control_count, self.muscle_count, self.basis_count, self.control_count)
        """The model's block sizes (its variables: the controls)."""
        d = self.device
        f64 = lambda a: wp.array(np.ascontiguousarray(a, dtype=np.float64), dtype=wp.float64, device=d)  # noqa: E731
        i32 = lambda a: wp.array(np.ascontiguousarray(a, dtype=np.int32), dtype=wp.int32, device=d)  # noqa: E731
        self._rest = wp.array(local.rest2, dtype=wp.vec3d, device=d)
        self._t1 = wp.array(local.triangles1.astype(np.int32), dtype=wp.vec3i, device=d)
        self._t1_weight, self._t1_length = f64(local.triangle_weight1), f64(local.rest_length1)
        inc1 = local.incidence1
        self._adj1_offsets, self._adj1 = i32(inc1.indptr), i32(inc1.indices)
        self._counts1, self._thickness1 = f64(local.counts1), f64(local.thickness1)
        self._s1_in_s2, self._s0_in_s1 = i32(local.s1_in_s2), i32(local.s0_in_s1)
        self._t0 = wp.array(local.triangles0.astype(np.int32), dtype=wp.vec3i, device=d)
        self._t0_weight = f64(local.triangle_weight0)
        inc0 = local.incidence0
        self._adj0_offsets, self._adj0 = i32(inc0.indptr), i32(inc0.indices)
        profile = sp.csr_matrix(local.profile0)
        profile.eliminate_zeros()
        self._profile_offsets, self._profile_wrinkle = i32(profile.indptr), i32(profile.indices)
        self._profile_value = f64(profile.data if profile.nnz else np.zeros(1))
        self._kr = f64(local.kr if len(local.kr) else np.zeros(1))
        self._sizes = dict(
            n2=len(local.rest2),
            t1=len(local.triangles1),
            n1=len(local.s1_in_s2),
            t0=len(local.triangles0),
            n0=local.count,
        )
        self._buffers: dict[int, _Buffers] = {}
        self._ones = f64(np.ones(self.control_count))
        active_basis = _active_controls(local)
        self.active_controls = {name: _basis_to_controls(csr, local) for name, csr in active_basis.items()}
        """Per element kind (``s2``, ``t1``, ``s1``, ``t0``, ``s0``): which controls can move it, sparse bool CSR."""
        self._active = {
            name: (i32(csr.indptr), i32(csr.indices if csr.nnz else np.zeros(1))) for name, csr in active_basis.items()
        }
        # The rig's constant derivative data per active (element, column) slot, stored in slot order: the
        # stages stream them instead of gathering from the dense (n2·B) field (~5x the bytes, cache misses).
        vec = lambda a: wp.array(
            np.ascontiguousarray(a, dtype=np.float64).reshape(-1, 3) if len(a) else np.zeros((1, 3)),  # noqa: E731
            dtype=wp.vec3d,
            device=d,
        )
        moved = active_basis["s2"]
        self._slot_field = vec(
            local.field2[np.repeat(np.arange(len(local.rest2)), np.diff(moved.indptr)), :, moved.indices]
        )
        """``W`` per active (vertex, column) slot of ``s2``, (slots,) vec3d."""
        touched = active_basis["t1"]
        owner = np.repeat(np.arange(len(local.triangles1)), np.diff(touched.indptr))
        corners = [local.field2[local.triangles1[owner, c], :, touched.indices] for c in range(3)]
        self._slot_edges = vec(np.stack([corners[1] - corners[0], corners[2] - corners[0]], axis=1))
        """Per active (triangle, column) slot of ``t1``: the derivatives of its two edges ``(W1 − W0, W2 − W0)``."""
        # Per vertex of s1, per (active column, incident triangle) pair in the bulge stage's loop order: the
        # triangle's slot for that column, or the always-zero slot past the last when the column misses it.
        ring = active_basis["s1"]
        adjacency = local.incidence1
        ring_vertex = np.repeat(np.arange(len(local.s1_in_s2)), np.diff(ring.indptr))
        incident_count = np.diff(adjacency.indptr)[ring_vertex]
        pair_column = np.repeat(ring.indices, incident_count)
        within = np.arange(incident_count.sum()) - np.repeat(np.cumsum(incident_count) - incident_count, incident_count)
        pair_triangle = adjacency.indices[np.repeat(adjacency.indptr[ring_vertex], incident_count) + within]
        slot_key = owner.astype(np.int64) * self.basis_count + touched.indices  # ascending: CSR rows, sorted columns
        pair_key = pair_triangle.astype(np.int64) * self.basis_count + pair_column
        found = np.minimum(np.searchsorted(slot_key, pair_key), max(len(slot_key) - 1, 0))
        hit = (slot_key[found] == pair_key) if len(slot_key) else np.zeros(len(pair_key), bool)
        pairs = np.where(hit, found, touched.nnz)
        pair_offsets = np.concatenate(
            [[0], np.cumsum(np.bincount(ring_vertex, weights=incident_count, minlength=len(local.s1_in_s2)))]
        ).astype(np.int64)
        self._sizes["t1_slots"] = touched.nnz + 1
        self._pair_offsets, self._pair_slot = i32(pair_offsets), i32(pairs if len(pairs) else [0])
        own = local.s1_in_s2[np.repeat(np.arange(len(local.s1_in_s2)), np.diff(ring.indptr))]
        self._slot_own = vec(local.field2[own, :, ring.indices])
        """Per active (vertex, column) slot of ``s1``: the vertex's own ``W`` (0 for a column that moves only
        its ring)."""
        self._rig = {
            "muscle": (self._rest, self._slot_field, *self._active["s2"]),
            "first_ring": (self._slot_edges, self._t1, self._t1_weight, self._t1_length, *self._active["t1"]),
            "bulge": (
                self._slot_own,
                self._s1_in_s2,
                self._adj1_offsets,
                self._adj1,
                self._counts1,
                self._thickness1,
                wp.float64(STRETCH_FLOOR),
                *self._active["s1"],
                self._pair_offsets,
                self._pair_slot,
            ),
            "second_ring": (self._t0, self._t0_weight, *self._active["t0"]),
            "wrinkle": (
                self._s0_in_s1,
                self._adj0_offsets,
                self._adj0,
                self._profile_offsets,
                self._profile_wrinkle,
                self._profile_value,
                self._kr,
                wp.float64(REST_STRETCH_BAND),
                *self._active["s0"],
            ),
        }
        """Each stage's constant rig arguments, in its kernel's order (between the frame's inputs and the Rings)."""

    @property
    def bytes_per_frame(self) -> int:
        """Device memory one frame of :meth:`buffers` takes with its Jacobian [bytes]."""
        s, m = self._sizes, self.basis_count
        vec, scalar = 24, 8
        per_control = s["n1"] * (vec + scalar) + s["t0"] * vec + s["n0"] * 3 * scalar
        values = s["n2"] * vec + s["t1"] * (vec + scalar) + s["n1"] * (vec + scalar) + s["t0"] * vec + s["n0"] * vec
        return per_control * m + s["t1_slots"] * (vec + scalar) + values + m * scalar

    @property
    def reach(self) -> int:
        """Vertices an evaluation touches (the two rings around the targets)."""
        return self.neighbourhood.reach

    def buffers(self, frames: int) -> _Buffers:
        if frames not in self._buffers:
            self._buffers[frames] = _Buffers(
                frames, self._sizes, self.basis_count, self.device, outputs=self.control_count
            )
        return self._buffers[frames]

    def upload(self, buffers: _Buffers, controls: np.ndarray) -> None:
        """Write (F, C) controls into ``buffers`` (CPU: in place; CUDA: one host-to-device copy)."""
        controls = np.asarray(controls, dtype=np.float64).reshape(-1, self.control_count)
        flat = np.ascontiguousarray(controls).reshape(-1)
        if buffers.host_controls is not None:
            buffers.host_controls[: flat.size] = flat
        else:
            buffers.staged.assign(wp.array(flat, dtype=wp.float64, device="cpu"))
        if buffers.raw_controls is not None:
            if buffers.basis_command is None:
                frames = len(buffers.frame_on)
                buffers.basis_command = wp.launch(
                    model_input_kernel,
                    dim=frames,
                    device=self.device,
                    record_cmd=True,
                    inputs=[buffers.raw_controls, self._ones, self.layout],
                    outputs=[buffers.controls],
                )
            buffers.basis_command.launch()

    def launch(self, buffers: _Buffers, frames: int, jacobian: bool, *, per_control: bool = True) -> None:
        """Run the five stages on ``buffers`` (controls already uploaded).

        ``per_control=False`` leaves the derivatives per basis column in ``buffers.dx3_basis`` (no jaw
        chain-rule pass): for a consumer that applies the chain rule itself (the solver's normal equations).
        """
        key = (jacobian, per_control)
        if key not in buffers.recorded:
            buffers.recorded[key] = self._record(buffers, frames, jacobian, per_control)
        for command in buffers.recorded[key]:
            command.launch()

    def _record(self, buffers: _Buffers, frames: int, jacobian: bool, per_control: bool) -> list:
        s, rig, b = self._sizes, self._rig, buffers
        rings = kernels.rings_of(s, self.basis_count, jacobian)
        commands = []

        def launch(kernel, count: int, inputs: list, outputs: list):
            """Record ``kernel`` over ``count`` elements per frame."""
            commands.append(
                wp.launch(
                    kernel, dim=frames * count, device=self.device, inputs=inputs, outputs=outputs, record_cmd=True
                )
            )

        launch(kernels.muscle_stage, s["n2"], [b.frame_on, b.controls, *rig["muscle"], rings], [b.x1])
        launch(
            kernels.first_ring_triangles,
            s["t1"],
            [b.frame_on, b.x1, *rig["first_ring"], rings],
            [b.area1, b.ratio1, b.darea1, b.dratio1],
        )
        launch(
            kernels.bulge_stage,
            s["n1"],
            [b.frame_on, b.x1, b.area1, b.ratio1, b.darea1, b.dratio1, *rig["bulge"], rings],
            [b.stretch, b.x2, b.dstretch, b.dx2],
        )
        launch(
            kernels.second_ring_triangles,
            s["t0"],
            [b.frame_on, b.x2, b.dx2, *rig["second_ring"], rings],
            [b.area0, b.darea0],
        )
        launch(
            kernels.wrinkle_stage,
            s["n0"],
            [b.frame_on, b.x2, b.stretch, b.dx2, b.dstretch, b.area0, b.darea0, *rig["wrinkle"], rings],
            [b.x3, b.dx3_basis],
        )
        if jacobian and per_control and self.has_jaw:
            launch(
                jaw_chain_rule_kernel,
                s["n0"] * 3,
                [b.dx3_basis, b.controls, s["n0"] * 3, self.layout],
                [b.dx3],
            )
        return commands

    def _checked(self, controls) -> np.ndarray:
        """``controls`` as a contiguous float64 (F, C) array; TypeError/ValueError naming them otherwise.

        The common case costs one pass (``|c| ≤ MAX_COORDINATE`` is False for NaN and ±inf as well): an
        optimiser calls :meth:`evaluate` many times per frame.
        """
        if isinstance(controls, np.ndarray) and controls.dtype == np.float64 and controls.ndim == 2:
            if controls.shape[1] == self.control_count and (
                controls.size == 0 or np.abs(controls).max() <= MAX_COORDINATE
            ):
                return np.ascontiguousarray(controls)
        checked = as_finite_array(controls, "controls", shape=(None, self.control_count), max_abs=MAX_COORDINATE)
        return np.ascontiguousarray(checked, dtype=np.float64)

    def evaluate(self, controls: np.ndarray, *, jacobian: bool = True, copy_jacobian: bool = True):
        """Final positions at :attr:`vertices` for each frame, and their derivatives.

        Args:
            controls: (F, C) contractions in muscle order, then the jaw's controls when there is a jaw.
            jacobian: also return ``∂x3/∂c``.
            copy_jacobian: False: the CPU Jacobian is a view of the device buffer, valid until the next
                evaluation with a Jacobian of the same frame count (a caller that consumes it at once).

        Returns:
            ``x3`` (F, n, 3) and, with ``jacobian``, ``∂x3/∂c`` (F, n, 3, C) — else ``None``.
        """
        controls = self._checked(controls)
        frames = controls.shape[0]
        buffers = self.buffers(frames)
        self.upload(buffers, controls)
        buffers.frame_on.fill_(1)
        self.launch(buffers, frames, jacobian)
        n0, m = self.count, self.control_count
        x3 = buffers.x3.numpy()[: frames * n0].reshape(frames, n0, 3).copy()
        if not jacobian:
            return x3, None
        jacobian = buffers.dx3.numpy()[: frames * n0 * 3 * m].reshape(frames, n0, 3, m)
        return x3, (jacobian.copy() if self.device.is_cpu and copy_jacobian else jacobian)


def _basis_to_controls(active: sp.csr_matrix, local: Neighbourhood) -> sp.csr_matrix:
    """Active basis columns → active controls (both angle columns belong to ``jaw_open``)."""
    if not local.has_jaw:
        return active
    m = local.muscle_count
    owner = np.concatenate([np.arange(m), [m, m, m + 1, m + 2]])
    mapping = sp.csr_matrix((np.ones(len(owner), bool), (np.arange(len(owner)), owner)), shape=(len(owner), m + 3))
    matrix = (active.astype(bool) @ mapping).astype(bool).tocsr()
    matrix.eliminate_zeros()
    matrix.sort_indices()
    return matrix


def _active_controls(local: Neighbourhood) -> dict:
    """Per element, the controls whose derivative can be non-zero there (CSR, sorted), fixed by the rig.

    A triangle of the first ring feels the muscles that move one of its corners; a first-ring vertex,
    those of its own motion and of its incident triangles (stretch, normal); and so on outward.
    """

    def spread(incidence: sp.csr_matrix, inner: sp.csr_matrix) -> sp.csr_matrix:
        return (incidence.astype(bool) @ inner).astype(bool).tocsr()

    def corners(triangles: np.ndarray, vertex_count: int) -> sp.csr_matrix:
        """Triangle → its three corners, (T, vertex_count) bool."""
        owner = np.repeat(np.arange(len(triangles)), 3)
        return sp.csr_matrix(
            (np.ones(triangles.size, bool), (owner, triangles.ravel())), shape=(len(triangles), vertex_count)
        )

    moved = sp.csr_matrix(np.any(local.field2 != 0.0, axis=1))  # (n2, M)
    t1 = spread(corners(local.triangles1, len(local.rest2)), moved)
    s1 = (spread(local.incidence1, t1) + moved[local.s1_in_s2]).astype(bool).tocsr()
    t0 = spread(corners(local.triangles0, len(local.s1_in_s2)), s1)
    s0 = (spread(local.incidence0, t0) + s1[local.s0_in_s1]).astype(bool).tocsr()
    result = {}
    for name, matrix in (("s2", moved), ("t1", t1), ("s1", s1), ("t0", t0), ("s0", s0)):
        matrix.eliminate_zeros()
        matrix.sort_indices()
        result[name] = matrix
    return result
