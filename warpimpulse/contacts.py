"""The contact stage of a step: detection on the predicted state, push-only impulses in the loop with the joints,
restitution and friction at t0+h (`kernels/contact_solve.py` has the maths, `kernels/collide.py` the geometry).

The Simulator calls, per (sub)step of h: `detect` once on the first prediction, then `measure` and
`solve_positions` in its correction loop (each time after predicting again), and `solve_velocities` after the
joints' velocity correction. A scene where nothing collides has no ContactStage at all.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import warp as wp

from .kernels import contact_rows as row_kernels
from .kernels import contact_solve as kernels
from .launch import Packed, record
from .launch import arguments as kernels_arguments
from .model import Model, State
from .transforms import quat_rotate

CONTACT_SOLVERS = ("pgs", "paper")
"""How the position phase's linear problem is solved between two predictions: "pgs" sweeps it to the tolerance
(projected Gauss-Seidel on the linearised contacts, the joints solved directly around it); "paper" takes one
sweep and predicts again (the method paper's nonlinear iteration, each contact in turn)."""

CONTACT_ROW_SLOTS = 32
"""Contacts on jointed bodies solved as rows with the joints, limits and motors (`kernels/contact_rows.py`), at
most this many a step (3 rows each, one solve with K's factor per row); further ones are swept alone."""

ROW_SWEEPS = 500
"""Projected Gauss-Seidel sweeps at most over those contacts' rows per solve (the limits and motors that hold
eliminated exactly), until no row moves a coordinate by more than a tenth of the tolerance over the step."""

VELOCITY_SWEEPS = 2
"""The velocity phase's sweeps at most per solve, in `contact_sweeps` (60 by default; it was 8, 240 sweeps,
before the contacts were ordered from the bottom up). On the 1,000-body pile at 1e-4 m over 4 s (docs/contacts.md,
"Where the time goes"): ordered, 75 sweeps a step and a mean kinetic energy of 0.017 J over the last second,
where the unordered 240 took 285 sweeps and left 0.024 J."""

POSITION_SLOP = 0.5
"""The penetration (in tolerances) the position phase leaves where it pushes: it runs when a contact is deeper
than the tolerance and closes it to half of it, so that a body resting within the tolerance is corrected less
often and by less (closed to 0, a 1,000-body pile at 6 mm kept 0.7 J of kinetic energy; docs/contacts.md)."""

WARM_DISTANCE = 0.01
"""How far (m, in the second body's frame) a contact's anchor may have moved since the last step for it to be
the same contact, whose impulses then start this step's sweeps (`contact_solve.match_contacts`)."""

BROAD_PHASES = ("bvh", "all_pairs")
"""`bvh`: Warp's BVH over the swept boxes of the colliders, rebuilt each step; `all_pairs`: every pair of boxes
tested (the baseline `benchmarks/contacts.py` measures it against)."""


@dataclass
class Contacts:
    """The contacts of the last step, numpy, world frame. k contacts.

    body_a, body_b: (k,) bodies; body_a is -1 for a ground plane. The normal points from a to b.
    point: (k, 3) the contact point on b's surface at the current state (m).
    normal: (k, 3) unit. depth: (k,) penetration at the current state (m; negative: apart).
    normal_impulse: (k,) N s, both phases of the step. friction_impulse: (k, 3) N s, on b, tangential.
    """

    body_a: np.ndarray
    body_b: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    normal_impulse: np.ndarray
    friction_impulse: np.ndarray

    def __len__(self) -> int:
        return len(self.body_a)


def _array(values, dtype, device) -> wp.array:
    return wp.array(np.ascontiguousarray(values), dtype=dtype, device=device)


def sort_pairs(keys: wp.array, values: wp.array, count: int) -> None:
    """The first `count` keys sorted, their values with them, stable (equal keys keep their order): Warp's radix
    sort on a GPU; on a CPU numpy's stable sort of the arrays' memory, the same order. Warp's CPU radix sort takes
    ~80 us whatever the count (4 contacts or 64), most of a detection's time on a robot's few feet."""
    if keys.device.is_cuda:
        wp.utils.radix_sort_pairs(keys, values, count)
        return
    k, v = keys.numpy()[:count], values.numpy()[:count]
    order = np.argsort(k, kind="stable")
    k[:], v[:] = k[order], v[order]


class ContactStage:
    """Device arrays of the colliders and the contacts, and the recorded launches of the contact stage."""

    def __init__(
        self,
        model: Model,
        frames,
        control,
        state: State,
        pred: State,
        tolerance: float,
        velocity_tolerance: float,
        margin: float = 0.005,
        solver: str = "pgs",
        broad_phase: str = "bvh",
        max_sweeps: int = 30,
        joints=None,
    ) -> None:
        """`joints`: the Simulator when it solves its joints directly (a factor of K to reuse): contacts on its
        jointed bodies are then rows solved with the joints, limits and motors (`kernels/contact_rows.py`)."""
        c, d = model.colliders, model.device
        self.model, self.frames, self.control, self.state, self.pred = model, frames, control, state, pred
        self.tolerance, self.velocity_tolerance = tolerance, velocity_tolerance
        self.solver, self.broad = solver, broad_phase
        self.sweeps = 1 if solver == "paper" else max_sweeps
        self.max_sweeps = max_sweeps
        colliders = np.flatnonzero(c.shape_kind >= 0)
        n = model.body_count
        self.geometry = SimpleNamespace(
            collider_body=_array(colliders.astype(np.int32), wp.int32, d),
            collider_count=len(colliders),
            body_count=n,
            body_shape=_array(c.shape_kind.astype(np.int32), wp.int32, d),
            body_size=_array(c.shape_size, wp.vec3d, d),
            body_bound=_array(c.bound, wp.float64, d),
            body_friction=_array(c.friction, wp.float64, d),
            body_restitution=_array(c.restitution, wp.float64, d),
            plane_normal=_array(c.plane_normal, wp.vec3d, d),
            plane_offset=_array(c.plane_offset, wp.float64, d),
            plane_material=_array(
                np.stack([c.plane_friction, c.plane_restitution], axis=1).reshape(-1, 2), wp.vec2d, d
            ),  # fmt: skip
            filter_keys=_array((c.filter_pairs[:, 0] * n + c.filter_pairs[:, 1]).astype(np.int64), wp.int64, d),
            margin=float(margin),
            lowers=wp.zeros(len(colliders), dtype=wp.vec3, device=d),
            uppers=wp.zeros(len(colliders), dtype=wp.vec3, device=d),
        )
        self.plane_count = c.plane_count
        self.bvh = wp.Bvh(self.geometry.lowers, self.geometry.uppers) if broad_phase == "bvh" else None
        self.geometry.bvh = self.bvh.id if self.bvh is not None else 0
        pairs = max(64, 16 * len(colliders))
        contacts = max(64, 4 * pairs + 8 * len(colliders) * self.plane_count)
        self._allocate(pairs, contacts)
        self.count = 0
        self.pair_total = 0
        self.last_sweeps = (0, 0)
        self.row_total = 0  # the rows of the step's coupled solve (limits' and contacts'); 0: none
        self._parity = 1  # the direction of the position sweeps' first sweep, alternated call by call
        self.warm_start = False
        """Start each step's sweeps from the last step's impulses of the contacts that go on (same bodies,
        anchor within WARM_DISTANCE): a box resting alone then takes 2 sweeps a step instead of 16-18, but a
        stack of 10 boxes, whose sweeps stop short, gathers kinetic energy (docs/contacts.md, "Warm starting"),
        so it is off by default. Needs (bodies + 1)^2 < 2^31 (the pairs' keys are int32)."""
        self._keys_fit = (n + 1) ** 2 < 2**31
        self.position_slop = 0.0 if solver == "paper" else POSITION_SLOP
        """`POSITION_SLOP`; 0 closes pushing contacts to touching (as before). Set before the first step. The
        "paper" solver closes them to touching: with its one sweep a prediction, half a tolerance left in place
        keeps contacts at the tolerance's edge, and the next prediction finds them deeper (10-box stack at 1e-4 m,
        1 s: 59 of 60 steps short of the tolerance at 0.5, 9 of 60 at 0; docs/contacts.md)."""
        self.take_back = True
        """The velocity phase may take back what the position phase pushed (the contact's total impulse over the
        step pushes): a position correction then leaves no speed apart. False: each phase pushes alone (the
        pile jitters at a coarse tolerance, docs/contacts.md). Set before the first step."""
        self._kept, self._kept_h = 0, 0.0  # the last step's solved contacts (kept in `data.kept_*`), its h
        self._solved = False  # the last step's velocity phase ran on its contacts: the next detection keeps them
        self._warm_pending = False  # the position phase's first solve of the step starts from the kept impulses
        self.joints, self.rows = None, None
        jointed = np.zeros(n, dtype=np.int32)
        if joints is not None:
            h = model.host
            jointed[h.constraint_body0[h.constraint_body0 >= 0]] = 1
            jointed[h.constraint_body1[h.constraint_body1 >= 0]] = 1
        if np.any(jointed[colliders]):
            self.joints = joints
            self._allocate_rows(jointed)

    # ---------------------------------------------------------------- arrays and launches
    def _allocate_rows(self, jointed: np.ndarray) -> None:
        """The coupled solve's arrays: rows for the limits and for CONTACT_ROW_SLOTS contacts."""
        d, m = self.model.device, self.model
        rows = m.limit_count + 3 * CONTACT_ROW_SLOTS
        nc = m.constraint_count
        z = wp.zeros
        self.rows = SimpleNamespace(
            body_jointed=_array(jointed, wp.int32, d),
            row_contact=z(CONTACT_ROW_SLOTS, dtype=wp.int32, device=d),
            row_count=z(1, dtype=wp.int32, device=d),
            row_body=z(rows, dtype=wp.vec2i, device=d),
            **{f"row_{name}": z(rows, dtype=wp.vec3d, device=d) for name in ("lin0", "ang0", "lin1", "ang1")},
            row_direction=z(rows, dtype=wp.vec3d, device=d),
            row_coupling=z(rows * nc, dtype=wp.vec3d, device=d),
            row_response=z(rows * nc, dtype=wp.vec3d, device=d),
            row_matrix=z(rows * rows, dtype=wp.float64, device=d),
            row_work=z(rows * rows, dtype=wp.float64, device=d),
            row_mask=z(rows, dtype=wp.int32, device=d),
            row_free=z(rows, dtype=wp.int32, device=d),
            **{f"row_{name}": z(rows * rows, dtype=wp.float64, device=d) for name in ("solved", "reduced")},
            **{f"row_{name}": z(rows, dtype=wp.float64, device=d)
               for name in ("goal", "before", "low", "high", "delta", "scratch", "column", "y",
                                                                "reduced_goal")},
        )  # fmt: skip
        self._row_slices = [
            (self.rows.row_coupling[r * nc : (r + 1) * nc], self.rows.row_response[r * nc : (r + 1) * nc])
            for r in range(rows)
        ]
        self._row_solves: list[list | None] = [None] * rows  # each row's solve with K's factor (`_row_solve`)

    def _allocate(self, pairs: int, contacts: int) -> None:
        """Arrays for this many pairs and contacts."""
        d = self.model.device
        z = wp.zeros
        self.data = SimpleNamespace(
            contact_row=wp.full(contacts, -1, dtype=wp.int32, device=d),
            contact_key=z(2 * contacts, dtype=wp.float32, device=d),
            contact_order=z(2 * contacts, dtype=wp.int32, device=d),
            pair_count=z(1, dtype=wp.int32, device=d),
            pair_body=z(pairs, dtype=wp.vec2i, device=d),
            contact_count=z(1, dtype=wp.int32, device=d),
            contact_body=z(contacts, dtype=wp.vec2i, device=d),
            contact_anchor_a=z(contacts, dtype=wp.vec3d, device=d),
            contact_anchor_b=z(contacts, dtype=wp.vec3d, device=d),
            contact_radius=z(contacts, dtype=wp.vec2d, device=d),
            contact_normal=z(contacts, dtype=wp.vec3d, device=d),
            contact_material=z(contacts, dtype=wp.vec2d, device=d),
            contact_impact=z(contacts, dtype=wp.float64, device=d),
            contact_gap=z(contacts, dtype=wp.float64, device=d),
            contact_arm_a=z(contacts, dtype=wp.vec3d, device=d),
            contact_arm_b=z(contacts, dtype=wp.vec3d, device=d),
            contact_slip=z(contacts, dtype=wp.vec3d, device=d),
            contact_u0=z(contacts, dtype=wp.vec3d, device=d),
            contact_mass=z(contacts, dtype=wp.vec2d, device=d),
            contact_approach=z(contacts, dtype=wp.float64, device=d),
            contact_impulse=z(contacts, dtype=wp.vec3d, device=d),
            contact_velocity_impulse=z(contacts, dtype=wp.vec3d, device=d),
            contact_error=z(3, dtype=wp.float64, device=d),
            contact_match=wp.full(contacts, -1, dtype=wp.int32, device=d),
            contact_warm=z(contacts, dtype=wp.vec3d, device=d),
            contact_warm_velocity=z(contacts, dtype=wp.vec3d, device=d),
            kept_body=z(contacts, dtype=wp.vec2i, device=d),
            kept_anchor_b=z(contacts, dtype=wp.vec3d, device=d),
            kept_normal=z(contacts, dtype=wp.vec3d, device=d),
            kept_impulse=z(contacts, dtype=wp.vec3d, device=d),
            kept_velocity_impulse=z(contacts, dtype=wp.vec3d, device=d),
            kept_key=z(2 * contacts, dtype=wp.int32, device=d),
            kept_order=z(2 * contacts, dtype=wp.int32, device=d),
        )
        self._kept = 0  # new arrays: nothing kept
        self._launches_by_h: dict[float, SimpleNamespace] = {}

    def _record(self, kernel, dim, **values):
        sources = (self.data, self.geometry, self.model, self.frames, self.control, self.rows, self.joints)
        p = self.pred
        return self._packed(record(kernel, dim, self.model.device, sources, self.state, self.state, pred_x=p.body_x,
                                   pred_q=p.body_q, pred_v=p.body_v, pred_w=p.body_w, **values))  # fmt: skip

    def _packed(self, launch):
        """A recorded launch as the stage runs it: on a CPU packed once (`launch.Packed`, ~0.3 us a call against
        ~3-5 us for a recorded launch, which packs its arguments again each call). The stage's launches run one
        at a time from the host and are never captured into a graph, which a packed launch would not enter."""
        return Packed(launch) if self.model.device.is_cpu and isinstance(launch, wp.Launch) else launch

    def _row_solve(self, r: int) -> list:
        """The launches of row r's solve with K's factor (`couple`): the solver's, packed on a CPU."""
        solves = self._row_solves[r]
        if solves is None:
            solves = self._row_solves[r] = [self._packed(launch) for launch in
                                            self.joints.linear.solve_launches(*self._row_slices[r])]  # fmt: skip
        return solves

    def _launches(self, h: float) -> SimpleNamespace:
        if h not in self._launches_by_h:
            g, data = self.geometry, self.data
            ncol, cap = g.collider_count, len(data.contact_body)
            broad = kernels.broad_phase if self.bvh is not None else kernels.all_pairs
            bounce = 2.0 * float(np.linalg.norm(self.model.host.gravity)) * h
            rows = None
            if self.rows is not None:
                nr, nc = len(self.rows.row_mask), self.model.constraint_count
                st = self.state
                cpu = self.model.device.is_cpu  # a row a thread: the rows' slots are mostly empty (`row_matrix`)
                bounce = 2.0 * float(np.linalg.norm(self.model.host.gravity)) * h
                rows = SimpleNamespace(
                    assign=self._record(row_kernels.assign_rows, 1),
                    jacobians=[self._record(row_kernels.row_jacobians, nr, velocity=v) for v in (0, 1)],
                    coupling=self._record(row_kernels.row_coupling, (nr, 1 if cpu else nc), span=nc if cpu else 1),
                    matrix=self._record(row_kernels.row_matrix, (nr, 1 if cpu else nr), span=nr if cpu else 1),
                    solve=[
                        self._record(row_kernels.solve_rows, 1, h=h, body_v=st.body_v, body_w=st.body_w, velocity=v,
                                     limit_impulse=self.joints.limit_impulse, max_sweeps=ROW_SWEEPS,
                                     bounce_speed=bounce,
                                     tolerance=self.tolerance if v == 0 else self.velocity_tolerance * h)
                        for v in (0, 1)
                    ],
                )  # fmt: skip
            self._launches_by_h[h] = SimpleNamespace(
                rows=rows,
                bounds=self._record(kernels.swept_bounds, ncol),
                broad=self._record(broad, ncol, lowers=g.lowers, uppers=g.uppers),
                narrow=self._record(kernels.narrow_phase, len(data.pair_body)),
                planes=self._record(kernels.plane_phase, (ncol, self.plane_count)),
                keys=self._record(kernels.contact_keys, cap, gravity=wp.vec3d(*self.model.host.gravity)),
                keep=self._record(kernels.keep_contacts, cap, body_count=g.body_count),
                warm=self._record(kernels.warm_positions, 1),
                measure=self._record(kernels.measure, cap, inv_h=1.0 / h),
                positions=[
                    self._record(
                        kernels.solve_positions,
                        1,
                        h=h,
                        sweeps=self.sweeps,
                        tolerance=0.1 * self.tolerance,
                        slop=self.position_slop * self.tolerance,
                        parity=parity,
                    )
                    for parity in (0, 1)
                ],  # fmt: skip
                velocities=[
                    self._record(
                        kernels.solve_velocities,
                        1,
                        sweeps=VELOCITY_SWEEPS * self.max_sweeps,
                        tolerance=0.1 * self.velocity_tolerance,
                        bounce_speed=bounce,
                        inv_h=1.0 / h,
                        first=first,
                        take_back=1.0 if self.take_back else 0.0,
                    )
                    for first in (1, 0)
                ],  # fmt: skip
            )
        return self._launches_by_h[h]

    # ---------------------------------------------------------------- the stage
    def detect(self, h: float) -> int:
        """Contacts of the current prediction (swept from the state at t0); returns their number. The arrays
        grow and detection reruns when a scene has more pairs or contacts than they hold. The last step's
        contacts, once solved, are kept first, and each new one is matched to the one it continues (its
        impulses start this step's sweeps, `warm_start`)."""
        if self._solved and self.warm_start:  # the last step's contacts, solved: kept for the match
            self._launches(h).keep.launch()
            self._kept, self._solved = self.count, False
            if self._kept > 1:
                sort_pairs(self.data.kept_key, self.data.kept_order, self._kept)
        self._warm_pending = False
        while True:
            run = self._launches(h)
            run.bounds.launch()
            if self.bvh is not None:
                self.bvh.rebuild()
            self.data.pair_count.zero_()
            self.data.contact_count.zero_()
            self.data.contact_impulse.zero_()
            run.broad.launch()
            run.narrow.launch()
            if self.plane_count:
                run.planes.launch()
            pairs, count = int(self.data.pair_count.numpy()[0]), int(self.data.contact_count.numpy()[0])
            if pairs <= len(self.data.pair_body) and count <= len(self.data.contact_body):
                self.count, self.pair_total = count, pairs
                run.keys.launch()  # the sweeps' order: from the bottom up
                if count > 1:
                    sort_pairs(self.data.contact_key, self.data.contact_order, count)
                self._match(h)
                return count
            self._allocate(max(pairs, len(self.data.pair_body)) * 2, max(count, len(self.data.contact_body)) * 2)

    def _match(self, h: float) -> None:
        """Each new contact's match among the kept ones and the impulses its phases start from."""
        self.data.contact_match.fill_(-1)
        if not (self.warm_start and self._keys_fit and self._kept and self.count):
            self._kept = 0
            return
        values = dict(body_count=self.geometry.body_count, distance=WARM_DISTANCE, scale=h / self._kept_h,
                      kept_count=self._kept)  # fmt: skip
        inputs = kernels_arguments(kernels.match_contacts, (self.data,), **values)
        wp.launch(kernels.match_contacts, dim=self.count, inputs=inputs, device=self.model.device)
        self._warm_pending = True

    def measure(self, h: float) -> float:
        """The deepest penetration of the current prediction (m; 0 when none)."""
        if not self.count:
            return 0.0
        self.data.contact_error.zero_()
        self._launches(h).measure.launch()
        return max(float(self.data.contact_error.numpy()[0]), 0.0)

    def couple(self, h: float, velocity: int = 0) -> int:
        """After `detect` (position pass) or the velocity phase's measurement (`velocity` 1): the rows of this
        step's contacts on jointed bodies, solved with the joints, limits and motors
        (`kernels/contact_rows.py`): their Jacobians at the contact points, one solve with K's factor each, the
        rows' system S. Returns the rows (0: none)."""
        self.row_total = 0
        if self.rows is None or not self.count:
            return 0
        run = self._launches(h).rows
        if velocity == 0:
            self.measure(h)
            run.assign.launch()
        nl, nc = self.model.limit_count, self.model.constraint_count
        total = int(self.rows.row_count.numpy()[0])
        if total == nl:
            return 0
        run.jacobians[velocity].launch()
        run.coupling.launch()
        if nl:  # the limits' rows: their K^-1 c of this step (the Simulator's)
            wp.copy(self.rows.row_response, self.joints.limit_response, count=nl * nc)
        for r in range(nl, total):
            for launch in self._row_solve(r):
                launch.launch()
        run.matrix.launch()
        self.row_total = total
        return total

    def solve_positions(self, h: float) -> int:
        """Impulses at t0 (into the state's velocities) that close the measured gaps; returns the sweeps taken.
        With rows (`couple`), the contacts on jointed bodies, the limits and the motors first, all at once."""
        if not self.count:
            return 0
        sweeps = 0
        if self._warm_pending:  # the first solve of the step: from the kept impulses
            self._launches(h).warm.launch()
            self._warm_pending = False
        if self.row_total:
            self._launches(h).rows.solve[0].launch()
            sweeps = int(self.data.contact_error.numpy()[1])
        self._parity ^= 1
        self._launches(h).positions[self._parity].launch()
        return sweeps + int(self.data.contact_error.numpy()[1])

    def solve_velocities(self, h: float, first: bool = True) -> int:
        """Restitution and friction at t0+h on the state; returns the sweeps taken. The `first` solve of a step
        starts from the position phase's impulses, a later one (after the joints' velocity correction) goes on
        from the last."""
        if first:  # the step's contacts are solved: the next detection keeps them
            self._solved, self._kept_h = self.count > 0, h
            self._kept = self._kept if self.count else 0
        if not self.count:
            return 0
        self._launches(h).velocities[0 if first else 1].launch()
        sweeps = int(self.data.contact_error.numpy()[2])
        if first and self.rows is not None:
            self.couple(h, velocity=1)  # at t0 + h
        if self.row_total:
            self._launches(h).rows.solve[1].launch()
            sweeps += int(self.data.contact_error.numpy()[2])
        return sweeps

    def contacts(self) -> Contacts:
        """The last step's contacts as numpy (`Contacts`), at the current state."""
        k = self.count
        data = self.data
        body = data.contact_body.numpy()[:k]
        a, b = body[:, 0], body[:, 1]
        x, q = self.state.body_x.numpy(), self.state.body_q.numpy()
        radius = data.contact_radius.numpy()[:k]
        normal = data.contact_normal.numpy()[:k]
        point = _world(b, data.contact_anchor_b.numpy()[:k], x, q) - normal * radius[:, 1:]
        other = _world(a, data.contact_anchor_a.numpy()[:k], x, q) + normal * radius[:, :1]
        depth = -np.einsum("ij,ij->i", normal, point - other)
        impulse = data.contact_impulse.numpy()[:k] + data.contact_velocity_impulse.numpy()[:k]
        t1, t2 = _tangents(normal)
        friction = t1 * impulse[:, 1:2] + t2 * impulse[:, 2:3]
        return Contacts(a.copy(), b.copy(), point, normal, depth, impulse[:, 0].copy(), friction)


def _world(body: np.ndarray, anchor: np.ndarray, x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Anchors in their bodies' frames to world points (world anchors where body < 0): the cores of the
    contact points (`contact_solve.surface_points` adds the radii)."""
    out = anchor.copy()
    on = body >= 0
    if np.any(on):
        out[on] = x[body[on]] + quat_rotate(q[body[on]], anchor[on])
    return out


def _tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangent basis `collide.any_perpendicular` builds on the device, for the same normals."""
    t = np.where(np.abs(n[:, :1]) > 0.7, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(n, t)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    return t1, np.cross(n, t1)
