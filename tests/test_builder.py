"""Bad input raises a clear error naming what is wrong."""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import SceneError


def one_body() -> tuple[wi.SceneBuilder, int]:
    b = wi.SceneBuilder()
    return b, b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -1.0), name="bob")


# A rotation that mixes all three axes, so a full tensor R diag(m) R^T has no zero entry.
R = np.array([[0.36, 0.48, -0.8], [-0.8, 0.6, 0.0], [0.48, 0.64, 0.6]])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mass": 0.0}, "body 'x': mass must be positive"),
        ({"mass": -2.0}, "body 'x': mass must be positive"),
        ({"mass": math.nan}, "body 'x': mass must be positive"),
        ({"inertia": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]}, "body 'x': inertia tensor is not symmetric"),
        ({"inertia": (1.0, -1.0, 1.0)}, "body 'x': inertia tensor is not positive definite"),
        ({"inertia": (1.0, 1.0, 5.0)}, "triangle inequality"),
        ({"inertia": (1.0, math.inf, 1.0)}, "body 'x': inertia contains NaN"),
        ({"position": (0.0, math.nan, 0.0)}, "body 'x' position contains NaN"),
        ({"orientation": (0.0, 0.0, 0.0, 0.0)}, "body 'x': orientation quaternion is zero"),
        ({"linear_velocity": (math.inf, 0, 0)}, "body 'x' linear_velocity contains NaN or Inf"),
        ({"angular_velocity": (0, 0, -math.inf)}, "body 'x' angular_velocity contains NaN or Inf"),
        ({"mass": math.inf}, "body 'x': mass must be positive and finite"),
        ({"mass": None}, "body 'x': mass must be a number, got None"),
        ({"inertia": (1.0, 1.0)}, "body 'x': inertia must be 3 moments or a 3x3 tensor"),
        ({"inertia": (0.0, 1.0, 1.0)}, "body 'x': inertia tensor is not positive definite"),
        # Full 3x3 tensors: the checks must look at the principal moments, not the diagonal.
        ({"inertia": R @ np.diag([1.0, -1.0, 1.0]) @ R.T}, "body 'x': inertia tensor is not positive definite"),
        ({"inertia": R @ np.diag([1.0, 1.0, 5.0]) @ R.T}, "body 'x': principal moments .* triangle inequality"),
        ({"inertia": [[1.0, 0.0, math.nan], [0.0, 1.0, 0.0], [math.nan, 0.0, 1.0]]}, "body 'x': inertia contains NaN"),
        ({"orientation": (0.0, 0.0, 1e-12, 0.0)}, "body 'x': orientation quaternion is zero"),
        ({"orientation": (0.0, 0.0, 1.0)}, "body 'x' orientation must have 4 components"),
        ({"orientation": (0.0, math.nan, 0.0, 1.0)}, "body 'x' orientation contains NaN"),
    ],
)
def test_bad_body(kwargs, message):
    args = {"mass": 1.0, "inertia": (1.0, 1.0, 1.0), "position": (0.0, 0.0, 0.0), "name": "x", **kwargs}
    with pytest.raises(SceneError, match=message):
        wi.SceneBuilder().add_body(**args)


def test_full_inertia_tensor_is_accepted_when_valid():
    b = wi.SceneBuilder()
    tensor = R @ np.diag([1.0, 2.0, 2.5]) @ R.T
    i = b.add_body(1.0, tensor + 1e-13 * np.triu(np.ones((3, 3))), (0, 0, 0))  # round-off asymmetry is tolerated
    assert np.allclose(b.bodies[i].inertia, tensor) and np.array_equal(b.bodies[i].inertia, b.bodies[i].inertia.T)
    b.add_body(1.0, (0.0 + 1e-9, 1.0, 1.0), (0, 0, 0))  # a thin rod: a + b = c at the limit is allowed


def test_non_unit_quaternion_is_normalised_with_a_warning():
    b = wi.SceneBuilder()
    with pytest.warns(UserWarning, match="body 'b0': orientation quaternion has norm 2; normalised"):
        i = b.add_body(1.0, (1, 1, 1), (0, 0, 0), orientation=(0, 0, 0, 2.0), name="b0")
    assert np.allclose(b.bodies[i].orientation, (0, 0, 0, 1))
    with pytest.warns(UserWarning, match="normalised"):
        b.add_static_body((0, 0, 0), orientation=(0, 0.5, 0, 0.5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # round-off of a unit quaternion is silently accepted
        b.add_body(1.0, (1, 1, 1), (0, 0, 0), orientation=(0, 0, 0, 1.0 + 1e-9))


def test_quaternion_policy_is_documented():
    """A zero quaternion is refused and a non-unit one normalised with a warning: the docs say which."""
    doc = wi.SceneBuilder.add_body.__doc__
    assert "A zero quaternion is refused" in " ".join(doc.split()) and "normalised" in doc
    readme = " ".join((Path(__file__).parents[1] / "docs" / "guide.md").read_text().split())
    assert "zero orientation quaternion is refused, a non-unit one is normalised with a warning" in readme


def test_bad_joints():
    b, body = one_body()
    with pytest.raises(SceneError, match="joint 'j' parent: body index 7 does not exist"):
        b.add_joint_ball(7, body, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j' child: no body named 'nobody'"):
        b.add_joint_ball(None, "nobody", (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j' axis is a zero vector"):
        b.add_joint_revolute(None, body, (0, 0, 0), (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="connects body 'bob' to itself"):
        b.add_joint_ball(body, body, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j' anchor contains NaN"):
        b.add_joint_ball(None, body, (math.nan, 0, 0), name="j")
    with pytest.raises(SceneError, match="unknown joint type 'hinge2'"):
        b.add_joint("hinge2", None, body, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="axes of an angle constraint are parallel"):
        b.add_joint_universal(None, body, (0, 0, 0), (0, 1, 0), (0, 2, 0), name="j")
    static = b.add_static_body((0, 0, 0), name="ground")
    with pytest.raises(SceneError, match="both bodies are static"):
        b.add_joint_fixed(None, static, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j' child: a body index or name is expected, got True"):
        b.add_joint_ball(static, True, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j' parent: body index -1 does not exist"):
        b.add_joint_ball(-1, body, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j': the child must be a body, not the world"):
        b.add_joint_ball(body, None, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j': unknown constraint kind 'hinge'"):
        b.add_constraint("hinge", None, body, (0, 0, 0), name="j")
    with pytest.raises(SceneError, match="joint 'j' child axis is a zero vector"):
        b.add_joint_universal(None, body, (0, 0, 0), (1, 0, 0), (0, 0, 0), name="j")
    for add in (b.add_joint_prismatic, b.add_joint_cylindrical, b.add_joint_planar):
        with pytest.raises(SceneError, match="joint 'j' axis is a zero vector"):
            add(None, body, (0, 0, 0), (0, 0, 0), name="j")
        with pytest.raises(SceneError, match="joint 'j' axis contains NaN or Inf"):
            add(None, body, (0, 0, 0), (0, math.inf, 0), name="j")
    assert b.joints == [] and b.constraints == [], "a refused joint must leave nothing behind"


def test_bad_forces_and_gravity():
    b, body = one_body()
    with pytest.raises(SceneError, match="force on body 'bob': force contains NaN"):
        b.add_force(body, (math.nan, 0, 0))
    with pytest.raises(SceneError, match="force on body 'bob': torque contains NaN or Inf"):
        b.add_force("bob", torque=(0, -math.inf, 0))
    with pytest.raises(SceneError, match="force on body 'bob': until is NaN"):
        b.add_force(body, (1, 0, 0), until=math.nan)
    with pytest.raises(SceneError, match="force: body None is not dynamic"):
        b.add_force(None, (1, 0, 0))
    with pytest.raises(SceneError, match="gravity contains NaN or Inf"):
        wi.SceneBuilder(gravity=(0, 0, math.nan))
    assert b.forces == []


@pytest.mark.parametrize(
    "spoil, message",
    [
        (lambda b: b.bodies[0].linear_velocity.__setitem__(1, math.nan), "body 'bob' linear_velocity contains NaN"),
        (lambda b: b.bodies[0].angular_velocity.__setitem__(2, math.inf), "body 'bob' angular_velocity contains"),
        (lambda b: b.bodies[0].position.__setitem__(0, math.nan), "body 'bob' position contains NaN"),
        (lambda b: setattr(b.bodies[0], "mass", 0.0), "body 'bob': mass must be positive"),
        (lambda b: b.bodies[0].angular_velocity.__setitem__(0, 1e300), "body 'bob' angular_velocity is too large"),
        (lambda b: b.bodies[0].inertia.__setitem__((0, 1), 0.5), "body 'bob': inertia tensor is not symmetric"),
        (lambda b: b.gravity.__setitem__(2, -math.inf), "gravity contains NaN or Inf"),
        (lambda b: b.forces[0].force.__setitem__(0, math.nan), "force on body 'bob' contains NaN"),
    ],
)
def test_finalize_rechecks_values_changed_after_adding(spoil, message):
    """The builder's arrays are mutable (scenes set velocities after add_body): finalize checks them again."""
    b, body = one_body()
    b.add_joint_ball(None, body, (0, 0, 0), name="hang")
    b.add_force(body, (1, 0, 0))
    b.finalize()
    spoil(b)
    with pytest.raises(SceneError, match=message):
        b.finalize()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"dt": 0.0}, "dt must be positive"),
        ({"dt": -1.0}, "dt must be positive"),
        ({"dt": math.nan}, "dt must be positive"),
        ({"tolerance": 0.0}, "tolerance must be positive"),
        ({"velocity_tolerance": -1.0}, "velocity_tolerance must be positive"),
        ({"dt": math.inf}, "dt must be positive"),
        ({"tolerance": -1e-6}, "tolerance must be positive"),
        ({"tolerance": math.nan}, "tolerance must be positive"),
        ({"tolerance": math.inf}, "tolerance must be positive"),
        ({"velocity_tolerance": math.nan}, "velocity_tolerance must be positive"),
        ({"max_iterations": 0}, "max_iterations must be an integer >= 1"),
        ({"max_iterations": -3}, "max_iterations must be an integer >= 1"),
        ({"max_iterations": 2.5}, "max_iterations must be an integer >= 1"),
        ({"solver": "lu"}, "unknown solver 'lu'"),
        ({"on_max_iterations": "ignore"}, "on_max_iterations must be one of"),
    ],
)
def test_bad_simulator_settings(kwargs, message):
    b, body = one_body()
    b.add_joint_ball(None, body, (0, 0, 0))
    with pytest.raises(ValueError, match=message):
        wi.Simulator(b.finalize(), **wi.StepOptions.fold({"dt": 0.01, **kwargs}))


def test_bad_external_forces():
    b, body = one_body()
    b.add_joint_ball(None, body, (0, 0, 0))
    sim = wi.Simulator(b.finalize(), 0.01)
    with pytest.raises(ValueError, match="force must have shape"):
        sim.set_external_forces(force=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="torque contains NaN"):
        sim.set_external_forces(torque=[[math.nan, 0, 0]])
