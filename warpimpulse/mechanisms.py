"""What a scene's bodies do to each other besides joints: forces, springs, motors and actuators, limits, ropes.

Each is a force element inside the prediction (a load, a spring, a joint spring or damper, a PID servo: RK4
evaluates it in every stage, the method paper's section 4.4) or a row solved with the joints (a joint limit, a
stiff motor, a distance constraint: push-only or capped impulses, `kernels/limits.py`); an actuator maps a
control input onto a motor as MuJoCo's `ctrl` does. Anchors and axes are in world coordinates at build time."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import checks
from .checks import SceneError
from .transforms import quat_conj, quat_rotate
from .types import COORDINATES, DRIVE_MODES, WORLD

_vec = checks.vector


@dataclass
class Force:
    """A constant world-frame force (at the centre of mass) and torque, active while t < until."""

    body: int
    force: np.ndarray
    torque: np.ndarray
    until: float = math.inf


@dataclass
class Spring:
    """A spring-damper between a point of body0 and a point of body1 (either may be WORLD), along the line
    joining them: force = -stiffness (length - rest_length) - damping d(length)/dt, in N (method paper,
    section 4.4: the car's wheel dampers)."""

    name: str
    body0: int
    body1: int
    anchor0: np.ndarray  # body0 frame (world frame for WORLD)
    anchor1: np.ndarray  # body1 frame
    stiffness: float  # N/m
    damping: float  # N s/m
    rest_length: float  # m


@dataclass
class Drive:
    """A torque about a revolute axis (N m) or a force along a prismatic axis (N) from the joint coordinate
    (rad or m, 0 as built) and its rate: a joint spring-damper, or a servo motor with a PID controller
    (method paper, section 4.4). Position mode: kp (target - x) + ki integral(target - x) - kd dx/dt;
    velocity mode: kp (target - dx/dt) + ki integral(target - dx/dt) - kd d2x/dt2 (kd is taken 0 there).
    The output is clamped to +-max_force. A joint spring is a position drive with ki = 0 and no clamp."""

    name: str
    joint: int
    mode: int  # an index into DRIVE_MODES: 0 position, 1 velocity, 2 effort
    target: float  # rad, m (position) or rad/s, m/s (velocity)
    kp: float
    ki: float
    kd: float
    max_force: float
    motor: bool  # False for a joint spring
    stiff: bool = False  # an impulse-level velocity constraint instead of a force (velocity mode only)


@dataclass
class Limit:
    """lower <= coordinate <= upper on a revolute (rad) or prismatic (m) joint: a push-only constraint."""

    joint: int
    lower: float
    upper: float


@dataclass
class Distance:
    """lower <= |B - A| <= upper (m) between a point A of body0 and a point B of body1 (either may be WORLD): a
    rope (upper) or a strut (lower), push-only like a joint limit, and no other constraint (a distance joint)."""

    name: str
    body0: int
    body1: int
    anchor0: np.ndarray  # body0 frame (world frame for WORLD)
    anchor1: np.ndarray  # body1 frame
    axis0: np.ndarray  # body0 frame: the push direction while A and B meet (the built one, else gravity's)
    lower: float
    upper: float


@dataclass
class Actuator:
    """A named control input that sets a motor's target as MuJoCo's `ctrl` does its actuator's:
    target = gain * clip(control, ctrl_range) + bias (rad, m, rad/s, m/s, or N m / N in effort mode), the
    control starting at 0. `Simulator.set_controls` sets them by name or index."""

    name: str
    drive: int  # an index into SceneBuilder.drives (a motor)
    gain: float
    bias: float
    ctrl_range: tuple[float, float] = (-math.inf, math.inf)


def _finite(value, what: str) -> float:
    x = checks.real(value, what)
    if not math.isfinite(x):
        raise SceneError(f"{what} must be finite, got {x}")
    return x


def _nonnegative(value, what: str) -> float:
    x = _finite(value, what)
    if x < 0.0:
        raise SceneError(f"{what} must be >= 0, got {x}")
    return x


class Mechanisms:
    """The force elements and rows of a `SceneBuilder` (a part of it: they fill its lists, checked when added)."""

    def add_force(self, body, force=0.0, torque=0.0, until: float = math.inf) -> int:
        """A constant world-frame force and torque on `body`, applied while the simulated time < `until`."""
        self._open("force")
        b = self._body_index(body, "force")
        if b == WORLD or self.bodies[b].static:
            raise SceneError(f"force: body {body!r} is not dynamic")
        what = f"force on body {self.bodies[b].name!r}"
        until = checks.real(until, f"{what}: until")
        if math.isnan(until):
            raise SceneError(f"{what}: until is NaN")
        self.forces.append(Force(b, _vec(force, f"{what}: force"), _vec(torque, f"{what}: torque"), until))
        return len(self.forces) - 1

    def add_spring(
        self, body0, body1, anchor0, anchor1, stiffness: float, damping: float = 0.0, rest_length=None, name=None
    ) -> int:
        """A spring-damper between `anchor0` on `body0` and `anchor1` on `body1` (world points at build time; a
        body of None is the world). `rest_length` (m) defaults to the built distance. Returns its index."""
        name = name or f"spring{len(self.springs)}"
        what = f"spring {name!r}"
        b0, b1, a0, a1, local0, local1, _ = self._two_ends(body0, body1, anchor0, anchor1, what)
        stiffness = _nonnegative(stiffness, f"{what}: stiffness")
        damping = _nonnegative(damping, f"{what}: damping")
        rest = float(np.linalg.norm(a1 - a0))
        if rest_length is not None:
            rest = _nonnegative(rest_length, f"{what}: rest_length")
        self.springs.append(Spring(name, b0, b1, local0, local1, stiffness, damping, rest))
        return len(self.springs) - 1

    def add_joint_spring(self, joint, stiffness: float, damping: float = 0.0, rest: float = 0.0) -> int:
        """A spring-damper on a revolute angle (N m/rad, N m s/rad, rest in rad) or a prismatic offset (N/m,
        N s/m, rest in m), the coordinate being 0 as built. Its damping is taken implicitly where it is stiff
        for the step (`Simulator.implicit_dampers`). Returns its index among the joint springs."""
        j = self._coordinate_joint(joint, "a joint spring")
        what = f"joint {self.joints[j].name!r}: joint spring"
        stiffness = _nonnegative(stiffness, f"{what} stiffness")
        damping = _nonnegative(damping, f"{what} damping")
        rest = _finite(rest, f"{what} rest")
        return self._add_drive(Drive(f"{self.joints[j].name}.spring", j, 0, rest, stiffness, 0.0, damping,
                                     math.inf, motor=False))  # fmt: skip

    def add_motor(
        self, joint, mode: str = "position", target: float = 0.0, kp: float = 1.0, ki: float = 0.0, kd: float = 0.0,
        max_force: float = math.inf, stiff: bool = False,
    ) -> int:  # fmt: skip
        """A servo motor on a revolute (torque, N m) or prismatic (force, N) joint, driven by a PID controller on
        the joint's angle/offset ("position", target in rad or m) or its rate ("velocity", rad/s or m/s), and
        clamped to +-max_force. The torque acts on both bodies, equal and opposite. Returns the motor index
        for `Simulator.set_motor_target`.

        The PID torque is a force inside the prediction (explicit RK4, each body predicted alone): stable while
        kp h / I and h sqrt(kp / I) (position mode) stay below about 2, with I the inertia about the axis of the
        lighter body of the joint, alone; a light crank or steering knuckle driven hard breaks that. The damping
        term (kd, or kp in velocity mode) of an uncapped motor is taken implicitly where it is stiff for the step
        (`Simulator.implicit_dampers`, docs/mechanisms.md), stable at any gain. `stiff=True` (the gains unused)
        makes the motor an impulse-level constraint instead: each step the joint turns by h target exactly
        (velocity mode) or reaches the target (position mode), with an impulse of at most max_force h, solved
        with the joints and limits (`kernels/limits.py`), stable at any stiffness. Use the PID for compliant,
        tuned servos on bodies heavy enough; `stiff` for a speed or angle that must hold, or a
        capped motor on a light body. "effort" mode applies the target itself as the torque or force
        (the gains unused, still clamped to +-max_force): a plain motor, MuJoCo's `motor` actuator."""
        j = self._coordinate_joint(joint, "a motor")
        what = f"joint {self.joints[j].name!r}: motor"
        if mode not in DRIVE_MODES:
            raise SceneError(f"{what} mode must be one of {DRIVE_MODES}, got {mode!r}")
        if stiff and mode == "effort":
            raise SceneError(f"{what}: an effort motor is a force, not a stiff constraint")
        kp, ki, kd = (_nonnegative(g, f"{what} {n}") for g, n in ((kp, "kp"), (ki, "ki"), (kd, "kd")))
        max_force = checks.real(max_force, f"{what} max_force")
        if not max_force > 0.0:
            raise SceneError(f"{what} max_force must be positive, got {max_force}")
        target = _finite(target, f"{what} target")
        drive = Drive(f"{self.joints[j].name}.motor", j, DRIVE_MODES.index(mode), target, kp, ki, kd, max_force,
                      motor=True, stiff=bool(stiff))  # fmt: skip
        return self._add_drive(drive)

    def add_actuator(self, motor: int, gain: float = 1.0, bias: float = 0.0, ctrl_range=None, name=None) -> int:
        """A named control input of motor `motor` (`add_motor`'s index): its target becomes
        gain * clip(control, ctrl_range) + bias, and is that at control 0 from the start (`Actuator`). Returns
        its index for `Simulator.set_controls`."""
        name = name or f"actuator{len(self.actuators)}"
        what = f"actuator {name!r}"
        self._open(what)
        motors = [i for i, d in enumerate(self.drives) if d.motor]
        if isinstance(motor, bool) or not isinstance(motor, (int, np.integer)) or not 0 <= motor < len(motors):
            raise SceneError(f"{what}: motor {motor!r} does not exist ({len(motors)} motors)")
        if any(a.name == name for a in self.actuators):
            raise SceneError(f"{what}: an actuator of that name already exists")
        gain, bias = _finite(gain, f"{what} gain"), _finite(bias, f"{what} bias")
        low, high = (-math.inf, math.inf) if ctrl_range is None else (checks.real(x, f"{what} ctrl_range")
                                                                      for x in ctrl_range)  # fmt: skip
        if not low <= high:
            raise SceneError(f"{what}: ctrl_range [{low}, {high}] is empty")
        drive = motors[motor]
        self.drives[drive].target = gain * min(max(0.0, low), high) + bias
        self.actuators.append(Actuator(name, drive, gain, bias, (low, high)))
        return len(self.actuators) - 1

    def chain_joints(self, joints: Sequence[int]) -> None:
        """Joints in series between two bodies through light bodies (each joint's child the next one's parent), as
        MJCF's several joints in one body: a joint spring or PID motor on one of them acts on the chain's two end
        bodies, not on the light bodies, along the direction that does work on its own coordinate only (the
        reciprocal of the chain's axes of its kind; a force at the hinges' common anchor). With the light bodies
        massless that is the same motion, and no force falls on a body of almost no inertia (which would make
        the explicit prediction unstable)."""
        self._open("chain_joints")
        chain = tuple(int(j) for j in joints)
        if len(chain) < 2 or not all(0 <= j < len(self.joints) for j in chain):
            raise SceneError(f"chain_joints: two or more existing joints are expected, got {joints!r}")
        for a, b in zip(chain, chain[1:]):
            if self.joints[a].child != self.joints[b].parent:
                raise SceneError(f"chain_joints: joint {self.joints[b].name!r} does not start where "
                                 f"{self.joints[a].name!r} ends")  # fmt: skip
        if any(set(chain) & set(c) for c in self.chains):
            raise SceneError(f"chain_joints: joint {self.joints[chain[0]].name!r} is in a chain already")
        self.chains.append(chain)

    def _drive_chains(self) -> tuple[np.ndarray, np.ndarray]:
        """Each drive's (sibling joint, sibling joint, anchor joint) and (body, body) for `Model` (drive_chain,
        drive_ends): for a drive on a chained joint, the chain's other joints of its kind, the hinge whose
        anchor a force acts at, and the chain's ends; checked that the direction exists."""
        j = self._joints
        chain = np.array([(-1, -1, d.joint) for d in self.drives], dtype=np.int64).reshape(-1, 3)
        ends = np.array([(j["parent"][d.joint], j["child"][d.joint]) for d in self.drives], dtype=np.int64)
        of = {joint: c for c in self.chains for joint in c}
        kinds = self.joint_types()
        for i, drive in enumerate(self.drives):
            links = of.get(drive.joint)
            if links is None or drive.stiff:  # a stiff motor is a row of the correction loop, not a force
                continue
            what = f"drive {drive.name!r} on chain {[kinds[k] for k in links]}"
            if "ball" in (kinds[k] for k in links):
                raise SceneError(f"{what}: a chain with a ball joint takes no joint springs or motors")
            same = [k for k in links if kinds[k] == kinds[drive.joint] and k != drive.joint]
            hinges = [k for k in links if kinds[k] == "revolute"]
            if len(same) > 2:
                raise SceneError(f"{what}: more than three joints of one kind")
            axes = j["axis"][[drive.joint, *same]]
            if abs(np.linalg.det(axes @ axes.T)) < 1e-9:
                raise SceneError(f"{what}: the chain's axes of its kind are dependent")
            if kinds[drive.joint] == "prismatic" and hinges:
                anchors = j["anchor"][hinges]
                if np.abs(anchors - anchors[0]).max() > 1e-9:
                    raise SceneError(f"{what}: a force along a chain needs its hinges' anchors to coincide")
            chain[i] = (*(same + [-1, -1])[:2], hinges[0] if kinds[drive.joint] == "prismatic" and hinges else
                        drive.joint)  # fmt: skip
            ends[i] = (j["parent"][links[0]], j["child"][links[-1]])
        return chain, ends.reshape(-1, 2)

    def mark_loop_joint(self, joint) -> None:
        """Close a kinematic loop with `joint` where the spanning tree has a choice (method paper, section 4.6;
        USD's physics:excludeFromArticulation): its constraints go to the loop part of the system."""
        if isinstance(joint, str):
            names = [j.name for j in self.joints]
            if joint not in names:
                raise SceneError(f"mark_loop_joint: no joint named {joint!r}")
            joint = names.index(joint)
        if not isinstance(joint, (int, np.integer)) or not 0 <= int(joint) < len(self.joints):
            raise SceneError(f"mark_loop_joint: joint {joint!r} does not exist ({len(self.joints)} joints)")
        self._open("mark_loop_joint")
        self.joints[int(joint)].loop = True

    def add_joint_limit(self, joint, lower: float, upper: float) -> int:
        """Keep a revolute angle (rad) or prismatic offset (m), 0 as built, within [lower, upper]."""
        j = self._coordinate_joint(joint, "a limit")
        what = f"joint {self.joints[j].name!r}: limit"
        lower, upper = checks.real(lower, f"{what} lower"), checks.real(upper, f"{what} upper")
        if math.isnan(lower) or math.isnan(upper):
            raise SceneError(f"{what} is NaN")
        self._open(what)
        if lower > upper:
            raise SceneError(f"{what} lower {lower} > upper {upper}")
        if not lower <= 0.0 <= upper:
            raise SceneError(f"{what} [{lower}, {upper}] excludes the built pose (coordinate 0)")
        if any(limit.joint == j for limit in self.limits):
            raise SceneError(f"{what}: the joint already has a limit")
        if self._never_binds(Limit(j, lower, upper)):
            warnings.warn(f"{what} [{lower:.6g}, {upper:.6g}] rad spans a full turn or more: an angle is measured "
                          "within one turn, so it never binds, and takes no row (kept for files written)",
                          stacklevel=2)  # fmt: skip
        self.limits.append(Limit(j, lower, upper))
        return len(self.limits) - 1

    def add_distance(
        self, body0, body1, anchor0, anchor1, min_distance: float = 0.0, max_distance: float = math.inf, name=None
    ) -> int:
        """Keep the distance between `anchor0` on `body0` and `anchor1` on `body1` (world points at build time; a
        body of None is the world) within [min_distance, max_distance] (m), by push-only impulses in the
        correction loop (`kernels/limits.py`): a rope of length max_distance, a strut of min_distance, or both.
        The built distance may lie outside; the first step brings it in. Returns its index."""
        name = name or f"distance{len(self.distances)}"
        what = f"distance {name!r}"
        b0, b1, a0, a1, local0, local1, q0 = self._two_ends(body0, body1, anchor0, anchor1, what)
        if (b0 == WORLD or self.bodies[b0].static) and (b1 == WORLD or self.bodies[b1].static):
            raise SceneError(f"{what}: both ends are static")
        lower = _nonnegative(min_distance, f"{what}: min_distance")
        upper = checks.real(max_distance, f"{what}: max_distance")
        if math.isnan(upper) or upper < lower:
            raise SceneError(f"{what}: max_distance {upper} must be >= min_distance {lower}")
        # The push direction while A and B meet: B - A as built, else gravity's (B hangs below A), else x.
        gap = a1 - a0
        for direction in (gap, np.asarray(self.gravity, dtype=np.float64), np.array([1.0, 0.0, 0.0])):
            if np.linalg.norm(direction) > 1e-12:
                direction = direction / np.linalg.norm(direction)
                break
        self.distances.append(Distance(name, b0, b1, local0, local1, quat_rotate(quat_conj(q0), direction), lower,
                                       upper))  # fmt: skip
        return len(self.distances) - 1

    def _two_ends(self, body0, body1, anchor0, anchor1, what: str):
        """The two ends of a spring or a distance: (body0's index, body1's, the anchors as world points (m), the
        anchors in their bodies' frames, body0's orientation as built); the bodies must differ."""
        self._open(what)
        b0 = self._body_index(body0, f"{what} body0")
        b1 = self._body_index(body1, f"{what} body1")
        if b0 == b1:
            raise SceneError(f"{what}: both ends are on the same body")
        a0, a1 = _vec(anchor0, f"{what} anchor0"), _vec(anchor1, f"{what} anchor1")
        (x0, q0), (x1, q1) = self._frame(b0), self._frame(b1)
        local0, local1 = quat_rotate(quat_conj(q0), a0 - x0), quat_rotate(quat_conj(q1), a1 - x1)
        return b0, b1, a0, a1, local0, local1, q0

    def _add_drive(self, drive: Drive) -> int:
        """Append a drive; its index among the drives of its kind (motors, or joint springs)."""
        self._open(f"joint {self.joints[drive.joint].name!r}: {'motor' if drive.motor else 'joint spring'}")
        self.drives.append(drive)
        return sum(d.motor == drive.motor for d in self.drives) - 1

    def _coordinate_joint(self, joint, what: str) -> int:
        """The index of `joint` (index or name), which must have one coordinate (revolute or prismatic)."""
        if isinstance(joint, str):
            matches = [j for j, jt in enumerate(self.joints) if jt.name == joint]
            if not matches:
                raise SceneError(f"{what}: no joint named {joint!r}")
            joint = matches[0]
        if isinstance(joint, (bool, np.bool_)) or not isinstance(joint, (int, np.integer)):
            raise SceneError(f"{what}: a joint index or name is expected, got {joint!r}")
        if not 0 <= int(joint) < len(self.joints):
            raise SceneError(f"{what}: joint index {joint} does not exist ({len(self.joints)} joints)")
        jt = self.joints[int(joint)]
        if jt.kind not in COORDINATES:
            raise SceneError(
                f"joint {jt.name!r} ({jt.kind}) has no single coordinate for {what}; only revolute and prismatic do"
            )
        return int(joint)

    def _never_binds(self, limit: Limit) -> bool:
        """A revolute limit of a turn or more: the angle is measured within the turn about the range's middle
        (kernels/limits.py, limit_error), which such a range holds all of."""
        return COORDINATES[self.joints[limit.joint].kind] == 0 and limit.upper - limit.lower >= 2.0 * math.pi

    def _mechanism_arrays(self) -> dict:
        """The springs, drives, limits and distances as `Model` arguments; a limit that never binds takes no row
        (a row would cost a solve a step and keep the step at order 2, `steps.ROWS_FALLBACK`)."""
        springs, drives = self.springs, self.drives
        limits = [x for x in self.limits if not self._never_binds(x)]
        return dict(
            spring_name=[s.name for s in springs],
            spring_body0=np.array([s.body0 for s in springs], dtype=np.int64),
            spring_body1=np.array([s.body1 for s in springs], dtype=np.int64),
            spring_anchor0=np.array([s.anchor0 for s in springs]).reshape(-1, 3),
            spring_anchor1=np.array([s.anchor1 for s in springs]).reshape(-1, 3),
            spring_params=np.array([(s.stiffness, s.damping, s.rest_length) for s in springs]).reshape(-1, 3),
            drive_name=[x.name for x in drives],
            drive_joint=np.array([x.joint for x in drives], dtype=np.int64),
            drive_mode=np.array([x.mode for x in drives], dtype=np.int32),
            drive_target=np.array([x.target for x in drives]),
            drive_gains=np.array([(x.kp, x.ki, x.kd) for x in drives]).reshape(-1, 3),
            drive_max_force=np.array([x.max_force for x in drives]),
            drive_motor=np.array([x.motor for x in drives], dtype=bool),
            drive_stiff=np.array([x.stiff for x in drives], dtype=bool),
            **dict(zip(("drive_chain", "drive_ends"), self._drive_chains())),
            limit_joint=np.array([x.joint for x in limits], dtype=np.int64),
            limit_bounds=np.array([(x.lower, x.upper) for x in limits]).reshape(-1, 2),
            joint_loop=self._joints["loop"].copy(),
            distance_name=[x.name for x in self.distances],
            distance_body=np.array([(x.body0, x.body1) for x in self.distances], dtype=np.int64).reshape(-1, 2),
            distance_anchor=np.array([(x.anchor0, x.anchor1, x.axis0) for x in self.distances]).reshape(-1, 3, 3),
            distance_bounds=np.array([(x.lower, x.upper) for x in self.distances]).reshape(-1, 2),
            actuator_name=[a.name for a in self.actuators],
            actuator_drive=np.array([a.drive for a in self.actuators], dtype=np.int64),
            actuator_map=np.array([(a.gain, a.bias, *a.ctrl_range) for a in self.actuators]).reshape(-1, 4),
        )
