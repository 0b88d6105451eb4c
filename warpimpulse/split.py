"""One large tree on several threads: the fused step with the tree cut at its root (`kernels/split.py`).

The cut: the top bodies of the tree (the separator, often the root alone) are taken out, one at a time from the
largest subtree left, until the subtrees below them can be dealt to the threads with the largest share within
2 % of an even one (at most `MAX_SEPARATOR` bodies); of the cuts tried, the one whose largest share plus
separator is smallest is kept. Each thread owns a part: its subtrees' bodies, the
constraints it evaluates (those on its bodies, including the ones that join them to the separator) and the
columns of the factor whose constraints lie wholly in it. The rest (the separator's bodies, static bodies,
the constraints on them alone and every column that joins a part to the separator) is the separator's, taken
by the calling thread between the parts' launches:

- the start of a step: the separator predicts, then every part predicts, measures and forward-solves;
- a joint iteration: the separator forward-solves and backward-solves its columns, applies and predicts; then
  every part backward-solves, applies, predicts, measures and forward-solves;
- after the correction: the separator accepts its bodies and their frames; every part accepts, assembles,
  factors, measures its velocities and forward-solves; the separator assembles and factors its columns;
- the velocity correction, like a joint iteration.

The host takes the fused step's decisions (kernels/step.py, `cholesky_steps`) from the parts' maxima and
writes the same status rows, so everything else of the fused schedule (the batch of steps, a spin split or a
failed correction handed to the parallel schedule) is unchanged. Every element gets the same arithmetic in
the same order as in the fused step, so the run is the fused run bit for bit (tests/test_split.py).

The cut must respect the factor's order: a part's column may depend only on its own part's columns, and a
separator column's rows below the diagonal must be the separator's. Leaves-first elimination gives that for
trees; scenes where the cut does not hold (loops, one long chain, a scene the fused schedule does not run)
run on one thread, and `split_note` says why.
"""

from __future__ import annotations

import functools
import heapq
import math
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np
import warp as wp

from . import capabilities
from .kernels import split as split_kernels
from .kernels import step as step_kernels
from .kernels.split import OUT_BAD, OUT_ERROR, OUT_SPIN, OUT_VELOCITY_ERROR, OUT_WIDTH
from .launch import capture, record
from .model import Model
from .options import take as take_options
from .pool import run_shared
from .simulator import Simulator
from .steps import diverging

SEPARATOR = -1
MAX_SEPARATOR = 64  # bodies
BALANCE = 1.02  # the largest share may exceed an even one by this factor before the cut goes deeper


class CutError(ValueError):
    """The scene cannot be cut into independent parts (why, in the message)."""


def _deal(sizes: list[int], threads: int) -> tuple[int, list[int]]:
    """The subtrees, largest first, each to the least loaded thread: (the largest load, each one's thread)."""
    loads = [(0, t) for t in range(threads)]
    thread_of = [0] * len(sizes)
    for i in sorted(range(len(sizes)), key=lambda i: -sizes[i]):
        load, t = heapq.heappop(loads)
        thread_of[i] = t
        heapq.heappush(loads, (load + sizes[i], t))
    return max(load for load, _ in loads), thread_of


def _forest(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(parent of each body, -1 at a root or a static body; depth; dynamic) of a scene without loops."""
    g, topo = model.topology.graph, model.topology
    if topo.loop_joints:
        raise CutError(f"joint {model.joint_name[topo.loop_joints[0]]!r} closes a loop")
    dynamic = ~np.asarray(g.body_static, bool)
    b0, b1 = np.asarray(g.constraint_body0), np.asarray(g.constraint_body1)
    both = (b0 >= 0) & (b1 >= 0)
    both[both] &= dynamic[b0[both]] & dynamic[b1[both]]
    u, v = b0[both], b1[both]
    deeper = topo.depth[u] > topo.depth[v]
    child, par = np.where(deeper, u, v), np.where(deeper, v, u)
    pairs = np.unique(np.stack([child, par], axis=1), axis=0) if len(child) else np.zeros((0, 2), np.int64)
    parent = np.full(g.body_count, -1, dtype=np.int64)
    if len(np.unique(pairs[:, 0])) != len(pairs):
        raise CutError("a body has two parents (a loop)")
    parent[pairs[:, 0]] = pairs[:, 1]
    return parent, topo.depth, dynamic


def cut(model: Model, pattern, threads: int) -> SimpleNamespace:
    """The parts and the separator of the tree for `threads` threads (see the module docstring); CutError
    where the scene does not cut."""
    if pattern.formulation != "constraint":
        raise CutError(f"the factor is of the {pattern.formulation!r} formulation, not 'constraint'")
    parent, depth, dynamic = _forest(model)
    nb = len(parent)
    size = dynamic.astype(np.int64)
    levels = int(depth[dynamic].max()) if dynamic.any() else 0
    for d in range(levels, 0, -1):
        at = np.flatnonzero(dynamic & (depth == d) & (parent >= 0))
        np.add.at(size, parent[at], size[at])
    order = np.argsort(parent, kind="stable")
    first = np.searchsorted(parent[order], np.arange(nb + 1))  # children of b: order[first[b]:first[b + 1]]
    subtrees = [int(b) for b in np.flatnonzero(dynamic & (parent < 0))]
    separator: list[int] = []
    total = int(dynamic.sum())
    ideal = total / threads
    best = None
    while True:  # the cost of a cut: its largest share, and the separator's bodies after it
        load, thread_of = _deal([int(size[r]) for r in subtrees], threads)
        if best is None or load + len(separator) < best[0] + len(best[1]):
            best = (load, list(separator), list(subtrees), thread_of)
        if load <= BALANCE * ideal or len(separator) >= MAX_SEPARATOR or not subtrees:
            break
        top = max(subtrees, key=lambda r: size[r])
        subtrees.remove(top)
        separator.append(top)
        subtrees += [int(c) for c in order[first[top] : first[top + 1]]]
    load, separator, subtrees, thread_of = best
    owner = np.full(nb, -2, dtype=np.int64)
    owner[~dynamic] = SEPARATOR
    owner[separator] = SEPARATOR
    owner[subtrees] = thread_of
    for d in range(1, levels + 1):
        at = np.flatnonzero((owner == -2) & (depth == d))
        owner[at] = owner[parent[at]]
    if (owner == -2).any():
        raise CutError(f"body {model.body_name[int(np.flatnonzero(owner == -2)[0])]!r} is in no part")
    used = len(np.unique(owner[owner >= 0]))
    if used < 2:
        raise CutError(f"the tree does not split: its largest part holds {load} of {total} bodies")
    if load > 0.75 * total:
        raise CutError(f"the cut is uneven: one part holds {load} of {total} bodies")
    return _columns(model, pattern, owner, threads)


def _columns(model: Model, pattern, owner: np.ndarray, threads: int) -> SimpleNamespace:
    """Each constraint's evaluating part, each column's and slot's part, and the checks that make the parts
    independent in the factor's order."""
    g = model.topology.graph
    b0, b1 = np.asarray(g.constraint_body0), np.asarray(g.constraint_body1)
    static = np.asarray(g.body_static, bool)

    def part_of(b: np.ndarray) -> np.ndarray:  # -3 for the world or a static body (no part, no coupling)
        out = np.full(len(b), -3, dtype=np.int64)
        real = b >= 0
        real[real] &= ~static[b[real]]
        out[real] = owner[b[real]]
        return out

    o0, o1 = part_of(b0), part_of(b1)
    if ((o0 >= 0) & (o1 >= 0) & (o0 != o1)).any():
        raise CutError("a constraint joins two parts")
    evaluator = np.maximum(np.maximum(o0, o1), SEPARATOR)  # a part's where it touches one, else the separator
    alone = np.where(o0 == -3, o1, np.where(o1 == -3, o0, np.where(o0 == o1, o0, SEPARATOR)))
    column_part = np.maximum(alone, SEPARATOR)[pattern.perm]  # a part's where all its dynamic bodies are
    n = len(pattern.perm)
    col_of_slot = np.repeat(np.arange(n), np.diff(pattern.col_start))
    row_of = np.repeat(np.arange(n), np.diff(pattern.row_start))
    target_of = np.repeat(np.arange(n), np.diff(pattern.update_start))
    mine = column_part[row_of] >= 0
    bad_forward = mine & (column_part[pattern.row_col] != column_part[row_of])
    mine = column_part[target_of] >= 0
    bad_update = mine & (column_part[col_of_slot[pattern.update_a]] != column_part[target_of])
    below = pattern.col_row != col_of_slot
    bad_backward = below & (column_part[col_of_slot] == SEPARATOR) & (column_part[pattern.col_row] >= 0)
    row_evaluator = evaluator[pattern.slot_row]
    bad_assembly = (column_part[col_of_slot] >= 0) & (row_evaluator >= 0)
    bad_assembly &= row_evaluator != column_part[col_of_slot]
    checks = (("forward row", bad_forward, row_of), ("update", bad_update, target_of),
              ("backward column", bad_backward, col_of_slot), ("slot", bad_assembly, col_of_slot))  # fmt: skip
    for what, bad, col in checks:
        if bad.any():
            j = int(col[np.flatnonzero(bad)[0]])
            raise CutError(f"the factor's order couples the parts: the {what} of column {j} crosses the cut")

    def lists(p: int) -> dict[str, np.ndarray]:
        columns = np.flatnonzero(column_part == p)
        return dict(
            part_bodies=np.flatnonzero(owner == p),
            part_constraints=np.flatnonzero(evaluator == p),
            part_columns=columns,
        )

    return SimpleNamespace(separator=lists(SEPARATOR), parts=[lists(p) for p in range(threads)], owner=owner)


def _max_or_nan(a: float, b: float) -> float:
    """`step.max_or_nan` on the host: the parts' maxima combined as the fused loop combines elements."""
    return a + b if not (np.isfinite(a) and np.isfinite(b)) else max(a, b)


class SplitSimulator(Simulator):
    """A Simulator whose fused step runs one tree on `threads` threads (see the module docstring); where the
    tree does not cut, or the fused schedule does not run, one thread, with `split_note` saying why."""

    def __init__(self, model: Model, dt: float, threads: int = 2, **settings) -> None:
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        options = take_options(settings, "SplitSimulator")
        if threads > 1 and options.newton is None:  # the parts' steps have no Newton step: by default none
            options = options.replace(newton=False)
        if threads > 1 and options.reuse_factor is None:  # nor a kept factor (`reuse_factor`): by default none
            options = options.replace(reuse_factor=False)
        super().__init__(model, dt, options=options, **settings)
        self.threads, self.split_note = 1, ""
        if threads == 1:
            return
        gap = capabilities.first_gap("threads", self.features - {"loops"}, "falls back")  # loops: `cut` names one
        if gap is not None:
            self.split_note = gap[1].note
            return
        if self.accuracy is not None:
            self.split_note = "accuracy control changes the step size; the split step is recorded for one"
            return
        if self.schedule != "fused" or self.linear is None or model.device.is_cuda:
            self.split_note = f"the fused schedule does not run: {self.schedule_note or 'a GPU or free bodies'}"
            return
        try:
            parts = cut(model, self.linear.pattern, threads)
        except CutError as exc:
            self.split_note = str(exc)
            return
        if self.reuse_factor:
            raise ValueError("reuse_factor needs one thread: the split step factors K at every step (threads=1)")
        self.threads = threads
        self.cut = parts
        self._record_split(parts)
        self._pool = ThreadPoolExecutor(threads - 1, thread_name_prefix="warpimpulse-split")

    def close(self) -> None:
        if self.threads > 1:
            self._pool.shutdown()

    def _record_split(self, parts: SimpleNamespace) -> None:
        """A captured graph per part and phase (captured now: nothing may capture while the threads run)."""
        d, k = self.model.device, split_kernels.split_kernels(frozenset(self._fused.kinds))
        count = self.threads + 1  # row 0: the separator
        self._out = wp.zeros((count, OUT_WIDTH), dtype=wp.float64, device=d)
        self._singular = wp.zeros((count, 2), dtype=wp.int32, device=d)
        self._out_view, self._singular_view = self._out.numpy(), self._singular.numpy()
        p = self.pred
        c, c_next, *_ = self._carry_arrays((self.dt, 0)) if self.carry else (self.rhs, self.rhs)  # (`Simulator.carry`)
        scratch = dict(pred_x=p.body_x, pred_q=p.body_q, pred_v=p.body_v, pred_w=p.body_w, v0=self._v0, w0=self._w0,
                       carrying=int(self.carry), carry=c, carry_next=c_next)  # fmt: skip
        sources = (self.linear.fused_args, self.model, self.frames, self.control, self, self.linear.device_pattern,
                   self.linear)  # fmt: skip

        # The index lists on the device, kept (with the launches) as long as the graphs that read them.
        self._part_arrays = [
            {name: wp.array(v, dtype=wp.int32, device=d) for name, v in lists.items()}
            for lists in (parts.separator, *parts.parts)
        ]
        self._launches = []

        def graphs(row: int, kernel, **values) -> wp.Graph:
            launch = record(kernel, 1, d, sources, data_out=self._state, separator=int(row == 0),
                            part_out=self._out[row], part_singular=self._singular[row], **self._part_arrays[row],
                            **scratch, **values)  # fmt: skip
            self._launches.append(launch)
            return capture(d, launch)

        rows = range(count)
        self._start_graphs = [graphs(r, k.correct, start=1, first=0, h=self.dt) for r in rows]
        self._first_graphs = [graphs(r, k.correct, start=0, first=1, h=self.dt) for r in rows]
        self._iterate_graphs = [graphs(r, k.correct, start=0, first=0, h=self.dt) for r in rows]
        self._split_accept = graphs(0, k.refactor, accept=1, factor=0)
        self._refactor_graphs = [graphs(r, k.refactor, accept=int(r > 0), factor=1) for r in rows]
        self._velocity_graphs = [graphs(r, k.velocity_fix) for r in rows]
        self._restore = capture(
            d, lambda: wp.copy(self._state.body_v, self._v0), lambda: wp.copy(self._state.body_w, self._w0)
        )

    def _parts(self, graphs: list[wp.Graph]) -> None:
        """The parts' graphs at once, on this thread and the pool's (`pool.run_shared`: a pool thread woken late
        on a busy machine leaves its part to this one)."""
        run_shared(self._pool, self.threads - 1, [functools.partial(wp.capture_launch, g) for g in graphs])

    def _phase(self, graphs: list[wp.Graph]) -> None:
        """The separator's graph, then the parts'."""
        wp.capture_launch(graphs[0])
        self._parts(graphs[1:])

    def _combined(self, column: int) -> float:
        worst = 0.0
        for value in self._out_view[:, column].tolist():
            worst = _max_or_nan(worst, value)
        return worst

    def _run_fused(self, batch: int, hand_out: bool) -> tuple[np.ndarray, list[float]]:
        """Up to `batch` steps of dt, each as `kernels/step.py`'s `cholesky_steps` takes it, with the status
        rows it writes and their summary row's values; a launch of no step (the velocity correction a deferred
        step left, `Simulator.state`) is the one-thread kernel's, the same solve with the same factor."""
        if self.threads == 1 or batch == 0:
            return super()._run_fused(batch, hand_out)
        status = self._threaded_steps(batch, hand_out)
        s = step_kernels
        ok = 0
        while ok < batch and status[ok, s.STATUS_CODE] == s.OK:
            ok += 1
        rows, summary = status[:ok], status[-1]
        summary[:] = 0.0  # as `finish` sums the OK steps up
        summary[s.STATUS_CODE] = ok
        for column in (s.STATUS_JOINT_ITERATIONS, s.STATUS_VELOCITY_ITERATIONS, s.STATUS_LINEAR_ITERATIONS):
            summary[column] = rows[:, column].sum()
        if ok:
            summary[s.STATUS_JOINT_ERROR] = max(0.0, rows[:, s.STATUS_JOINT_ERROR].max())
            summary[s.STATUS_VELOCITY_ERROR] = rows[-1, s.STATUS_VELOCITY_ERROR]
            summary[s.STATUS_SPIN] = rows[-1, s.STATUS_SPIN]
        return status, summary.tolist()

    def _threaded_steps(self, batch: int, hand_out: bool) -> np.ndarray:
        """`_run_fused`'s steps, their status rows written here."""
        s = step_kernels
        status = self._views[0]
        h, spin = self.dt, self._spin
        max_rotation = self.max_rotation or 0.0
        final = self.max_substep_depth == 0
        lin_singular = self.linear.singular.numpy()

        def turns_too_far(spin: float) -> bool:
            return max_rotation > 0.0 and spin * abs(h) > max_rotation

        for k in range(batch):
            row = status[k]
            row[s.STATUS_SPIN] = spin
            if turns_too_far(spin):
                row[s.STATUS_CODE] = s.SPLIT
                return status
            self._phase(self._start_graphs)
            err = self._combined(OUT_ERROR)
            iterations, best, ok = 0, err, False
            while np.isfinite(err):
                best = min(best, err)
                if err <= self.tolerance:
                    ok = True
                    break
                if iterations >= self.max_iterations or diverging(err, best, iterations):
                    break
                self._phase(self._iterate_graphs if iterations else self._first_graphs)
                err = self._combined(OUT_ERROR)
                iterations += 1
            new_spin = spin
            if ok:
                new_spin = float(self._out_view[:, OUT_SPIN].max())
                if self._out_view[:, OUT_BAD].sum() > 0 or (not final and turns_too_far(new_spin)):
                    ok = False
            row[s.STATUS_JOINT_ITERATIONS] = iterations
            row[s.STATUS_JOINT_ERROR] = err
            if not ok:  # the failed attempt's work, as the fused kernel writes it (one stage, no velocity pass)
                wp.capture_launch(self._restore)
                row[s.STATUS_VELOCITY_ITERATIONS] = 0
                row[s.STATUS_LINEAR_ITERATIONS] = iterations
                row[s.STATUS_CODE] = s.RETRY
                return status
            spin = new_spin
            wp.capture_launch(self._split_accept)
            self._parts(self._refactor_graphs[1:])
            wp.capture_launch(self._refactor_graphs[0])
            singular = self._singular_view
            lin_singular[1] = singular[:, 1].sum()
            first = singular[:, 0][singular[:, 0] > 0]
            if lin_singular[0] == 0 and len(first):
                lin_singular[0] = first.min()
            singular[:] = 0
            verr, velocity_iterations = math.nan, 0  # deferred: not measured (`Simulator.defer_velocities`)
            corrected = not self.defer_velocities or (hand_out and k == batch - 1)
            if corrected:
                verr = self._combined(OUT_VELOCITY_ERROR)
            if corrected and not verr <= self.velocity_tolerance:
                self._phase(self._velocity_graphs)
                verr = self._combined(OUT_VELOCITY_ERROR)
                velocity_iterations = 1
            row[s.STATUS_VELOCITY_ITERATIONS] = velocity_iterations
            row[s.STATUS_VELOCITY_ERROR] = verr
            row[s.STATUS_LINEAR_ITERATIONS] = iterations + velocity_iterations
            row[s.STATUS_SPIN] = spin
            code = s.OK
            if lin_singular[0] != 0:
                code = s.SINGULAR
            elif corrected and not verr <= self.velocity_tolerance:
                code = s.VELOCITY
            row[s.STATUS_FAILED_VELOCITY] = _max_or_nan(0.0, verr) if code == s.VELOCITY else 0.0
            row[s.STATUS_CODE] = code
            if self.carry and iterations and code in (s.OK, s.VELOCITY):  # the step is kept: so is its c
                self._keep_carry((self.dt, 0))
            if code != s.OK:
                return status
        return status
