"""The first joint iteration's carried right-hand side (issue 12; docs/architecture.md, "Fewer joint iterations").

The joint correction solves K lambda = rhs with K = J(t0) M^-1 J(t0)^T, but the predicted joint points move with the
arms of the step's END, so the error answers an impulse through K + E (E: the arms' turn over the step). The first
solve of a step therefore leaves a residual of about -E lambda, and lambda and E change little from one step to the
next. So the first solve of a step takes rhs + c, where c is what the first solve of the last step of the same size
left: with c in, the residual after the first solve is r1 = rhs - (K + E) lambda = -c - E lambda, so c + r1 = -E lambda
is this step's value of c. Nothing else changes: every later iteration solves for the residual it measures, and the
loop stops on the measured error alone, so c only moves where the iteration starts.

A step's new c is held aside (`carry_next`) and taken (`carry_commit`) only when the whole (composed) step is
accepted, so a failed step, redone or halved, starts from the same c in every schedule. Each step size (each stage
of a composition, each halving) keeps its own c: E scales with the step.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d


@wp.func
def carry_into(i: int, carry: wp.array(dtype=vec3d), rhs: wp.array(dtype=vec3d)):
    """Constraint i's first right-hand side of the step: rhs + c (m/s or rad/s, world frame)."""
    rhs[i] = rhs[i] + carry[i]


@wp.func
def carry_measure(i: int, carry: wp.array(dtype=vec3d), rhs: wp.array(dtype=vec3d), carry_next: wp.array(dtype=vec3d)):
    """Constraint i's c for the next step: c + the residual the first solve left (rhs measured after it)."""
    carry_next[i] = carry[i] + rhs[i]


@wp.func
def carry_into_all(constraint_count: int, carry: wp.array(dtype=vec3d), rhs: wp.array(dtype=vec3d)):
    """Every constraint's first right-hand side (`carry_into`): the fused step's pass."""
    i = wp.int32(0)
    while i < constraint_count:
        carry_into(i, carry, rhs)
        i += 1


@wp.func
def carry_measure_all(
    constraint_count: int, carry: wp.array(dtype=vec3d), rhs: wp.array(dtype=vec3d), carry_next: wp.array(dtype=vec3d)
):
    """Every constraint's next c (`carry_measure`): the fused step's pass."""
    i = wp.int32(0)
    while i < constraint_count:
        carry_measure(i, carry, rhs, carry_next)
        i += 1


@wp.kernel
def carry_in(
    # Data in:
    carry: wp.array(dtype=vec3d),
    # Data out:
    rhs_out: wp.array(dtype=vec3d),
):
    """The first solve's right-hand side, rhs + c (`carry_into`), a constraint a thread."""
    carry_into(wp.tid(), carry, rhs_out)


@wp.kernel
def carry_out(
    # Data in:
    carry: wp.array(dtype=vec3d),
    rhs_in: wp.array(dtype=vec3d),
    # Data out:
    carry_next_out: wp.array(dtype=vec3d),
):
    """The next step's c, from the residual measured after the first solve (`carry_measure`)."""
    carry_measure(wp.tid(), carry, rhs_in, carry_next_out)


@wp.func
def commit_carry(
    measured: int, constraint_count: int, carry: wp.array2d(dtype=vec3d), carry_next: wp.array2d(dtype=vec3d)
):
    """A kept step's c: every row whose bit is set in `measured` (the step sizes whose first solve ran) takes
    the value measured in the step (`carry_measure`); the others keep theirs."""
    r = wp.int32(0)
    while r < carry.shape[0]:
        if (measured >> r) & 1 != 0:
            i = wp.int32(0)
            while i < constraint_count:
                carry[r, i] = carry_next[r, i]
                i += 1
        r += 1


@wp.kernel
def carry_commit(
    # Model:
    constraint_world: wp.array(dtype=int),
    # Data in:
    world_take: wp.array(dtype=int),
    carry_next: wp.array(dtype=vec3d),
    # Data out:
    carry_out: wp.array(dtype=vec3d),
):
    """Batched worlds: the c measured in the step, for the constraints of the worlds that keep it (world_take
    != 0: their step is kept and its first solve ran), a constraint a thread."""
    c = wp.tid()
    if world_take[constraint_world[c]] != 0:
        carry_out[c] = carry_next[c]
