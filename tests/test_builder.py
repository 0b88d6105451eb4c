"""Bad input raises a clear error naming what is wrong."""

import math

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import SceneError


def one_body() -> tuple[wi.SceneBuilder, int]:
    b = wi.SceneBuilder()
    return b, b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -1.0), name="bob")


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
    ],
)
def test_bad_body(kwargs, message):
    args = {"mass": 1.0, "inertia": (1.0, 1.0, 1.0), "position": (0.0, 0.0, 0.0), "name": "x", **kwargs}
    with pytest.raises(SceneError, match=message):
        wi.SceneBuilder().add_body(**args)


def test_non_unit_quaternion_is_normalised_with_a_warning():
    b = wi.SceneBuilder()
    with pytest.warns(UserWarning, match="normalised"):
        i = b.add_body(1.0, (1, 1, 1), (0, 0, 0), orientation=(0, 0, 0, 2.0))
    assert np.allclose(b.bodies[i].orientation, (0, 0, 0, 1))


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


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"dt": 0.0}, "dt must be a positive"),
        ({"dt": -1.0}, "dt must be a positive"),
        ({"dt": math.nan}, "dt must be a positive"),
        ({"tolerance": 0.0}, "tolerance must be positive"),
        ({"velocity_tolerance": -1.0}, "velocity_tolerance must be positive"),
        ({"max_iterations": 0}, "max_iterations must be an integer >= 1"),
        ({"solver": "lu"}, "unknown solver 'lu'"),
    ],
)
def test_bad_simulator_settings(kwargs, message):
    b, body = one_body()
    b.add_joint_ball(None, body, (0, 0, 0))
    with pytest.raises(ValueError, match=message):
        wi.Simulator(b.finalize(), **{"dt": 0.01, **kwargs})


def test_bad_external_forces():
    b, body = one_body()
    b.add_joint_ball(None, body, (0, 0, 0))
    sim = wi.Simulator(b.finalize(), 0.01)
    with pytest.raises(ValueError, match="force must have shape"):
        sim.set_external_forces(force=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="torque contains NaN"):
        sim.set_external_forces(torque=[[math.nan, 0, 0]])
