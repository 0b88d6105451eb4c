"""Host-side symbolic analysis, once per topology: elimination order, fill pattern, slots, schedules.

Two formulations of one linear system (see `Pattern`). In K = J M^-1 J^T the unknowns are the basic
constraints (3 rows each), coupled when they share a dynamic body (method paper, section 4.5). For a
tree, ordering the constraints deepest body first is a perfect elimination order: no fill, linear cost,
unless a body carries many joints (a star), whose constraints form a dense block. The augmented matrix
of bodies and constraints keeps such scenes linear. Joints that close loops (section 4.6) go last.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .types import WORLD, Slot


@dataclass(frozen=True)
class Graph:
    """The scene's connectivity as arrays: all the symbolic analysis reads. Body indices are WORLD (-1) for the
    world; a static body is fixed like the world but has an index (and a pose)."""

    body_static: np.ndarray  # (bodies,) bool
    constraint_body0: np.ndarray  # (constraints,) int: the parent side of each basic constraint
    constraint_body1: np.ndarray  # (constraints,) int: the child side
    constraint_joint: np.ndarray  # (constraints,) int: the joint a constraint belongs to
    joint_parent: np.ndarray  # (joints,) int
    joint_child: np.ndarray  # (joints,) int
    world_count: int = 1  # batched worlds, world-major (`Model`): each world's unknowns are eliminated together
    joint_loop: np.ndarray | None = None  # (joints,) bool: close loops with these where there is a choice

    @property
    def body_count(self) -> int:
        return len(self.body_static)

    @property
    def constraint_count(self) -> int:
        return len(self.constraint_body0)

    @property
    def joint_count(self) -> int:
        return len(self.joint_parent)

    def body_world(self, b: int) -> int:
        return b * self.world_count // max(self.body_count, 1)

    def constraint_world(self, c: int) -> int:
        return c * self.world_count // max(self.constraint_count, 1)


@dataclass
class Pattern:
    """Index arrays of a block factor L S L^T (columns in elimination order), and how to assemble its blocks.

    Formulation "constraint": the unknowns are the basic constraints and the matrix is K = J M^-1 J^T
    (method paper, section 4.5). Formulation "body": the unknowns are every dynamic body's linear and angular
    velocity change and every constraint, and the matrix is the augmented [[M, J^T], [J, 0]] (Baraff 1996,
    "Linear-time dynamics using Lagrange multipliers"): eliminated bodies first, it stays as sparse as the
    scene's graph, so a body with many joints (a star) costs linear time where K is dense.
    Unknown numbering of "body": body b's linear part b, its angular part n_bodies + b, constraint c at
    2 n_bodies + c.
    """

    formulation: str
    perm: np.ndarray  # elimination position -> unknown
    # L: block column j owns slots col_start[j]..col_start[j+1]-1, diagonal first
    col_start: np.ndarray
    col_row: np.ndarray  # elimination position of each slot's row
    col_sign: np.ndarray  # S: +1 (K, or a body's pivot) or -1 (a constraint's pivot in the augmented matrix)
    update_start: np.ndarray
    update_target: np.ndarray
    update_a: np.ndarray
    update_b: np.ndarray
    update_sign: np.ndarray  # S of the column an update comes from
    row_start: np.ndarray  # forward solve: row j's off-diagonal slots and their columns
    row_slot: np.ndarray
    row_col: np.ndarray
    height: np.ndarray  # of each column in the elimination tree (0 = leaf)
    # assembly, "constraint": the two constraints of a slot and (side in row, side in col) of the bodies they
    # share; "body": what a slot holds (a `types.Slot` code) and the body or Jacobian row it comes from
    slot_row: np.ndarray
    slot_col: np.ndarray
    slot_sides: np.ndarray
    slot_code: np.ndarray
    slot_ref: np.ndarray

    @property
    def updates(self) -> int:
        return len(self.update_target)


@dataclass
class BlockCSR:
    """The full K in block CSR for CG; rows and columns are constraints."""

    start: np.ndarray
    col: np.ndarray
    row: np.ndarray
    sides: np.ndarray
    diag: np.ndarray


@dataclass
class Topology:
    graph: Graph
    body_rows_start: np.ndarray  # per body: its Jacobian rows (2 * constraint + side)
    body_rows: np.ndarray
    depth: np.ndarray  # of every body in the spanning tree
    loop_joints: list[int]  # joints that close a kinematic loop
    level_order: bool  # columns sorted by elimination-tree height: the parallel schedule of a GPU

    def __post_init__(self) -> None:
        self._patterns: dict[str, Pattern] = {}
        self._csr: BlockCSR | None = None

    def pattern(self, formulation: str = "auto") -> Pattern:
        """The factor pattern of `formulation`, built once. "auto" takes K while every body has few
        constraints (then K is as sparse as it gets, and smaller), else the one with fewer block updates. With
        loop-closing joints "auto" takes K: their redundant rows are judged against K's assembled diagonal
        (`kernels/cholesky.py`), which the augmented matrix does not have (its constraint diagonal is 0)."""
        if formulation == "auto" and self.loop_joints:
            formulation = "constraint"
        if formulation == "auto":
            cost = constraint_cost(self.graph)
            small = cost <= 8.0 * (self.graph.body_count + self.graph.constraint_count)
            formulation = "constraint" if small or self.pattern("body").updates >= cost else "body"
        if formulation not in self._patterns:
            build = {"constraint": constraint_pattern, "body": body_pattern, "split": split_pattern}[formulation]
            pattern = build(self.graph, self.depth, self.loop_joints)
            if self.level_order:
                order = np.argsort(pattern.height, kind="stable")
                pattern = build(self.graph, self.depth, self.loop_joints, pattern.perm[order])
            self._patterns[formulation] = pattern
        return self._patterns[formulation]

    def csr(self) -> BlockCSR:
        if self._csr is None:
            self._csr = block_csr(self.graph)
        return self._csr


def _bodies(graph: Graph, c: int) -> tuple[int, int]:
    return int(graph.constraint_body0[c]), int(graph.constraint_body1[c])


def _dynamic(graph: Graph, b: int) -> bool:
    return b != WORLD and not graph.body_static[b]


def shared_sides(graph: Graph, i: int, j: int) -> list[int]:
    """(side in i, side in j) for each dynamic body that constraints i and j share, flattened, -1 padded."""
    out: list[int] = []
    bi, bj = _bodies(graph, i), _bodies(graph, j)
    for si in (0, 1):
        if _dynamic(graph, bi[si]):
            for sj in (0, 1):
                if bj[sj] == bi[si]:
                    out += [si, sj]
    return (out + [-1, -1, -1, -1])[:4]


def _spanning_tree(graph: Graph) -> tuple[np.ndarray, list[int]]:
    """Depth of every body from the world (or from a root per floating island), and the loop joints: those
    the breadth-first spanning tree does not use. Joints marked `joint_loop` (USD's excludeFromArticulation)
    join the tree only where no other joint reaches a body, so they close the loops when the scene says so."""
    n = graph.body_count
    hinted = np.zeros(graph.joint_count, bool) if graph.joint_loop is None else np.asarray(graph.joint_loop, bool)
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    grounded: list[tuple[int, int]] = []
    for ji, (parent, child) in enumerate(zip(graph.joint_parent.tolist(), graph.joint_child.tolist())):
        if parent == WORLD or graph.body_static[parent]:
            grounded.append((child, ji))
        else:
            adjacency[parent].append((child, ji))
            adjacency[child].append((parent, ji))
    for b in np.flatnonzero(graph.body_static).tolist():
        grounded.append((b, -1))
    depth = np.full(n, -1, dtype=np.int64)
    tree_joints: set[int] = set()
    queue: deque[int] = deque()

    def grow(allow_hinted: bool) -> None:
        while queue:
            b = queue.popleft()
            for other, ji in adjacency[b]:
                if depth[other] < 0 and (allow_hinted or not hinted[ji]):
                    depth[other] = depth[b] + 1
                    tree_joints.add(ji)
                    queue.append(other)

    for allow_hinted in (False, True):
        for b, ji in grounded:
            if depth[b] < 0 and (allow_hinted or ji < 0 or not hinted[ji]):
                depth[b] = 0
                queue.append(b)
                tree_joints.add(ji)
        if allow_hinted:  # grow on from everything reached, now through the marked joints too
            queue.extend(sorted(np.flatnonzero(depth >= 0).tolist(), key=lambda b: depth[b]))
        grow(allow_hinted)
    for b in range(n):  # floating islands: root at their first body
        if depth[b] < 0:
            depth[b] = 0
            queue.append(b)
            grow(True)
    loops = [ji for ji in range(graph.joint_count) if ji not in tree_joints]
    return depth, loops


def elimination_order(graph: Graph, depth: np.ndarray, loop_joints: list[int]) -> np.ndarray:
    """Constraints deepest first; loop-closing joints last; a joint's constraints stay together. Batched worlds
    one after the other, each in the order it has alone (so each factors as it does alone, bit for bit, and a
    world's columns are contiguous)."""
    loops = set(loop_joints)
    keys = []
    for c in range(graph.constraint_count):
        level = max(depth[b] if b != WORLD else -1 for b in _bodies(graph, c))
        keys.append((graph.constraint_world(c), int(graph.constraint_joint[c]) in loops, -level, c))
    return np.array([k[-1] for k in sorted(keys)], dtype=np.int64)


def _constraints_on_bodies(graph: Graph) -> list[list[int]]:
    on_body: list[list[int]] = [[] for _ in range(graph.body_count)]
    for c in range(graph.constraint_count):
        for b in _bodies(graph, c):
            if _dynamic(graph, b):
                on_body[b].append(c)
    return on_body


def _coupling(graph: Graph) -> list[set[int]]:
    """Constraints sharing a dynamic body with each constraint (itself excluded)."""
    adj: list[set[int]] = [set() for _ in range(graph.constraint_count)]
    for cs in _constraints_on_bodies(graph):
        for c in cs:
            adj[c].update(cs)
    for c, s in enumerate(adj):
        s.discard(c)
    return adj


def constraint_cost(graph: Graph) -> float:
    """About the block updates of factoring K: the d constraints on one body are all coupled, and eliminating
    them costs about d^3 / 6 updates."""
    return sum(len(cs) ** 3 for cs in _constraints_on_bodies(graph)) / 6.0 + graph.constraint_count


def _structure(perm: np.ndarray, adj: list[set[int]], unknowns: int) -> dict:
    """Symbolic block Cholesky of the pattern `adj` (unknown -> neighbouring unknowns) in the order `perm`."""
    n = len(perm)
    pos = np.full(unknowns, -1, dtype=np.int64)
    pos[perm] = np.arange(n)
    # Column structures of L in elimination positions, by the elimination tree.
    struct: list[list[int]] = []
    children: list[list[int]] = [[] for _ in range(n)]
    parent = np.full(n, -1, dtype=np.int64)
    for j in range(n):
        rows = {int(pos[c]) for c in adj[perm[j]] if pos[c] > j}
        for ch in children[j]:
            rows.update(r for r in struct[ch] if r > j)
        srt = sorted(rows)
        struct.append(srt)
        if srt:
            parent[j] = srt[0]
            children[srt[0]].append(j)
    height = np.zeros(n, dtype=np.int64)
    for j in range(n):
        if parent[j] >= 0:
            height[parent[j]] = max(height[parent[j]], height[j] + 1)

    col_start = np.zeros(n + 1, dtype=np.int64)
    col_row: list[int] = []
    slot_of: dict[tuple[int, int], int] = {}
    for j in range(n):
        for r in [j, *struct[j]]:
            slot_of[(r, j)] = len(col_row)
            col_row.append(r)
        col_start[j + 1] = len(col_row)

    updates: list[list[tuple[int, int, int, int]]] = [[] for _ in range(n)]
    row_entries: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for k in range(n):
        s = struct[k]
        for a, j in enumerate(s):
            b_slot = slot_of[(j, k)]
            row_entries[j].append((b_slot, k))
            for i in s[a:]:
                updates[j].append((slot_of[(i, j)], slot_of[(i, k)], b_slot, k))
    flat = np.array([u for col in updates for u in col], dtype=np.int64).reshape(-1, 4)
    rflat = np.array([e for row in row_entries for e in row], dtype=np.int64).reshape(-1, 2)
    col_row_arr = np.array(col_row, dtype=np.int64)
    return dict(
        perm=perm,
        col_start=col_start,
        col_row=col_row_arr,
        slot_row=perm[col_row_arr],
        slot_col=perm[np.repeat(np.arange(n), np.diff(col_start))],
        update_start=np.cumsum([0] + [len(u) for u in updates]),
        update_target=flat[:, 0],
        update_a=flat[:, 1],
        update_b=flat[:, 2],
        update_column=flat[:, 3],
        row_start=np.cumsum([0] + [len(r) for r in row_entries]),
        row_slot=rflat[:, 0],
        row_col=rflat[:, 1],
        height=height,
    )


def _pattern(formulation: str, st: dict, col_sign: np.ndarray, **assembly) -> Pattern:
    empty = np.zeros(0, dtype=np.int64)
    fields = dict(slot_sides=np.zeros((0, 4), np.int32), slot_code=empty, slot_ref=empty)
    fields.update(assembly)
    update_column = st.pop("update_column")
    return Pattern(formulation=formulation, col_sign=col_sign, update_sign=col_sign[update_column], **st, **fields)


def constraint_pattern(graph: Graph, depth: np.ndarray, loop_joints: list[int], perm=None) -> Pattern:
    """K = J M^-1 J^T with constraints deepest first: a perfect elimination order for trees."""
    if perm is None:
        perm = elimination_order(graph, depth, loop_joints)
    st = _structure(perm, _coupling(graph), graph.constraint_count)
    sides = [shared_sides(graph, int(i), int(j)) for i, j in zip(st["slot_row"], st["slot_col"])]
    return _pattern("constraint", st, np.ones(len(perm)), slot_sides=np.array(sides, np.int32).reshape(-1, 4))


def split_pattern(graph: Graph, depth: np.ndarray, loop_joints: list[int], perm=None) -> Pattern:
    """K without the blocks that couple a loop joint's constraints to the tree's: the tree's system and the
    loop joints' system of the method paper's section 4.6, factored apart (no fill between them) and solved
    side by side from the same prediction in each iteration of the common loop, until both hold."""
    if perm is None:
        perm = elimination_order(graph, depth, loop_joints)
    loops = np.isin(graph.constraint_joint, loop_joints)
    adj = [{d for d in near if loops[d] == loops[c]} for c, near in enumerate(_coupling(graph))]
    st = _structure(perm, adj, graph.constraint_count)
    sides = [shared_sides(graph, int(i), int(j)) for i, j in zip(st["slot_row"], st["slot_col"])]
    return _pattern("split", st, np.ones(len(perm)), slot_sides=np.array(sides, np.int32).reshape(-1, 4))


def body_pattern(graph: Graph, depth: np.ndarray, loop_joints: list[int], perm=None) -> Pattern:
    """The augmented matrix, bodies deepest first, each constraint after its deeper body and before the other:
    every pivot then has a definite sign (+ for bodies, - for constraints) and a tree has no fill beyond the
    blocks of one body and one joint."""
    nb, nc = graph.body_count, graph.constraint_count
    if perm is None:
        loops = set(loop_joints)
        keys = []
        for b in range(nb):  # (world, loop, level, is constraint, index, angular part)
            if _dynamic(graph, b):
                w = graph.body_world(b)
                keys += [(w, False, -2 * depth[b], 0, b, 0), (w, False, -2 * depth[b], 0, b, 1)]
        for c in range(nc):
            level = max(depth[b] for b in _bodies(graph, c) if _dynamic(graph, b))
            keys.append((graph.constraint_world(c), int(graph.constraint_joint[c]) in loops, 1 - 2 * level, 1, c, 0))
        perm = np.array([2 * nb + k[4] if k[3] else k[4] + k[5] * nb for k in sorted(keys)], dtype=np.int64)
    adj: list[set[int]] = [set() for _ in range(2 * nb + nc)]
    for b, constraints in enumerate(_constraints_on_bodies(graph)):
        for c in constraints:
            for u in (b, nb + b):
                adj[u].add(2 * nb + c)
                adj[2 * nb + c].add(u)
    st = _structure(perm, adj, 2 * nb + nc)
    side_of = {(c, b): 2 * c + side for c in range(nc) for side, b in enumerate(_bodies(graph, c))}
    code = np.full(len(st["slot_row"]), Slot.ZERO, dtype=np.int64)
    ref = np.zeros(len(code), dtype=np.int64)
    for s, (r, c) in enumerate(zip(st["slot_row"].tolist(), st["slot_col"].tolist())):
        if r == c:
            kind = min(r // nb, 2) if nb else 2
            code[s] = (Slot.MASS, Slot.INERTIA, Slot.PAD)[kind]
            ref[s] = r - kind * nb
        elif (r >= 2 * nb) != (c >= 2 * nb):  # a constraint and a body part: J, or J^T above the diagonal
            con, part, transposed = (r - 2 * nb, c, False) if r >= 2 * nb else (c - 2 * nb, r, True)
            row = side_of.get((con, part % nb))
            if row is not None:
                code[s] = ((Slot.JLIN, Slot.JANG), (Slot.JLIN_T, Slot.JANG_T))[transposed][part >= nb]
                ref[s] = row
    sign = np.where(perm >= 2 * nb, -1.0, 1.0)
    return _pattern("body", st, sign, slot_code=code, slot_ref=ref)


def block_csr(graph: Graph) -> BlockCSR:
    adj = _coupling(graph)
    n = len(adj)
    cols = [sorted(adj[i] | {i}) for i in range(n)]
    start = np.cumsum([0] + [len(c) for c in cols])
    col = np.array([c for cs in cols for c in cs], dtype=np.int64)
    row = np.repeat(np.arange(n), np.diff(start))
    sides = np.array([shared_sides(graph, int(i), int(j)) for i, j in zip(row, col)], dtype=np.int32)
    diag = np.array([start[i] + cols[i].index(i) for i in range(n)], dtype=np.int64)
    return BlockCSR(start, col, row, sides.reshape(-1, 4), diag)


def analyze(graph: Graph, level_order: bool = False) -> Topology:
    """The spanning tree, loops and Jacobian rows per body; factor patterns are built when a solver asks."""
    depth, loops = _spanning_tree(graph)
    # Jacobian row 2 c + side of every constraint side on a body, grouped by body (a stable sort keeps the
    # rows of one body in constraint order).
    bodies = np.stack([graph.constraint_body0, graph.constraint_body1], axis=1).reshape(-1)
    rows = np.flatnonzero(bodies != WORLD)
    body_rows = rows[np.argsort(bodies[rows], kind="stable")]
    body_rows_start = np.concatenate([[0], np.cumsum(np.bincount(bodies[rows], minlength=graph.body_count))])
    return Topology(graph, body_rows_start, body_rows, depth, loops, level_order)


def schedule(pattern: Pattern, parallel: bool) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Groups of columns a thread runs in order, and the launches as ranges of groups.

    Serial (CPU): one group of every column, one launch. Parallel: a group per column, a launch per
    level of the elimination tree (requires `analyze(level_order=True)`).
    """
    n = len(pattern.perm)
    if not parallel:
        return np.array([0, n], dtype=np.int64), [(0, 1)]
    group_start = np.arange(n + 1, dtype=np.int64)
    levels = []
    start = 0
    for h in np.unique(pattern.height):
        count = int(np.sum(pattern.height == h))
        levels.append((start, count))
        start += count
    return group_start, levels
