"""Run time against error, compared honestly: a Pareto front per engine, each read at given error levels.

A configuration (engine, integrator or order, step size, tolerance) is a point (error, cost): its trajectory
error against a reference (m) and its run time per simulated second (s). An engine's front keeps the points no
other point beats on both. At an error level L an engine's cost is read off its front by log-log
interpolation between the two front points that bracket L (the grid of step sizes is fine enough that a
configuration between them exists); that is only a reading where the front reaches L. The rules:

- A level an engine never reached is "not reached" by it: no ratio, and never counted as a win of the other.
- Where even the cheapest configuration measured is below L, the engine's cost at L is at most that point's
  (a coarser step might be cheaper still): the cost is an upper bound, and the ratio a bound ("<=" or ">=").
- Errors are clamped to the reference's own floor (its distance from the reference at half its step), and
  a level below `FLOOR_MARGIN` times the floor is not compared: the reference cannot tell errors apart there.

Nothing here measures: `compare` takes plain dicts, so the rules are tested on synthetic data.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

LEVELS = (1e-2, 1e-3, 1e-4, 1e-5)  # m: the error levels of the tables
FLOOR_MARGIN = 10.0  # a level is compared only if it is at least this many times the reference's floor


def front(points: Iterable[dict], floor: float = 0.0) -> list[dict]:
    """The Pareto front of points with "error" (m) and "cost" (s per simulated s): ordered from the most
    accurate (dearest) to the cheapest, each strictly cheaper and strictly less accurate than the one before.
    Errors are clamped to `floor` (the key "error" of the returned copies; "measured_error" keeps the value)."""
    usable = [
        p | {"measured_error": p["error"], "error": max(p["error"], floor)}
        for p in points
        if p.get("error") is not None and p.get("cost") is not None and math.isfinite(p["error"])
    ]
    out: list[dict] = []
    for p in sorted(usable, key=lambda p: (p["error"], p["cost"])):
        if not out or p["cost"] < out[-1]["cost"]:  # a tie in error keeps the cheaper, which sorts first
            out.append(p)
    return out


def cost_at(points: list[dict], level: float, floor: float = 0.0) -> dict:
    """An engine's cost at error `level` from its front: {"reached": bool, "cost": s or None, "bound": True
    where the cost is only an upper bound (its cheapest configuration is already below the level),
    "grid": the cheapest measured point at or below the level (or None), "between": the bracketing points}."""
    pts = front(points, floor)
    below = [p for p in pts if p["error"] <= level]
    if not below:
        return {"reached": False, "cost": None, "bound": False, "grid": None, "between": None}
    a = below[-1]  # the cheapest point at or below the level
    above = [p for p in pts if p["error"] > level]
    if not above:
        return {"reached": True, "cost": a["cost"], "bound": True, "grid": a, "between": (a, None)}
    b = above[0]  # the most accurate point above the level, cheaper than a
    if a["error"] == level:
        cost = a["cost"]
    else:
        t = (math.log(level) - math.log(a["error"])) / (math.log(b["error"]) - math.log(a["error"]))
        cost = math.exp(math.log(a["cost"]) + t * (math.log(b["cost"]) - math.log(a["cost"])))
    return {"reached": True, "cost": cost, "bound": False, "grid": a, "between": (a, b)}


def compare(ours: list[dict], theirs: list[dict], level: float, floor: float = 0.0, peer: str = "MuJoCo") -> dict:
    """Our cost and the peer's at `level`, and their ratio (peer / ours: > 1, we are cheaper) only where both
    reached it. "status": "compared", "not reached by <peer>", "not reached by warpimpulse", "reached by
    neither" or "below the reference floor"; "ratio_bound": "<=" or ">=" where a cost is only an upper bound,
    "?" where both are (then the ratio says nothing), "" where both are read off brackets."""
    cell = {"level": level, "ours": None, "theirs": None, "ratio": None, "ratio_bound": "", "status": ""}
    if level < FLOOR_MARGIN * floor:
        cell["status"] = "below the reference floor"
        return cell
    mine, peer_cost = cost_at(ours, level, floor), cost_at(theirs, level, floor)
    cell["ours"], cell["theirs"] = mine, peer_cost
    if not mine["reached"] or not peer_cost["reached"]:
        cell["status"] = (
            "reached by neither"
            if not mine["reached"] and not peer_cost["reached"]
            else f"not reached by {peer}"
            if mine["reached"]
            else "not reached by warpimpulse"
        )
        return cell
    cell["status"] = "compared"
    cell["ratio"] = peer_cost["cost"] / mine["cost"]
    # The peer's cost an upper bound: the true ratio is at most this; ours an upper bound: at least this.
    cell["ratio_bound"] = {(False, False): "", (True, False): "<=", (False, True): ">=", (True, True): "?"}[
        (peer_cost["bound"], mine["bound"])
    ]
    return cell


def ratio_text(cell: dict, peer: str = "MuJoCo") -> str:
    """A table cell: "2.31", "<= 1.4" (a bound), or why there is no ratio."""
    if cell["ratio"] is None:
        return cell["status"]
    if cell["ratio_bound"] == "?":
        return f"~{cell['ratio']:.2f} (both at their coarsest)"
    bound = f"{cell['ratio_bound']} " if cell["ratio_bound"] else ""
    return f"{bound}{cell['ratio']:.2f}"
