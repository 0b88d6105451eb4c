"""The benchmark's write-up, from the harness's JSON: the markdown report (RESULTS.md), the plots, and
docs/results.md's results block.

Nothing here measures. `python -m warpimpulse.bench.report --from-json ... --readme docs/results.md` is how
`make bench` regenerates that block; `warpimpulse bench` itself never touches the docs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from . import pareto
from .blocks import markers, write_block
from .harness import CHECK_RATE, DRIFT_DURATION, ERROR_TIME, REFERENCE_RATE, SCALING_RATE, SCALING_TOLERANCE, log

BAR_SCENE = "tree127"  # the scene of "the bar": ours against the fastest MuJoCo at matched error


# ------------------------------------------------------------------------------------------ the bar
def _usable(runs: list[dict], scene: str, engine: str) -> list[dict]:
    """The rows of one engine on `scene` that have both an error and a time (failed rows are `excluded`)."""
    return [r for r in runs if r["scene"] == scene and r["engine"] == engine and r["failed"] is None
            and r["time_per_step"] is not None and r["trajectory_error"] is not None]  # fmt: skip


def _points(rows: list[dict]) -> list[dict]:
    """Rows as pareto points: error (m) and cost (s per simulated second)."""
    return [r | {"error": r["trajectory_error"], "cost": r["time_per_step"] * r["rate"]} for r in rows]


def level_cells(runs: list[dict], scene: str, floor: float) -> list[dict]:
    """Ours against MuJoCo at each of `pareto.LEVELS`, each engine's cost read off its front."""
    ours, theirs = _points(_usable(runs, scene, "warpimpulse")), _points(_usable(runs, scene, "mujoco"))
    return [pareto.compare(ours, theirs, level, floor) for level in pareto.LEVELS]


def excluded(runs: list[dict], scene: str) -> list[str]:
    """Every configuration of `scene` left out of the comparison, and why (diverged, failed, no time)."""
    out = []
    for r in runs:
        if r["scene"] == scene and (r["failed"] is not None or r["time_per_step"] is None):
            why = " ".join((r["failed"] or "no timing").split())[:100]
            out.append(f"{r['engine']} {r['variant']}{_order_suffix(r)} 1/{r['rate']} ({why})")
    return out


def speed_ratios(runs: list[dict], scene: str = BAR_SCENE, floor: float = 0.0) -> list[dict]:
    """For each of our configurations on `scene`: the cheapest MuJoCo configuration whose trajectory error is
    at most ours, and the ratio of its cost to ours (> 1: we are faster); None where no MuJoCo configuration
    reached our error, which is no win: MuJoCo at a finer step might. "front_ratio": MuJoCo's cost read off its
    Pareto front at exactly our error (`pareto.cost_at`) over ours, "front_bound" True where that cost is only an
    upper bound; the measured match can be far more accurate than ours where MuJoCo's grid is coarse.
    "under_floor" marks an error under `pareto.FLOOR_MARGIN` times the reference's floor, where errors are not
    told apart.

    Cost is run time per simulated second (time per step / h), not per step: configurations with different
    step sizes reach the same simulated time in different numbers of steps.
    """
    ours = _usable(runs, scene, "warpimpulse")
    peers = _usable(runs, scene, "mujoco")
    out = []
    for r in sorted(ours, key=lambda r: r["trajectory_error"]):
        match = [p for p in peers if p["trajectory_error"] <= r["trajectory_error"]]
        best = min(match, key=lambda p: p["time_per_step"] * p["rate"]) if match else None
        cost = r["time_per_step"] * r["rate"]
        on_front = pareto.cost_at(_points(peers), r["trajectory_error"], floor)
        out.append({
            "rate": r["rate"], "tolerance": r["tolerance"], "order": r.get("order", 2),
            "trajectory_error": r["trajectory_error"],
            "time_per_step": r["time_per_step"], "time_per_second": cost,
            "mujoco": None if best is None else f"{best['variant']} 1/{best['rate']}",
            "mujoco_error": None if best is None else best["trajectory_error"],
            "mujoco_time_per_step": None if best is None else best["time_per_step"],
            "mujoco_time_per_second": None if best is None else best["time_per_step"] * best["rate"],
            "ratio": None if best is None else best["time_per_step"] * best["rate"] / cost,
            "front_ratio": on_front["cost"] / cost if on_front["reached"] else None,
            "front_bound": on_front["bound"],
            "under_floor": r["trajectory_error"] < pareto.FLOOR_MARGIN * floor,
        })  # fmt: skip
    return out


# ------------------------------------------------------------------------------------------ reports
def _num(value, fmt: str = ".3g") -> str:
    return "—" if value is None else format(value, fmt)


def _us(seconds) -> str:
    return "—" if seconds is None else f"{seconds * 1e6:.1f}"


def markdown(results: dict) -> str:
    """The full report (RESULTS.md): references, one table per scene, where we win and lose, the tree127 bar,
    scaling."""
    lines = ["# warpimpulse benchmark", ""]
    if results.get("paper_tables"):
        lines += paper_markdown(results["paper_tables"])
    sweep, scale = results.get("run_vs_error"), results.get("scaling")
    if sweep:
        lines += ["## Run time against error", "", *_provenance(sweep),
                  f"Reference: MuJoCo RK4 at h = 1/{REFERENCE_RATE}, checked against itself at h = 1/{CHECK_RATE} and "
                  f"against pinocchio (ABA, RK4) at h = 1/{REFERENCE_RATE}. Trajectory error: max distance at "
                  f"t = {ERROR_TIME:g} s over every centre of mass and leaf tip. Energy drift: max |E(t) - E(t_f)| "
                  f"over {DRIFT_DURATION:g} s after the forces stop (t_f), divided by the work the forces did (trees) "
                  "or the peak kinetic energy (no forces). Joint error: max distance between a point joint's two "
                  "anchors over the run, from body poses, for every engine (reduced coordinates keep it at "
                  "round-off); ours also reports its own max joint error (m or rad) after each step. Time: median "
                  f"over repeats of the mean time per step over the first {ERROR_TIME:g} s, after a warm-up run. "
                  "pinocchio's RK4 is stepped from Python (four ABA calls a step), so its small scenes time the "
                  "Python loop more than pinocchio.", "",
                  *summary_markdown(sweep)]  # fmt: skip
        for name, ref in sweep["references"].items():
            lines += [f"### {name}", "", f"Energy scale {ref['energy_scale']:.4g} J.", "",
                      "| engine | variant | h | tolerance | µs/step | trajectory error (m) | energy drift | "
                      "anchor gap (m) | our joint error | joint it/step | note |",
                      "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
            for r in (r for r in sweep["runs"] if r["scene"] == name):
                lines.append(
                    f"| {r['engine']} | {r['variant']}{_order_suffix(r)} | 1/{r['rate']} | "
                    f"{_num(r['tolerance'], 'g')} | "
                    f"{_us(r['time_per_step'])} | {_num(r['trajectory_error'])} | {_num(r['energy_drift'])} | "
                    f"{_num(r['joint_error_anchor_gap'])} | {_num(r.get('joint_error_internal_max'))} | "
                    f"{_num(r.get('joint_iterations_mean'), '.2f')} | {(r['failed'] or '')[:60]} |"
                )
            lines.append("")
        lines += bar_markdown(sweep["runs"], floor=_floor(sweep))
    if scale:
        lines += scaling_markdown(scale)
    return "\n".join(lines) + "\n"


def paper_markdown(tables: dict, level: str = "##") -> list[str]:
    """The method paper's Tables 1-3 and its star beside ours, from `benchmarks/paper_tables.py`'s JSON."""
    tolerances = sorted({r["tolerance"] for r in tables["rows"]}, reverse=True)
    sizes = sorted({int(r["scene"][4:]) for r in tables["rows"]})
    paper = tables["paper"]

    def cell(n: int, solver: str, tol: float) -> dict:
        return next(
            r for r in tables["rows"] if r["scene"] == f"tree{n}" and r["solver"] == solver and r["tolerance"] == tol
        )

    machine = tables["machine"]
    lines = [
        f"{level} The paper's tables",
        "",
        f"`python benchmarks/paper_tables.py` on {machine['processor']} (Python {machine['python']}, Warp "
        f"{machine['warp']}), h = 1/{round(1 / tables['dt'])} s, median time per step over "
        f"{tables['rows'][0]['steps']} steps; the paper's figures are from a Pentium 4 at 3.4 GHz.",
    ]
    if 127 in sizes and 1e-6 in tolerances:  # Table 1 is the 127-body tree at 1e-6
        header = "| | paper without SLE | ours without SLE | paper with SLE | ours with SLE |"
        lines += ["", "Table 1: the 127-body tree, tolerance 1e-6.", "", header, "|---|---:|---:|---:|---:|"]
        it, ch = cell(127, "iterative", 1e-6), cell(127, "cholesky", 1e-6)
        p_it, p_ch = paper["table1"]["iterative"], paper["table1"]["cholesky"]
        table1 = (
            ("time per step (ms)", "ms", "median_ms"),
            ("joint-correction iterations", "jc", "joint_iterations"),
            ("velocity-correction iterations", "vc", "velocity_iterations"),
        )
        for label, key, ours in table1:
            digits = 3 if key == "ms" else 2
            lines.append(f"| {label} | {p_it[key]} | {it[ours]:.{digits}f} | {p_ch[key]} | {ch[ours]:.{digits}f} |")
    for title, solver, figures in (
        ("Table 3: with the system", "cholesky", paper["with_sle"]),
        ("Table 2: without the system", "iterative", paper["without_sle"]),
    ):
        lines += [
            "",
            f"{title} (ms per step, paper / ours, mean joint iterations in brackets).",
            "",
            "| | " + " | ".join(f"{t:g}" for t in tolerances) + " |",
            "|---|" + "---:|" * len(tolerances),
        ]
        for n in sizes:
            ref = figures.get(str(n), figures.get(n))
            cells = [
                f"{'—' if ref is None else ref[k]} / {cell(n, solver, t)['median_ms']:.3f} "
                f"({cell(n, solver, t)['joint_iterations']:.1f})"
                for k, t in enumerate(tolerances)
            ]
            lines.append(f"| tree {n} | " + " | ".join(cells) + " |")
    star = {r["solver"]: r for r in tables["star"]}
    s_it, s_ch = star["iterative"], star["cholesky"]
    lines += [
        "",
        f"The star of 127 (every joint on the root), tolerance {s_ch['tolerance']:g}: "
        f"{s_ch['median_ms']:.3f} ms "
        f"a step with the system against {s_it['median_ms']:.3f} ms without "
        f"({s_it['median_ms'] / s_ch['median_ms']:.1f}x; the paper reports almost 80x).",
        "",
    ]
    return lines


def _provenance(section: dict) -> list[str]:
    """Which command measured a section, where and when; which peers were missing."""
    lines = []
    meta = section.get("meta")
    if meta:
        quick = " (the reduced `--quick` sweep)" if "--quick" in meta["command"].split() else ""
        where = f"{meta['machine']}, {meta['date']} ({meta['versions']})"
        lines += [f"Measured with `{meta['command']}`{quick} on {where}.", ""]
    missing = [f"> Not measured: {why}" for why in filter(None, section.get("missing", {}).values())]
    return lines + (missing + [""] if missing else [])


def summary_markdown(sweep: dict, level: str = "##") -> list[str]:
    """Per scene: how far the references agree, and ours against MuJoCo at each error level, each engine's cost
    read off its Pareto front (`pareto`): a level one engine never reached has no ratio and is no win."""
    levels = pareto.LEVELS
    lines = [f"{level} Where we win and lose", "",
             "Ratio = MuJoCo's cheapest run time per simulated second at that trajectory error over ours (> 1: we "
             "are faster), each engine's cost interpolated (log-log) on its Pareto front over every configuration "
             "(integrator or order, tolerance, h). \"not reached by MuJoCo\" is no ratio and no win; \"<=\" where "
             "MuJoCo's coarsest step already beats the level, \">=\" likewise for ours; a level under "
             f"{pareto.FLOOR_MARGIN:g}x the reference's floor (its self-check) is not compared.", "",
             "| scene | bodies | reference self-check = floor (m) | pinocchio vs reference (m) | "
             + " | ".join(f"{lv:g} m" for lv in levels) + " |",
             "|---|---|---|---|" + "---|" * len(levels)]  # fmt: skip
    notes = []
    for name, ref in sweep["references"].items():
        floor = ref["self_check_residual"]
        cells = " | ".join(pareto.ratio_text(c) for c in level_cells(sweep["runs"], name, floor))
        lines.append(f"| {name} | {ref['bodies']} | {floor:.2e} | {_num(ref.get('pinocchio_residual'))} | {cells} |")
        left = excluded(sweep["runs"], name)
        if left:
            notes.append(f"- {name}: " + "; ".join(left) + ".")
    lines += ["", *(["Excluded (failed or diverged anywhere in the run, the 10 s after the forces included):", "",
                     *notes] if notes else ["No configuration failed or diverged."])]  # fmt: skip
    counts = sorted({len(r["time_per_step_runs"]) for r in sweep["runs"] if r.get("time_per_step_runs")})
    if counts:
        lines += ["", f"Each time is the median of {counts[0]} to {counts[-1]} timed runs ("
                  + spread_text([r["time_per_step_runs"] for r in sweep["runs"] if r.get("time_per_step_runs")])
                  + "); every run's time is in the JSON."]  # fmt: skip
    if any(r.get("error_source") != "timed run" for r in sweep["runs"]):
        lines += [
            "",
            "In this JSON the trajectory error comes from a separate run stepped one step a call and the "
            "time from runs of step(n) (the harness now reads the error from the timed runs themselves).",
        ]
    return lines + [""]


def spread_text(samples: list[list[float]]) -> str:
    """How far repeated timings scatter: each configuration's interquartile range over its median, given for
    the median configuration and the worst (a shared machine's load shows here)."""
    spreads = []
    for times in samples:
        if len(times) >= 2:
            q1, q2, q3 = np.percentile(times, [25, 50, 75])
            spreads.append((q3 - q1) / q2)
    if not spreads:
        return "no repeated timings"
    return (f"interquartile range over median: {np.median(spreads) * 100:.0f}% for the median configuration, "
            f"{max(spreads) * 100:.0f}% at most")  # fmt: skip


def _floor(sweep: dict, scene: str = BAR_SCENE) -> float:
    ref = sweep["references"].get(scene)
    return 0.0 if ref is None else ref["self_check_residual"]


def _order_suffix(r: dict) -> str:
    order = r.get("order") or 2
    return "" if order == 2 else f" order {order}"


def _ours(r: dict) -> str:
    """Our configuration's tolerance, and its order in time where not the paper's 2."""
    return f"tol {r['tolerance']:g}" + _order_suffix(r).replace(" order", ", order")


def _front_ratio(r: dict) -> str:
    if r["front_ratio"] is None:
        return "not reached by MuJoCo"
    return ("<= " if r["front_bound"] else "") + f"{r['front_ratio']:.3g}"


def bar_markdown(runs: list[dict], scene: str = BAR_SCENE, level: str = "##", floor: float = 0.0) -> list[str]:
    if not any(r["scene"] == scene for r in runs):
        return []
    ratios = speed_ratios(runs, scene, floor)
    if not ratios:
        return [f"{level} The bar ({scene})", "", "No warpimpulse run on this scene.", ""]
    lines = [f"{level} The bar: {scene}, each of our configurations against MuJoCo", "",
             "Run time per simulated second (per second, not per step: h differs between the two) of the fastest "
             "MuJoCo configuration measured whose error is at most ours, and of MuJoCo's Pareto front read at "
             "exactly our error (log-log between its two bracketing configurations; \"<=\" where its coarsest "
             "step is already more accurate); ratio = that front's cost over ours (> 1: warpimpulse is faster), "
             "counted below.", "",
             "| our h | tolerance, order | our error (m) | our µs/step | our ms/sim s | "
             "fastest MuJoCo at ≤ that error | its error (m) | its µs/step | its ms/sim s | its ratio | "
             "ratio to MuJoCo's front at our error |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in ratios:
        theirs = r["mujoco_time_per_second"]
        lines.append(
            f"| 1/{r['rate']} | {_ours(r)} | {r['trajectory_error']:.3g} | {_us(r['time_per_step'])} | "
            f"{r['time_per_second'] * 1e3:.1f} | {r['mujoco'] or 'not reached by MuJoCo'} | "
            f"{_num(r['mujoco_error'])} | "
            f"{_us(r['mujoco_time_per_step'])} | {'—' if theirs is None else f'{theirs * 1e3:.1f}'} | "
            + f"{_num(r['ratio'], '.3g')} | "
            + ("under the reference floor" if r["under_floor"] else _front_ratio(r))
            + " |"
        )
    counted = [r for r in ratios if not r["under_floor"] and r["front_ratio"] is not None]
    wins = [r for r in counted if r["front_ratio"] > 1.0]
    losses = [r for r in counted if r["front_ratio"] <= 1.0]
    unmatched = [r for r in ratios if not r["under_floor"] and r["front_ratio"] is None]
    floor_rows = [r for r in ratios if r["under_floor"]]
    lines += ["", f"Of {len(ratios)} configurations, we are faster in {len(wins)} and slower in {len(losses)}; "
              f"MuJoCo never reached the error of {len(unmatched)} (no ratio, not counted as a win), and "
              f"{len(floor_rows)} are under {pareto.FLOOR_MARGIN:g}x the reference's floor of {floor:.2g} m "
              "(not compared)."]  # fmt: skip
    if wins:
        best = max(wins, key=lambda r: r["front_ratio"])
        lines.append(f"Best: h=1/{best['rate']}, {_ours(best)}, error {best['trajectory_error']:.3g} m, "
                     f"{_front_ratio(best)}x faster than MuJoCo's front at that error.")  # fmt: skip
        lines.append("We win at: " + ", ".join(f"1/{r['rate']} {_ours(r)}" for r in wins) + ".")
    if losses:
        worst = min(losses, key=lambda r: r["front_ratio"])
        lines.append(f"Worst: h=1/{worst['rate']}, {_ours(worst)}, error {worst['trajectory_error']:.3g} "
                     f"m, {1.0 / worst['front_ratio']:.2f}x slower than MuJoCo's front at that error.")  # fmt: skip
    return lines + [""]


def scaling_markdown(scale: dict, level: str = "##") -> list[str]:
    rows = scale["rows"]
    lines = [f"{level} Scaling", "", *_provenance(scale),
             f"h = 1/{SCALING_RATE}; warpimpulse at tolerance {SCALING_TOLERANCE:g}. Each point runs in its own "
             f"process, stopped at the budget of {scale['budget_s']:.0f} s (set-up and timing); a size projected "
             f"past it is skipped. Time: median of {scale['repeats']} blocks of {scale['steps']} steps after a "
             "warm-up block. Set-up: from the scene builder call to an engine ready to step (ours: the scene, "
             "its Model and symbolic analysis, the Simulator; MuJoCo: the scene and its compiler); peak memory: "
             "the measuring process's peak resident set by then, Python, Warp and MuJoCo included.", "",
             "| family | bodies | engine | variant | set-up (s) | peak memory (GB) | µs/step | µs/body/step | "
             "joint it/step (max) | linear it/step | note |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        note = " ".join((r.get("skipped") or r.get("failed") or "").split())
        per_body = r.get("time_per_body_step")
        iters = r.get("joint_iterations_mean")
        lines.append(
            f"| {r['family']} | {r['bodies']} | {r['engine']} | {r['variant']} | {_num(r.get('setup_s'), '.2f')} | "
            f"{_num(r.get('setup_peak_rss_gb'), '.2f')} | {_us(r.get('time_per_step'))} | "
            f"{'—' if per_body is None else f'{per_body * 1e6:.3f}'} | "
            + ("—" if iters is None else f"{iters:.2f} ({r['joint_iterations_max']})")
            + f" | {_num(r.get('linear_iterations_mean'), '.1f')} | {note} |"
        )
    return lines + [""] + growth_lines(rows) + [""]


def growth_lines(rows: list[dict]) -> list[str]:
    """How time per step and our iteration counts grow with size: log-log slopes over sizes of 100 and up."""
    lines = []
    for family in dict.fromkeys(r["family"] for r in rows):
        for key in dict.fromkeys((r["engine"], r["variant"]) for r in rows if r["family"] == family):
            mine = [r for r in rows if r["family"] == family and (r["engine"], r["variant"]) == key]
            pts = [(r["bodies"], r["time_per_step"]) for r in mine if r.get("time_per_step")]
            big = [(n, t) for n, t in pts if n >= 100]
            if len(big) >= 2:
                slope = np.polyfit(np.log([n for n, _ in big]), np.log([t for _, t in big]), 1)[0]
                lines.append(f"- {family}s, {' '.join(key)}: time per step ~ n^{slope:.2f} "
                             f"({big[0][0]} to {big[-1][0]} bodies).")  # fmt: skip
        ours = [r for r in rows if r["family"] == family and r["engine"] == "warpimpulse" and r.get("time_per_step")]
        if ours:
            counts = ", ".join(f"{r['joint_iterations_mean']:.2f} at {r['bodies']}" for r in ours)
            lines.append(f"- {family}s, warpimpulse joint-correction iterations per step: {counts}.")
    return lines


README_BLOCK = "results"  # the block of docs/results.md written from run_vs_error.json (`blocks.write_block`)
README_BEGIN, README_END = markers(README_BLOCK)


def readme_block(results: dict, plots_dir: str = "benchmarks/results") -> str:
    """The README's benchmark section, generated from the JSON so it is never typed by hand."""
    lines = [
        "<!-- generated from benchmarks/results/*.json by `python -m warpimpulse.bench.report --from-json ... "
        "--readme docs/results.md` (make bench): edit the generator, not this text -->",
        "",
    ]
    if results.get("paper_tables"):
        lines += paper_markdown(results["paper_tables"], "###")
    sweep, scale = results.get("run_vs_error"), results.get("scaling")
    if sweep:
        runs = sweep["runs"]
        rates = sorted({r["rate"] for r in runs if r["engine"] != "mujoco"})
        mujoco_rates = sorted({r["rate"] for r in runs if r["engine"] == "mujoco"})
        tolerances = sorted({r["tolerance"] for r in runs if r["tolerance"] is not None and (r.get("order") or 2) == 2},
                            reverse=True)  # fmt: skip
        grid = (
            f"h in {{{', '.join(f'1/{r}' for r in rates)}}} and tolerance in "
            f"{{{', '.join(f'{t:g}' for t in tolerances)}}} (MuJoCo: h in "
            f"{{{', '.join(f'1/{r}' for r in mujoco_rates)}}}"
            + (")" if not mujoco_rates or mujoco_rates[0] <= 10 else
               f"; its grid stops at 1/{mujoco_rates[0]}, so at loose errors its cost may be over-estimated)")
        )  # fmt: skip
        peers = ", ".join(dict.fromkeys(f"{r['engine']} {r['variant']}" for r in runs if r["engine"] != "warpimpulse"))
        lines += [f"`warpimpulse bench` (`pip install 'warpimpulse[bench]'`; `make bench` regenerates the JSON, the "
                  f"plots, [RESULTS.md]({plots_dir}/RESULTS.md) and this section) runs {grid} "
                  f"on {', '.join(sweep['references'])} against {peers}, with MuJoCo RK4 at h = 1/{REFERENCE_RATE} as "
                  f"the reference (checked against h = 1/{CHECK_RATE} and against pinocchio)."
                  + (f" {sweep['timing']}." if sweep.get("timing") else ""),
                  "",
                  *_provenance(sweep), *summary_markdown(sweep, "###"),
                  *bar_markdown(runs, level="###", floor=_floor(sweep))]  # fmt: skip
        lines += [f"![Pareto {name}]({plots_dir}/pareto_{name}.png)" for name in sweep["references"]]
        lines += ["", f"![Energy drift]({plots_dir}/energy_drift.png)", ""]
    if scale:
        lines += scaling_markdown(scale, "###") + [f"![Scaling]({plots_dir}/scaling.png)", ""]
    return "\n".join(lines)


def plots(results: dict, directory: Path) -> list[Path]:
    """Pareto plot per scene, energy drift over time, log-log scaling; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    sweep = results.get("run_vs_error")
    if sweep:
        for name in sweep["references"]:
            # Left: per step, as measured. Right: per simulated second, the cost at equal simulated time.
            fig, axes = plt.subplots(1, 2, figsize=(12, 5))
            for ax, per_second in zip(axes, (False, True)):
                for label, curve in _curves(sweep["runs"], name).items():
                    ok = [r for r in curve if r["trajectory_error"] is not None and r["time_per_step"] is not None]
                    ys = [r["time_per_step"] * (r["rate"] * 1e3 if per_second else 1e6) for r in ok]
                    if not ok:
                        continue
                    ax.plot([r["trajectory_error"] for r in ok], ys,
                            "o-" if label.startswith("warpimpulse") else "s--", label=label)  # fmt: skip
                    for r, y in zip(ok, ys):
                        ax.annotate(f"1/{r['rate']}", (r["trajectory_error"], y), fontsize=6)
                ylabel = "run time per simulated second (ms)" if per_second else "time per step (µs)"
                ax.set(xscale="log", yscale="log", xlabel=f"trajectory error at t = {ERROR_TIME:g} s (m)",
                       ylabel=ylabel, title=f"{name} (lower left is better)")  # fmt: skip
                ax.grid(True, which="both", alpha=0.3)
                ax.legend(fontsize=7)
            written.append(_save(fig, directory / f"pareto_{name}.png"))
        names = list(sweep["references"])
        fig, axes = plt.subplots(len(names), 1, figsize=(7, 2.6 * len(names)), squeeze=False)
        for ax, name in zip(axes[:, 0], names):
            for label, curve in _curves(sweep["runs"], name).items():
                # One step size for readability: the finest of the sweep that every curve has.
                for r in curve:
                    if r["rate"] == max(c["rate"] for c in curve) and r["energy_series"]:
                        t, d = np.array(r["energy_series"]).T
                        ax.plot(t, np.abs(d) + 1e-16, label=f"{label} h=1/{r['rate']}")
            ax.set(yscale="log", title=name, ylabel="|ΔE| / scale")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=6, ncol=2)
        axes[-1, 0].set_xlabel("time (s)")
        written.append(_save(fig, directory / "energy_drift.png"))
    if results.get("scaling"):
        rows = [r for r in results["scaling"]["rows"] if r.get("time_per_step")]
        panels = (("time per step (µs)", lambda r: r["time_per_step"] * 1e6),
                  ("time per body per step (µs)", lambda r: r["time_per_body_step"] * 1e6),
                  ("our joint iterations per step", lambda r: r.get("joint_iterations_mean")))  # fmt: skip
        fig, axes = plt.subplots(len(panels), 2, figsize=(11, 3.6 * len(panels)), squeeze=False)
        for col, family in enumerate(("tree", "chain")):
            mine = [r for r in rows if r["family"] == family]
            for ax, (ylabel, of) in zip(axes[:, col], panels):
                for key in sorted({(r["engine"], r["variant"]) for r in mine}):
                    pts = sorted((r["bodies"], of(r)) for r in mine if (r["engine"], r["variant"]) == key)
                    pts = [p for p in pts if p[1] is not None]
                    if pts:
                        ax.plot(*zip(*pts), "o-", label=" ".join(key))
                ax.set(xscale="log", yscale="log", xlabel="bodies", ylabel=ylabel, title=f"{family}s")
                ax.grid(True, which="both", alpha=0.3)
                ax.legend(fontsize=8)
        written.append(_save(fig, directory / "scaling.png"))
    return written


def _curves(runs: list[dict], scene: str) -> dict[str, list[dict]]:
    curves: dict[str, list[dict]] = {}
    for r in runs:
        if r["scene"] != scene:
            continue
        order = r.get("order") or 2
        if r["engine"] != "warpimpulse":
            label = f"{r['engine']} {r['variant']}"
        elif order == 2:
            label = f"warpimpulse tol {r['tolerance']:g}"
        else:  # one front per order: its tolerance follows h
            label = f"warpimpulse order {order}"
        curves.setdefault(label, []).append(r)
    return curves


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def load(paths: list[Path]) -> dict:
    """Merge earlier JSON files (the paper's tables, the sweep and the scaling, measured apart) into one dict."""
    results: dict = {}
    for path in paths:
        data = json.loads(path.read_text())
        results.update({"paper_tables": data} if "paper" in data else data)
    return results


def write(results: dict, plots_dir: Path | None = None, report: Path | None = None) -> str:
    """Write the plots and the markdown report where asked; return the report."""
    if plots_dir:
        for path in plots(results, plots_dir):
            log(f"wrote {path}")
    text = markdown(results)
    if report:
        report.parent.mkdir(parents=True, exist_ok=True)
        report.write_text(text)
    return text


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m warpimpulse.bench.report", description=__doc__.split("\n\n")[0])
    p.add_argument("--from-json", type=Path, nargs="+", required=True,
                   help="earlier `warpimpulse bench --json` files and paper_tables.json (merged)")  # fmt: skip
    p.add_argument("--plots", type=Path, help="write the PNG plots into this directory")
    p.add_argument("--report", type=Path, help="write the full markdown report (the stdout text) here too")
    p.add_argument("--readme", type=Path,
                   help=f"regenerate the block between {README_BEGIN} and {README_END} in this file")  # fmt: skip
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    results = load(args.from_json)
    text = write(results, args.plots, args.report)
    if args.readme:
        plots_dir = os.path.relpath(args.plots or Path("benchmarks/results"), args.readme.resolve().parent)
        write_block(args.readme, README_BLOCK, readme_block(results, Path(plots_dir).as_posix()))
        log(f"regenerated the results block of {args.readme}")
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
