"""Linear solvers for K lambda = rhs behind one interface: `prepare()` once per step, `solve()` per use.

- CholeskySolver: block L L^T on the host's symbolic pattern, numeric work in Warp kernels. Factored
  once a step and reused for the velocity correction and the next joint correction (section 4.5).
- CGSolver: block-Jacobi preconditioned, warm-started conjugate gradient in Warp kernels.
The paper's iterative method without a system needs no linear solver; see `simulator.py`.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .kernels import assemble as assemble_kernels
from .kernels import cg as cg_kernels
from .kernels import cholesky as cholesky_kernels
from .model import Model
from .topology import schedule


class SingularSystemError(RuntimeError):
    """K is singular: redundant or degenerate constraints."""


def _int(values, device) -> wp.array:
    return wp.array(np.ascontiguousarray(values, dtype=np.int32), dtype=wp.int32, device=device)


class Frames:
    """Per-step geometry the solvers share: P_i, J_ib and the world inverse inertias."""

    def __init__(self, model: Model) -> None:
        d, nb, nc = model.device, model.body_count, model.constraint_count
        self.proj = wp.zeros(nc, dtype=wp.mat33d, device=d)
        self.jac_lin = wp.zeros(2 * nc, dtype=wp.mat33d, device=d)
        self.jac_ang = wp.zeros(2 * nc, dtype=wp.mat33d, device=d)
        self.inv_inertia_world = wp.zeros(nb, dtype=wp.mat33d, device=d)


def _assemble_launch(model: Model, frames: Frames, row, col, sides, values) -> wp.Launch:
    d = model.device
    return wp.launch(
        assemble_kernels.assemble,
        dim=len(row),
        inputs=[
            model.constraint_kind, model.constraint_body0, model.constraint_body1, model.body_inv_mass,
            _int(row, d), _int(col, d), wp.array(np.asarray(sides, np.int32), dtype=wp.vec4i, device=d),
            frames.inv_inertia_world, frames.jac_lin, frames.jac_ang,
        ],
        outputs=[values],
        device=d,
        record_cmd=True,
    )  # fmt: skip


class CholeskySolver:
    name = "cholesky"

    def __init__(self, model: Model, frames: Frames, pivot_tolerance: float = 1e-12) -> None:
        self.model = model
        d = model.device
        pat = model.topology.pattern
        n = model.constraint_count
        self.values = wp.zeros(len(pat.slot_row), dtype=wp.mat33d, device=d)
        self.diag_inv = wp.zeros(n, dtype=wp.mat33d, device=d)
        self.work = wp.zeros(n, dtype=wp.vec3d, device=d)
        self.singular = wp.zeros(1, dtype=wp.int32, device=d)
        self._assemble = _assemble_launch(model, frames, pat.slot_row, pat.slot_col, pat.slot_sides, self.values)
        group_start, levels = schedule(pat, parallel=d.is_cuda)
        self._group_start = _int(group_start, d)
        self._perm = _int(pat.perm, d)
        col_start = _int(pat.col_start, d)
        factor_args = [
            self._group_start, col_start, _int(pat.update_start, d), _int(pat.update_target, d),
            _int(pat.update_a, d), _int(pat.update_b, d), wp.float64(pivot_tolerance),
            self.values, self.diag_inv, self.singular,
        ]  # fmt: skip
        self._factor = [
            wp.launch(cholesky_kernels.factor, dim=count, inputs=[first, *factor_args], device=d, record_cmd=True)
            for first, count in levels
        ]
        self._levels = levels
        self._forward_args = [_int(pat.row_start, d), _int(pat.row_slot, d), _int(pat.row_col, d)]
        self._backward_args = [col_start, _int(pat.col_row, d)]
        self._solves: dict[tuple[int, int], list[wp.Launch]] = {}

    def prepare(self) -> None:
        """Assemble K at the current frames and factor it."""
        self.singular.zero_()
        self._assemble.launch()
        for launch in self._factor:
            launch.launch()
        col = int(self.singular.numpy()[0])
        if col:
            c = int(self.model.topology.pattern.perm[col - 1])
            joint = self.model.builder.joints[self.model.builder.constraints[c].joint]
            raise SingularSystemError(
                f"the system matrix is singular at joint {joint.name!r} ({joint.kind}, constraint {c}): "
                "its constraints are redundant with others on the same bodies, or degenerate"
            )

    def _solve_launches(self, rhs: wp.array, out: wp.array) -> list[wp.Launch]:
        d = self.model.device
        fwd = [
            wp.launch(
                cholesky_kernels.solve_forward,
                dim=count,
                inputs=[
                    first,
                    self._group_start,
                    self._perm,
                    *self._forward_args,
                    self.values,
                    self.diag_inv,
                    rhs,
                    self.work,
                ],
                device=d,
                record_cmd=True,
            )  # fmt: skip
            for first, count in self._levels
        ]
        bwd = [
            wp.launch(
                cholesky_kernels.solve_backward,
                dim=count,
                inputs=[
                    first,
                    self._group_start,
                    self._perm,
                    *self._backward_args,
                    self.values,
                    self.diag_inv,
                    self.work,
                    out,
                ],
                device=d,
                record_cmd=True,
            )  # fmt: skip
            for first, count in reversed(self._levels)
        ]
        return fwd + bwd

    def solve(self, rhs: wp.array, out: wp.array, warm_key: str | None = None) -> int:
        key = (rhs.ptr, out.ptr)
        if key not in self._solves:
            self._solves[key] = self._solve_launches(rhs, out)
        for launch in self._solves[key]:
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
        pat = model.topology.pattern
        self.values = wp.zeros(len(pat.csr_col), dtype=wp.mat33d, device=d)
        self._assemble = _assemble_launch(model, frames, pat.csr_row, pat.csr_col, pat.csr_sides, self.values)
        self.precond = wp.zeros(n, dtype=wp.mat33d, device=d)
        self._diag = wp.launch(
            cg_kernels.diagonal_inverse, dim=n, inputs=[_int(pat.csr_diag, d), self.values, self.precond],
            device=d, record_cmd=True,
        )  # fmt: skip
        self.row_start = _int(pat.csr_start, d)
        self.col = _int(pat.csr_col, d)
        self.b, self.x, self.r, self.p, self.q, self.z = (wp.zeros(n, dtype=wp.vec3d, device=d) for _ in range(6))
        self.scalars = wp.zeros(4, dtype=wp.float64, device=d)
        self._scalars_host = self.scalars.numpy() if not d.is_cuda else None
        self._warm: dict[str, wp.array] = {}

        def rec(kernel, dim, inputs):
            return wp.launch(kernel, dim=dim, inputs=inputs, device=d, record_cmd=True)

        csr = [self.row_start, self.col, self.values]
        self._start = rec(cg_kernels.cg_start, n, [*csr, self.precond, self.b, self.x, self.r, self.p, self.scalars])
        self._iteration = [
            rec(cg_kernels.cg_rotate_scalars, 1, [self.scalars]),
            rec(cg_kernels.cg_matvec, n, [*csr, self.p, self.q, self.scalars]),
            rec(cg_kernels.cg_step, n, [self.precond, self.p, self.q, self.x, self.r, self.z, self.scalars]),
            rec(cg_kernels.cg_direction, n, [self.z, self.p, self.scalars]),
        ]
        self.iterations = 0

    def prepare(self) -> None:
        self._assemble.launch()
        self._diag.launch()

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
            raise FloatingPointError("CG diverged: the system matrix is singular or indefinite")
        wp.copy(out, self.x)
        if warm_key is not None:
            self._warm.setdefault(warm_key, wp.zeros_like(self.x))
            wp.copy(self._warm[warm_key], self.x)
        self.iterations = it
        return it


SOLVERS = {"cholesky": CholeskySolver, "cg": CGSolver}
