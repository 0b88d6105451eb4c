"""Host-side symbolic analysis, once per topology: elimination order, fill pattern, slots, schedules.

Two formulations of one linear system (see `Pattern`). In K = J M^-1 J^T the unknowns are the basic
constraints (3 rows each), coupled when they share a dynamic body (method paper, section 4.5). For a
tree, ordering the constraints deepest body first is a perfect elimination order: no fill, linear cost,
unless a body carries many joints (a star), whose constraints form a dense block. The augmented matrix
of bodies and constraints keeps such scenes linear. Joints that close loops (section 4.6) go last.
"""

from __future__ import annotations

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


def _ranges(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For groups of `counts` items: each item's group and its index within the group."""
    counts = np.asarray(counts, dtype=np.int64)
    group = np.repeat(np.arange(len(counts)), counts)
    starts = np.cumsum(counts) - counts
    return group, np.arange(len(group)) - starts[group]


def _unique(values: np.ndarray) -> np.ndarray:
    """The sorted distinct values (by a sort: numpy 2's hashing `np.unique` is several times slower here)."""
    values = np.sort(values)
    return values[np.concatenate([[True], values[1:] != values[:-1]])] if len(values) else values


def _member(values: np.ndarray, sorted_set: np.ndarray) -> np.ndarray:
    """Whether each value is in the sorted array `sorted_set`."""
    at = np.minimum(np.searchsorted(sorted_set, values), max(len(sorted_set) - 1, 0))
    return sorted_set[at] == values if len(sorted_set) else np.zeros(len(values), dtype=bool)


def _worlds(world_count: int, count: int) -> np.ndarray:
    """The batched world of each of `count` world-major items (`Graph.body_world`, `constraint_world`)."""
    return np.arange(count, dtype=np.int64) * world_count // max(count, 1)


def _first_occurrences(values: np.ndarray) -> np.ndarray:
    """Indices of the first occurrence of each value, in the order they occur."""
    _, first = np.unique(values, return_index=True)
    return np.sort(first)


def _dynamic(graph: Graph, bodies: np.ndarray) -> np.ndarray:
    """Whether each body index is a dynamic body (not WORLD, not static)."""
    bodies = np.asarray(bodies)
    if graph.body_count == 0:
        return np.zeros(bodies.shape, dtype=bool)
    return (bodies != WORLD) & ~graph.body_static[np.where(bodies == WORLD, 0, bodies)]


def shared_sides(graph: Graph, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(side in i, side in j) of each dynamic body that constraints i and j share, flattened and -1 padded:
    (len(i), 4), the matches in the order (0, 0), (0, 1), (1, 0), (1, 1)."""
    b0, b1 = graph.constraint_body0, graph.constraint_body1
    bi, bj = (b0[i], b1[i]), (b0[j], b1[j])
    pairs = [(si, sj) for si in (0, 1) for sj in (0, 1)]
    match = np.stack([_dynamic(graph, bi[si]) & (bj[sj] == bi[si]) for si, sj in pairs], axis=1)
    out = np.full((len(match), 4), -1, dtype=np.int32)
    rank = np.cumsum(match, axis=1) - 1  # the place of each match among the slot's matches
    for k, (si, sj) in enumerate(pairs):
        put = match[:, k] & (rank[:, k] < 2)
        out[put, 2 * rank[put, k]] = si
        out[put, 2 * rank[put, k] + 1] = sj
    return out


def _spanning_tree(graph: Graph) -> tuple[np.ndarray, list[int]]:
    """Depth of every body from the world (or from a root per floating island), and the loop joints: those
    the breadth-first spanning tree does not use. Joints marked `joint_loop` (USD's excludeFromArticulation)
    join the tree only where no other joint reaches a body, so they close the loops when the scene says so.

    A breadth-first search a round at a time: a round's frontier, in queue order, expands to its neighbours in
    joint order, and a body found twice keeps its first finder, which is the order of a queue: the same tree,
    depths and loop joints as a body-at-a-time search."""
    n, parent, child = graph.body_count, graph.joint_parent, graph.joint_child
    hinted = np.zeros(graph.joint_count, bool) if graph.joint_loop is None else np.asarray(graph.joint_loop, bool)
    depth = np.full(n, -1, dtype=np.int64)
    tree = np.zeros(graph.joint_count, dtype=bool)
    if n == 0:
        return depth, np.flatnonzero(~tree).tolist()
    grounded = ~_dynamic(graph, parent)
    free = np.flatnonzero(~grounded)
    u = np.concatenate([parent[free], child[free]])
    order = np.lexsort((np.concatenate([free, free]), u))
    other = np.concatenate([child[free], parent[free]])[order]
    via = np.concatenate([free, free])[order]
    start = np.searchsorted(u[order], np.arange(n + 1))

    def grow(frontier: np.ndarray, allow_hinted: bool) -> None:
        while len(frontier):
            counts = start[frontier + 1] - start[frontier]
            group, offset = _ranges(counts)
            edges = start[frontier][group] + offset
            found, joints, finder = other[edges], via[edges], frontier[group]
            new = depth[found] < 0
            if not allow_hinted:
                new &= ~hinted[joints]
            found, joints, finder = found[new], joints[new], finder[new]
            first = _first_occurrences(found)
            frontier = found[first]
            depth[frontier] = depth[finder[first]] + 1
            tree[joints[first]] = True

    static = np.flatnonzero(graph.body_static)
    roots = np.concatenate([child[grounded], static])
    joints = np.concatenate([np.flatnonzero(grounded), np.full(len(static), -1)])
    for allow_hinted in (False, True):
        eligible = depth[roots] < 0
        if not allow_hinted:
            by_joint = joints >= 0
            eligible[by_joint] &= ~hinted[joints[by_joint]]
        take = np.flatnonzero(eligible)[_first_occurrences(roots[eligible])]
        depth[roots[take]] = 0
        tree[joints[take][joints[take] >= 0]] = True
        frontier = roots[take]
        if allow_hinted:  # grow on from everything reached, now through the marked joints too
            reached = np.flatnonzero(depth >= 0)
            frontier = np.concatenate([frontier, reached[np.argsort(depth[reached], kind="stable")]])
        grow(frontier, allow_hinted)
    # Floating islands, rooted at their first body; a body without joints is an island of its own.
    alone = (depth < 0) & (start[1:] == start[:-1])
    depth[alone] = 0
    for b in np.flatnonzero(depth < 0).tolist():
        if depth[b] < 0:
            depth[b] = 0
            grow(np.array([b]), True)
    return depth, np.flatnonzero(~tree).tolist()


def _constraint_levels(graph: Graph, depth: np.ndarray) -> np.ndarray:
    """The depth of each constraint's deeper body (-1 for the world)."""
    b0, b1 = graph.constraint_body0, graph.constraint_body1
    d0 = np.where(b0 != WORLD, depth[np.maximum(b0, 0)] if len(depth) else -1, -1)
    d1 = np.where(b1 != WORLD, depth[np.maximum(b1, 0)] if len(depth) else -1, -1)
    return np.maximum(d0, d1)


def elimination_order(graph: Graph, depth: np.ndarray, loop_joints: list[int]) -> np.ndarray:
    """Constraints deepest first; loop-closing joints last; a joint's constraints stay together. Batched worlds
    one after the other, each in the order it has alone (so each factors as it does alone, bit for bit, and a
    world's columns are contiguous)."""
    loop = np.isin(graph.constraint_joint, np.asarray(loop_joints, dtype=np.int64))
    level = _constraint_levels(graph, depth)
    world = _worlds(graph.world_count, graph.constraint_count)
    return np.lexsort((np.arange(graph.constraint_count), -level, loop, world)).astype(np.int64)


def _body_constraints(graph: Graph) -> tuple[np.ndarray, np.ndarray]:
    """(body, constraint) for every constraint side on a dynamic body, by body, each body's in constraint order."""
    body = np.stack([graph.constraint_body0, graph.constraint_body1], axis=1).reshape(-1)
    constraint = np.repeat(np.arange(graph.constraint_count), 2)
    keep = _dynamic(graph, body)
    body, constraint = body[keep], constraint[keep]
    order = np.argsort(body, kind="stable")
    return body[order], constraint[order]


def _coupling(graph: Graph) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j), i != j, of constraints that share a dynamic body, both ways round (repeats possible)."""
    body, constraint = _body_constraints(graph)
    counts = np.bincount(body, minlength=graph.body_count) if len(body) else np.zeros(0, np.int64)
    starts = np.cumsum(counts) - counts
    # Every ordered pair within each body's group.
    first_group, first_offset = _ranges(counts[body])
    i = constraint[np.repeat(np.arange(len(body)), counts[body])]
    j = constraint[starts[body][first_group] + first_offset]
    keep = i != j
    return i[keep], j[keep]


def constraint_cost(graph: Graph) -> float:
    """About the block updates of factoring K: the d constraints on one body are all coupled, and eliminating
    them costs about d^3 / 6 updates."""
    body, _ = _body_constraints(graph)
    d = np.bincount(body, minlength=graph.body_count).astype(np.float64)
    return float(np.sum(d**3)) / 6.0 + graph.constraint_count


def _fill(n: int, key: np.ndarray) -> np.ndarray:
    """The nonzero blocks below the diagonal of the factor of a symmetric pattern, in elimination positions,
    as sorted keys j * n + r (column j, row r > j).

    Column j's rows r are its matrix entries plus, from every column c whose first row (its parent in the
    elimination tree) is j, c's other rows. Added a round at a time from the columns whose rows changed, until
    none do: every round adds only entries of the true factor (a column's later neighbours form a clique), and
    the end is a pattern in which the order is a perfect elimination, so it is the factor's. A tree ordered
    deepest first has no fill: one round checks it."""
    active = _unique(key // n)
    while len(active):
        col, row = key // n, key % n
        head = np.searchsorted(key, np.arange(n + 1) * n)  # each column's first entry
        parent = np.where(head[1:] > head[:-1], row[np.minimum(head[:-1], len(key) - 1)], -1)
        take = _member(col, active) & (row != parent[col])
        candidates = _unique(parent[col[take]] * n + row[take])
        new = candidates[~_member(candidates, key)]
        key = _unique(np.concatenate([key, new]))
        active = _unique(new // n)
    return key


def _heights(parent: np.ndarray) -> np.ndarray:
    """Each node's height in a forest given by `parent` (-1 at a root): the longest path down to a leaf (0 for a
    leaf). By pointer doubling, about log2(depth) vectorised rounds: first every node's depth, then the deepest
    depth below each node, gathered from the nodes 1, 2, 4, ... levels down."""
    depth = (parent >= 0).astype(np.int64)
    up = parent.copy()
    while np.any(up >= 0):  # depth += depth of the 2^k-th ancestor, then jump twice as far
        has = np.flatnonzero(up >= 0)
        depth[has] += depth[up[has]]
        up[has] = up[up[has]]
    deepest = depth.copy()  # the deepest depth within 2^k levels below each node
    up = parent.copy()
    while np.any(up >= 0):
        has = np.flatnonzero(up >= 0)
        gathered = deepest.copy()
        np.maximum.at(gathered, up[has], deepest[has])
        deepest = gathered
        up[has] = up[up[has]]
    return deepest - depth


def _structure(perm: np.ndarray, pair_u: np.ndarray, pair_v: np.ndarray, unknowns: int) -> dict:
    """Symbolic block Cholesky of the pattern of pairs (u, v) of coupled unknowns, in the order `perm`."""
    n = len(perm)
    pos = np.full(unknowns, -1, dtype=np.int64)
    pos[perm] = np.arange(n)
    pj, pr = pos[pair_u], pos[pair_v]
    keep = (pj >= 0) & (pr > pj)
    lower = _fill(n, _unique(pj[keep] * n + pr[keep]))
    # Slots: every column's diagonal first, then its rows in order; a slot is found by its key.
    slot_key = np.sort(np.concatenate([lower, np.arange(n, dtype=np.int64) * (n + 1)]))
    slot_col_pos, col_row = slot_key // n, slot_key % n
    col_start = np.searchsorted(slot_col_pos, np.arange(n + 1)).astype(np.int64)
    below = np.flatnonzero(col_row != slot_col_pos)  # off-diagonal slots, by column then row
    k_of, r_of = slot_col_pos[below], col_row[below]
    parent = np.full(n, -1, dtype=np.int64)
    has = col_start[1:] - col_start[:-1] > 1
    parent[has] = col_row[col_start[:-1][has] + 1]
    height = _heights(parent)
    # Updates of column k: for its rows j <= i, L_ij -= L_ik L_jk^T, grouped by the target slot (its column j,
    # then its row i), then k: the order the factor applies them, each target summed in registers.
    size = np.diff(col_start) - 1
    a_group, a_offset = _ranges(size)  # (column k, place a of row j in it)
    b_group, b_extra = _ranges(size[a_group] - a_offset)  # (that pair, place b >= a of row i)
    k = a_group[b_group]
    a_slot = col_start[k] + 1 + a_offset[b_group]
    b_slot = a_slot + b_extra
    j, i = col_row[a_slot], col_row[b_slot]
    target = np.searchsorted(slot_key, j * n + i)
    order = np.lexsort((k, target))
    row_order = np.lexsort((k_of, r_of))
    return dict(
        perm=perm,
        col_start=col_start,
        col_row=col_row,
        slot_row=perm[col_row],
        slot_col=perm[slot_col_pos],
        update_start=np.concatenate([[0], np.cumsum(np.bincount(j, minlength=n))]).astype(np.int64),
        update_target=target[order],
        update_a=b_slot[order],
        update_b=a_slot[order],
        update_column=k[order],
        row_start=np.concatenate([[0], np.cumsum(np.bincount(r_of, minlength=n))]).astype(np.int64),
        row_slot=below[row_order],
        row_col=k_of[row_order],
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
    st = _structure(perm, *_coupling(graph), graph.constraint_count)
    sides = shared_sides(graph, st["slot_row"], st["slot_col"])
    return _pattern("constraint", st, np.ones(len(perm)), slot_sides=sides)


def split_pattern(graph: Graph, depth: np.ndarray, loop_joints: list[int], perm=None) -> Pattern:
    """K without the blocks that couple a loop joint's constraints to the tree's: the tree's system and the
    loop joints' system of the method paper's section 4.6, factored apart (no fill between them) and solved
    side by side from the same prediction in each iteration of the common loop, until both hold."""
    if perm is None:
        perm = elimination_order(graph, depth, loop_joints)
    loops = np.isin(graph.constraint_joint, np.asarray(loop_joints, dtype=np.int64))
    i, j = _coupling(graph)
    same = loops[i] == loops[j]
    st = _structure(perm, i[same], j[same], graph.constraint_count)
    sides = shared_sides(graph, st["slot_row"], st["slot_col"])
    return _pattern("split", st, np.ones(len(perm)), slot_sides=sides)


def body_pattern(graph: Graph, depth: np.ndarray, loop_joints: list[int], perm=None) -> Pattern:
    """The augmented matrix, bodies deepest first, each constraint after its deeper body and before the other:
    every pivot then has a definite sign (+ for bodies, - for constraints) and a tree has no fill beyond the
    blocks of one body and one joint."""
    nb, nc = graph.body_count, graph.constraint_count
    if perm is None:
        # Sort keys (world, loop joint, level, constraint after body, index, part) as in the docstring.
        bodies = np.flatnonzero(_dynamic(graph, np.arange(nb)))
        b0, b1 = graph.constraint_body0, graph.constraint_body1
        d0 = np.where(_dynamic(graph, b0), depth[np.maximum(b0, 0)] if nb else -1, -1)
        d1 = np.where(_dynamic(graph, b1), depth[np.maximum(b1, 0)] if nb else -1, -1)
        loop = np.isin(graph.constraint_joint, np.asarray(loop_joints, dtype=np.int64))
        keys = np.concatenate(
            [
                np.stack([np.repeat(_worlds(graph.world_count, nb)[bodies], 2), np.zeros(2 * len(bodies)),
                          np.repeat(-2 * depth[bodies], 2), np.zeros(2 * len(bodies)), np.repeat(bodies, 2),
                          np.tile([0, 1], len(bodies))], axis=1),
                np.stack([_worlds(graph.world_count, nc), loop, 1 - 2 * np.maximum(d0, d1), np.ones(nc),
                          np.arange(nc), np.zeros(nc)], axis=1),
            ]
        ).astype(np.int64)  # fmt: skip
        keys = keys[np.lexsort(keys.T[::-1])]
        perm = np.where(keys[:, 3] == 1, 2 * nb + keys[:, 4], keys[:, 4] + keys[:, 5] * nb).astype(np.int64)
    body, constraint = _body_constraints(graph)
    u = np.concatenate([body, nb + body, 2 * nb + constraint, 2 * nb + constraint])
    v = np.concatenate([2 * nb + constraint, 2 * nb + constraint, body, nb + body])
    st = _structure(perm, u, v, 2 * nb + nc)
    r, c = st["slot_row"], st["slot_col"]
    code = np.full(len(r), Slot.ZERO, dtype=np.int64)
    ref = np.zeros(len(code), dtype=np.int64)
    diag = r == c
    kind = np.minimum(r // nb, 2) if nb else np.full(len(r), 2)
    code[diag] = np.array([Slot.MASS, Slot.INERTIA, Slot.PAD])[kind[diag]]
    ref[diag] = (r - kind * nb)[diag]
    # A constraint and a body part: J below the diagonal, J^T above, when the constraint has a side on the body.
    mixed = ~diag & ((r >= 2 * nb) != (c >= 2 * nb))
    transposed = c >= 2 * nb
    con = np.where(transposed, c, r) - 2 * nb
    part = np.where(transposed, r, c)
    con_safe = np.clip(con, 0, max(nc - 1, 0))
    b = part % nb if nb else part
    side1 = mixed & (graph.constraint_body1[con_safe] == b) if nc else mixed
    side0 = mixed & (graph.constraint_body0[con_safe] == b) & ~side1 if nc else mixed
    on = side0 | side1
    angular = part >= nb
    codes = np.array([[Slot.JLIN, Slot.JANG], [Slot.JLIN_T, Slot.JANG_T]])
    code[on] = codes[transposed[on].astype(int), angular[on].astype(int)]
    ref[on] = 2 * con[on] + side1[on]
    sign = np.where(perm >= 2 * nb, -1.0, 1.0)
    return _pattern("body", st, sign, slot_code=code, slot_ref=ref)


def block_csr(graph: Graph) -> BlockCSR:
    n = graph.constraint_count
    i, j = _coupling(graph)
    key = _unique(np.concatenate([i * n + j, np.arange(n, dtype=np.int64) * (n + 1)]))
    row, col = key // n, key % n
    start = np.searchsorted(row, np.arange(n + 1)).astype(np.int64)
    diag = np.searchsorted(key, np.arange(n, dtype=np.int64) * (n + 1)).astype(np.int64)
    return BlockCSR(start, col, row, shared_sides(graph, row, col), diag)


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
