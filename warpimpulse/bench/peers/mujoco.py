"""MuJoCo on a builder's scene: the benchmark's reference and a peer.

MuJoCo works in reduced coordinates: bodies form a tree, each body carries the joints that connect it to
its parent (`reduced`). Each MuJoCo body frame is placed exactly at our body frame (origin at the centre of mass,
axes along the builder's orientation), so `xpos`/`xquat` compare with our positions/orientations
directly and the inertia tensor goes in unchanged.

The model is built through `mujoco.MjSpec` (`to_spec`); `to_mjcf` serializes it; `MujocoScene` holds the
compiled model and `MujocoRunner` steps it for the harness. Everything that needs `mujoco` imports it when
called, so this module imports without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...builder import WORLD, SceneBuilder
from ...transforms import quat_between, quat_conj, quat_mul, quat_rotate
from ..runner import StepFailed
from .reduced import joint_elements, parent_joints

if TYPE_CHECKING:
    import mujoco

INTEGRATORS = ("Euler", "implicitfast", "RK4")  # the peers of the sweep


def _wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    return np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]])


_JOINT_TYPES = {"ball": "mjJNT_BALL", "hinge": "mjJNT_HINGE", "slide": "mjJNT_SLIDE"}


def _add_geom(el, shape, friction: float) -> None:
    """A body's colliding shape as a MuJoCo geom at the body frame (our shapes are centred on it, axis z)."""
    import mujoco

    kind = {"sphere": "mjGEOM_SPHERE", "capsule": "mjGEOM_CAPSULE", "box": "mjGEOM_BOX",
            "cylinder": "mjGEOM_CYLINDER"}[shape.kind]  # fmt: skip
    el.add_geom(
        type=getattr(mujoco.mjtGeom, kind),
        size=np.array(shape.collision_size(), dtype=np.float64),
        friction=np.array([friction, 0.005, 0.0001]),
    )


def to_spec(
    builder: SceneBuilder,
    timestep: float = 0.01,
    integrator: str = "RK4",
    model_name: str = "warpimpulse",
    contacts: bool = False,
):
    """The builder's scene as a `mujoco.MjSpec`: same bodies, masses, inertias, joints, gravity. Contacts are
    off unless `contacts`: then every colliding shape is a geom (with the body's friction; MuJoCo takes the
    larger of two geoms' coefficients, we take their geometric mean, the same for equal ones), every ground a
    plane, and MuJoCo's own filters apply (a body never collides with its parent).

    Built through MjSpec rather than MJCF text because MuJoCo's XML parser refuses documents nested more
    than a few hundred bodies deep (a long chain). Forces and initial velocities are not part of the
    model; `MujocoScene` applies them at run time.
    """
    import mujoco

    parents = parent_joints(builder)
    children: dict[int, list[int]] = {}
    for b, joint in enumerate(parents):
        host = joint.parent if joint is not None else WORLD
        children.setdefault(host, []).append(b)

    spec = mujoco.MjSpec()
    spec.modelname = model_name
    spec.option.timestep = float(timestep)
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
    spec.option.gravity = np.asarray(builder.gravity, dtype=np.float64)
    if not contacts:
        spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    else:
        for ground in builder.grounds:
            spec.worldbody.add_geom(
                type=mujoco.mjtGeom.mjGEOM_PLANE,
                size=np.array([0.0, 0.0, 1.0]),
                pos=ground.normal * ground.height,
                quat=_wxyz(quat_between([0.0, 0.0, 1.0], ground.normal)),
                friction=np.array([ground.friction, 0.005, 0.0001]),
            )
    spec.option.enableflags |= int(mujoco.mjtEnableBit.mjENBL_ENERGY)
    if len(builder.bodies) > 1000:  # the default arena is too small for thousands of bodies
        spec.memory = max(64, len(builder.bodies) // 16) << 20
    if contacts:  # and for the constraints of thousands of contacts (a 1,000-body pile needs over 64 MB)
        spec.memory = max(spec.memory, len(builder.bodies) // 2 << 20)

    # Depth-first with an explicit stack: a chain of thousands of links nests thousands of bodies deep.
    stack = [(spec.worldbody, WORLD, b) for b in reversed(children.get(WORLD, []))]
    while stack:
        parent_el, parent, b = stack.pop()
        body = builder.bodies[b]
        if parent == WORLD:
            pos, quat = body.position, body.orientation
        else:
            pb = builder.bodies[parent]
            pos = quat_rotate(quat_conj(pb.orientation), body.position - pb.position)
            quat = quat_mul(quat_conj(pb.orientation), body.orientation)
        el = parent_el.add_body(name=body.name, pos=pos, quat=_wxyz(quat))
        if contacts and body.shape is not None and body.shape.collide:
            _add_geom(el, body.shape, body.friction)
        if not body.static:
            i = body.inertia
            el.explicitinertial = True
            el.mass = float(body.mass)
            el.ipos = np.zeros(3)
            el.fullinertia = np.array([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])
            joint = parents[b]
            if joint is None:
                el.add_freejoint(name=f"{body.name}_free")
            else:
                q_inv = quat_conj(body.orientation)
                anchor = quat_rotate(q_inv, joint.anchor - body.position)
                elements = joint_elements(joint, lambda v, q_inv=q_inv: quat_rotate(q_inv, v))
                for k, (kind, axis) in enumerate(elements):
                    el.add_joint(
                        name=joint.name if len(elements) == 1 else f"{joint.name}_{k}",
                        type=getattr(mujoco.mjtJoint, _JOINT_TYPES[kind]),
                        pos=anchor,
                        axis=axis,
                    )
        stack.extend((el, b, c) for c in reversed(children.get(b, [])))
    return spec


def to_mjcf(
    builder: SceneBuilder, timestep: float = 0.01, integrator: str = "RK4", model_name: str = "warpimpulse"
) -> str:
    """The same model as MJCF text (to inspect or load elsewhere; MuJoCo reads it back only for scenes nested
    less than a few hundred bodies deep)."""
    spec = to_spec(builder, timestep, integrator, model_name)
    spec.compile()
    return spec.to_xml()


@dataclass
class MujocoScene:
    """A compiled MuJoCo model of a builder's scene, with our body order and our forces."""

    builder: SceneBuilder
    model: mujoco.MjModel
    body_ids: np.ndarray  # MuJoCo body id of each builder body (-1: none, a light body of a chain of joints)
    qvel: np.ndarray | None = None  # MuJoCo's initial joint velocities, where the builder was made from them

    @classmethod
    def from_builder(
        cls, builder: SceneBuilder, timestep: float, integrator: str = "RK4", contacts: bool = False
    ) -> MujocoScene:
        import mujoco

        model = to_spec(builder, timestep, integrator, contacts=contacts).compile()
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b.name) for b in builder.bodies]
        return cls(builder, model, np.array(ids, dtype=np.int64))

    def set_integrator(self, integrator: str, timestep: float) -> None:
        import mujoco

        self.model.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
        self.model.opt.timestep = timestep

    def set_energy(self, enabled: bool) -> None:
        """Energy bookkeeping costs a little per step: enable it for accuracy runs, not for timing."""
        import mujoco

        bit = int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        self.model.opt.enableflags = (
            (self.model.opt.enableflags | bit) if enabled else (self.model.opt.enableflags & ~bit)
        )

    def make_data(self) -> mujoco.MjData:
        """MjData at the builder's initial pose and velocities: `qvel` where given (the builder was loaded from
        this model with it), else fitted by least squares to the bodies' velocities, since MuJoCo's velocity
        coordinates are per joint, not per body."""
        import mujoco

        data = mujoco.MjData(self.model)
        if self.qvel is not None:
            data.qvel[:] = self.qvel
        mujoco.mj_forward(self.model, data)
        dynamic = [b for b, body in enumerate(self.builder.bodies) if not body.static]
        target = np.concatenate(
            [
                np.concatenate([self.builder.bodies[b].linear_velocity, self.builder.bodies[b].angular_velocity])
                for b in dynamic
            ]
        )
        if self.qvel is None and np.any(target != 0.0):
            nv = self.model.nv
            rows = np.zeros((6 * len(dynamic), nv))
            for k, b in enumerate(dynamic):
                mujoco.mj_jacBodyCom(
                    self.model, data, rows[6 * k : 6 * k + 3], rows[6 * k + 3 : 6 * k + 6], self.body_ids[b]
                )
            qvel, *_ = np.linalg.lstsq(rows, target, rcond=None)
            residual = float(np.abs(rows @ qvel - target).max())
            if residual > 1e-8 * (1.0 + float(np.abs(target).max())):
                raise ValueError(f"initial body velocities violate the joints (residual {residual:.3g})")
            data.qvel[:] = qvel
            mujoco.mj_forward(self.model, data)
        self.apply_forces(data)
        return data

    def apply_forces(self, data: mujoco.MjData) -> None:
        """Set xfrc_applied (world frame, at the centre of mass, like our Force) for the step at data.time.

        A force is active for a step that starts before `until`; the tolerance absorbs the rounding of
        time accumulated over many steps, so both engines switch forces on the same step.
        """
        data.xfrc_applied[:] = 0.0
        eps = 1e-6 * self.model.opt.timestep
        for f in self.builder.forces:
            if data.time < f.until - eps:
                data.xfrc_applied[self.body_ids[f.body], :3] += f.force
                data.xfrc_applied[self.body_ids[f.body], 3:] += f.torque

    def positions(self, data: mujoco.MjData) -> np.ndarray:
        """Centres of mass (N, 3) in builder order."""
        return data.xipos[self.body_ids].copy()

    def orientations(self, data: mujoco.MjData) -> np.ndarray:
        """Body orientations (N, 4), xyzw as in Warp, of the same body frames as ours."""
        return data.xquat[self.body_ids][:, [1, 2, 3, 0]].copy()

    def points(self, data: mujoco.MjData, bodies: np.ndarray, local: np.ndarray) -> np.ndarray:
        """World positions of points given in body frames."""
        ids = self.body_ids[bodies]
        return data.xpos[ids] + np.einsum("nij,nj->ni", data.xmat[ids].reshape(-1, 3, 3), local)

    def energy(self, data: mujoco.MjData) -> float:
        """Potential + kinetic energy (needs `set_energy(True)` before the step that computed it)."""
        return float(data.energy[0] + data.energy[1])

    def total_mass(self) -> float:
        return float(self.model.body_mass.sum())

    def diverged(self, data: mujoco.MjData) -> bool:
        """MuJoCo resets the state itself when accelerations blow up; its warning counter tells us."""
        import mujoco

        bad = int(mujoco.mjtWarning.mjWARN_BADQACC)
        return data.warning[bad].number > 0 or not math.isfinite(float(data.qpos.sum()))


class MujocoRunner:
    """MuJoCo on the exported scene. Forces are switched off by step count, so the timed loop holds only
    mj_step and a comparison, as fair to MuJoCo as our loop is to us."""

    def __init__(self, mscene, integrator: str, rate: int, energy: bool = False) -> None:
        import mujoco

        self._mj = mujoco
        self.scene = mscene
        mscene.set_integrator(integrator, 1.0 / rate)
        mscene.set_energy(energy)
        self.model = mscene.model
        self.data = mscene.make_data()  # forces of the first step applied
        self.steps = 0
        self.rate = rate
        # Steps at which some force switches off (the first step starting at or after its `until`).
        switches = {math.ceil(f.until * rate - 1e-6) for f in mscene.builder.forces}
        self._switches = sorted(switches, reverse=True)
        self._next_switch = self._switches.pop() if self._switches else -1

    def step(self) -> None:
        if self.steps == self._next_switch:
            self.scene.apply_forces(self.data)
            self._next_switch = self._switches.pop() if self._switches else -1
        self._mj.mj_step(self.model, self.data)
        self.steps += 1

    def run(self, steps: int) -> None:
        """`steps` steps as mj_step calls with nstep, one between each two force switches."""
        end = self.steps + steps
        while self.steps < end:
            if self.steps == self._next_switch:
                self.step()
                continue
            stop = end if self._next_switch < self.steps else min(end, self._next_switch)
            self._mj.mj_step(self.model, self.data, nstep=stop - self.steps)
            self.steps = stop

    def check(self) -> None:
        if self.scene.diverged(self.data):
            raise StepFailed(f"MuJoCo diverged (bad qacc) before t = {self.steps / self.rate:.4g} s")

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        return self.scene.positions(self.data), self.scene.orientations(self.data)

    def energy(self) -> tuple[float, float]:
        """(total, kinetic) at the current state; mj_forward recomputes it without changing the state."""
        self._mj.mj_forward(self.model, self.data)
        return float(self.data.energy[0] + self.data.energy[1]), float(self.data.energy[1])


def mujoco_available() -> str | None:
    try:
        import mujoco
    except ImportError:
        return "mujoco is not installed (pip install 'warpimpulse[bench]')"
    # MuJoCo would print every instability warning and append it to MUJOCO_LOG.TXT in the working
    # directory; the harness reads the warning counters instead.
    mujoco.set_mju_user_warning(lambda msg: None)
    return None


def comparable(m: mujoco.MjModel, off: tuple[str, ...] = ("contact", "limit")) -> mujoco.MjModel:
    """MuJoCo's compiled model `m`, changed in place to run the equations ours runs from the same file: the
    `off` features disabled (MuJoCo's contacts and limits are soft, ours hold exactly; "damper" where dampers
    differ by design), armature and frictionloss zeroed (armature has no rigid-body equivalent and
    `load_mjcf` says so; frictionloss is a soft constraint in MuJoCo, exact dry friction here), and the energy
    bookkeeping off (it costs MuJoCo time the dynamics do not need). Returns `m`."""
    import mujoco

    for flag in off:
        m.opt.disableflags |= int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag.upper()}"))
    m.dof_armature[:] = 0.0
    m.dof_frictionloss[:] = 0.0
    m.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_ENERGY)
    return m
