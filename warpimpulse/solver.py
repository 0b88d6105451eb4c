"""Linear solvers for K lambda = rhs behind one interface: `prepare()` once per step, `solve()` per use.

- CholeskySolver: block L L^T on the host's symbolic pattern, numeric work in Warp kernels. Factored
  once a step and reused for the velocity correction and the next joint correction (section 4.5).
- CGSolver: block-Jacobi preconditioned, warm-started conjugate gradient in Warp kernels.
The paper's iterative method without a system needs no linear solver; see `simulator.py`.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import warp as wp

from .diagnose import mass_ratio_note
from .kernels import assemble as assemble_kernels
from .kernels import cg as cg_kernels
from .kernels import cholesky as cholesky_kernels
from .kernels.constraints import constant_frames
from .kernels.inertia import sym33d
from .launch import record
from .model import Model
from .topology import schedule
from .types import ConstraintKind

LOOP_TOLERANCE_FLOOR = 1e-6
"""The smallest `loop_tolerance`: a loop row's pivot below this fraction of its diagonal is redundant at any
joint tolerance. Round-off in the elimination of a mechanism's tree leaves its redundant loop pivots well above
1e-16: on the walking machine standing on its feet at tolerance 1e-6, up to about 1e-7 of their diagonal (at
1e-9 or 1e-7, 9 or 10 of its 12 redundant rows were found, and one velocity correction gave impulses of 1e6 to
1e8 N s where 0.4 do)."""

MISALIGNMENT_LENGTH = 0.03
"""m: the shortest lever a joint tolerance is read over (`loop_tolerance_for`)."""


def loop_tolerance_for(tolerance: float) -> float:
    """The pivot fraction below which a loop joint's row counts as redundant when the joints hold to `tolerance`
    (m or rad): max(1e-6, (tolerance / 0.03 m)^2).

    A planar loop's out-of-plane rows repeat the tree's only while its axes are parallel; joints left within the
    tolerance tilt them by up to eps ~ tolerance / lever, and the rows' pivot is then ~eps^2 of its diagonal,
    not round-off. Unregularised, such a pivot turns the tilt's inconsistent errors into impulses of 1/eps times
    the consistent ones: the free walking machine at tolerance 1e-3 (pivots ~1e-7) threw its cranks to
    hundreds of rad/s within three steps under a 300 N push (tests/test_mechanisms.py)."""
    return max(LOOP_TOLERANCE_FLOOR, (tolerance / MISALIGNMENT_LENGTH) ** 2)


class SingularSystemError(RuntimeError):
    """K is singular: redundant or degenerate constraints. `where` names the joint or body whose pivot was lost
    ('' when the message is about something else), so that a caller who knows the cause can say it there."""

    def __init__(self, message: str, where: str = "") -> None:
        super().__init__(message)
        self.where = where


class Frames:
    """Per-step geometry the solvers share: P_i, J_ib and the world inverse inertias."""

    def __init__(self, model: Model) -> None:
        d, nb = model.device, model.body_count
        proj, jac_lin, jac_ang = constant_frames(model.host.constraint_kind)  # the blocks no pose changes
        self.proj = wp.array(proj, dtype=wp.mat33d, device=d)
        self.jac_lin = wp.array(jac_lin, dtype=wp.mat33d, device=d)
        self.jac_ang = wp.array(jac_ang, dtype=wp.mat33d, device=d)
        # A point constraint's J_ang = [s]x per row as s alone: what apply and J v read (24 bytes, not 72).
        self.jac_skew = wp.zeros(2 * model.constraint_count, dtype=wp.vec3d, device=d)
        # J~^-1 of every body as its upper triangle (`kernels/inertia.py`: 48 bytes, not 72).
        self.inv_inertia_world = wp.zeros(nb, dtype=sym33d, device=d)


def _int(values, device) -> wp.array:
    return wp.array(np.ascontiguousarray(values, dtype=np.int32), dtype=wp.int32, device=device)


def _float(values, device) -> wp.array:
    return wp.array(np.ascontiguousarray(values, dtype=np.float64), dtype=wp.float64, device=device)


def _slots(row, col, sides, device) -> SimpleNamespace:
    """The slots of K to assemble: (row constraint, col constraint) and the sides of the bodies they share."""
    return SimpleNamespace(
        slot_row=_int(row, device),
        slot_col=_int(col, device),
        slot_sides=wp.array(np.asarray(sides, np.int32).reshape(-1, 4), dtype=wp.vec4i, device=device),
    )


class CholeskySolver:
    """Block L S L^T of K, or of the augmented body-joint matrix where that is cheaper (`Topology.pattern`);
    either way `solve` returns the constraint impulses lambda of K lambda = rhs."""

    name = "cholesky"

    def __init__(
        self,
        model: Model,
        frames: Frames,
        pivot_tolerance: float = 1e-14,
        formulation: str = "auto",
        loop_tolerance: float = LOOP_TOLERANCE_FLOOR,
    ) -> None:
        """`loop_tolerance`: a pivot of a loop-closing joint's column below this times its diagonal is a row
        redundant with the tree (a planar four-bar's out-of-plane rows) and is regularised, not an error;
        `redundant_rows` counts them at the last factorization (kernels/cholesky.py, `factor`)."""
        self.model = model
        d = model.device
        pat = model.topology.pattern(formulation)
        self.pattern = pat
        n = len(pat.perm)
        self.values = wp.zeros(len(pat.col_row), dtype=wp.mat33d, device=d)
        self.singular = wp.zeros(2, dtype=wp.int32, device=d)  # first degenerate column + 1, redundant rows
        self._singular_host = None if d.is_cuda else self.singular.numpy()  # CPU memory, read without a copy
        self.redundant_rows = 0
        self._augmented = pat.formulation == "body"
        group_start, levels = schedule(pat, parallel=d.is_cuda)
        # The pattern on the device, under the names the kernels' parameters have.
        ints = ("perm", "col_start", "col_row", "update_start", "update_target", "update_a", "update_b",
                "row_start", "row_slot", "row_col", "slot_code", "slot_ref")  # fmt: skip
        self.device_pattern = SimpleNamespace(
            group_start=_int(group_start, d),
            col_sign=_float(pat.col_sign, d),
            col_loop=_int(self._loop_columns(model, pat), d),
            slot_shape=wp.array(self._slot_shape(model, pat), dtype=wp.vec2i, device=d),
            update_sign=_float(pat.update_sign, d),
            **{name: _int(getattr(pat, name), d) for name in ints},
        )
        if self._augmented:
            self._offset = 2 * model.body_count  # the constraints' place in the augmented vectors
            size = self._offset + model.constraint_count
            self._rhs, self._x = wp.zeros(size, dtype=wp.vec3d, device=d), wp.zeros(size, dtype=wp.vec3d, device=d)
            self._assemble = record(
                assemble_kernels.assemble_augmented,
                len(pat.col_row),
                d,
                (model, frames, self.device_pattern),
                values_out=self.values,
            )
        else:
            slots = _slots(pat.slot_row, pat.slot_col, pat.slot_sides, d)
            sources = (model, frames, self.device_pattern, slots)
            self._assemble = record(assemble_kernels.assemble_columns, n, d, sources, values_out=self.values)
        self.work = wp.zeros(n, dtype=wp.vec3d, device=d)
        # What the fused step (`kernels/step.py`) reads besides the pattern: the slots to assemble (K's, or the
        # augmented matrix's codes) and the augmented vectors.
        none = _int([], d)
        if self._augmented:
            slots = _slots([], [], np.zeros((0, 4)), d)
            slots.slot_code, slots.slot_ref = self.device_pattern.slot_code, self.device_pattern.slot_ref
            slots.aug_rhs, slots.aug_x = self._rhs, self._x
        else:
            slots.slot_code, slots.slot_ref = none, none
            slots.aug_rhs = slots.aug_x = wp.zeros(0, dtype=wp.vec3d, device=d)
        self.fused_args = SimpleNamespace(
            augmented=int(self._augmented),
            offset=getattr(self, "_offset", 0),
            pivot_tolerance=pivot_tolerance,
            loop_tolerance=loop_tolerance,
            **vars(slots),
        )
        sources = (self.device_pattern, self)
        self._factor = [
            record(
                cholesky_kernels.factor,
                count,
                d,
                sources,
                first_group=first,
                signs=int(self._augmented),
                pivot_tolerance=pivot_tolerance,
                loop_tolerance=loop_tolerance,
            )  # fmt: skip
            for first, count in levels
        ]
        self._levels = levels
        self._solves: dict[tuple[int, int], list[wp.Launch]] = {}

    @property
    def prepare_launches(self) -> list[wp.Launch]:
        """Assemble the matrix at the current frames and factor it; `check()` afterwards."""
        return [self._assemble, *self._factor]

    def prepare(self) -> None:
        for launch in self.prepare_launches:
            launch.launch()
        self.check()

    @staticmethod
    def _loop_columns(model: Model, pat) -> np.ndarray:
        """1 for the columns (in elimination order) of the constraints of loop-closing joints; none in the
        augmented matrix, whose constraint diagonal is 0: there no assembled scale tells redundancy apart."""
        if pat.formulation == "body":
            return np.zeros(len(pat.perm), dtype=np.int32)
        loops = np.zeros(model.joint_count, dtype=bool)
        loops[model.topology.loop_joints] = True
        return loops[model.constraint_joint[pat.perm]].astype(np.int32)

    @staticmethod
    def _slot_shape(model: Model, pat) -> np.ndarray:
        """(rows, columns) of each slot's block that are not structurally zero: its row unknown's dimension by
        its column unknown's. A constraint of dimension k < 3 is padded to 3 rows with a unit pivot and zeros
        elsewhere (`assemble.pad_unused_rows`, `Slot.PAD`), so rows k..2 of its blocks in L, and columns k..2,
        stay zero through the factor, which skips them (kernels/cholesky.py; the solves keep their full
        products: docs/architecture.md, "Cheaper stages"). A body's unknowns (the augmented matrix) have 3 rows."""
        dims = np.array([kind.dim for kind in ConstraintKind], dtype=np.int32)[model.host.constraint_kind]
        if pat.formulation == "body":
            dims = np.concatenate([np.full(2 * model.body_count, 3, dtype=np.int32), dims])
        dim = dims[pat.perm]  # by elimination position
        col = np.repeat(np.arange(len(pat.perm)), np.diff(pat.col_start))
        return np.ascontiguousarray(np.stack([dim[pat.col_row], dim[col]], axis=1), dtype=np.int32)

    def check(self) -> None:
        """Raise SingularSystemError naming the joint (or body) whose pivot the last factorization lost; note
        the rows of loop joints found redundant (`redundant_rows`)."""
        col, self.redundant_rows = (
            self._singular_host.tolist() if self._singular_host is not None else (int(x) for x in self.singular.numpy())
        )
        if self.redundant_rows:
            self.singular.zero_()
        if col:
            self.singular.zero_()
            unknown = int(self.pattern.perm[col - 1])
            m = self.model
            if self._augmented and unknown < self._offset:
                where, cause = f"body {m.body_name[unknown % m.body_count]!r}", "its mass or inertia"
            else:
                c = unknown - self._offset if self._augmented else unknown
                j = int(m.constraint_joint[c])
                where = f"joint {m.joint_name[j]!r} ({m.joint_type[j]}, constraint {c})"
                cause = "its constraints are redundant with others on the same bodies, or degenerate"
            # Masses 1e30 apart lose a pivot too: name them rather than call the joint redundant.
            raise SingularSystemError(f"the system matrix is singular at {where}: {mass_ratio_note(m) or cause}", where)

    def solve_launches(self, rhs: wp.array, out: wp.array) -> list[wp.Launch]:
        """The launches of one solve from `rhs` into `out`, recorded once per pair of arrays."""
        key = (rhs.ptr, out.ptr)
        if key not in self._solves:
            self._solves[key] = self._record_solve(rhs, out)
        return self._solves[key]

    def _record_solve(self, rhs: wp.array, out: wp.array) -> list[wp.Launch]:
        d = self.model.device
        launches = []
        if self._augmented:
            nc = self.model.constraint_count
            launches.append(self._copy(rhs, 0, -1.0, self._rhs, self._offset, nc))
            rhs, x = self._rhs, self._x
        else:
            x = out
        sources = (self.device_pattern, self)
        for first, count in self._levels:
            launches.append(record(cholesky_kernels.solve_forward, count, d, sources, first_group=first, rhs=rhs,
                                   y=self.work))  # fmt: skip
        for first, count in reversed(self._levels):
            launches.append(record(cholesky_kernels.solve_backward, count, d, sources, first_group=first, y=self.work,
                                   x=x))  # fmt: skip
        if self._augmented:
            launches.append(self._copy(x, self._offset, 1.0, out, 0, self.model.constraint_count))
        return launches

    def _copy(self, src, src_offset: int, scale: float, dst, dst_offset: int, count: int) -> wp.Launch:
        return record(cholesky_kernels.copy_scaled, count, self.model.device, src=src, src_offset=src_offset,
                      scale=scale, dst=dst, dst_offset=dst_offset)  # fmt: skip

    def solve(self, rhs: wp.array, out: wp.array, warm_key: str | None = None) -> int:
        for launch in self.solve_launches(rhs, out):
            launch.launch()
        return 1


class CGSolver:
    name = "cg"

    def __init__(self, model: Model, frames: Frames, tolerance: float = 1e-13, max_iterations: int | None = None):
        self.model = model
        self.tolerance = tolerance
        n = model.constraint_count
        self.max_iterations = max_iterations or max(10 * n, 100)
        d = model.device
        csr = model.topology.csr()
        self.values = wp.zeros(len(csr.col), dtype=wp.mat33d, device=d)
        slots = _slots(csr.row, csr.col, csr.sides, d)
        self._assemble = record(
            assemble_kernels.assemble, len(csr.col), d, (model, frames, slots), values_out=self.values
        )
        self.precond = wp.zeros(n, dtype=wp.mat33d, device=d)
        self.diag_slot = _int(csr.diag, d)
        self.row_start = _int(csr.start, d)
        self.col = _int(csr.col, d)
        self.b, self.x, self.r, self.p, self.q, self.z = (wp.zeros(n, dtype=wp.vec3d, device=d) for _ in range(6))
        self.scalars = wp.zeros(4, dtype=wp.float64, device=d)
        self._scalars_host = self.scalars.numpy() if not d.is_cuda else None
        self._warm: dict[str, wp.array] = {}
        self._diag = record(cg_kernels.diagonal_inverse, n, d, (self,))
        self._start = record(cg_kernels.cg_start, n, d, (self,))
        self._iteration = [
            record(kernel, 1 if kernel is cg_kernels.cg_rotate_scalars else n, d, (self,))
            for kernel in (
                cg_kernels.cg_rotate_scalars,
                cg_kernels.cg_matvec,
                cg_kernels.cg_step,
                cg_kernels.cg_direction,
            )
        ]
        self.iterations = 0

    @property
    def prepare_launches(self) -> list[wp.Launch]:
        return [self._assemble, self._diag]

    def prepare(self) -> None:
        for launch in self.prepare_launches:
            launch.launch()

    def check(self) -> None:
        """CG finds a singular K while it iterates (`solve`)."""

    def _rr(self) -> float:
        s = self._scalars_host if self._scalars_host is not None else self.scalars.numpy()
        return float(s[cg_kernels.RR])

    def solve(self, rhs: wp.array, out: wp.array, warm_key: str | None = None) -> int:
        """Iterate until |r| <= tolerance * |b|, from the last solution of `warm_key`. Returns the iterations."""
        wp.copy(self.b, rhs)
        b_norm = float(np.linalg.norm(self.b.numpy()))
        warm = self._warm.get(warm_key) if warm_key is not None else None
        if warm is not None:
            wp.copy(self.x, warm)
        else:
            self.x.zero_()
        self.scalars.zero_()
        self._start.launch()
        goal = (self.tolerance * b_norm) ** 2
        it = 0
        while self._rr() > goal and b_norm > 0.0 and it < self.max_iterations:
            for launch in self._iteration:
                launch.launch()
            it += 1
        if not math.isfinite(self._rr()):
            note = mass_ratio_note(self.model)
            raise FloatingPointError(
                f"CG diverged: the system matrix is singular or indefinite{'; ' + note if note else ''}"
            )
        wp.copy(out, self.x)
        if warm_key is not None:
            self._warm.setdefault(warm_key, wp.zeros_like(self.x))
            wp.copy(self._warm[warm_key], self.x)
        self.iterations = it
        return it
