"""Where a step's time goes, and the step beside MuJoCo's (issue: one launch a step).

For each scene: the time of a step by the fused schedule (whole steps, many a launch: `sim.step(n)`; and one
`sim.step()` a call), by the parallel schedule, and of MuJoCo's Euler and RK4 steps on the same scene and step
(`mj_step(nstep=n)` and one `mj_step` a call), medians of interleaved rounds. Then the fused step by stage:
each serial stage of kernels/step.py (predict every body, joint errors, solve, apply, frames, assemble, factor,
velocity errors, the NaN/spin summary) launched alone, its marginal time a call (launches of `REPEATS` and
3 `REPEATS` calls), times the number of times a step runs it
(from the run's StepStats); "other" is the measured step minus their sum. chain10 with a force element on every
link: fused against parallel. Big trees give the cost per body-step and the set-up time (builder, finalize,
Simulator). The first iteration's Newton step (`Simulator(newton=...)`) off and on, interleaved, on the small
scenes and two big trees: where it pays places `types.NEWTON_BODIES`; the velocity correction deferred to where
the state is handed out (`Simulator(defer_velocities=...)`) off and on, likewise. Step times are CPU time of this
process (`time.process_time`): on a shared machine, time spent descheduled is not the engine's.

`--mechanisms`: only the mechanisms, fused against parallel, interleaved blocks from the same state, into their own
JSON: chain10 with a force element on every link, and the scenes with rows of the correction loop (kernels/limits.py):
chain10 with a +-0.3 rad limit on every hinge, chain10 with a stiff velocity motor on every hinge, and the paper's
walking machine and car held in the air (`collide=False`: joints, motors and springs alone; with their collision
shapes they have a contact stage, which the fused step does not have).

    python benchmarks/step_breakdown.py [--quick] [--json results/step_breakdown.json] [--readme docs/results.md]
    python benchmarks/step_breakdown.py --mechanisms [--json benchmarks/results/fused_mechanisms.json]
"""

from __future__ import annotations

import argparse
import gc
import json
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp
from warpimpulse.kernels import step as step_kernels
from warpimpulse.kernels.inertia import sym33d

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.blocks import write_block
from warpimpulse.bench.harness import metadata
from warpimpulse.launch import record

ROOT = Path(__file__).resolve().parent.parent
REPEATS = 200  # stage calls a launch
ROUNDS = 7
# Steps a timed block, each timed after an untimed run of the same block (`_median_time`'s `prepare`; blocks of
# 600 ran the chains into split steps and MuJoCo into divergence).
STEPS = 60
SCENES = {  # name: (builder, dt, tolerance)
    "tree127": (lambda: scenes.binary_tree(127), 1 / 60, 1e-6),
    "double_pendulum": (scenes.double_pendulum, 1 / 120, 1e-6),
    "chain10": (lambda: scenes.chain(10), 1 / 60, 1e-6),
    "chain50": (lambda: scenes.chain(50), 1 / 60, 1e-6),
}
MECHANISMS = ("springs", "joint springs")  # benchmarks/mechanisms.py's chain10 variants (force elements)
ROW_CHAINS = ("limits", "stiff motors")  # its chain10 variants with rows of the correction loop
ROW_SCENES = {  # name: builder (h = 1/60): the paper's mechanisms held, their shapes for display only
    "walking machine (held)": lambda: scenes.walking_machine(collide=False),
    "car (held)": lambda: scenes.car(collide=False),
}
STEP_JSON = ROOT / "benchmarks/results/step_breakdown.json"
MECHANISMS_JSON = ROOT / "benchmarks/results/fused_mechanisms.json"
BIG = (2047, 65535)  # binary trees for the cost per body-step and set-up
ANALYSIS = (65535, 1048575)  # binary trees for the symbolic analysis alone

vec3d, quatd, mat33d, f64 = wp.vec3d, wp.quatd, wp.mat33d, wp.float64


def _stage_kernels(ns):
    """One kernel a stage, running it `repeats` times, with the fused kernel's parameter names."""
    module = f"step_breakdown_{ns.module.rsplit('.', 1)[-1]}"
    position_errors_all, frames_all, summary_all = ns.position_errors_all, ns.frames_all, ns.summary_all

    @wp.kernel(module=module)
    def predict(repeats: int, body_count: int, body_inv_mass: wp.array(dtype=f64), body_inertia: wp.array(dtype=mat33d),
                body_inv_inertia: wp.array(dtype=mat33d), body_principal: wp.array(dtype=int),
                body_euler: wp.array(dtype=vec3d), body_axes: wp.array(dtype=quatd), gravity: vec3d, h: f64,
                body_x_out: wp.array(dtype=vec3d), body_q_out: wp.array(dtype=quatd), body_v_out: wp.array(dtype=vec3d),
                body_w_out: wp.array(dtype=vec3d), body_force_in: wp.array(dtype=vec3d),
                body_torque_in: wp.array(dtype=vec3d), pred_x: wp.array(dtype=vec3d), pred_q: wp.array(dtype=quatd),
                pred_v: wp.array(dtype=vec3d), pred_w: wp.array(dtype=vec3d)):  # fmt: skip
        for _ in range(repeats):
            step_kernels.predict_all(
                body_count, body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler,
                body_axes, gravity, h, body_x_out, body_q_out, body_v_out, body_w_out,
                body_force_in, body_torque_in, pred_x, pred_q, pred_v, pred_w,
            )  # fmt: skip

    @wp.kernel(module=module)
    def joint_errors(repeats: int, constraint_count: int, constraint_kind: wp.array(dtype=int),
                     constraint_body0: wp.array(dtype=int), constraint_body1: wp.array(dtype=int),
                     constraint_anchor0: wp.array(dtype=vec3d), constraint_anchor1: wp.array(dtype=vec3d),
                     constraint_axis0: wp.array(dtype=vec3d), constraint_axis1: wp.array(dtype=vec3d),
                     constraint_rest_rotation: wp.array(dtype=quatd), constraint_rest_angle: wp.array(dtype=f64),
                     h: f64, proj: wp.array(dtype=mat33d), pred_x: wp.array(dtype=vec3d),
                     pred_q: wp.array(dtype=quatd), errors: wp.array(dtype=f64),
                     rhs: wp.array(dtype=vec3d)):  # fmt: skip
        for _ in range(repeats):
            position_errors_all(
                constraint_count, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
                constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation,
                constraint_rest_angle, f64(1.0) / h, proj, pred_x, pred_q, errors, rhs,
            )  # fmt: skip

    @wp.kernel(module=module)
    def solve(repeats: int, augmented: int, offset: int, constraint_count: int, perm: wp.array(dtype=int),
              col_start: wp.array(dtype=int), col_row: wp.array(dtype=int), col_sign: wp.array(dtype=f64),
              row_start: wp.array(dtype=int), row_slot: wp.array(dtype=int), row_col: wp.array(dtype=int),
              values: wp.array(dtype=mat33d), work: wp.array(dtype=vec3d),
              aug_rhs: wp.array(dtype=vec3d), aug_x: wp.array(dtype=vec3d), rhs: wp.array(dtype=vec3d),
              impulse: wp.array(dtype=vec3d)):  # fmt: skip
        for _ in range(repeats):
            step_kernels.cholesky_solve(
                augmented, offset, constraint_count, perm, col_start, col_row, col_sign, row_start, row_slot,
                row_col, values, work, aug_rhs, aug_x, rhs, impulse,
            )  # fmt: skip

    @wp.kernel(module=module)
    def apply(repeats: int, body_count: int, constraint_kind: wp.array(dtype=int), body_inv_mass: wp.array(dtype=f64),
              body_rows_start: wp.array(dtype=int), body_rows: wp.array(dtype=int),
              inv_inertia_world: wp.array(dtype=sym33d), jac_lin: wp.array(dtype=mat33d),
              jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d), impulse: wp.array(dtype=vec3d),
              pred_v: wp.array(dtype=vec3d), pred_w: wp.array(dtype=vec3d)):  # fmt: skip
        for _ in range(repeats):  # into the scratch prediction: the state stays as it was
            step_kernels.apply_all(
                body_count, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin,
                jac_ang, jac_skew, impulse, pred_v, pred_w,
            )  # fmt: skip

    @wp.kernel(module=module)
    def frames(repeats: int, body_count: int, constraint_count: int, body_principal: wp.array(dtype=int),
               body_inv_principal: wp.array(dtype=vec3d), body_inv_inertia: wp.array(dtype=mat33d),
               constraint_kind: wp.array(dtype=int), constraint_body0: wp.array(dtype=int),
               constraint_body1: wp.array(dtype=int), constraint_anchor0: wp.array(dtype=vec3d),
               constraint_anchor1: wp.array(dtype=vec3d), constraint_axis0: wp.array(dtype=vec3d),
               constraint_axis1: wp.array(dtype=vec3d), body_x_out: wp.array(dtype=vec3d),
               body_q_out: wp.array(dtype=quatd), inv_inertia_world: wp.array(dtype=sym33d),
               proj: wp.array(dtype=mat33d), jac_lin: wp.array(dtype=mat33d),
               jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d)):  # fmt: skip
        for _ in range(repeats):
            frames_all(
                body_count, constraint_count, body_principal, body_inv_principal, body_inv_inertia, constraint_kind,
                constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1, constraint_axis0,
                constraint_axis1, body_x_out, body_q_out, inv_inertia_world, proj, jac_lin, jac_ang, jac_skew,
            )  # fmt: skip

    @wp.kernel(module=module)
    def assemble_factor(repeats: int, factor: int, augmented: int, constraint_kind: wp.array(dtype=int),
                        constraint_body0: wp.array(dtype=int), constraint_body1: wp.array(dtype=int),
                        body_inv_mass: wp.array(dtype=f64), slot_row: wp.array(dtype=int),
                        perm: wp.array(dtype=int), slot_sides: wp.array(dtype=wp.vec4i),
                        slot_code: wp.array(dtype=int), slot_ref: wp.array(dtype=int),
                        inv_inertia_world: wp.array(dtype=sym33d), jac_lin: wp.array(dtype=mat33d),
                        jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d), pivot_tolerance: f64,
                        loop_tolerance: f64,
                        col_loop: wp.array(dtype=int), col_start: wp.array(dtype=int),
                        update_start: wp.array(dtype=int), update_target: wp.array(dtype=int),
                        update_a: wp.array(dtype=int), update_b: wp.array(dtype=int),
                        update_sign: wp.array(dtype=f64), col_sign: wp.array(dtype=f64),
                        slot_shape: wp.array(dtype=wp.vec2i), values: wp.array(dtype=mat33d),
                        singular: wp.array(dtype=int)):  # fmt: skip
        for _ in range(repeats):
            for s in range(slot_code.shape[0]):
                step_kernels.augmented_slot(
                    s, constraint_kind, body_inv_mass, slot_code, slot_ref, inv_inertia_world, jac_lin, jac_ang,
                    jac_skew, values,
                )  # fmt: skip
            j = wp.int32(0)  # as the fused step: each column assembled, then factored (a while loop, as there)
            while j < col_start.shape[0] - 1:
                if slot_row.shape[0] > 0:
                    step_kernels.assemble_column(
                        j, perm, col_start, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                        slot_row, slot_sides, inv_inertia_world, jac_lin, jac_ang, jac_skew, values,
                    )  # fmt: skip
                if factor != 0:
                    step_kernels.factor_column(
                        j, augmented, col_start, update_start, update_target, update_a, update_b, update_sign, col_sign,
                        col_loop, slot_shape, pivot_tolerance, loop_tolerance, values, singular,
                    )  # fmt: skip
                j += 1

    @wp.kernel(module=module)
    def velocity_errors(repeats: int, constraint_count: int, constraint_kind: wp.array(dtype=int),
                        constraint_body0: wp.array(dtype=int),
                        constraint_body1: wp.array(dtype=int), jac_lin: wp.array(dtype=mat33d),
                        jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d),
                        body_v_out: wp.array(dtype=vec3d),
                        body_w_out: wp.array(dtype=vec3d), errors: wp.array(dtype=f64),
                        rhs: wp.array(dtype=vec3d)):  # fmt: skip
        for _ in range(repeats):
            step_kernels.velocity_errors_all(
                constraint_count, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang, jac_skew,
                body_v_out, body_w_out, errors, rhs,
            )  # fmt: skip

    @wp.kernel(module=module)
    def summary(repeats: int, body_count: int, pred_x: wp.array(dtype=vec3d), pred_q: wp.array(dtype=quatd),
                pred_v: wp.array(dtype=vec3d), pred_w: wp.array(dtype=vec3d), errors: wp.array(dtype=f64)):  # fmt: skip
        for _ in range(repeats):
            bad, spin = summary_all(body_count, pred_x, pred_q, pred_v, pred_w)
            errors[0] = spin + f64(bad)

    return dict(predict=predict, joint_errors=joint_errors, solve=solve, apply=apply, frames=frames,
                assemble_factor=assemble_factor, velocity_errors=velocity_errors, summary=summary)  # fmt: skip


def _median_time(fn, rounds: int = ROUNDS, prepare=None) -> float:
    """The median CPU time of `fn()`, the garbage collector run before each call and held off during it;
    `prepare()`, untimed, between the collection and the call (a collection walks every object and leaves the
    caches cold: the double pendulum's 60 steps took 3.8 us a step right after one, 2.4 without)."""
    times = []
    for _ in range(rounds):
        gc.collect()
        gc.disable()
        try:
            if prepare is not None:
                prepare()
            start = time.process_time()
            fn()
            times.append(time.process_time() - start)
        finally:
            gc.enable()
    return statistics.median(times)


def per_step(stats: list, field: str, steps: int) -> float:
    """A StepStats count a step over `steps` steps, from their own or combined (`Simulator.step(n)`) stats."""
    return sum(getattr(s, field) for s in stats) / steps


def breakdown(sim: wi.Simulator, stats: list, steps: int) -> dict:
    """Seconds a step spends in each serial stage of the fused schedule (stage time x calls a step)."""
    kernels = _stage_kernels(sim._fused)
    p = sim.pred
    sources = (sim.linear.fused_args, sim.model, sim.frames, sim.control, sim, sim.linear.device_pattern, sim.linear)
    common = dict(pred_x=p.body_x, pred_q=p.body_q, pred_v=p.body_v, pred_w=p.body_w, h=sim.dt)

    def per_call(name: str, **values) -> float:
        """The marginal time of a call: launches of REPEATS and 3 REPEATS calls, their difference over 2 REPEATS
        (a launch's own cost, tens of us on the CPU, would otherwise weigh on the small scenes' stages). The two
        launches take turns and each keeps its least time: a median of each, taken apart, went negative on a
        busy machine (another process's burst in one of them)."""
        launches = [
            record(kernels[name], 1, sim.model.device, sources, data_out=sim.state, repeats=repeats, **common,
                   **values)
            for repeats in (REPEATS, 3 * REPEATS)
        ]  # fmt: skip
        for launch in launches:
            launch.launch()  # compile and warm
        times = [[], []]
        for _ in range(ROUNDS):
            for timed, launch in zip(times, launches):
                timed.append(_median_time(launch.launch, rounds=1))
        return (min(times[1]) - min(times[0])) / (2 * REPEATS)

    it, vel = per_step(stats, "joint_iterations", steps), per_step(stats, "velocity_iterations", steps)
    wp.copy(p.body_x, sim.state.body_x)
    wp.copy(p.body_q, sim.state.body_q)
    assemble = per_call("assemble_factor", factor=0)
    stage = {
        "predict": (per_call("predict"), 1 + it),
        "joint_errors": (per_call("joint_errors"), 1 + it),
        "solve": (per_call("solve"), it + vel),
        "apply": (per_call("apply"), it + vel),
        "frames": (per_call("frames"), 1.0),
        "assemble": (assemble, 1.0),
        "factor": (per_call("assemble_factor", factor=1) - assemble, 1.0),
        "velocity_errors": (per_call("velocity_errors"), 1 + vel),
        "summary": (per_call("summary"), 1.0),
    }
    return {name: {"per_call_us": t * 1e6, "calls_per_step": calls, "per_step_us": t * calls * 1e6}
            for name, (t, calls) in stage.items()}  # fmt: skip


class _Ours:
    """Our simulator, restored to a snapshot before each timed block (not timed)."""

    def __init__(self, make, dt: float, tolerance: float, schedule: str, batched: bool, **options) -> None:
        self.sim = wi.Simulator(
            make().finalize("cpu"),
            dt,
            tolerance=tolerance,
            **wi.StepOptions.fold({**options, "schedule": schedule}),
        )
        self.batched = batched
        self.stats: list = []
        self.sim.step(int(round(1.1 / dt)))  # past the start forces, kernels compiled
        self.snapshot = [a() for a in (self.sim.positions, self.sim.orientations, self.sim.linear_velocities,
                                       self.sim.angular_velocities)]  # fmt: skip
        self.clock = (self.sim.time, self.sim.step_count)

    def restore(self) -> None:
        self.sim.set_state(*self.snapshot)
        self.sim.time, self.sim.step_count = self.clock

    def run(self, steps: int) -> None:
        if self.batched:
            self.stats = [self.sim.step(steps)]  # one StepStats of the steps (substeps: their count)
        else:
            self.stats = [self.sim.step() for _ in range(steps)]


class _MuJoCo:
    def __init__(self, make, dt: float, integrator: str, batched: bool) -> None:
        import mujoco

        from warpimpulse.bench.peers.mujoco import MujocoRunner, MujocoScene

        self.mj, self.batched = mujoco, batched
        self.runner = MujocoRunner(MujocoScene.from_builder(make(), dt, integrator), integrator, int(round(1 / dt)))
        for _ in range(int(round(1.1 / dt))):  # past the start forces
            self.runner.step()
        d = self.runner.data
        self.snapshot = (d.time, d.qpos.copy(), d.qvel.copy(), d.qacc_warmstart.copy())

    def restore(self) -> None:
        d = self.runner.data
        d.time, d.qpos[:], d.qvel[:], d.qacc_warmstart[:] = self.snapshot

    def run(self, steps: int) -> None:
        m, d = self.runner.model, self.runner.data
        if self.batched:
            self.mj.mj_step(m, d, steps)
        else:
            for _ in range(steps):
                self.mj.mj_step(m, d)

    def diverged(self) -> bool:
        return bool(self.runner.scene.diverged(self.runner.data))


def _interleaved(engines: dict, steps: int) -> dict:
    """Each engine's us a step in ROUNDS rounds of blocks of `steps` steps, the engines taking turns, every block
    from the same state: run once untimed, restored, then timed."""
    times: dict = {key: [] for key in engines}
    for _ in range(ROUNDS):
        for key, engine in engines.items():
            engine.restore()

            def warm(engine=engine) -> None:
                engine.run(steps)
                engine.restore()

            times[key].append(_median_time(lambda e=engine: e.run(steps), rounds=1, prepare=warm) / steps * 1e6)
    return times


def scene_point(name: str, steps: int) -> dict:
    """Every engine from the same state (the scene at 1.1 s), `steps` steps a block, blocks interleaved."""
    make, dt, tolerance = SCENES[name]
    engines = {
        "fused_batched": _Ours(make, dt, tolerance, "fused", True),
        "fused_per_call": _Ours(make, dt, tolerance, "fused", False),
        "parallel": _Ours(make, dt, tolerance, "parallel", False),
    }
    try:
        for integrator in ("Euler", "RK4"):
            for batched in (True, False):
                engines[f"mujoco_{integrator}_{'batched' if batched else 'per_call'}"] = _MuJoCo(
                    make, dt, integrator, batched
                )
    except ImportError:
        pass
    times = _interleaved(engines, steps)
    out: dict = {"scene": name, "dt": dt, "tolerance": tolerance, "steps": steps}
    out.update({f"{key}_us": statistics.median(t) for key, t in times.items()})
    out["mujoco_diverged"] = sorted(k for k, e in engines.items() if isinstance(e, _MuJoCo) and e.diverged())
    fused = engines["fused_batched"]
    out["joint_iterations"] = per_step(fused.stats, "joint_iterations", steps)
    fused.restore()
    out["stages"] = breakdown(fused.sim, fused.stats, steps)
    out["stages_sum_us"] = sum(s["per_step_us"] for s in out["stages"].values())
    return out


def _chain(kind: str):
    """benchmarks/mechanisms.py's chain10 with `kind` on every link, as a builder function."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from mechanisms import chain

    return lambda: chain(kind)


def mechanism_point(kind: str, steps: int, make=None) -> dict:
    """chain10 with `kind` on every link (benchmarks/mechanisms.py), or the scene `make` builds: the fused step
    (the coupled RK4 prediction, the rows, in the launch) against the parallel one, interleaved blocks from the
    same state."""
    dt = 1 / 60
    label = kind if make else f"chain10 {kind}"
    make = make or _chain(kind)
    engines = {s: _Ours(make, dt, 1e-6, s, s == "fused") for s in ("fused", "parallel")}
    assert engines["fused"].sim.schedule == "fused", engines["fused"].sim.schedule_note
    times = _interleaved(engines, steps)
    fused = engines["fused"].stats
    return {"scene": label, "dt": dt, "steps": steps,
            "fused_batched_us": statistics.median(times["fused"]), "parallel_us": statistics.median(times["parallel"]),
            "joint_iterations": per_step(fused, "joint_iterations", steps),
            "velocity_iterations": per_step(fused, "velocity_iterations", steps)}  # fmt: skip


def specialization(name: str, steps: int) -> dict:
    """The fused step compiled for the scene's constraint kinds only, and for all six (`wp.static` dispatch
    inside the fused loop), in interleaved rounds, every block from the same state (the scene at 1.1 s: run on,
    chain10 whips into split steps that the parallel schedule takes)."""
    make, dt, tolerance = SCENES[name]
    engines = {flag: _Ours(make, dt, tolerance, "fused", True, specialize=flag) for flag in (True, False)}
    times = _interleaved(engines, steps)
    kinds = list(engines[True].sim._fused.kinds)
    return {"scene": name, "kinds": kinds, "specialized_us": statistics.median(times[True]),
            "all_kinds_us": statistics.median(times[False])}  # fmt: skip


OPTIONS = {  # the Simulator flags measured off and on: the JSON's key, the table's label
    "newton": "first iteration's Newton step",
    "defer_velocities": "velocity correction only where handed out",
}


def option_point(option: str, name: str | int, steps: int) -> dict:
    """The fused step with a flag of OPTIONS off and on (`Simulator(newton=...)`, `Simulator(defer_velocities=...)`),
    interleaved rounds, every block from the same state: a scene of SCENES, or the binary tree of `name` bodies
    (an int, h = 1/60, the default tolerance), at 1.1 s. The Newton step's default takes it from
    `types.NEWTON_BODIES` bodies: this is the measurement that places that line; the deferral's shows what the
    skipped velocity corrections save."""
    make, dt, tolerance = SCENES[name] if name in SCENES else (lambda: scenes.binary_tree(name), 1 / 60, 1e-6)
    engines = {flag: _Ours(make, dt, tolerance, "fused", True, **{option: flag}) for flag in (False, True)}
    times = _interleaved(engines, steps)
    out = {"scene": name if name in SCENES else f"tree{name}", "bodies": engines[False].sim.model.body_count,
           "steps": steps}  # fmt: skip
    for flag, key in ((False, "off"), (True, "on")):
        out[f"{key}_us"] = statistics.median(times[flag])
        out[f"{key}_iterations"] = per_step(engines[flag].stats, "joint_iterations", steps)
    out["rounds_faster"] = sum(a < b for a, b in zip(times[True], times[False]))
    return out


def big_point(bodies: int, steps: int) -> dict:
    t0 = time.process_time()
    builder = scenes.binary_tree(bodies)
    t1 = time.process_time()
    model = builder.finalize("cpu")
    t2 = time.process_time()
    sim = wi.Simulator(model, 1 / 60)
    t3 = time.process_time()
    sim.step(2)
    per_step = _median_time(lambda: sim.step(steps), rounds=3) / steps
    return {"bodies": bodies, "build_s": t1 - t0, "finalize_s": t2 - t1, "simulator_s": t3 - t2,
            "per_step_ms": per_step * 1e3, "per_body_step_us": per_step / bodies * 1e6}  # fmt: skip


def analysis_point(bodies: int) -> dict:
    """The symbolic analysis alone (topology.analyze and the factor pattern) of a binary tree given as arrays,
    its CPU time and the process's peak memory (run last: the peak is the whole run's)."""
    from warpimpulse import topology

    parent = np.concatenate([[-1], (np.arange(1, bodies) - 1) // 2])
    graph = topology.Graph(body_static=np.zeros(bodies, bool), constraint_body0=parent,
                           constraint_body1=np.arange(bodies), constraint_joint=np.arange(bodies),
                           joint_parent=parent, joint_child=np.arange(bodies))  # fmt: skip
    t0 = time.process_time()
    pattern = topology.analyze(graph).pattern("auto")
    seconds = time.process_time() - t0
    return {"bodies": bodies, "analysis_s": seconds, "formulation": pattern.formulation,
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6}  # fmt: skip


def table(result: dict) -> str:
    """The README's block: per-step times beside MuJoCo, and the fused step by stage."""
    rows = ["| scene | fused, n steps a launch | fused, a step a call | parallel | MuJoCo Euler | MuJoCo RK4 |",
            "|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    for p in result["scenes"]:
        cells = []
        for integrator in ("Euler", "RK4"):
            key = f"mujoco_{integrator}"
            mark = " (diverged)" if any(k.startswith(key) for k in p["mujoco_diverged"]) else ""
            cells.append(f"{p[key + '_batched_us']:.1f} / {p[key + '_per_call_us']:.1f}{mark}"
                         if key + "_batched_us" in p else "-")  # fmt: skip
        rows.append(f"| {p['scene']} (h = 1/{round(1 / p['dt'])}) | {p['fused_batched_us']:.1f} | "
                    f"{p['fused_per_call_us']:.1f} | {p['parallel_us']:.1f} | {cells[0]} | {cells[1]} |")  # fmt: skip
    n = result["scenes"][0]["steps"]
    lines = [f"µs a step (CPU time), medians of interleaved blocks of n = {n} steps from the same state (the scene",
             "at 1.1 s), each block timed after an untimed run of itself; MuJoCo: `mj_step(nstep=n)` / one `mj_step`",
             "a call.", "", *rows, ""]  # fmt: skip
    stages = list(result["scenes"][0]["stages"])
    lines += ["The fused step by stage (µs a step: one call's time x calls a step):", "",
              "| scene | " + " | ".join(stages) + " | other |", "|---|" + "---:|" * (len(stages) + 1)]  # fmt: skip
    for p in result["scenes"]:
        other = p["fused_batched_us"] - p["stages_sum_us"]
        cells = [f"{p['stages'][s]['per_step_us']:.1f}" for s in stages]
        lines.append(f"| {p['scene']} | " + " | ".join(cells) + f" | {other:.1f} |")
    if result["big"]:
        lines += ["", "| tree bodies | build | finalize | Simulator | µs a body-step |", "|---:|---:|---:|---:|---:|"]
        for b in result["big"]:
            lines.append(f"| {b['bodies']:,} | {b['build_s']:.1f} s | {b['finalize_s']:.1f} s | "
                         f"{b['simulator_s']:.1f} s | {b['per_body_step_us']:.3f} |")  # fmt: skip
    if result.get("analysis"):
        lines += ["", "| tree bodies | symbolic analysis (arrays in) | peak memory of the run |", "|---:|---:|---:|"]
        for a in result["analysis"]:
            lines.append(f"| {a['bodies']:,} | {a['analysis_s']:.1f} s | {a['peak_rss_gb']:.2f} GB |")
    if result.get("mechanisms"):
        lines += [
            "",
            "| force elements (coupled RK4 prediction) | fused, n steps a launch | parallel |",
            "|---|---:|---:|",
        ]
        for p in result["mechanisms"]:
            lines.append(f"| {p['scene']} (h = 1/{round(1 / p['dt'])}) | {p['fused_batched_us']:.1f} | "
                         f"{p['parallel_us']:.1f} |")  # fmt: skip
    if result.get("specialization"):
        lines += ["", "| fused step, compiled for | " + " | ".join(p["scene"] for p in result["specialization"]) + " |",
                  "|---|" + "---:|" * len(result["specialization"])]  # fmt: skip
        for key, label in (("specialized_us", "the scene's kinds"), ("all_kinds_us", "all six kinds")):
            lines.append(f"| {label} | " + " | ".join(f"{p[key]:.1f} µs" for p in result["specialization"]) + " |")
    for option, title in OPTIONS.items():
        points = result.get(option)
        if not points:
            continue
        lines += ["", f"| {title} | " + " | ".join(p["scene"] for p in points) + " |",
                  "|---|" + "---:|" * len(points)]  # fmt: skip
        for key, label in (("off", "off: µs a step (iterations)"), ("on", "on: µs a step (iterations)")):
            lines.append(f"| {label} | " + " | ".join(f"{p[key + '_us']:.1f} ({p[key + '_iterations']:.2f})"
                                                     for p in points) + " |")  # fmt: skip
        lines.append("| on / off (rounds faster) | " + " | ".join(
            f"{p['on_us'] / p['off_us']:.3f} ({p['rounds_faster']} of {ROUNDS})" for p in points) + " |")  # fmt: skip
    meta = result["meta"]
    lines += ["", f"{meta['machine']}; {meta['versions']}; {meta['date']}; `python benchmarks/step_breakdown.py`."]
    return "\n".join(lines)


def mechanisms_table(result: dict) -> str:
    """The `--mechanisms` run: fused against parallel, a row a scene."""
    lines = [f"µs a step (CPU time), medians of {ROUNDS} interleaved blocks of {result['mechanisms'][0]['steps']} "
             "steps from the same state (the scene at 1.1 s):", "",
             "| scene | fused, n steps a launch | parallel | parallel / fused | joint iterations a step |",
             "|---|---:|---:|---:|---:|"]  # fmt: skip
    for p in result["mechanisms"]:
        lines.append(f"| {p['scene']} (h = 1/{round(1 / p['dt'])}) | {p['fused_batched_us']:.1f} | "
                     f"{p['parallel_us']:.1f} | {p['parallel_us'] / p['fused_batched_us']:.1f} | "
                     f"{p['joint_iterations']:.2f} |")  # fmt: skip
    meta = result["meta"]
    lines += ["", f"{meta['machine']}; {meta['versions']}; {meta['date']}; "
              "`python benchmarks/step_breakdown.py --mechanisms`."]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps, no 65,535-body tree")
    parser.add_argument("--json", default=None, help=f"default {STEP_JSON} ({MECHANISMS_JSON} with --mechanisms)")
    parser.add_argument("--readme", default=None, help="rewrite README.md's step-time block from the results")
    parser.add_argument("--from-json", action="store_true", help="only regenerate the README block")
    parser.add_argument("--mechanisms", action="store_true", help="only the mechanisms, fused against parallel")
    args = parser.parse_args(argv)
    steps = 30 if args.quick else STEPS
    if args.mechanisms:
        wp.config.quiet = True
        result = {"meta": metadata(sys.argv[1:]), "mechanisms": []}
        points = [(kind, None) for kind in MECHANISMS + ROW_CHAINS] + list(ROW_SCENES.items())
        for kind, make in points:
            result["mechanisms"].append(mechanism_point(kind, steps, make))
            print(json.dumps(result["mechanisms"][-1]), file=sys.stderr)
        Path(args.json or MECHANISMS_JSON).write_text(json.dumps(result, indent=1) + "\n")
        print(mechanisms_table(result))
        return 0
    args.json = args.json or STEP_JSON
    if args.from_json:
        result = json.loads(Path(args.json).read_text())
    else:
        wp.config.quiet = True
        result = {"meta": metadata(sys.argv[1:]), "scenes": [], "big": []}
        for name in SCENES:
            result["scenes"].append(scene_point(name, steps))
            print(json.dumps(result["scenes"][-1]), file=sys.stderr)
        result["mechanisms"] = [mechanism_point(kind, steps) for kind in MECHANISMS]
        print(json.dumps(result["mechanisms"]), file=sys.stderr)
        result["specialization"] = [specialization(name, steps) for name in ("tree127", "chain10")]
        print(json.dumps(result["specialization"]), file=sys.stderr)
        trees = [(16383, 10), (65535, 5)] if not args.quick else []
        result["newton"] = [option_point("newton", name, steps) for name in ("tree127", "double_pendulum", "chain10")]
        result["newton"] += [option_point("newton", bodies, n) for bodies, n in trees]
        print(json.dumps(result["newton"]), file=sys.stderr)
        small = ("tree127", "double_pendulum", "chain10", "chain50")
        result["defer_velocities"] = [option_point("defer_velocities", name, steps) for name in small]
        result["defer_velocities"] += [option_point("defer_velocities", bodies, n) for bodies, n in trees[:1]]
        print(json.dumps(result["defer_velocities"]), file=sys.stderr)
        for bodies in BIG[:1] if args.quick else BIG:
            result["big"].append(big_point(bodies, 5 if bodies > 10000 else 40))
            print(json.dumps(result["big"][-1]), file=sys.stderr)
        result["analysis"] = [analysis_point(n) for n in ANALYSIS]
        print(json.dumps(result["analysis"]), file=sys.stderr)
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
    text = table(result)
    print(text)
    if args.readme:
        write_block(args.readme, "step-time", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
