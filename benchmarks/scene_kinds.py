"""Run time against error over kinds of articulated scenes: warpimpulse against MuJoCo on the very same MJCF models.

    .venv/bin/python benchmarks/scene_kinds.py                 # every scene -> results/scene_kinds.json, plots, README
    .venv/bin/python benchmarks/scene_kinds.py --quick         # two scenes on a coarse grid, tables to stdout only
    .venv/bin/python benchmarks/scene_kinds.py --from-json     # plots and the README block again from the JSON
    .venv/bin/python benchmarks/scene_kinds.py --write-models  # benchmarks/models/*.xml again from their builders

Scenes (`KINDS`, one line each: name, MJCF file, window, pushes, probe): a 3D double pendulum of two ball-jointed
capsules, a 7-hinge arm with alternating axes released bent, a 30-link hinge chain released horizontal, a
humanoid-like tree hung by its neck and the paper's 127-body tree with its root torque. Both engines read the
MJCF file: MuJoCo's compiler, and ours through `warpimpulse.load_mjcf` (which maps MuJoCo's compiled model).

Each configuration is timed the two ways a user calls an engine: one step per Python call (our `sim.step()`,
`mujoco.mj_step(m, d)`) and every step of the window in one call (our `sim.step(n)`, `mj_step(m, d, nstep)`).
Every timed run starts from the initial state and runs the whole window; its error is read from its own final
state, outside the timed region, so error and time come from the same run. A warm-up round first, then
`REPEATS` rounds, each round timing every configuration once in turn. The clock is the process's CPU time
(`time.process_time`, every thread): on a shared machine a run's wall time includes other processes' time
slices, and more of them the longer the run, which would favour whatever runs shortest.

Error: the largest distance of a tracked point (every centre of mass and leaf tip) at the end of the window from
MuJoCo RK4 at h = 1/`REFERENCE_RATE` / 2; its distance from the same at twice that step is the reference's
floor. Cost: median CPU time per simulated second. The comparison's rules are `warpimpulse.bench.pareto`'s.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from warpimpulse import scenes
from warpimpulse.bench.blocks import write_block
from warpimpulse.bench.harness import Probe, log, quiet_warp
from warpimpulse.bench.pareto import FLOOR_MARGIN, LEVELS, compare, front, ratio_text
from warpimpulse.bench.peers.mujoco import MujocoScene, comparable, mujoco_available, to_spec
from warpimpulse.bench.report import spread_text
from warpimpulse.builder import SceneBuilder
from warpimpulse.mjcf import load_mjcf
from warpimpulse.shapes import Shape
from warpimpulse.simulator import SimulationError, Simulator
from warpimpulse.transforms import quat_between, quat_from_axis_angle, quat_mul, quat_rotate

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "benchmarks" / "models"
RESULTS = ROOT / "benchmarks" / "results"
JSON = RESULTS / "scene_kinds.json"
README = ROOT / "README.md"  # the front page: the ratio table and one plot (`summary_block`)
DOC = ROOT / "docs" / "results.md"  # the whole write-up (`readme_block`)
BLOCK, SUMMARY_BLOCK = "scene-kinds", "scene-kinds-summary"  # docs/results.md's and README.md's (`write_block`)

MUJOCO_INTEGRATORS = ("Euler", "implicitfast", "RK4")
MUJOCO_RATES = (10, 15, 20, 30, 40, 60, 80, 120, 160, 240, 320, 480, 640, 1000)  # h = 1/10 ... 1/1000
# (order, tolerance or None for the order's own, rates). Order 4 runs to h = 1/480: to 1/120 at its own
# tolerance (`composition.default_tolerance`, 10 h^5: 4e-10 at 1/120), then at 1e-9, far under its error there,
# so a front that stops short of 1e-5 m stops because the error does, not the grid. (Its own goes on down to
# 1e-12, under the round-off of the light bodies of the dm_control humanoid, whose velocity correction stalls
# at 1e-10 to 5e-10.) Order 4 at 1e-6 from 1/60 to 1/240 too: the serial scenes (arm7, chain30, the humanoid)
# reach the error of their own tolerance there with about half the iterations (benchmarks/tolerances.py,
# docs/tolerance.md), where the paper's tree needs its own. Dropped, as no error level of the
# 2026-12-03 run used them (results/scene_kinds.json: neither the cheapest at or below a level nor a bracketing point):
# order 2 at 1e-6 at 1/15, 1/60 and 1/120 (1e-4 there instead), order 4 at 1e-9 at 1/320. Order 4 at 1e-4 and
# 1e-5 at the large steps: where the trajectory error is 1e-3 m or more a tolerance a tenth of it leaves the error
# as it was for 25-35% less time (2026-12-03, `--scenes`-style runs of single configurations: the 3D double
# pendulum at 1/30 6.7e-4 m in 0.41 ms against 7.6e-4 in 0.55 at its own 4e-7; arm7 at 1/20 5.9e-3 in 3.7 ms
# against 5.7e-3 in 4.8; chain30 at 1/30 2.4e-4 in 7.3 ms against 2.2e-4 in 9.6).
OURS = (
    (2, 1e-4, (15, 20, 30, 40, 60, 80, 120, 160, 240, 320, 480)),
    (2, 1e-6, (20, 30, 40, 80, 160, 240, 320, 480)),
    (4, None, (8, 10, 15, 20, 30, 40, 60, 80, 120)),
    (4, 1e-4, (10, 15, 20, 30, 40)),
    (4, 1e-5, (30, 40, 60, 80, 120)),
    (4, 1e-6, (60, 80, 120, 160, 240)),
    (4, 1e-9, (160, 240, 480)),
)
QUICK_MUJOCO_RATES = (10, 30, 100, 300, 1000)
QUICK_OURS = ((2, 1e-6, (30, 120)), (4, None, (15, 60)))
QUICK_SCENES = ("double_pendulum_3d", "arm7")
REPEATS, QUICK_REPEATS = 7, 3
REFERENCE_RATE = 16000  # the reference runs at twice this; this one gives its floor
MODES = {"per_call": "one step per Python call", "one_call": "all steps in one call"}
DENSITY = 1000.0  # kg/m^3


# ------------------------------------------------------------------------------------------ models
def capsule(builder: SceneBuilder, start, direction, length: float, radius: float, name: str, parent, axis=None):
    """A capsule from `start` along `direction` (joint at `start`, its far end returned), jointed to `parent`
    (None: the world) by a hinge about `axis` (world frame), or by a ball joint without one."""
    direction = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    shape = Shape("capsule", radius=radius, length=length - 2.0 * radius, collide=False)
    mass, inertia = shape.mass_properties(DENSITY)
    start = np.asarray(start, dtype=np.float64)
    body = builder.add_body(mass, inertia, start + 0.5 * length * direction, quat_between([0, 0, 1], direction),
                            name=name, shape=shape)  # fmt: skip
    if axis is None:
        builder.add_joint_ball(parent, body, start, name=f"{name}_ball")
    else:
        builder.add_joint_revolute(parent, body, start, axis, name=f"{name}_hinge")
    return body, start + length * direction


def double_pendulum_3d() -> SceneBuilder:
    """Two 1 m capsules on ball joints, the first leaning out along x, the second along y: it moves in 3D."""
    b = SceneBuilder()
    first, elbow = capsule(b, (0, 0, 0), (1.0, 0.0, -0.3), 1.0, 0.05, "upper", None)
    capsule(b, elbow, (0.0, 1.0, 0.2), 1.0, 0.05, "lower", first)
    return b


def arm7() -> SceneBuilder:
    """A 7-hinge arm on a world hinge, reaching out level: the hinge axes alternate between two directions
    across the links (the previous link's x and y), the links taper from 0.35 m (radius 6 cm) to 0.15 m
    (4 cm), released bent (0.3 to 0.5 rad at each joint) so every joint is loaded; it falls and swings in 3D."""
    b = SceneBuilder()
    lengths = (0.35, 0.4, 0.4, 0.3, 0.3, 0.2, 0.15)
    radii = (0.06, 0.06, 0.05, 0.05, 0.045, 0.04, 0.04)
    angles = (0.3, 0.5, 0.4, -0.5, 0.4, 0.5, 0.3)
    frame = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.5 * math.pi)  # the previous link's: z along +x
    start, parent = np.zeros(3), None
    for i, (length, radius, angle) in enumerate(zip(lengths, radii, angles)):
        axis = quat_rotate(frame, np.eye(3)[i % 2])  # the previous link's x, then y, ...
        frame = quat_mul(quat_from_axis_angle(axis, angle), frame)
        direction = quat_rotate(frame, np.array([0.0, 0.0, 1.0]))
        parent, start = capsule(b, start, direction, length, radius, f"link{i}", parent, axis)
    return b


def chain30() -> SceneBuilder:
    """30 capsules of 1 m hinged about y, released horizontal (`warpimpulse.scenes.chain`)."""
    return scenes.chain(30)


def humanoid() -> SceneBuilder:
    """A torso hung from the world by a ball joint at its neck; a head on a ball joint; two arms of three hinged
    segments and two legs of four, the hinge axes alternating across the limb, limbs released spread and bent."""
    b = SceneBuilder()
    torso, pelvis = capsule(b, (0, 0, 0), (0.1, 0.0, -1.0), 0.6, 0.12, "torso", None)
    capsule(b, (0, 0, 0), (0.0, 0.1, 1.0), 0.25, 0.1, "head", torso)
    x, y = np.eye(3)[:2]
    limbs = (  # name, root, first direction, segment lengths, bend per segment (rad)
        ("arm_l", (0.0, 0.2, -0.05), (0.2, 1.0, 0.1), (0.3, 0.28, 0.12), 0.5),
        ("arm_r", (0.0, -0.2, -0.05), (0.1, -1.0, -0.3), (0.3, 0.28, 0.12), -0.6),
        ("leg_l", pelvis + (0.0, 0.1, 0.0), (0.3, 0.2, -1.0), (0.45, 0.42, 0.15, 0.08), 0.4),
        ("leg_r", pelvis + (0.0, -0.1, 0.0), (-0.2, -0.1, -1.0), (0.45, 0.42, 0.15, 0.08), -0.5),
    )
    for name, root, direction, lengths, bend in limbs:
        parent, start, d = torso, np.asarray(root, dtype=np.float64), np.asarray(direction, dtype=np.float64)
        for k, length in enumerate(lengths):
            axis = x if k % 2 == 0 else y
            parent, start = capsule(b, start, d, length, 0.2 * length if k < 2 else 0.03, f"{name}{k}", parent, axis)
            d = quat_rotate(quat_from_axis_angle(y if k % 2 == 0 else x, bend), d / np.linalg.norm(d))
    return b


def centres_of_mass(builder: SceneBuilder) -> Probe:
    """Every body's centre of mass and nothing else: a robot's leaf is a foot or a hand, not a capsule with a tip."""
    probe = Probe.from_builder(builder)
    return replace(probe, bodies=np.arange(len(builder.bodies)), local=np.zeros((len(builder.bodies), 3)))


def tree127() -> SceneBuilder:
    """The paper's tree (`warpimpulse.scenes.tree_arrays`), ball joints; its root torque is a push of `KINDS`."""
    b = SceneBuilder()
    args = scenes.tree_arrays(127)
    b.add_bodies(**args["bodies"])
    b.add_joints("ball", **args["joints"])
    return b


@dataclass(frozen=True)
class Push:
    """A torque (N m, world frame) on a named body while t < until (s): a scene's drive, given to both engines."""

    body: str
    torque: tuple[float, float, float]
    until: float


@dataclass(frozen=True)
class Kind:
    """One scene of the benchmark: the MJCF model both engines read, the window at whose end the error is taken,
    the pushes, the tracked points (`probe`), and the builder that wrote the file (None for a model from
    elsewhere, a robot's MJCF say: then only --write-models skips it).

    A robot's model ships with an installed package (`package`, the [mjcf-robots] extra): `model` is its path
    inside that package, read where pip put it, never copied here. Both engines read it with contacts and
    joint limits off (MuJoCo's are soft, ours hold exactly: they would differ by design, not by error),
    armature and frictionloss zeroed (armature has no rigid-body equivalent; frictionloss is a soft constraint
    in MuJoCo), as in tests/test_mjcf.py, and joint damping off: ours is an explicit force, unstable where
    kd h / I > 2 (docs/mjcf.md), and without the armature the ant's legs (damping 1) are split down to
    h = 1/960 at every step asked (2 s took 3 to 15 s of ours at any h). It starts from joint velocities drawn
    standard normal with `seed` times `speed`, so every limb moves. A free base falls under gravity: the limbs'
    motion relative to it is what tests the solver, and the fall is the same in both engines."""

    name: str
    title: str
    model: str  # file name in benchmarks/models, or a path inside `package`
    window: float = 2.0  # s
    pushes: tuple[Push, ...] = ()
    probe: Callable[[SceneBuilder], Probe] = Probe.from_builder
    build: Callable[[], SceneBuilder] | None = None
    package: str | None = None
    seed: int | None = None  # joint velocities standard normal from this seed, times `speed`; None: at rest
    speed: float = 1.0  # rad/s (m/s for a slide)

    def path(self) -> Path:
        """The MJCF file: in benchmarks/models, or inside the installed `package`."""
        if self.package is None:
            return MODELS / self.model
        import importlib.util

        spec = importlib.util.find_spec(self.package)
        if spec is None or spec.origin is None:
            raise FileNotFoundError(f"{self.name}: {self.package} is not installed (pip install "
                                    "'warpimpulse[mjcf-robots]')")  # fmt: skip
        return Path(spec.origin).parent / self.model

    def where(self) -> str:
        return f"{self.package}/{self.model} (installed)" if self.package else f"benchmarks/models/{self.model}"


KINDS = (
    Kind("double_pendulum_3d", "3D double pendulum, 2 ball joints", "double_pendulum_3d.xml", build=double_pendulum_3d),
    Kind("arm7", "7-hinge arm, alternating axes, released bent", "arm7.xml", build=arm7),
    Kind("chain30", "30-link hinge chain, released horizontal", "chain30.xml", build=chain30),
    Kind("humanoid", "humanoid-like tree: torso, head, limbs of 3-4 hinges", "humanoid.xml", build=humanoid),
    Kind("tree127", "the paper's tree, 127 ball joints, root torque", "tree127.xml",
         pushes=(Push("b0", (scenes.START_TORQUE, 0.0, 0.0), scenes.START_TORQUE_DURATION),), build=tree127),
    Kind("reacher", "dm_control reacher: a 2-hinge arm", "suite/reacher.xml", package="dm_control", seed=0,
         speed=10.0, probe=centres_of_mass),  # flat, no gravity along its hinges: it moves as it is started
    Kind("ant", "gymnasium ant: 4 legs of 2 hinges, free base", "envs/mujoco/assets/ant.xml", package="gymnasium",
         seed=0, probe=centres_of_mass),
    Kind("dm_humanoid", "dm_control humanoid: 21 hinges, free base", "suite/humanoid.xml", package="dm_control",
         seed=0, probe=centres_of_mass),
)  # fmt: skip


def write_models() -> list[Path]:
    """Each builder's scene as MJCF in benchmarks/models (contacts off, energy bookkeeping off: both cost MuJoCo
    time the comparison does not ask for)."""
    import mujoco

    MODELS.mkdir(parents=True, exist_ok=True)
    written = []
    for kind in KINDS:
        if kind.build is None:
            continue
        spec = to_spec(kind.build(), timestep=0.01, integrator="RK4", model_name=kind.name)
        spec.option.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        spec.compile()
        path = MODELS / kind.model
        path.write_text(spec.to_xml())
        written.append(path)
    return written


# ------------------------------------------------------------------------------------------ loading
@dataclass
class Loaded:
    """A scene read for both engines: our builder (pushes added), its finalized model, MuJoCo's scene with the
    same bodies by name, the tracked points in each engine's body frames."""

    kind: Kind
    builder: SceneBuilder
    model: object  # our finalized Model
    mscene: MujocoScene
    probe: Probe
    mujoco_local: np.ndarray  # tracked points in MuJoCo's body frames (probe.bodies order)
    source: str
    mismatch: float  # m: largest distance between the two engines' initial centres of mass


def mujoco_model(kind: Kind):
    """MuJoCo's compiled model of the scene; a robot's with contacts and limits off, armature and frictionloss
    zeroed (see `Kind`)."""
    import mujoco

    path = kind.path()
    m = mujoco.MjModel.from_xml_path(str(path))
    return m if kind.package is None else comparable(m, ("contact", "limit", "damper"))


def body_id(mj_model, name: str) -> int:
    """MuJoCo's id of our body `name`: by name, or "body<id>" for a body MuJoCo has no name for (load_mjcf's
    naming); -1 for a light body of a chain of joints ("<body>/<joint>"), which is no MuJoCo body."""
    import mujoco

    found = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, name)
    if found < 0 and name.startswith("body") and name[4:].isdigit() and int(name[4:]) < mj_model.nbody:
        if not mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_BODY, int(name[4:])):
            found = int(name[4:])
    return found


def load(kind: Kind) -> Loaded:
    """Both engines' scene from the one compiled model. Our bodies are MuJoCo's bodies that have joints, each
    with the bodies welded to it merged in, and a light body between two joints of one MuJoCo body: those are
    no MuJoCo body and are not tracked."""

    mj_model = mujoco_model(kind)
    qvel = None if kind.seed is None else kind.speed * np.random.default_rng(kind.seed).standard_normal(mj_model.nv)
    builder, source = load_mjcf(mj_model, qvel=qvel), "warpimpulse.load_mjcf"
    names = [body.name for body in builder.bodies]
    for push in kind.pushes:
        builder.add_force(names.index(push.body), torque=push.torque, until=push.until)
    ids = np.array([body_id(mj_model, n) for n in names], dtype=np.int64)
    mscene = MujocoScene(builder, mj_model, ids, qvel)
    probe = kind.probe(builder)
    keep = ids[probe.bodies] >= 0
    probe = replace(probe, bodies=probe.bodies[keep], local=probe.local[keep])
    data = mscene.make_data()
    world = probe.points(np.array([b.position for b in builder.bodies]), np.array([b.orientation for b in
                                                                                  builder.bodies]))  # fmt: skip
    mids = ids[probe.bodies]
    rot = data.xmat[mids].reshape(-1, 3, 3)
    local = np.einsum("nji,nj->ni", rot, world - data.xpos[mids])
    tracked = np.unique(probe.bodies)
    welded = [np.flatnonzero(mj_model.body_weldid == ids[b]) for b in tracked]  # a body and those welded to it
    centres = [mj_model.body_mass[w] @ data.xipos[w] / mj_model.body_mass[w].sum() for w in welded]
    mismatch = float(np.linalg.norm(np.array(centres) - np.array([builder.bodies[b].position for b in tracked]),
                                    axis=1).max())  # fmt: skip
    return Loaded(kind, builder, builder.finalize("cpu"), mscene, probe, local, source, mismatch)


# ------------------------------------------------------------------------------------------ runs
class OursRun:
    """Our Simulator at an order, step and tolerance; `reset` before each run (a fresh state, kernels kept)."""

    engine = "warpimpulse"

    def __init__(self, scene: Loaded, rate: int, order: int, tolerance: float | None) -> None:
        self.scene, self.rate, self.order = scene, rate, order
        self.sim = Simulator(scene.model, 1.0 / rate, tolerance=tolerance, order=order)
        self.tolerance = self.sim.tolerance
        self.variant = f"order {order}, tol {self.tolerance:.0e}" if tolerance else f"order {order}"

    def start(self) -> None:
        self.sim.reset()

    def per_call(self, n: int) -> None:
        step = self.sim.step
        for _ in range(n):
            step()

    def one_call(self, n: int) -> None:
        self.sim.step(n)

    def points(self) -> np.ndarray:
        return self.scene.probe.points(self.sim.positions(), self.sim.orientations())


class MujocoRun:
    """MuJoCo at an integrator and step: the window split where a push switches (xfrc_applied set between
    segments), each segment `mj_step(m, d)` n times or `mj_step(m, d, nstep=n)` once."""

    engine = "mujoco"

    def __init__(self, scene: Loaded, rate: int, integrator: str) -> None:
        self.scene, self.rate, self.variant = scene, rate, integrator
        self.order, self.tolerance = None, None

    def start(self) -> None:
        import mujoco

        self.mj_step = mujoco.mj_step
        self.scene.mscene.set_integrator(self.variant, 1.0 / self.rate)
        self.model = self.scene.mscene.model
        self.data = self.scene.mscene.make_data()  # the pushes of the first segment applied

    def _segments(self, n: int) -> list[int]:
        cuts = sorted({min(n, math.ceil(p.until * self.rate - 1e-6)) for p in self.scene.kind.pushes} | {0, n})
        return [b - a for a, b in zip(cuts, cuts[1:]) if b > a]

    def per_call(self, n: int) -> None:
        step, m, d, apply = self.mj_step, self.model, self.data, self.scene.mscene.apply_forces
        for k, count in enumerate(self._segments(n)):
            if k:
                apply(d)
            for _ in range(count):
                step(m, d)

    def one_call(self, n: int) -> None:
        step, m, d, apply = self.mj_step, self.model, self.data, self.scene.mscene.apply_forces
        for k, count in enumerate(self._segments(n)):
            if k:
                apply(d)
            step(m, d, nstep=count)

    def points(self) -> np.ndarray:
        if self.scene.mscene.diverged(self.data):
            raise FloatingPointError(f"MuJoCo diverged (bad qacc, state reset) before t = {self.data.time:.3g} s")
        ids = self.scene.mscene.body_ids[self.scene.probe.bodies]
        rot = self.data.xmat[ids].reshape(-1, 3, 3)
        return self.data.xpos[ids] + np.einsum("nij,nj->ni", rot, self.scene.mujoco_local)


@dataclass
class Measured:
    """One configuration timed one way: seconds per step and error (m) of every run, or why it failed."""

    run: OursRun | MujocoRun
    mode: str
    times: list[float] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)
    failed: str | None = None

    def once(self, ref: np.ndarray, window: float, timed: bool) -> None:
        """One run of the window from the initial state: time it (if `timed`) and take its error."""
        if self.failed:
            return
        n = int(round(window * self.run.rate))
        go = getattr(self.run, self.mode)
        self.run.start()
        try:
            start = time.process_time()  # CPU time: on a shared machine wall time counts others' time slices
            go(n)
            elapsed = time.process_time() - start
        except SimulationError as e:
            self.failed = str(e).split(";")[0][:160]
            return
        try:
            points = self.run.points()
        except FloatingPointError as e:
            self.failed = str(e)
            return
        if not np.all(np.isfinite(points)):
            self.failed = "non-finite positions at the end of the window"
            return
        self.errors.append(float(np.linalg.norm(points - ref, axis=1).max()))
        if timed:
            self.times.append(elapsed / n)

    def row(self) -> dict:
        r = self.run
        out = {"engine": r.engine, "variant": r.variant, "order": r.order, "tolerance": r.tolerance,
               "rate": r.rate, "mode": self.mode, "failed": self.failed, "times": self.times,
               "errors": self.errors}  # fmt: skip
        if self.failed is None and self.times:
            q = np.percentile(self.times, [25, 50, 75])
            out |= {"time_per_step": float(q[1]), "time_per_step_iqr": [float(q[0]), float(q[2])],
                    "time_per_step_min": min(self.times), "time_per_step_max": max(self.times),
                    "cost": float(q[1]) * r.rate, "error": max(self.errors),
                    "error_spread": max(self.errors) - min(self.errors)}  # fmt: skip
        return out


def reference(scene: Loaded) -> dict:
    """MuJoCo RK4 at 1/(2 REFERENCE_RATE) over the window; its distance from 1/REFERENCE_RATE is the floor."""
    pts = []
    for rate in (REFERENCE_RATE, 2 * REFERENCE_RATE):
        m = Measured(MujocoRun(scene, rate, "RK4"), "one_call")
        m.run.start()
        m.run.one_call(int(round(scene.kind.window * rate)))
        pts.append(m.run.points())
    return {"points": pts[1], "floor": float(np.linalg.norm(pts[0] - pts[1], axis=1).max()),
            "what": f"MuJoCo RK4 h = 1/{2 * REFERENCE_RATE}", "check": f"h = 1/{REFERENCE_RATE}"}  # fmt: skip


def run_scene(kind: Kind, quick: bool) -> dict:
    start = time.perf_counter()
    scene = load(kind)
    ref = reference(scene)
    log(f"{kind.name}: {len(scene.builder.bodies)} bodies ({scene.source}), reference floor {ref['floor']:.2g} m, "
        f"initial centres of mass agree to {scene.mismatch:.2g} m")  # fmt: skip
    if scene.mismatch > 1e-9:
        raise RuntimeError(f"{kind.where()}: the two engines' initial centres of mass differ by {scene.mismatch:.3g} m")
    runs: list[OursRun | MujocoRun] = [
        OursRun(scene, rate, order, tol) for order, tol, rates in (QUICK_OURS if quick else OURS) for rate in rates
    ]
    runs += [MujocoRun(scene, rate, integ) for integ in MUJOCO_INTEGRATORS
             for rate in (QUICK_MUJOCO_RATES if quick else MUJOCO_RATES)]  # fmt: skip
    measured = [Measured(r, mode) for r in runs for mode in MODES]
    repeats = QUICK_REPEATS if quick else REPEATS
    for round_ in range(repeats + 1):  # round 0: the warm-up (kernels, caches), its error kept, its time not
        # The collector stays off through a round (a collection costs 0.3 s with Warp loaded, more than most runs).
        gc.collect()
        gc.disable()
        try:
            for m in measured:
                m.once(ref["points"], kind.window, timed=round_ > 0)
        finally:
            gc.enable()
        log(f"  round {round_}/{repeats} done, {time.perf_counter() - start:.0f} s")
    rows = [m.row() for m in measured]
    return {"title": kind.title, "model": kind.where(), "source": scene.source,
            "bodies": len(scene.builder.bodies), "tracked_points": len(scene.probe.bodies), "window": kind.window,
            "pushes": [vars(p) | {"torque": list(p.torque)} for p in kind.pushes],
            "reference": {k: v for k, v in ref.items() if k != "points"}, "initial_mismatch": scene.mismatch,
            "repeats": repeats, "seconds": time.perf_counter() - start, "runs": rows}  # fmt: skip


# ------------------------------------------------------------------------------------------ write-up
def points_of(scene: dict, engine: str, mode: str) -> list[dict]:
    return [r for r in scene["runs"] if r["engine"] == engine and r["mode"] == mode and r["failed"] is None]


def cells(scene: dict, mode: str) -> list[dict]:
    floor = scene["reference"]["floor"]
    ours, theirs = points_of(scene, "warpimpulse", mode), points_of(scene, "mujoco", mode)
    return [compare(ours, theirs, level, floor) for level in LEVELS]


def _config(point: dict | None) -> str:
    if point is None:
        return "—"
    return f"{point['variant']} 1/{point['rate']}"


def exclusions(scene: dict) -> list[str]:
    """Every configuration left out of the fronts, and why."""
    out = []
    for r in scene["runs"]:
        if r["failed"]:
            out.append(f"{r['engine']} {r['variant']} 1/{r['rate']} ({MODES[r['mode']]}): {r['failed']}")
    return out


def ratio_table(results: dict) -> list[str]:
    head = "| scene | bodies | floor (m) | timing | " + " | ".join(f"{lv:g} m" for lv in LEVELS) + " |"
    lines = [head, "|---|---:|---:|---|" + "---:|" * len(LEVELS)]
    for scene in results["scenes"].values():
        for mode, what in MODES.items():
            row = " | ".join(ratio_text(c) for c in cells(scene, mode))
            lines.append(f"| {scene['title']} | {scene['bodies']} | {scene['reference']['floor']:.1g} | {what} | "
                         f"{row} |")  # fmt: skip
    return lines


def detail_table(results: dict) -> list[str]:
    """Per scene, timing way and level: the front points each engine's cost is read between."""
    lines = ["| scene | timing | error | ours: ms per simulated s (between) | MuJoCo: ms per simulated s (between) | "
             "ratio |", "|---|---|---:|---|---|---:|"]  # fmt: skip
    for name, scene in results["scenes"].items():
        for mode, what in MODES.items():
            for c in cells(scene, mode):
                if c["status"] == "below the reference floor":
                    continue
                sides = []
                for side in (c["ours"], c["theirs"]):
                    if not side["reached"]:
                        sides.append("not reached")
                        continue
                    a, b = side["between"]
                    where = _config(a) + ("" if b is None else f" .. {_config(b)}")
                    sides.append(f"{'<= ' if side['bound'] else ''}{side['cost'] * 1e3:.3g} ({where})")
                lines.append(f"| {name} | {what} | {c['level']:g} | {sides[0]} | {sides[1]} | {ratio_text(c)} |")
    return lines


def spread_line(results: dict) -> str:
    return spread_text([r["times"] for scene in results["scenes"].values() for r in scene["runs"] if r["times"]])


def _grid(results: dict) -> tuple[str, str]:
    """The configurations measured, from the JSON: MuJoCo's integrators and steps, our orders and tolerances."""
    runs = [r for scene in results["scenes"].values() for r in scene["runs"]]
    theirs = [r for r in runs if r["engine"] == "mujoco"]
    ours = [r for r in runs if r["engine"] == "warpimpulse"]
    mj_rates = sorted({r["rate"] for r in theirs})
    mujoco = (f"{', '.join(dict.fromkeys(r['variant'] for r in theirs))} at h = 1/{mj_rates[0]} ... "
              f"1/{mj_rates[-1]} ({len(mj_rates)} steps)")  # fmt: skip
    rates = sorted({r["rate"] for r in ours})
    parts = []
    for order in sorted({r["order"] for r in ours}):
        tols = sorted({r["variant"].split("tol ")[1] if "tol " in r["variant"] else "its own"
                       for r in ours if r["order"] == order})  # fmt: skip
        parts.append(f"order {order} at tolerance {' and '.join(tols)}")
    return mujoco, f"{', '.join(parts)}, h = 1/{rates[0]} ... 1/{rates[-1]}"


def readme_block(results: dict) -> str:
    scenes_ = results["scenes"]
    sources = sorted({s["source"] for s in scenes_.values()})
    refs = sorted({f"{s['reference']['what']} (floor: its distance from {s['reference']['check']})"
                   for s in scenes_.values()})  # fmt: skip
    windows = sorted({s["window"] for s in scenes_.values()})
    runs_by = sorted({(s.get("meta", results["meta"])["command"], s.get("meta", results["meta"])["date"])
                      for s in scenes_.values()})  # fmt: skip
    meta = results["meta"]
    repeats = sorted({s["repeats"] for s in scenes_.values()})
    mujoco, ours = _grid(results)
    robots = [s["model"] for s in scenes_.values() if s["model"].endswith("(installed)")]
    robot_text = (
        f" The robots' files ({', '.join(r.split(' ')[0] for r in robots)}) are read where pip installed them "
        "(the [mjcf-robots] extra), with contacts, joint limits and joint damping off and armature and frictionloss "
        "zeroed on both sides (see `Kind` in benchmarks/scene_kinds.py for why), from joint velocities drawn "
        "standard normal (seed 0; the reacher's times 10 rad/s, it lies flat across gravity); their free bases "
        "fall; their tracked points are the bodies' centres of mass."
        if robots
        else ""
    )
    lines = [
        "<!-- generated from benchmarks/results/scene_kinds.json by `python benchmarks/scene_kinds.py --from-json`"
        " (make bench): edit the generator, not this text -->",
        "Ratio = MuJoCo's cheapest run time per simulated second / ours, at the same trajectory error (> 1: "
        "warpimpulse is cheaper), each engine's cost read off its Pareto front by log-log interpolation. Both "
        f"engines read the same MJCF file (benchmarks/models/; ours through {', '.join(sources)}).{robot_text} "
        f"MuJoCo: {mujoco}; "
        f"ours: {ours}. Error: the largest distance of a centre of mass or leaf tip after "
        f"{' / '.join(f'{w:g}' for w in windows)} s from {'; '.join(refs)}, read from the very run that is timed; "
        f'a level under {FLOOR_MARGIN:g}x the floor is not compared. "not reached by MuJoCo" (or by warpimpulse) '
        'is no ratio and no win; "<=" where MuJoCo\'s coarsest step already beats the level (a coarser one might '
        'be cheaper), ">=" likewise for ours.',
        "",
        "Measured with "
        + "; ".join(
            f"`{c.strip()}` ({', '.join(d for c2, d in runs_by if c2 == c)})"
            for c in dict.fromkeys(c for c, _ in runs_by)
        )
        + f" on {meta['machine']} "
        f"({meta['versions']}); a shared, loaded machine, so the clock is the process's CPU time (wall time "
        "would count other processes' time slices, the more the longer a run): each cost is the median of "
        f"{'/'.join(map(str, repeats))} runs, each round timing every configuration once in turn "
        f"({spread_line(results)}; every run's times are in the JSON).",
        "",
        *ratio_table(results),
        "",
    ]
    excluded = {name: exclusions(s) for name, s in scenes_.items()}
    if any(excluded.values()):
        lines.append("Excluded from the fronts (diverged or failed within the window):")
        lines.append("")
        for name, items in excluded.items():
            if items:
                lines.append(f"- {name}: " + "; ".join(items) + ".")
    else:
        lines.append("No configuration diverged or failed.")
    lines += ["", "Where each cost is read (ms per simulated second, between which front points):", "",
              *detail_table(results), ""]  # fmt: skip
    lines += [f"![{name}](../benchmarks/results/scene_kinds_{name}.png)" for name in scenes_]
    return "\n".join(lines)


def summary_block(results: dict) -> str:
    """The front page's part: the ratio table, what it means, one plot, and where the rest is."""
    plot = "tree127" if "tree127" in results["scenes"] else next(iter(results["scenes"]))
    return "\n".join([
        "<!-- generated from benchmarks/results/scene_kinds.json by `python benchmarks/scene_kinds.py --from-json`"
        " (make bench): edit the generator, not this text -->",
        "MuJoCo's cheapest run time per simulated second over ours at the same trajectory error after 2 s (> 1: "
        "warpimpulse is cheaper), both engines reading the same MJCF file, each engine's cost read off its Pareto "
        "front over its integrators or orders, step sizes and tolerances; \"not reached\" is no ratio and no win. "
        "How it was measured, what was excluded and where each figure is read: "
        "[docs/results.md](docs/results.md#run-time-against-error-by-kind-of-scene).",
        "",
        *ratio_table(results),
        "",
        f"![{plot}: run time against error](benchmarks/results/scene_kinds_{plot}.png)",
    ])  # fmt: skip


def write_readme(results: dict) -> None:
    """The write-up into docs/results.md and its summary into README.md, between their markers."""
    write_block(DOC, BLOCK, readme_block(results))
    write_block(README, SUMMARY_BLOCK, summary_block(results))


def plots(results: dict, directory: Path = RESULTS) -> list[Path]:
    """Per scene, cost against error for both timing ways; each engine's front drawn thick."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for name, scene in results["scenes"].items():
        fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharey=True)
        for ax, (mode, what) in zip(axes, MODES.items()):
            curves: dict[str, list[dict]] = {}
            for r in scene["runs"]:
                if r["mode"] == mode and r["failed"] is None:
                    curves.setdefault(f"{r['engine']} {r['variant']}", []).append(r)
            for label, rows in curves.items():
                rows.sort(key=lambda r: r["rate"])
                ax.plot([r["error"] for r in rows], [r["cost"] * 1e3 for r in rows],
                        "o-" if label.startswith("warp") else "s--", ms=3, lw=0.8, label=label)  # fmt: skip
            for engine, color in (("warpimpulse", "k"), ("mujoco", "r")):
                pts = front(points_of(scene, engine, mode), scene["reference"]["floor"])
                ax.plot([p["error"] for p in pts], [p["cost"] * 1e3 for p in pts], "-", color=color, lw=2.5,
                        alpha=0.35, label=f"{engine} front")  # fmt: skip
            for level in LEVELS:
                ax.axvline(level, color="grey", lw=0.5, ls=":")
            ax.axvspan(1e-16, 10 * scene["reference"]["floor"], color="grey", alpha=0.15, label="under 10x floor")
            ax.set(xscale="log", yscale="log", xlabel=f"error after {scene['window']:g} s (m)",
                   ylabel="run time per simulated second (ms)", title=f"{name}: {what}")  # fmt: skip
            ax.set_xlim(left=max(1e-12, scene["reference"]["floor"]))
            ax.grid(True, which="both", alpha=0.3)
        axes[1].legend(fontsize=6, loc="upper right")
        fig.tight_layout()
        path = directory / f"scene_kinds_{name}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written


def meta(argv: list[str]) -> dict:
    import mujoco
    import warp as wp

    cores = len(__import__("os").sched_getaffinity(0))
    return {"command": "python benchmarks/scene_kinds.py " + " ".join(argv), "date": time.strftime("%Y-%m-%d %H:%M UTC",
            time.gmtime()), "machine": f"{platform.machine()}, {cores} cores", "versions": f"python "
            f"{platform.python_version()}, warp {wp.__version__}, mujoco {mujoco.__version__}"}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help=f"{' and '.join(QUICK_SCENES)} on a coarse grid, "
                   f"{QUICK_REPEATS} repeats; prints the tables, writes nothing unless --out")  # fmt: skip
    p.add_argument("--scenes", nargs="+", choices=[k.name for k in KINDS])
    p.add_argument("--out", type=Path, help=f"the JSON (default {JSON.relative_to(ROOT)}, none with --quick)")
    p.add_argument("--from-json", action="store_true", help="only the plots and the README block, from the JSON")
    p.add_argument("--write-models", action="store_true", help="only write benchmarks/models/*.xml from builders")
    args = p.parse_args(argv)
    if args.write_models:
        for path in write_models():
            log(f"wrote {path}")
        return 0
    out = args.out or (None if args.quick else JSON)
    if args.from_json:
        results = json.loads((out or JSON).read_text())
    else:
        missing = mujoco_available()
        if missing:
            log(f"scene_kinds: {missing}")
            return 2
        quiet_warp()
        names = args.scenes or (QUICK_SCENES if args.quick else [k.name for k in KINDS])
        measured = {k.name: run_scene(k, args.quick) | {"meta": meta(argv)} for k in KINDS if k.name in names}
        # --scenes re-measures some scenes of an earlier full run: the others are kept, each with its own meta.
        kept = json.loads(out.read_text())["scenes"] if args.scenes and out and out.exists() else {}
        order = [k.name for k in KINDS if k.name in measured or k.name in kept]
        results = {"meta": meta(argv), "levels": list(LEVELS),
                   "scenes": {n: measured[n] if n in measured else kept[n] for n in order}}  # fmt: skip
        if out:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(results, indent=1))
    print("\n".join(ratio_table(results) + [""] + detail_table(results)))
    if out:
        for path in plots(results, out.parent):
            log(f"wrote {path}")
        if not args.quick:
            write_readme(results)
            log(f"regenerated the {BLOCK} block of docs/results.md and the summary in README.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
