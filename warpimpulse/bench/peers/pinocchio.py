"""pinocchio (the articulated-body algorithm, ABA) on a builder's scene: the benchmark's second reference
and a peer.

The model comes from the same tree of elementary joints (`reduced`) that `mujoco` gives MuJoCo: each body's
parent joint becomes one pinocchio joint (a composite where MuJoCo needs several elements), its frame at
the anchor with the body's orientation, the body at its centre of mass in that frame. A fixed joint welds
the body to its parent's joint; a static body welds to the universe. pinocchio has no integrator, so
`PinocchioRunner` steps with classical RK4 on the configuration in its embedding (a ball joint's quaternion
as a 4-vector, q' = q (w, 0) / 2, renormalized after the step): ABA in C++, the four stages in Python. That
is fourth order. RK4 in the tangent space (one exp of h * sum b_i v_i, MuJoCo's scheme) adds up body-frame
velocities of different stage frames: on the trees' fast-spinning ball joints it measured second order.

Everything imports `pinocchio` when called, so this module imports without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...builder import WORLD, SceneBuilder
from ...transforms import quat_conj, quat_rotate, quat_to_matrix
from ..runner import StepFailed
from .reduced import joint_elements, parent_joints

if TYPE_CHECKING:
    import pinocchio


def pinocchio_available() -> str | None:
    """None when pinocchio imports, else why not."""
    try:
        import pinocchio  # noqa: F401
    except ImportError:
        return "pinocchio is not installed (pip install 'warpimpulse[bench]', or pip install pin)"
    return None


def _joint_model(elements: list[tuple[str, np.ndarray]]):
    import pinocchio as pin

    models = []
    for kind, axis in elements:
        if kind == "ball":
            models.append(pin.JointModelSpherical())
        elif kind == "hinge":
            models.append(pin.JointModelRevoluteUnaligned(*axis))
        else:
            models.append(pin.JointModelPrismaticUnaligned(*axis))
    if len(models) == 1:
        return models[0]
    composite = pin.JointModelComposite()
    for m in models:
        composite.addJoint(m)
    return composite


@dataclass
class PinocchioScene:
    """A pinocchio model of a builder's scene, one frame per builder body (at its centre of mass).

    Its Data is the runners' shared workspace (they hold their state in q and v): pinocchio sizes some of it
    by joints x dofs^2, 1.7 GB for the 127-body tree, too much to allocate per runner.
    """

    builder: SceneBuilder
    model: pinocchio.Model
    data: pinocchio.Data
    embedding: Embedding
    frame_ids: list[int]
    joint_ids: np.ndarray  # the joint each builder body moves with (0: the universe)

    @classmethod
    def from_builder(cls, builder: SceneBuilder) -> PinocchioScene:
        import pinocchio as pin

        def se3(rotation_xyzw: np.ndarray, translation: np.ndarray) -> pin.SE3:
            return pin.SE3(quat_to_matrix(rotation_xyzw), np.asarray(translation, dtype=np.float64))

        parents = parent_joints(builder)
        model = pin.Model()
        model.gravity = pin.Motion(np.concatenate([builder.gravity, np.zeros(3)]))
        n = len(builder.bodies)
        joint_of, joint_pose = np.zeros(n, dtype=np.int64), [pin.SE3.Identity()] * n  # host joint, its rest pose
        frame_ids = [0] * n
        done = [False] * n

        def place(b: int) -> None:
            body, joint = builder.bodies[b], parents[b]
            pose = se3(body.orientation, body.position)
            host = WORLD if joint is None else joint.parent
            host_id, host_pose = (0, pin.SE3.Identity()) if host == WORLD else (joint_of[host], joint_pose[host])
            if body.static or (joint is not None and joint.kind == "fixed"):
                jid, jpose = host_id, host_pose
            else:
                if joint is None:
                    jm, origin = pin.JointModelFreeFlyer(), body.position
                else:
                    q_inv = quat_conj(body.orientation)
                    jm = _joint_model(joint_elements(joint, lambda v: quat_rotate(q_inv, v)))
                    origin = joint.anchor
                jpose = se3(body.orientation, origin)
                jid = model.addJoint(int(host_id), jm, host_pose.actInv(jpose), joint.name if joint else body.name)
            local = jpose.actInv(pose)
            if not body.static:
                model.appendBodyToJoint(int(jid), pin.Inertia(body.mass, np.zeros(3), body.inertia), local)
            joint_of[b], joint_pose[b] = jid, jpose
            frame_ids[b] = model.addFrame(pin.Frame(body.name, int(jid), local, pin.FrameType.OP_FRAME))
            done[b] = True

        # Parents before children: follow each body up to the first placed ancestor (no recursion).
        for start in range(n):
            path, b = [], start
            while not done[b]:
                path.append(b)
                joint = parents[b]
                if joint is None or joint.parent == WORLD:
                    break
                b = joint.parent
            for b in reversed(path):
                place(b)
        return cls(builder, model, model.createData(), Embedding(model), frame_ids, joint_of)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) at the builder's pose; v fitted by least squares to the bodies' velocities, as MuJoCo's."""
        import pinocchio as pin

        q = pin.neutral(self.model)
        v = np.zeros(self.model.nv)
        dynamic = [b for b, body in enumerate(self.builder.bodies) if not body.static]
        target = np.concatenate(
            [np.concatenate([self.builder.bodies[b].linear_velocity, self.builder.bodies[b].angular_velocity])
             for b in dynamic]
        )  # fmt: skip
        if np.any(target != 0.0):
            pin.computeJointJacobians(self.model, self.data, q)
            pin.updateFramePlacements(self.model, self.data)
            rows = np.vstack(
                [
                    pin.getFrameJacobian(self.model, self.data, self.frame_ids[b], pin.LOCAL_WORLD_ALIGNED)
                    for b in dynamic
                ]
            )
            v, *_ = np.linalg.lstsq(rows, target, rcond=None)
            residual = float(np.abs(rows @ v - target).max())
            if residual > 1e-8 * (1.0 + float(np.abs(target).max())):
                raise ValueError(f"initial body velocities violate the joints (residual {residual:.3g})")
        return q, v


class Embedding:
    """Index maps that give q' from (q, v), for RK4 on q as a plain vector: joints whose q and v match
    (hinges, slides and their composites), quaternions (ball joints, the rotation of free joints) and the
    positions of free joints (v is in the body frame)."""

    def __init__(self, model) -> None:
        same_q, same_v, quat_q, quat_v, pos_q, pos_rot, pos_v = [], [], [], [], [], [], []
        for joint in model.joints[1:]:
            iq, iv, kind = joint.idx_q, joint.idx_v, joint.shortname()
            if kind == "JointModelSpherical":
                quat_q.append(range(iq, iq + 4))
                quat_v.append(range(iv, iv + 3))
            elif kind == "JointModelFreeFlyer":
                pos_q.append(range(iq, iq + 3))
                pos_rot.append(range(iq + 3, iq + 7))
                pos_v.append(range(iv, iv + 3))
                quat_q.append(range(iq + 3, iq + 7))
                quat_v.append(range(iv + 3, iv + 6))
            elif joint.nq == joint.nv:
                same_q.extend(range(iq, iq + joint.nq))
                same_v.extend(range(iv, iv + joint.nv))
            else:
                raise NotImplementedError(f"pinocchio peer: no embedding for {kind}")
        index = lambda rows, width: np.array(rows, dtype=np.int64).reshape(-1, width)  # noqa: E731
        self.same_q, self.same_v = np.array(same_q, dtype=np.int64), np.array(same_v, dtype=np.int64)
        self.quat_q, self.quat_v = index(quat_q, 4), index(quat_v, 3)
        self.pos_q, self.pos_rot, self.pos_v = index(pos_q, 3), index(pos_rot, 4), index(pos_v, 3)

    def rate(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """q' for the velocity v at q (written out, not via the generic helpers: it runs four times a step)."""
        out = np.empty_like(q)
        out[self.same_q] = v[self.same_v]
        if len(self.quat_q):
            quat, omega = q[self.quat_q], v[self.quat_v]
            vec, w = quat[:, :3], quat[:, 3:]
            out[self.quat_q[:, :3]] = 0.5 * (w * omega + np.cross(vec, omega))  # q (omega, 0) / 2
            out[self.quat_q[:, 3]] = -0.5 * np.einsum("ij,ij->i", vec, omega)
        if len(self.pos_q):
            out[self.pos_q] = quat_rotate(self.normalized_quats(q[self.pos_rot]), v[self.pos_v])
        return out

    def normalized(self, q: np.ndarray) -> np.ndarray:
        if not len(self.quat_q):
            return q
        q = q.copy()
        q[self.quat_q] = self.normalized_quats(q[self.quat_q])
        return q

    @staticmethod
    def normalized_quats(quats: np.ndarray) -> np.ndarray:
        return quats / np.sqrt(np.einsum("ij,ij->i", quats, quats))[:, None]


class PinocchioRunner:
    """RK4 over h with the ABA accelerations; the scene's forces act on the steps that start before `until`
    (constant in the world frame over the step), as in MujocoRunner."""

    def __init__(self, scene: PinocchioScene, rate: int) -> None:
        import pinocchio as pin

        self._pin = pin
        self.scene, self.model = scene, scene.model
        self.data = scene.data
        self.h, self.rate, self.steps = 1.0 / rate, rate, 0
        self.embedding = scene.embedding
        self.q, self.v = scene.initial_state()
        self.tau = np.zeros(self.model.nv)
        self._fext = pin.StdVec_Force()
        for _ in range(self.model.njoints):
            self._fext.append(pin.Force.Zero())
        # Steps at which the set of active forces changes (the first step starting at or after an `until`).
        self._until = [(math.ceil(f.until * rate - 1e-6), f) for f in scene.builder.forces]

    def _accel(self, q: np.ndarray, v: np.ndarray, forces: list) -> np.ndarray:
        pin = self._pin
        if not forces:
            return pin.aba(self.model, self.data, q, v, self.tau)
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        for k in range(self.model.njoints):
            self._fext[k] = pin.Force.Zero()
        for f in forces:
            jid = int(self.scene.joint_ids[f.body])
            com = self.data.oMf[self.scene.frame_ids[f.body]].translation
            world = pin.Force(f.force, f.torque + np.cross(com, f.force))  # about the world origin
            self._fext[jid] = self._fext[jid] + self.data.oMi[jid].actInv(world)
        return pin.aba(self.model, self.data, q, v, self.tau, self._fext)

    def step(self) -> None:
        h, emb = self.h, self.embedding
        forces = [f for end, f in self._until if self.steps < end]
        q, v = self.q, self.v
        dq, dv = [], []
        stage_q, stage_v = q, v
        for c in (0.5, 0.5, 1.0, None):  # classical RK4: stages at h/2, h/2, h
            dq.append(emb.rate(stage_q, stage_v))
            dv.append(self._accel(emb.normalized(stage_q), stage_v, forces).copy())
            if c is not None:
                stage_q, stage_v = q + c * h * dq[-1], v + c * h * dv[-1]
        self.q = emb.normalized(q + h / 6.0 * (dq[0] + 2.0 * dq[1] + 2.0 * dq[2] + dq[3]))
        self.v = v + h / 6.0 * (dv[0] + 2.0 * dv[1] + 2.0 * dv[2] + dv[3])
        self.steps += 1

    def check(self) -> None:
        if not (np.all(np.isfinite(self.q)) and np.all(np.isfinite(self.v))):
            raise StepFailed(f"pinocchio diverged before t = {self.steps / self.rate:.4g} s")

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres of mass (N, 3) and orientations (N, 4, xyzw) in builder order."""
        pin = self._pin
        pin.framesForwardKinematics(self.model, self.data, self.q)
        frames = [self.data.oMf[f] for f in self.scene.frame_ids]
        x = np.array([m.translation for m in frames])
        q = np.array([pin.Quaternion(m.rotation).coeffs() for m in frames])
        return x, q

    def energy(self) -> tuple[float, float]:
        """(total, kinetic): kinetic plus potential in the scene's gravity."""
        kinetic = self._pin.computeKineticEnergy(self.model, self.data, self.q, self.v)
        potential = self._pin.computePotentialEnergy(self.model, self.data, self.q)
        return float(kinetic + potential), float(kinetic)
