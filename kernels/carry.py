"""The first joint iteration's carried right-hand side (issue 12; docs/architecture.md, "Fewer joint iterations").

The joint correction solves K lambda = rhs with K = J(t0) M^-1 J(t0)^T, but the predicted joint points move with the
arms of the step's END, so the error answers an impulse through K + E (E: the arms' turn over the step). The first
solve of a step therefore leaves a residual of about -E lambda, and lambda and E change little from one step to the
next. So the first solve of a step takes rhs + c, where c is what the first solve of the last step of the same size
left: with c in, the residual after the first solve is r1 = rhs - (K + E) lambda = -c - E lambda, so c + r1 = -E lambda
is this step's value of c. Nothing else changes: every later iteration solves for the residual it measures, and the
loop stops on the measured error alone, so c only moves where the iteration starts.

A step's new c is held aside (`carry_next`) and taken (`carry_commit`) only when the whole (composed) step is
accepted, so a failed step, redone or halved, starts from the same c in every schedule. Each step size (each
halving, each spin split) keeps its own c: E scales with the step; and each stage of a composition keeps its own,
stages of one size too (`composition.stage_keys`), so that each is measured a whole step apart at its own point of
the step (sharing one, suzuki5's four stages of size p extrapolated the last one's values).

c changes from step to step as the motion does, and a whipping chain or arm turns its links' arms by a good part
of a radian in a few steps: the last step's c then leaves a first residual of several percent, and a step takes
2-3 iterations. So the c a step starts from is extrapolated from the values measured in the last steps: the line
through the last two or the parabola through the last three, whose errors are second and third order in the step
where the last value's is first order. Where c jumps from step to step (a motion the step does not resolve, a
chain of 50 at h = 1/60) extrapolation amplifies the jumps, so each constraint takes the rule that would have
predicted its newest value best a step earlier (`extrapolated`; docs/architecture.md, "Fewer joint
iterations"). Where fewer values are known (after `reset`, `set_state`, for a new step size: NaN) it takes the
line through two or the last value alone.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
f64 = wp.float64
PAST = 3  # measured values a row of c keeps besides it (a row each of `Simulator._carry_past`)


@wp.func
def extrapolated(m0: vec3d, m1: vec3d, m2: vec3d, m3: vec3d) -> vec3d:
    """The next step's c from the last four values measured (m0 the newest, m/s or rad/s; NaN: unknown).

    Of the last value (m0), the line through the last two (2 m0 - m1) and the parabola through the last three
    (3 m0 - 3 m1 + m2), the one whose rule, applied a step earlier (to m1, m2, m3), came nearest m0: a higher
    order only where it came nearer by a margin (half the squared miss of the order below, a quarter of the
    last value's), since extrapolating a value that jumps (a motion the step size does not resolve) amplifies
    the jump. With m2 unknown the line is taken, with m1 unknown m0."""
    if wp.isnan(m1[0]):
        return m0
    line = f64(2.0) * m0 - m1
    if wp.isnan(m2[0]):
        return line
    miss0 = wp.length_sq(m0 - m1)
    miss1 = wp.length_sq(m0 - (f64(2.0) * m1 - m2))
    if not wp.isnan(m3[0]):
        miss2 = wp.length_sq(m0 - (f64(3.0) * (m1 - m2) + m3))
        if miss2 < f64(0.5) * miss1 and miss2 < f64(0.25) * miss0:
            return f64(3.0) * (m0 - m1) + m2
    if miss1 < f64(0.5) * miss0:
        return line
    return m0


@wp.func
def carry_take(
    i: int,
    carry: wp.array(dtype=vec3d),
    carry_next: wp.array(dtype=vec3d),
    past1: wp.array(dtype=vec3d),
    past2: wp.array(dtype=vec3d),
    past3: wp.array(dtype=vec3d),
):
    """Constraint i of a kept step: the value it measured (carry_next) joins the past (past1 the last step's,
    past2 and past3 the ones before), and c for the next step is extrapolated from the four (`extrapolated`)."""
    m0 = carry_next[i]
    carry[i] = extrapolated(m0, past1[i], past2[i], past3[i])
    past3[i] = past2[i]
    past2[i] = past1[i]
    past1[i] = m0


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
    measured: int,
    constraint_count: int,
    carry: wp.array2d(dtype=vec3d),
    carry_next: wp.array2d(dtype=vec3d),
    carry_past: wp.array2d(dtype=vec3d),
):
    """A kept step's c: every row whose bit is set in `measured` (the stages whose first solve ran) takes
    the value measured in the step into its past and extrapolates its next c (`carry_take`; row r's past is
    carry_past[3 r] to [3 r + 2], `PAST` rows); the others keep theirs."""
    r = wp.int32(0)
    while r < carry.shape[0]:
        if (measured >> r) & 1 != 0:
            i = wp.int32(0)
            while i < constraint_count:
                carry_take(i, carry[r], carry_next[r], carry_past[3 * r], carry_past[3 * r + 1], carry_past[3 * r + 2])
                i += 1
        r += 1


@wp.kernel
def carry_keep(
    # Data in:
    carry_next: wp.array(dtype=vec3d),
    # Data out:
    carry_out: wp.array(dtype=vec3d),
    past1_out: wp.array(dtype=vec3d),
    past2_out: wp.array(dtype=vec3d),
    past3_out: wp.array(dtype=vec3d),
):
    """A kept step's c and past (`carry_take`), a constraint a thread."""
    carry_take(wp.tid(), carry_out, carry_next, past1_out, past2_out, past3_out)


@wp.kernel
def carry_commit(
    # Model:
    constraint_world: wp.array(dtype=int),
    # Data in:
    world_take: wp.array(dtype=int),
    carry_next: wp.array(dtype=vec3d),
    # Data out:
    carry_out: wp.array(dtype=vec3d),
    past1_out: wp.array(dtype=vec3d),
    past2_out: wp.array(dtype=vec3d),
    past3_out: wp.array(dtype=vec3d),
):
    """Batched worlds: `carry_keep` for the constraints of the worlds that keep their step (world_take != 0:
    their step is kept and its first solve ran), a constraint a thread."""
    c = wp.tid()
    if world_take[constraint_world[c]] != 0:
        carry_take(c, carry_out, carry_next, past1_out, past2_out, past3_out)
