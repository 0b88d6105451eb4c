"""Stiff joint dampers, taken implicitly (docs/mechanisms.md, "Stiff dampers"): accuracy at h = 1 ms.

Two damped models, each against an independent reference, beside MuJoCo's implicit integrator at the same step:
- a light bob (1 kg, I 1e-3 kg m^2 at 0.5 m) on a damped hinge released at 0.5 rad: the pendulum ODE
  (scipy at 1e-12);
- a 3-link arm of light links (1, 0.5, 0.25 kg, I 1e-3 kg m^2, 0.5 m) falling from horizontal, every hinge
  damped: MuJoCo RK4 at 1e-5 s.
The error is the largest joint-angle difference over 1 s (rad).

    python benchmarks/implicit_dampers.py [--json benchmarks/results/implicit_dampers.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

import mujoco
import numpy as np
from scipy.integrate import solve_ivp

import warpimpulse as wi

ROOT = Path(__file__).resolve().parents[1]
H, DURATION = 1e-3, 1.0


def pendulum_xml(c: float, h: float, integrator: str) -> str:
    """Built at 0.5 rad from hanging (the joint's 0 there)."""
    return (f'<mujoco><compiler angle="radian"/><option timestep="{h}" gravity="0 -9.81 0" '
            f'integrator="{integrator}"/><worldbody><body name="bob" euler="0 0 0.5">'
            f'<joint name="hinge" type="hinge" axis="0 0 1" damping="{c}"/>'
            '<inertial pos="0 -0.5 0" mass="1" diaginertia="1e-3 1e-3 1e-3"/></body></worldbody></mujoco>')  # fmt: skip


def arm_xml(c: float, h: float, integrator: str) -> str:
    def link(name: str, mass: float, pos: float, inner: str) -> str:
        return (f'<body name="{name}" pos="{pos} 0 0"><joint name="{name}" type="hinge" axis="0 1 0" damping="{c}"/>'
                f'<inertial pos="0.25 0 0" mass="{mass}" diaginertia="1e-3 1e-3 1e-3"/>{inner}</body>')  # fmt: skip

    tree = link("l1", 1.0, 0.0, link("l2", 0.5, 0.5, link("l3", 0.25, 0.5, "")))
    return (f'<mujoco><option timestep="{h}" gravity="0 0 -9.81" integrator="{integrator}"/>'
            f"<worldbody>{tree}</worldbody></mujoco>")  # fmt: skip


def mujoco_angles(xml: str, h: float) -> np.ndarray:
    """MuJoCo's joint angles every millisecond over DURATION."""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    every, out = round(H / h), []
    for i in range(round(DURATION / h)):
        mujoco.mj_step(m, d)
        if (i + 1) % every == 0:
            out.append(d.qpos.copy())
    return np.array(out)


def our_angles(xml: str, joints: list[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    """Our joint angles every step of H over DURATION, and the dampers taken implicitly."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        builder = wi.load_mjcf(xml)
    sim = wi.Simulator(builder.finalize(), H)
    out = []
    for _ in range(round(DURATION / H)):
        sim.step()
        out.append([sim.joint_coordinates(j)[0] for j in joints])
    return np.array(out), sim.implicit_dampers


def pendulum_reference(c: float) -> np.ndarray:
    inertia, mgl = 1e-3 + 0.25, 9.81 * 0.5
    sol = solve_ivp(lambda t, y: [y[1], (-mgl * math.sin(y[0]) - c * y[1]) / inertia], (0.0, DURATION), [0.5, 0.0],
                    rtol=1e-12, atol=1e-12, dense_output=True)  # fmt: skip
    return sol.sol(H * np.arange(1, round(DURATION / H) + 1))[0][:, None] - 0.5  # the joint's 0 is at 0.5 rad


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=ROOT / "benchmarks/results/implicit_dampers.json")
    args = p.parse_args(argv)
    rows = []
    for model, dampings in (("pendulum", (5.0, 50.0, 500.0)), ("3-link arm", (0.5, 5.0, 50.0))):
        for c in dampings:
            if model == "pendulum":
                xml, joints, reference = pendulum_xml, ["hinge"], pendulum_reference(c)
            else:
                xml, joints = arm_xml, ["l1", "l2", "l3"]
                reference = mujoco_angles(arm_xml(c, 1e-5, "RK4"), 1e-5)
            ours, implicit = our_angles(xml(c, H, "RK4"), joints)
            theirs = mujoco_angles(xml(c, H, "implicitfast"), H)
            row = dict(model=model, damping=c, implicit=list(implicit),
                       warpimpulse_error=float(np.abs(ours - reference).max()),
                       mujoco_implicitfast_error=float(np.abs(theirs - reference).max()))  # fmt: skip
            rows.append(row)
            print(json.dumps(row), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"h": H, "duration": DURATION, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
