"""`warpimpulse stress`: the stress suite.

Every case builds a scene, runs it, and is judged against criteria stated with the case:

- ``hold``: every step converges (joint error <= tolerance, velocity error <= velocity tolerance), the state
  stays finite, the joints hold at the end (checked again from the final state), and the energy does not
  grow by more than ``energy_gain`` of the energy scale (the largest kinetic energy seen). Any stop is a FAIL.
- ``hold_or_stop``: the suite's general rule, for set-ups beyond the method's comfort zone (large steps,
  high spin, near-singular joints): either everything ``hold`` asks for, or the run stops with a *clear*
  error: a SimulationError naming the step, the iterations and the joints (or bodies) at fault, a
  SingularSystemError naming the joint, or a SceneError naming the joint. The table says which ("held" or
  "stopped") and stops are listed as findings at the end.
- ``error``: the run must stop with a clear error of the expected kind (redundant constraints, a joint the
  builder must refuse). Holding is also accepted where ``solved_ok`` says so (a solver that solves a
  consistent redundant system is allowed: redundant constraints are to be detected and reported, or solved).

A FAIL is anything else: NaN or Inf that reached the user, a joint error above tolerance without an error
(silent drift), an error that does not name the step / iterations / joints, another exception, a crash,
or a case that does not finish in its time budget. The exit status is 1 when any case fails.

Energy drift is (E_end - E_ref) / E_scale, where E is kinetic plus gravitational potential energy, E_ref is
taken after the scene's start-up (the trees' start torque acts for the first second; initial velocities
that break the joints are projected in the first step), and E_scale is the largest kinetic energy seen
after E_ref. The worst gain over the samples is also reported.
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..builder import SceneBuilder, SceneError
from ..cliutil import ArgumentParser, check_writable
from ..scenes import binary_tree, chain, star
from ..shapes import Shape
from ..simulator import SimulationError, Simulator
from ..solver import SingularSystemError
from ..transforms import quat_between, quat_from_axis_angle, quat_rotate, quat_to_matrix
from .harness import quiet_warp

DEFAULT_JSON = Path("benchmarks/results/stress.json")
QUICK_BUDGET_S = 300.0


# ------------------------------------------------------------------------------------------------ scenes
def capsule(
    builder: SceneBuilder, top, direction, length, name, mass_factor=1.0, density=1000.0
) -> tuple[int, np.ndarray]:
    """A capsule of `length` m (radius 5% of it) hanging from `top` along `direction` (world frame), of
    `density` kg/m^3 times `mass_factor`; returns the body and its far end (world, m)."""
    radius = 0.05 * length
    span = length - 2.0 * radius
    shape = Shape("capsule", radius=radius, length=span, collide=False)
    mass, inertia = shape.mass_properties(density)
    direction = np.asarray(direction, dtype=float)
    q = quat_between([0.0, 0.0, 1.0], direction)
    body = builder.add_body(mass * mass_factor, inertia * mass_factor, np.asarray(top) + 0.5 * span * direction, q,
                            name=name, shape=shape)  # fmt: skip
    return body, np.asarray(top) + span * direction


def mass_ratio_chain(ratio: float, heavy: str, links: int = 8, joint: str = "revolute") -> SceneBuilder:
    """A horizontal chain of 0.5 m capsules hinged about y, falling under gravity. Neighbouring masses differ
    by `ratio`: `heavy` = "tip" (the last link is heavy), "root" (the first link is heavy) or "alternate"
    (every other link is heavy, so every pair of neighbours has the ratio)."""
    builder = SceneBuilder()
    x_axis, y_axis = np.eye(3)[0], np.eye(3)[1]
    top, parent = np.zeros(3), None
    for i in range(links):
        factor = {"tip": ratio if i == links - 1 else 1.0, "root": ratio if i == 0 else 1.0,
                  "alternate": ratio if i % 2 else 1.0}[heavy]  # fmt: skip
        body, bottom = capsule(builder, top, x_axis, 0.5, f"link{i}", factor)
        builder.add_joint(joint, parent, body, top, y_axis, None, f"j{i}")
        parent, top = body, bottom
    return builder


def spinning_tree(bodies: int, omega) -> SceneBuilder:
    """The paper's tree with its root body given angular velocity `omega` (world, rad/s) before finalize.
    The root's linear velocity is made consistent with its world ball joint; its children start at rest."""
    builder = binary_tree(bodies)
    root = builder.bodies[0]
    root.angular_velocity[:] = omega
    anchor = builder.joints[0].anchor
    root.linear_velocity[:] = np.cross(root.angular_velocity, root.position - anchor)
    return builder


def near_parallel_universal(angle: float) -> SceneBuilder:
    """A rod hanging from the world on a universal joint whose two axes are `angle` radians apart, swinging
    and twisting (initial angular velocity about all three axes)."""
    builder = SceneBuilder()
    down = np.array([0.0, 0.0, -1.0])
    body, _ = capsule(builder, np.zeros(3), quat_rotate(quat_from_axis_angle([0, 1, 0], 0.3), down), 1.0, "rod")
    builder.bodies[body].angular_velocity[:] = (0.5, 1.0, 2.0)
    builder.bodies[body].linear_velocity[:] = np.cross((0.5, 1.0, 2.0), builder.bodies[body].position)
    axis0 = np.array([1.0, 0.0, 0.0])
    axis1 = quat_rotate(quat_from_axis_angle([0.0, 0.0, 1.0], angle), axis0)
    builder.add_joint_universal(None, body, np.zeros(3), axis0, axis1, name="universal")
    # A second rod below, on a ball joint, so the universal joint carries a moving load.
    top = builder.bodies[body].position * 2.0
    child, _ = capsule(builder, top, down, 1.0, "rod2")
    builder.add_joint_ball(body, child, top, name="ball")
    return builder


def hinge_through_centre() -> SceneBuilder:
    """A pendulum rod carrying a wheel on a hinge through the wheel's centre of mass, spinning at 50 rad/s,
    plus a free-tumbling box on a hinge through its centre of mass fixed to the world."""
    builder = SceneBuilder()
    y_axis = np.array([0.0, 1.0, 0.0])
    rod, bottom = capsule(
        builder, np.zeros(3), quat_rotate(quat_from_axis_angle(y_axis, 0.8), [0, 0, -1.0]), 1.0, "rod"
    )
    builder.add_joint_revolute(None, rod, np.zeros(3), y_axis, name="pivot")
    wheel = Shape("cylinder", radius=0.3, length=0.05, collide=False)
    mass, inertia = wheel.mass_properties(1000.0)
    q = quat_between([0.0, 0.0, 1.0], [0.0, 1.0, 0.0])  # wheel axis along y
    w = builder.add_body(mass, inertia, bottom, q, angular_velocity=(0.0, 50.0, 0.0), name="wheel", shape=wheel)
    builder.add_joint_revolute(rod, w, bottom, y_axis, name="axle")  # through the wheel's centre of mass
    box = Shape("box", size=(0.4, 0.2, 0.1), collide=False)
    mass, inertia = box.mass_properties(500.0)
    b = builder.add_body(mass, inertia, (2.0, 0.0, 0.0), angular_velocity=(3.0, 20.0, 1.0), name="box", shape=box)
    builder.add_joint_revolute(None, b, (2.0, 0.0, 0.0), (1.0, 1.0, 0.0), name="box_hinge")
    return builder


def redundant_pair() -> SceneBuilder:
    """A rod on a world ball joint and a second rod held to it by a fixed joint and a hinge at the same point."""
    builder = SceneBuilder()
    x_axis, y_axis = np.eye(3)[0], np.eye(3)[1]
    a, bottom = capsule(builder, np.zeros(3), x_axis, 1.0, "rod_a")
    builder.add_joint_ball(None, a, np.zeros(3), name="hang")
    b, _ = capsule(builder, bottom, x_axis, 1.0, "rod_b")
    builder.add_joint_fixed(a, b, bottom, name="weld")
    builder.add_joint_revolute(a, b, bottom, y_axis, name="hinge")
    return builder


def _tree(n):
    return lambda: binary_tree(n)


def _star(n):
    return lambda: star(n)


def _chain(n):
    return lambda: chain(n, "revolute")


# ------------------------------------------------------------------------------------------------ cases
@dataclass
class Case:
    name: str
    group: str
    build: Callable[[], SceneBuilder]
    dt: float
    steps: int
    expect: str = "hold"  # hold | hold_or_stop | error
    solver: str = "auto"
    tolerance: float = 1e-6
    max_iterations: int = 100
    energy_from: float = 0.0  # seconds; the energy reference is taken at the first step at or after this
    energy_gain: float = 0.05  # hold: E may not grow by more than this fraction of the energy scale
    expected_errors: tuple[str, ...] = ()  # for expect="error": exception class names accepted
    solved_ok: bool = False  # for expect="error": holding is accepted too
    budget_s: float = 120.0  # wall time for build + run; more is a FAIL
    isolate: bool = False  # run in a child process (time and memory limits, survives a crash)
    memory_gb: float = 10.0  # child process address-space limit
    energy_every: int = 1  # sample the energy every k steps
    note: str = ""

    @property
    def criterion(self) -> str:
        if self.expect == "hold":
            return f"joints <= {self.tolerance:g} every step, finite, energy gain <= {self.energy_gain:.0%}"
        if self.expect == "hold_or_stop":
            return f"hold (joints <= {self.tolerance:g}, energy gain <= {self.energy_gain:.0%}) or a clear error"
        accepted = " / ".join(self.expected_errors)
        return f"clear {accepted} naming the joint" + (", or hold" if self.solved_ok else "")


def cases(quick: bool) -> list[Case]:
    q = quick
    out: list[Case] = []
    for ratio in (1e3, 1e6):
        for heavy in ("tip", "root", "alternate"):
            # Under a tip 1e6 times heavier, the light links' transverse (string) mode has a frequency of
            # thousands of rad/s, beyond what a step of 1/100 s can hold (README, "Known limits"): a clear
            # stop is what this case can ask for.
            beyond = ratio == 1e6 and heavy == "tip"
            out.append(Case(
                f"mass_ratio_1e{round(math.log10(ratio))}_{heavy}", "mass ratio",
                (lambda r=ratio, h=heavy: mass_ratio_chain(r, h)), dt=1 / 100, steps=100 if q else 500,
                expect="hold_or_stop" if beyond else "hold",
                note=f"8 revolute links, neighbour mass ratio 1:{ratio:g}, heavy {heavy}"
                + ("; string mode beyond h = 1/100" if beyond else ""),
            ))  # fmt: skip
    out.append(Case("chain_1000", "size", _chain(1000), dt=1 / 60, steps=60 if q else 600,
                    note="1,000 revolute links falling from horizontal"))  # fmt: skip
    out.append(Case("star_1023", "size", _star(1023), dt=1 / 60, steps=90 if q else 300, budget_s=300.0,
                    energy_from=1.0, energy_every=10,
                    note="1,022 joints on the root: K is dense; the augmented body-joint matrix is not"))  # fmt: skip
    out.append(Case("tree_16383", "size", _tree(16383), dt=1 / 60, steps=10 if q else 120, energy_from=1.0,
                    budget_s=300.0, energy_every=10, note="binary tree, 16,383 bodies"))  # fmt: skip
    spin_steps = 60 if q else 300
    for axis_name, omega in (("long_axis", (0.0, 0.0, 100.0)), ("tumbling", (100.0, 0.0, 0.0))):
        for dt, label in ((1 / 60, "60"), (1 / 240, "240")):
            out.append(Case(
                f"spin_{axis_name}_h1_{label}", "high spin", (lambda w=omega: spinning_tree(127, w)), dt=dt,
                steps=int(round(spin_steps / 60 / dt)), expect="hold_or_stop",
                energy_from=dt,
                note=f"tree127, root at 100 rad/s about {'its long axis (z)' if omega[2] else 'x'}, h = 1/{label}",
            ))  # fmt: skip
    for dt, label in ((1 / 10, "10"), (1 / 5, "5")):
        for scene, build in (("tree31", _tree(31)), ("tree127", _tree(127)), ("star127", _star(127))):
            out.append(Case(f"large_step_{scene}_h1_{label}", "large steps", build, dt=dt,
                            steps=int(round((5.0 if q else 20.0) / dt)), expect="hold_or_stop", energy_from=1.0,
                            note=f"{scene}, h = 1/{label}"))  # fmt: skip
    out.append(Case("long_run_tree31", "long run", _tree(31), dt=1 / 60, steps=10_000 if q else 100_000,
                    energy_from=1.0, energy_every=100, budget_s=240.0,
                    note="joint and energy drift over the run"))  # fmt: skip
    for angle in (1e-2, 1e-4, 1e-6):
        refused = angle < 1e-9**0.5  # |cos| > 1 - 1e-9: the builder must refuse the pair of axes
        out.append(Case(f"universal_axes_{angle:g}_rad", "near-singular", (lambda a=angle: near_parallel_universal(a)),
                        dt=1 / 100, steps=100 if q else 500,
                        expect="error" if refused else "hold_or_stop", expected_errors=("SceneError",),
                        note=f"universal joint, axes {angle:g} rad apart"))  # fmt: skip
    out.append(Case("hinge_through_com", "near-singular", hinge_through_centre, dt=1 / 100, steps=100 if q else 500,
                    note="hinges through the centres of mass of a spinning wheel and a tumbling box"))  # fmt: skip
    for solver in ("cholesky", "cg", "iterative"):
        out.append(Case(
            f"redundant_fixed_hinge_{solver}", "redundant", redundant_pair, dt=1 / 100, steps=50, expect="error",
            solver=solver, expected_errors=("SingularSystemError", "SimulationError"), solved_ok=True,
            note="fixed joint plus hinge on one pair; solving it is allowed (Cholesky regularises the loop joint's "
            "redundant rows and reports them as Simulator.redundant_rows)",
        ))  # fmt: skip
    return out


# ------------------------------------------------------------------------------------------------ running
@dataclass
class Result:
    name: str
    group: str
    status: str = "FAIL"  # PASS | FAIL
    outcome: str = ""  # held | stopped | error | crash | timeout
    criterion: str = ""
    note: str = ""
    solver: str = ""
    bodies: int = 0
    joints: int = 0
    unknowns: int = 0  # rows of K
    dt: float = 0.0
    steps_planned: int = 0
    steps_done: int = 0
    max_joint_error: float | None = None  # over all steps
    final_joint_error: float | None = None  # recomputed from the final state
    max_velocity_error: float | None = None
    energy_drift: float | None = None
    energy_max_gain: float | None = None
    iterations_mean: float | None = None  # joint-correction solves a step
    iterations_max: int | None = None
    linear_iterations_mean: float | None = None  # CG iterations a step
    build_s: float = 0.0  # the SceneBuilder calls (host Python)
    setup_s: float = 0.0  # build + finalize + Simulator()
    run_s: float = 0.0
    ms_per_step: float | None = None
    error: str = ""
    reasons: list[str] = field(default_factory=list)


def clear_error(err: BaseException, builder: SceneBuilder | None) -> tuple[bool, str]:
    """Is `err` a clear error: one that names the step, the iterations (or, for the velocity correction, what it
    left) and the joints (or bodies) at fault?
    Returns (clear, why not)."""
    msg = str(err)
    joint_names = {j.name for j in builder.joints} if builder is not None else set()
    body_names = {b.name for b in builder.bodies} if builder is not None else set()
    names_joint = any(repr(n) in msg for n in joint_names)
    names_body = any(repr(n) in msg for n in body_names)
    if isinstance(err, SingularSystemError):
        return (names_joint, "" if names_joint else "does not name a joint")
    if isinstance(err, SceneError):
        return (names_joint or names_body or "joint '" in msg, "" if msg else "empty message")
    if isinstance(err, SimulationError):
        missing = []
        if "step " not in msg:
            missing.append("the step")
        if "NaN" in msg or "Inf" in msg:
            if not names_body:
                missing.append("the bodies")
        else:
            # A joint correction names its iterations; a velocity correction names what its one solve left.
            if "iterations" not in msg and "velocity correction left" not in msg:
                missing.append("the iterations")
            if not names_joint:
                missing.append("the joints")
        return (not missing, "does not name " + ", ".join(missing) if missing else "")
    return False, f"{type(err).__name__} is not one of the engine's clear errors"


def kinetic_energy(sim: Simulator) -> float:
    """Kinetic energy of the simulator's state, J (translation and rotation): the suite's energy scale."""
    m = sim.model.host.body_mass
    v, w = sim.state.body_v.numpy(), sim.state.body_w.numpy()
    r = quat_to_matrix(sim.state.body_q.numpy())
    iw = np.einsum("nij,njk,nlk->nil", r, sim.model.body_inertia.numpy(), r)
    return float(0.5 * np.sum(m * np.sum(v * v, axis=1)) + 0.5 * np.einsum("ni,nij,nj->", w, iw, w))


def _f(x) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def run_case(case: Case, progress: Callable[[str], None] | None = None) -> Result:
    """Build and run one case in this process, and judge it."""
    phase = ["start"]

    def say(msg: str) -> None:
        phase[0] = msg.split(" ")[0]
        if progress is not None:
            progress(msg)

    res = Result(case.name, case.group, criterion=case.criterion, note=case.note, dt=case.dt,
                 steps_planned=case.steps)  # fmt: skip
    builder = sim = None
    t0 = time.perf_counter()
    deadline = t0 + case.budget_s
    errs, verrs, its, lin = [], [], [], []
    e_ref = None
    ke_max = 0.0
    gain_max = -math.inf
    stopped: BaseException | None = None
    try:
        say("build")
        builder = case.build()
        res.build_s = time.perf_counter() - t0
        res.bodies, res.joints = len(builder.bodies), len(builder.joints)
        res.unknowns = sum(int(c.kind.dim) if hasattr(c.kind, "dim") else 0 for c in builder.constraints)
        say("finalize")
        model = builder.finalize()
        say("simulator")
        sim = Simulator(model, case.dt, tolerance=case.tolerance, solver=case.solver,
                        max_iterations=case.max_iterations, on_max_iterations="raise")  # fmt: skip
        res.solver = sim.solver_name
        t1 = time.perf_counter()
        res.setup_s = t1 - t0
        say(f"run (set-up {res.setup_s:.1f} s, of which build {res.build_s:.1f} s)")
        ref_step = max(int(math.ceil(case.energy_from / case.dt - 1e-9)), 0)
        for k in range(case.steps):
            if k == ref_step:
                e_ref = sim.energy()
            elif e_ref is not None and (k - ref_step) % case.energy_every == 0:
                e, ke = sim.energy(), kinetic_energy(sim)
                ke_max = max(ke_max, ke)
                gain_max = max(gain_max, e - e_ref)
            s = sim.step()
            res.steps_done = k + 1
            errs.append(s.max_joint_error)
            verrs.append(s.max_velocity_error)
            its.append(s.joint_iterations)
            lin.append(s.linear_iterations)
            if time.perf_counter() > deadline:
                res.reasons.append(f"time budget of {case.budget_s:g} s spent after {k + 1} of {case.steps} steps")
                break
        res.run_s = time.perf_counter() - t1
    except (SimulationError, SingularSystemError, SceneError) as err:
        stopped = err
        res.error = f"{type(err).__name__}: {err}"
    except MemoryError as err:  # a case too big for the machine is a finding, not a crash of the suite
        res.outcome, res.error = "error", f"MemoryError: {err}"
        res.reasons.append(f"out of memory in {phase[0]} after {time.perf_counter() - t0:.1f} s")
    except Exception as err:  # noqa: BLE001 - anything else is an unclear failure, reported as such
        res.outcome = "error"
        res.error = f"{type(err).__name__}: {err}"
        res.reasons.append(f"unexpected {type(err).__name__} in {phase[0]}")
        tb = traceback.format_exc(limit=4)
        res.error += "\n" + tb
    if sim is None:
        res.setup_s = time.perf_counter() - t0
    elif res.run_s == 0.0 and res.steps_done:
        res.run_s = time.perf_counter() - t0 - res.setup_s
    if res.steps_done:
        res.ms_per_step = 1e3 * res.run_s / res.steps_done
        res.max_joint_error = _f(max(errs))
        res.max_velocity_error = _f(max(verrs))
        res.iterations_mean = float(np.mean(its))
        res.iterations_max = int(max(its))
        res.linear_iterations_mean = float(np.mean(lin)) if res.solver == "cg" else None

    if res.outcome == "error":
        res.status = "FAIL"
        return res
    if stopped is not None:
        res.outcome = "stopped"
        clear, why = clear_error(stopped, builder)
        kind = type(stopped).__name__
        if not clear:
            res.reasons.append(f"the error is not clear: {why}")
        elif case.expect == "hold":
            res.reasons.append(f"stopped with {kind}, but this case must hold")
        elif case.expect == "error" and kind not in case.expected_errors:
            res.reasons.append(f"stopped with {kind}; expected {' or '.join(case.expected_errors)}")
        res.status = "FAIL" if res.reasons else "PASS"
        return res

    # The run went through: judge it.
    res.outcome = "held"
    if sim is not None:
        state_ok = all(np.all(np.isfinite(getattr(sim.state, f"body_{n}").numpy())) for n in "xqvw")
        if not state_ok:
            res.reasons.append("the state holds NaN or Inf and no error was raised")
        final = sim.joint_errors()
        res.final_joint_error = _f(float(final.max()) if final.size else 0.0)
        tol = case.tolerance * (1.0 + 1e-9)
        if res.final_joint_error is None or res.final_joint_error > tol:
            res.reasons.append(f"silent drift: final joint error {final.max():.3g} > {case.tolerance:g}")
        if res.max_joint_error is not None and res.max_joint_error > tol:
            res.reasons.append(f"silent drift: a step ended with joint error {res.max_joint_error:.3g}")
        if res.max_velocity_error is not None and res.max_velocity_error > sim.velocity_tolerance * (1 + 1e-9):
            res.reasons.append(f"velocity error {res.max_velocity_error:.3g} > {sim.velocity_tolerance:g}")
        if e_ref is not None and state_ok:
            e_end = sim.energy()
            ke_max = max(ke_max, kinetic_energy(sim))
            gain_max = max(gain_max, e_end - e_ref)
            scale = max(ke_max, 1e-300)
            res.energy_drift = _f((e_end - e_ref) / scale)
            res.energy_max_gain = _f(gain_max / scale)
            if res.energy_max_gain is not None and res.energy_max_gain > case.energy_gain:
                res.reasons.append(f"energy grew by {res.energy_max_gain:.1%} of the energy scale")
    if case.expect == "error" and not case.solved_ok:
        res.reasons.append(f"expected {' or '.join(case.expected_errors)}, but the run went on")
    res.status = "FAIL" if res.reasons else "PASS"
    return res


def run_isolated(case: Case, quick: bool) -> Result:
    """Run a case in a child process with the case's time budget and an address-space limit."""
    code = (
        "import json, sys\n"
        "from dataclasses import asdict\n"
        "from warpimpulse.bench import stress\n"
        "stress.quiet_warp()\n"
        f"case = next(c for c in stress.cases({quick!r}) if c.name == {case.name!r})\n"
        "res = stress.run_case(case, lambda m: print('phase:', m, file=sys.stderr, flush=True))\n"
        "print(json.dumps(asdict(res)))\n"
    )
    limit = int(case.memory_gb * 2**30)

    def limits():  # pragma: no cover - runs in the child
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    t0 = time.perf_counter()
    res = Result(case.name, case.group, criterion=case.criterion, note=case.note, dt=case.dt, steps_planned=case.steps)
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=case.budget_s,
                              preexec_fn=limits if os.name == "posix" else None)  # fmt: skip
    except subprocess.TimeoutExpired as exc:
        err = exc.stderr.decode() if isinstance(exc.stderr, bytes) else (exc.stderr or "")
        phases = [line[7:] for line in err.splitlines() if line.startswith("phase:")]
        res.outcome = "timeout"
        res.setup_s = time.perf_counter() - t0
        res.reasons.append(f"did not finish in {case.budget_s:g} s (last phase: {phases[-1] if phases else 'start'})")
        res.error = "killed at the time budget"
        return res
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode == 0 and lines:
        data = json.loads(lines[-1])
        return Result(**data)
    tail = proc.stderr.strip().splitlines()[-3:]
    phases = [line[7:] for line in proc.stderr.splitlines() if line.startswith("phase:")]
    res.outcome = "crash"
    res.setup_s = time.perf_counter() - t0
    res.reasons.append(f"child process exited with {proc.returncode} in phase {phases[-1] if phases else 'start'} "
                       f"(memory limit {case.memory_gb:g} GB)")  # fmt: skip
    res.error = " | ".join(tail)
    return res


# ------------------------------------------------------------------------------------------------ output
def _g(x, fmt=".2e") -> str:
    return "-" if x is None else format(x, fmt)


def table_row(r: Result) -> str:
    """One case's line of the table, in the columns of HEADER."""
    its = "-" if r.iterations_mean is None else f"{r.iterations_mean:.2f}/{r.iterations_max}"
    total = r.setup_s + r.run_s
    return (f"{r.name:34s} {r.bodies:6d} {r.steps_done:>6d}/{r.steps_planned:<6d} {_g(r.max_joint_error):>9s} "
            f"{_g(r.energy_drift, '+.2e'):>10s} {its:>9s} {_g(r.ms_per_step, '.2f'):>9s} {r.setup_s:7.2f} "
            f"{total:8.2f}  {r.status:4s} {r.outcome}")  # fmt: skip


HEADER = (f"{'case':34s} {'bodies':>6s} {'steps':>13s} {'max joint':>9s} {'E drift':>10s} {'it/step':>9s} "
          f"{'ms/step':>9s} {'setup s':>7s} {'total s':>8s}  result")  # fmt: skip


def _short(text: str, n: int = 240) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 3] + "..."


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="warpimpulse stress", description="the stress suite")
    parser.add_argument("--quick", action="store_true", help=f"reduced cases, under {QUICK_BUDGET_S:g} s on 2 cores")
    parser.add_argument("--json", nargs="?", const=str(DEFAULT_JSON), default=None, metavar="PATH",
                        help=f"write the results as JSON (default path {DEFAULT_JSON})")  # fmt: skip
    parser.add_argument("--case", action="append", default=[], metavar="TEXT",
                        help="run only the cases whose name contains TEXT (repeatable)")  # fmt: skip
    parser.add_argument("--list", action="store_true", help="list the cases and their criteria, and exit")
    parser.add_argument("--no-isolate", action="store_true", help="run every case in this process")
    args = parser.parse_args(argv)

    import warp as wp

    quiet_warp()
    selected = [c for c in cases(args.quick) if not args.case or any(t in c.name for t in args.case)]
    if args.list:
        for c in selected:
            print(f"{c.name:34s} {c.expect:12s} {c.criterion}  [{c.note}]")
        return 0
    if not selected:
        print(f"warpimpulse stress: error: no case matches {args.case}", file=sys.stderr)
        return 2
    if args.json:
        try:
            check_writable(Path(args.json), create_parent=True)
        except SceneError as err:
            print(f"warpimpulse stress: error: {err}", file=sys.stderr)
            return 2
    mode = "quick" if args.quick else "full"
    print(f"warpimpulse stress ({mode}): {len(selected)} cases; warp {wp.config.version}, {os.cpu_count()} cores")
    print(HEADER, flush=True)
    start = time.perf_counter()
    results = []
    for case in selected:
        res = run_isolated(case, args.quick) if case.isolate and not args.no_isolate else run_case(case)
        results.append(res)
        print(table_row(res), flush=True)
        for reason in res.reasons:
            print(f"{'':36s}-> {reason}")
        if res.error and res.outcome != "held":
            print(f"{'':36s}   {_short(res.error)}")
    total = time.perf_counter() - start
    failed = [r for r in results if r.status != "PASS"]
    stops = [r for r in results if r.outcome == "stopped" and r.status == "PASS"]
    print(f"\n{len(results) - len(failed)} passed, {len(failed)} failed, in {total:.1f} s")
    if stops:
        print("clean stops (accepted by the case's criterion; findings):")
        for r in stops:
            print(f"  {r.name}: {_short(r.error, 200)}")
    if failed:
        print("failed: " + ", ".join(r.name for r in failed))
    if args.json:
        path = Path(args.json)
        doc = {
            "mode": mode,
            "warp": wp.config.version,
            "python": platform.python_version(),
            "machine": platform.machine(),
            "cores": os.cpu_count(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "total_s": total,
            "passed": len(results) - len(failed),
            "failed": len(failed),
            "criteria": __doc__.split("\n\n")[1:4],
            "cases": [asdict(r) for r in results],
        }
        path.write_text(json.dumps(doc, indent=1, allow_nan=False, default=str) + "\n")
        print(f"wrote {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
