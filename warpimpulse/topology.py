"""Host-side symbolic analysis, once per topology: elimination order, fill pattern, slots, schedules.

The unknowns of the system are the basic constraints (3 rows each). Two constraints are coupled when
they share a dynamic body (method paper, section 4.5). For a tree, ordering the constraints deepest
body first is a perfect elimination order: the factor has no fill, so the cost stays linear in the
number of joints. Joints that close loops (section 4.6) go last.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .builder import WORLD, SceneBuilder


@dataclass
class Pattern:
    """Index arrays of the lower factor L (columns in elimination order) and of the full K."""

    perm: np.ndarray  # elimination position -> constraint
    # L: block column j owns slots col_start[j]..col_start[j+1]-1, diagonal first
    col_start: np.ndarray
    col_row: np.ndarray  # elimination position of each slot's row
    slot_row: np.ndarray  # constraint of each slot's row (for assembly)
    slot_col: np.ndarray
    slot_sides: np.ndarray  # (n, 4): (side in row, side in col) of up to two shared bodies, -1 if none
    update_start: np.ndarray
    update_target: np.ndarray
    update_a: np.ndarray
    update_b: np.ndarray
    row_start: np.ndarray  # forward solve: row j's off-diagonal slots and their columns
    row_slot: np.ndarray
    row_col: np.ndarray
    height: np.ndarray  # of each column in the elimination tree (0 = leaf)
    # full K in block CSR, rows and columns are constraints
    csr_start: np.ndarray
    csr_col: np.ndarray
    csr_row: np.ndarray
    csr_sides: np.ndarray
    csr_diag: np.ndarray


@dataclass
class Topology:
    body_rows_start: np.ndarray  # per body: its Jacobian rows (2 * constraint + side)
    body_rows: np.ndarray
    loop_joints: list[int]  # joints that close a kinematic loop
    pattern: Pattern

    @property
    def fill(self) -> int:
        """Blocks of L that are not blocks of K."""
        return len(self.pattern.slot_row) - (len(self.pattern.csr_col) + len(self.pattern.perm)) // 2


def _bodies(builder: SceneBuilder, c: int) -> tuple[int, int]:
    con = builder.constraints[c]
    return con.body0, con.body1


def _dynamic(builder: SceneBuilder, b: int) -> bool:
    return b != WORLD and not builder.bodies[b].static


def shared_sides(builder: SceneBuilder, i: int, j: int) -> list[int]:
    """(side in i, side in j) for each dynamic body that constraints i and j share, flattened, -1 padded."""
    out: list[int] = []
    bi, bj = _bodies(builder, i), _bodies(builder, j)
    for si in (0, 1):
        if _dynamic(builder, bi[si]):
            for sj in (0, 1):
                if bj[sj] == bi[si]:
                    out += [si, sj]
    return (out + [-1, -1, -1, -1])[:4]


def _spanning_tree(builder: SceneBuilder) -> tuple[np.ndarray, list[int]]:
    """Depth of every body from the world (or from a root per floating island), and the loop joints."""
    n = len(builder.bodies)
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    grounded: list[tuple[int, int]] = []
    for ji, joint in enumerate(builder.joints):
        if joint.parent == WORLD or builder.bodies[joint.parent].static:
            grounded.append((joint.child, ji))
        else:
            adjacency[joint.parent].append((joint.child, ji))
            adjacency[joint.child].append((joint.parent, ji))
    for b, body in enumerate(builder.bodies):
        if body.static:
            grounded.append((b, -1))
    depth = np.full(n, -1, dtype=np.int64)
    tree_joints: set[int] = set()
    queue: deque[int] = deque()
    for b, ji in grounded:
        if depth[b] < 0:
            depth[b] = 0
            queue.append(b)
            tree_joints.add(ji)

    def grow() -> None:
        while queue:
            b = queue.popleft()
            for other, ji in adjacency[b]:
                if depth[other] < 0:
                    depth[other] = depth[b] + 1
                    tree_joints.add(ji)
                    queue.append(other)

    grow()
    for b in range(n):  # floating islands: root at their first body
        if depth[b] < 0:
            depth[b] = 0
            queue.append(b)
            grow()
    loops = [ji for ji in range(len(builder.joints)) if ji not in tree_joints]
    return depth, loops


def elimination_order(builder: SceneBuilder, depth: np.ndarray, loop_joints: list[int]) -> np.ndarray:
    """Deepest constraints first; loop-closing joints last; a joint's constraints stay together."""
    loops = set(loop_joints)
    keys = []
    for c, con in enumerate(builder.constraints):
        level = max(depth[b] if b != WORLD else -1 for b in (con.body0, con.body1))
        keys.append((con.joint in loops, -level, c))
    return np.array([k[2] for k in sorted(keys)], dtype=np.int64)


def _coupling(builder: SceneBuilder) -> list[set[int]]:
    """Constraints sharing a dynamic body with each constraint (itself excluded)."""
    on_body: list[list[int]] = [[] for _ in builder.bodies]
    for c, con in enumerate(builder.constraints):
        for b in (con.body0, con.body1):
            if _dynamic(builder, b):
                on_body[b].append(c)
    adj: list[set[int]] = [set() for _ in builder.constraints]
    for cs in on_body:
        for c in cs:
            adj[c].update(cs)
    for c, s in enumerate(adj):
        s.discard(c)
    return adj


def symbolic(builder: SceneBuilder, perm: np.ndarray, adj: list[set[int]]) -> Pattern:
    n = len(perm)
    pos = np.empty(n, dtype=np.int64)
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
    col_row_arr = np.array(col_row, dtype=np.int64)
    col_of_slot = np.repeat(np.arange(n), np.diff(col_start))
    slot_row = perm[col_row_arr]
    slot_col = perm[col_of_slot]
    slot_sides = np.array([shared_sides(builder, int(i), int(j)) for i, j in zip(slot_row, slot_col)], dtype=np.int32)

    updates: list[list[tuple[int, int, int]]] = [[] for _ in range(n)]
    row_entries: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for k in range(n):
        s = struct[k]
        for a, j in enumerate(s):
            b_slot = slot_of[(j, k)]
            row_entries[j].append((b_slot, k))
            for i in s[a:]:
                updates[j].append((slot_of[(i, j)], slot_of[(i, k)], b_slot))
    update_start = np.cumsum([0] + [len(u) for u in updates])
    flat = np.array([u for col in updates for u in col], dtype=np.int64).reshape(-1, 3)
    row_start = np.cumsum([0] + [len(r) for r in row_entries])
    rflat = np.array([e for row in row_entries for e in row], dtype=np.int64).reshape(-1, 2)

    csr_cols = [sorted(adj[i] | {i}) for i in range(n)]
    csr_start = np.cumsum([0] + [len(c) for c in csr_cols])
    csr_col = np.array([c for cols in csr_cols for c in cols], dtype=np.int64)
    csr_row = np.repeat(np.arange(n), np.diff(csr_start))
    csr_sides = np.array([shared_sides(builder, int(i), int(j)) for i, j in zip(csr_row, csr_col)], dtype=np.int32)
    csr_diag = np.array([csr_start[i] + csr_cols[i].index(i) for i in range(n)], dtype=np.int64)

    return Pattern(
        perm=perm,
        col_start=col_start,
        col_row=col_row_arr,
        slot_row=slot_row,
        slot_col=slot_col,
        slot_sides=slot_sides.reshape(-1, 4),
        update_start=update_start,
        update_target=flat[:, 0],
        update_a=flat[:, 1],
        update_b=flat[:, 2],
        row_start=row_start,
        row_slot=rflat[:, 0],
        row_col=rflat[:, 1],
        height=height,
        csr_start=csr_start,
        csr_col=csr_col,
        csr_row=csr_row,
        csr_sides=csr_sides.reshape(-1, 4),
        csr_diag=csr_diag,
    )


def analyze(builder: SceneBuilder, level_order: bool = False) -> Topology:
    """The whole symbolic analysis. `level_order` sorts columns by elimination-tree height (same fill)
    so that every level is a contiguous range: the parallel schedule of a GPU."""
    depth, loops = _spanning_tree(builder)
    adj = _coupling(builder)
    perm = elimination_order(builder, depth, loops)
    pattern = symbolic(builder, perm, adj)
    if level_order:
        order = np.argsort(pattern.height, kind="stable")
        pattern = symbolic(builder, perm[order], adj)
    rows: list[list[int]] = [[] for _ in builder.bodies]
    for c, con in enumerate(builder.constraints):
        for side, b in enumerate((con.body0, con.body1)):
            if b != WORLD:
                rows[b].append(2 * c + side)
    body_rows_start = np.cumsum([0] + [len(r) for r in rows])
    body_rows = np.array([r for rs in rows for r in rs], dtype=np.int64)
    return Topology(body_rows_start, body_rows, loops, pattern)


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
