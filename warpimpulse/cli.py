"""Command line: `warpimpulse simulate | convert | preview | sweep | bench | stress`.

User mistakes (bad flags, bad scene files) print one clear line and exit 2, never a traceback. A run
that stops early (divergence, joints that do not converge, Ctrl-C, SIGTERM, SIGHUP) keeps the frames done
so far in a valid file, says so once the file holds them, and exits 1 (128 + the signal for a signal). An
output the file system refuses (disk full, a size limit) is one line and exit 1, the previous file intact.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time
import warnings
from pathlib import Path

from . import __version__
from .builder import SceneError
from .cliutil import EXIT_USAGE, ArgumentParser, check_writable
from .files import Interrupted, WriteError, same_file, signals_interrupt
from .options import StepOptions
from .scenes import SCENES
from .types import NEWTON_BODIES, SOLVERS

AUTO_ON_OFF = {"auto": None, "on": True, "off": False}  # a switch's choices on the command line

DEFAULT_DURATION = 10.0  # s, without --duration and without a time range in the scene file
DEFAULT_FPS = 30.0  # without --fps, for built-in scenes
MJCF_SUFFIXES = (".xml", ".mjcf")  # MuJoCo models (`mjcf.load_mjcf`)
USD_SUFFIXES = (".usd", ".usda", ".usdc")


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (value > 0 and math.isfinite(value)):
            raise argparse.ArgumentTypeError(f"must be positive and finite, got {text}")
        return value

    return parse


def _add_simulate(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a scene and write USD animation")
    p.add_argument("input", nargs="?", type=Path, help="a UsdPhysics scene file (.usd/.usda/.usdc), a URDF robot "
                   "(.urdf) or a MuJoCo model (.xml, needs the [mjcf] extra); or use --scene")  # fmt: skip
    p.add_argument("--scene", choices=sorted(SCENES), help="a built-in procedural scene (default: tree127)")
    p.add_argument("--out", "-o", type=Path, help="output USD file (default: out/<scene>.usdc)")
    p.add_argument("--duration", type=_positive(float),
                   help="seconds (default: a scene file's time range, else 10)")  # fmt: skip
    p.add_argument("--fps", type=_positive(float),
                   help="frames per second written (default: a scene file's timeCodesPerSecond, else 30)")  # fmt: skip
    p.add_argument("--dt", type=_positive(float),
                   help="step size, s; 1/fps must be a multiple (default: the scene file's, else 1/fps)")  # fmt: skip
    p.add_argument("--tolerance", type=_positive(float),
                   help="joint tolerance, m or rad (default 1e-6; tighter at --order 4, 6)")  # fmt: skip
    p.add_argument(
        "--accuracy",
        type=_positive(float),
        metavar="E",
        help="m: choose order, tolerance and step size (at most --dt, default 1/fps) so that the body "
        "centres stay within about E of the exact trajectory over --duration (docs/accuracy.md)",
    )
    p.add_argument("--order", type=int, choices=(2, 4, 6), default=2,
                   help="order in time: 2 is the paper's step, 4 and 6 compose it (default 2)")  # fmt: skip
    p.add_argument("--velocity-tolerance", type=_positive(float), help="default: the joint tolerance")
    p.add_argument("--solver", choices=SOLVERS, default="auto", help="auto = cholesky (see types.SOLVERS)")
    p.add_argument("--max-iterations", type=_positive(int), default=100)
    p.add_argument(
        "--newton",
        choices=("auto", "on", "off"),
        default="auto",
        help=f"the first joint iteration's Newton step (auto: on from {NEWTON_BODIES:,} bodies without loops)",
    )
    p.add_argument(
        "--carry",
        choices=("auto", "on", "off"),
        default="auto",
        help="the first joint iteration takes what the last step's left (auto: on with cholesky, no contacts)",
    )
    p.add_argument(
        "--defer-velocities",
        choices=("auto", "on", "off"),
        default="auto",
        help="correct the velocities only where a frame is written, the next step's joint correction reaching the "
        "same (auto: on with cholesky and no force elements, rows or contacts)",
    )
    p.add_argument(
        "--reuse-factor",
        choices=("auto", "on", "off"),
        default="auto",
        help="keep K's factor across steps while it serves, factoring again where it costs solves (auto: at order 4 "
        "and 6, with the fused cholesky step without limits, motors' rows, distance rows or loops)",
    )
    p.add_argument(
        "--split-forces",
        choices=("auto", "on", "off"),
        default="auto",
        help="springs and motors whose force depends on the poses alone act as half kicks about each step, the "
        "bodies predicted alone (auto: wherever every element allows it: no explicit damper, velocity drive or "
        "PID integral, one world)",
    )
    p.add_argument("--on-max-iterations", choices=("raise", "warn"), default="raise",
                   help="stop the run (keeping the frames so far) or warn and go on")  # fmt: skip
    p.add_argument("--max-rotation", type=_positive(float), default=0.5,
                   help="rad a body may turn per substep: faster steps are split (default 0.5)")  # fmt: skip
    p.add_argument("--whole-steps", action="store_true", help="never split a step for a fast spin")
    p.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    p.add_argument("--threads", type=_positive(int), default=1,
                   help="cut one large tree at its root across this many threads (the same run)")  # fmt: skip
    p.add_argument("--flatten", action="store_true", help="one self-contained file instead of a layer over the input")
    p.add_argument("--instancer", action=argparse.BooleanOptionalAction, default=None,
                   help="write a PointInstancer (default: automatic above a body count)")  # fmt: skip
    p.add_argument("--ignore-unsupported", action="store_true",
                   help="drop what is not simulated (cone limits, break forces, MJCF tendons, URDF mimics, ...) with "
                   "a warning instead of stopping")  # fmt: skip
    _add_urdf_flags(p)
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar (default: when stderr is a terminal)")  # fmt: skip
    p.add_argument("--verbose", action="store_true", help="show Warp's start-up banner and module loads")


def _add_convert(sub) -> None:
    p = sub.add_parser("convert", help="write a robot (URDF, MJCF) or a scene file as a UsdPhysics scene")
    p.add_argument("input", type=Path, help="a .urdf, an MJCF .xml, or a UsdPhysics scene (.usd/.usda/.usdc)")
    p.add_argument("--out", "-o", type=Path, required=True, help="the UsdPhysics scene to write (.usda/.usdc/.usd)")
    p.add_argument("--ignore-unsupported", action="store_true",
                   help="drop what is not simulated with a warning naming it, instead of stopping")  # fmt: skip
    _add_urdf_flags(p)


def _add_urdf_flags(p) -> None:
    p.add_argument("--floating", action=argparse.BooleanOptionalAction, default=None,
                   help="URDF: the root link free (a floating base), or fixed to the world (default: fixed "
                   "unless the URDF joins it to the world by a floating joint)")  # fmt: skip
    p.add_argument("--no-collisions", action="store_true", help="URDF: no collision shapes (no contacts)")
    p.add_argument("--self-collisions", action="store_true",
                   help="URDF: the links collide with each other, but for jointed ones (default: off)")  # fmt: skip
    p.add_argument("--ground", action="store_true",
                   help="URDF: a ground plane 1 mm under the robot's lowest collision shape, as built")  # fmt: skip


def _load_input(source: Path, args):
    """A URDF or an MJCF file as a SceneBuilder, a UsdPhysics scene as its `UsdScene` (with the prim paths and the
    step size it asks for), by extension; what --ignore-unsupported drops is one warning line each. The URDF
    flags (--floating, --no-collisions, --self-collisions, --ground) are refused for any other input rather than
    ignored."""
    from . import usd
    from .urdf import load_urdf

    if not source.is_file():
        raise SceneError(f"{source}: " + ("not a file" if source.exists() else "no such file"))
    ext = source.suffix.lower()
    if ext != ".urdf":
        for flag in _given_urdf_flags(args):
            raise SceneError(f"{source}: {flag} is for a URDF")
    if args.ground and args.no_collisions:
        raise SceneError("--ground with --no-collisions: the robot would have nothing to stand on")
    with warnings.catch_warnings():
        warnings.simplefilter("always")  # every note, whatever the caller's filters
        warnings.showwarning = _one_line
        if ext == ".urdf":
            builder = load_urdf(source, ignore_unsupported=args.ignore_unsupported, floating=args.floating,
                                collisions=not args.no_collisions, self_collisions=args.self_collisions)  # fmt: skip
            if args.ground:
                shaped = [b for b in builder.bodies if b.shape is not None]
                if not shaped:
                    raise SceneError(f"{source}: --ground: the robot has no collision shape to stand on (its "
                                     "collisions are meshes, or --no-collisions)")  # fmt: skip
                builder.add_ground(min(b.position[2] - b.shape.bounding_radius() for b in shaped) - 1e-3)
            return builder
        if ext in MJCF_SUFFIXES:
            from .mjcf import load_mjcf

            return load_mjcf(str(source), ignore_unsupported=args.ignore_unsupported)
        if ext in USD_SUFFIXES:
            return usd.load_stage(source, ignore_unsupported=args.ignore_unsupported)
    raise SceneError(f"{source}: not a .urdf, an MJCF {'/'.join(MJCF_SUFFIXES)} or a {'/'.join(USD_SUFFIXES)} file")


def _given_urdf_flags(args) -> list[str]:
    """The URDF-only flags given, which any other input refuses rather than ignores."""
    given = [("--floating/--no-floating", args.floating is not None), ("--no-collisions", args.no_collisions),
             ("--self-collisions", args.self_collisions), ("--ground", args.ground)]  # fmt: skip
    return [flag for flag, on in given if on]


def _convert(args) -> int:
    from . import usd

    loaded = _load_input(args.input, args)
    builder, dt = (loaded.builder, loaded.dt) if isinstance(loaded, usd.UsdScene) else (loaded, None)
    if same_file(args.out, args.input):
        raise SceneError(f"{args.out}: is the input; the output would replace it (choose another --out)")
    check_writable(args.out)
    path = usd.save_scene(builder, args.out, dt=dt)
    print(f"wrote {path}: {len(builder.bodies)} bodies, {len(builder.joints)} joints, {len(builder.limits)} limits, "
          f"{len(builder.drives)} drives, {len(builder.visuals)} visuals")  # fmt: skip
    return 0


def _add_preview(sub) -> None:
    p = sub.add_parser("preview", help="draw the bodies of a written USD file at a few frames (needs matplotlib)")
    p.add_argument("input", type=Path, help="a file written by `warpimpulse simulate` or warpimpulse.usd.record")
    p.add_argument("--out", "-o", type=Path, help="picture to write: .png (a few frames side by side) or .gif "
                   "(every frame, up to --gif-frames) (default: <input>.png)")  # fmt: skip
    p.add_argument("--frames", type=_positive(int), default=4, help="panels in a .png (default 4)")
    p.add_argument("--gif-frames", type=_positive(int), default=60, help="most frames in a .gif (default 60)")


def _add_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="a grid or random sample of parameters over scenes, as batched worlds on Ray or "
                       "a local process pool, into one table")  # fmt: skip
    p.add_argument("config", nargs="?", type=Path, help="a TOML file: [params] name = [values] (a grid); [random] "
                   "samples = N, seed = S, [random.ranges] name = [low, high]")  # fmt: skip
    p.add_argument("--param", action="append", default=[], metavar="NAME=V1,V2",
                   help="values of one parameter (repeat the flag): scene, dt, tolerance, duration, max_iterations; "
                   "per world: mass_scale, spin, force (warpimpulse.sweep.PARAMETERS)")  # fmt: skip
    p.add_argument("--samples", type=_positive(int), help="a random sample of this many points instead of the grid")
    p.add_argument("--seed", type=int, help="of the random sample (default 0)")
    p.add_argument("--out", "-o", type=Path, default=Path("out/sweep"),
                   help="folder for points.jsonl (a sweep run again there resumes), sweep.csv, sweep.json, sweep.png "
                   "(default out/sweep)")  # fmt: skip
    p.add_argument("--workers", type=_positive(int), help="processes or Ray CPUs (default: one per core)")
    p.add_argument("--chunk", type=_positive(int), default=16, help="most points one task runs as batched worlds")
    p.add_argument("--backend", choices=("auto", "ray", "pool"), default="auto",
                   help="auto: Ray when installed (the [sweep] extra), else the standard library's process "
                   "pool")  # fmt: skip
    p.add_argument("--address", metavar="HOST:PORT", help="a running Ray cluster (default: a local one, ray.init())")
    p.add_argument("--plot", action=argparse.BooleanOptionalAction, default=True, help="sweep.png (needs matplotlib)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar (default: when stderr is a terminal)")  # fmt: skip


def _sweep(args) -> int:
    from . import sweep

    params, samples, seed, ranges = {}, None, 0, {}
    if args.config is not None:
        config = sweep.load_config(args.config)
        params, samples, seed, ranges = config["params"], config["samples"], config["seed"], config["ranges"]
    params.update(sweep.parse_param(text) for text in args.param)
    samples = args.samples or samples
    seed = seed if args.seed is None else args.seed
    if not params and not ranges:
        raise ValueError("nothing to sweep: give a TOML file or --param name=v1,v2,...")
    try:
        points = sweep.make_points(params, samples, seed, ranges)
    except ValueError as err:  # the size of the sweep, what its file asks
        raise ValueError(f"{args.config}: {err}" if args.config is not None else str(err)) from None
    workers = args.workers or os.cpu_count() or 1
    backend = args.backend
    if backend != "pool" and not sweep.ray_available():
        if backend == "ray" or args.address:
            raise ValueError("Ray is not installed: pip install 'warpimpulse[sweep]'")
        print("warpimpulse: Ray is not installed (pip install 'warpimpulse[sweep]'); running on the standard "
              f"library's process pool, {workers} workers, on this machine", file=sys.stderr)  # fmt: skip
        backend = "pool"
    if args.address and backend == "pool":
        raise ValueError("--address names a Ray cluster; it does not go with --backend pool")
    check_writable(args.out / "sweep.csv", create_parent=True)
    show = sys.stderr.isatty() if args.progress is None else args.progress
    result = sweep.run(points, args.out, workers, backend, args.address, args.chunk,
                       progress=sweep.progress_bar if show else None)  # fmt: skip
    outcomes = [row["outcome"] for row in result.rows]
    before = len(points) - len(result.computed)
    print(f"swept {len(points)} points ({len(result.computed)} computed on {result.backend}, {before} done before): "
          f"{outcomes.count('ok')} ok, {outcomes.count('stopped')} stopped, {outcomes.count('error')} errors; "
          f"table in {args.out / 'sweep.csv'} and sweep.json")  # fmt: skip
    for line in sweep.failures(result.rows):
        print(f"warpimpulse: {line}", file=sys.stderr)
    if args.plot:
        if sweep.plot(result.rows, args.out / "sweep.png"):
            print(f"plots in {args.out / 'sweep.png'}")
        else:
            print("warpimpulse: no plots: matplotlib is not installed (pip install 'warpimpulse[preview]')",
                  file=sys.stderr)  # fmt: skip
    return 1 if "error" in outcomes else 0


def _timing(args, scene) -> tuple[float, float]:
    """(duration s, fps) from the flags, else from the scene file's time (its range [startTimeCode,
    endTimeCode] at its timeCodesPerSecond), else 10 s at 30 fps; what came from the file is said on stdout."""
    if scene is None:
        return args.duration or DEFAULT_DURATION, args.fps or DEFAULT_FPS
    rate = scene.time_codes_per_second
    fps = args.fps or rate
    start, end = scene.time_range or (0.0, 0.0)
    duration = args.duration or ((end - start) / rate if end > start else DEFAULT_DURATION)
    chosen = []
    if args.duration is None:
        chosen.append(f"{duration:.6g} s (time codes {start:g}-{end:g} at {rate:g} per second, from the stage)"
                      if end > start else f"{duration:g} s (the stage has no time range)")  # fmt: skip
    if args.fps is None:
        chosen.append(f"{fps:g} fps (the stage's timeCodesPerSecond)")
    if chosen:
        print(f"simulating {' at '.join(chosen)}; --duration / --fps override")
    return duration, fps


def _refuse_no_frame(duration: float, fps: float) -> None:
    """SceneError when `duration` holds no frame at `fps` (`run.frame_count`)."""
    from . import run

    try:
        run.frame_count(duration, fps)
    except ValueError as err:
        raise SceneError(f"--{err}".replace("the duration", "--duration")) from None


def _say_fallbacks(sim) -> None:
    """Each reason the run took steps at a lower order than --order asked, once (`Simulator.fallbacks`; the output
    records them too, warpimpulse:fallbacks), and the dampers taken implicitly (warpimpulse:damperNote)."""
    for reason in sim.fallbacks:
        print(f"warpimpulse: {sim.fallback_note(reason)}", file=sys.stderr)
    if getattr(sim, "damper_note", None) and sim.damper_note():
        print(f"warpimpulse: {sim.damper_note()}", file=sys.stderr)


def _simulate(args) -> int:
    from . import checks, run, usd
    from .energy import EnergyWatch
    from .simulator import SimulationError
    from .solver import SingularSystemError
    from .split import SplitSimulator
    from .verbosity import verbose

    if args.verbose:
        verbose()
    if args.input and args.scene:
        raise SceneError("give either a scene file or --scene, not both")
    checks.device(args.device)  # before the scene is read: a long load must not end on a missing GPU
    if args.accuracy is not None and args.order != 2:
        raise SceneError(f"--accuracy chooses the order itself; drop --order {args.order}")
    if args.duration is not None and args.fps is not None:
        _refuse_no_frame(args.duration, args.fps)  # before the scene is read, when the flags settle it
    stage = None  # a USD scene file's (its time range and step size)
    if args.input:
        source = args.input
        loaded = _load_input(source, args)  # a robot (URDF, MJCF) is written whole, with its visuals
        stage = loaded if isinstance(loaded, usd.UsdScene) else None
        builder = stage.builder if stage else loaded
        name = source.stem
    else:
        flags = _given_urdf_flags(args)
        if flags:
            raise SceneError(f"{', '.join(flags)}: for a URDF input")
        name = args.scene or "tree127"
        builder = SCENES[name]()
    scene = stage or builder
    args.duration, args.fps = _timing(args, stage)
    _refuse_no_frame(args.duration, args.fps)
    file_dt = stage.dt if stage else None  # a scene file may record the step size it needs
    dt = args.dt if args.dt is not None else (file_dt or 1.0 / args.fps)
    try:
        run.frame_steps(dt, args.fps)  # refuse a dt that does not divide the frame time, before any work
    except ValueError as err:
        raise ValueError(f"{err} (dt from {source}'s warpimpulse:dt; pass --dt)" if dt == file_dt else err) from None
    out = args.out or Path("out") / f"{name}.usdc"
    if args.input and same_file(out, source):
        raise SceneError(f"{out}: is the input scene; the output would replace it (choose another --out)")
    check_writable(out, create_parent=args.out is None)
    if out.is_file():
        print(f"warpimpulse: overwriting {out}", file=sys.stderr)
    sim = SplitSimulator(
        builder.finalize(args.device),
        dt,
        threads=args.threads,
        tolerance=args.tolerance,
        velocity_tolerance=args.velocity_tolerance,
        solver=args.solver,
        max_iterations=args.max_iterations,
        on_max_iterations=args.on_max_iterations,
        order=args.order,
        accuracy=args.accuracy,
        options=StepOptions(
            max_rotation=None if args.whole_steps else args.max_rotation,
            newton=AUTO_ON_OFF[args.newton],
            carry=AUTO_ON_OFF[args.carry],
            defer_velocities=AUTO_ON_OFF[args.defer_velocities],
            reuse_factor=AUTO_ON_OFF[args.reuse_factor],
            split_forces=AUTO_ON_OFF[args.split_forces],
        ),
    )
    if sim.accuracy is not None:
        sim.accuracy.horizon = args.duration
        if sim.accuracy.plan.note:
            print(f"warpimpulse: accuracy: {sim.accuracy.plan.note}", file=sys.stderr)
    if sim.split_note:
        print(f"warpimpulse: one thread: {sim.split_note}", file=sys.stderr)
    if sim.redundant_rows:  # information: loop joints repeating what the tree already holds (a planar loop in 3D)
        print(f"warpimpulse: {sim.redundant_rows} constraint rows of loop-closing joints are redundant "
              "(regularised)", file=sys.stderr)  # fmt: skip
    start = time.perf_counter()
    writer = usd.AnimationWriter(
        out, scene, args.fps, settings=run.settings(sim), flatten=args.flatten, instancer=args.instancer
    )
    energy = EnergyWatch(sim)
    on_frame = energy.follow(writer.settings)

    def kept() -> str:  # true whatever happened: the file holds the frames only once it is saved
        return f"{out} holds the {writer.frames_written} frames done" if writer.saved else f"{out} was not written"

    try:
        with writer:
            frames = run.record_frames(sim, writer, args.duration, progress=args.progress, on_frame=on_frame,
                                       record=writer.settings)  # fmt: skip
    except WriteError as err:  # disk full, a file size limit: the previous file is unchanged
        print(f"warpimpulse: error: {err}", file=sys.stderr)
        return 1
    except (SimulationError, SingularSystemError, FloatingPointError) as err:
        _say_fallbacks(sim)
        print(f"warpimpulse: stopped at t = {sim.time:.6g} s: {err}", file=sys.stderr)
        print(f"warpimpulse: {kept()} before the stop", file=sys.stderr)
        return 1
    except KeyboardInterrupt as err:
        signum = err.signum if isinstance(err, Interrupted) else signal.SIGINT
        print(f"\nwarpimpulse: interrupted ({signal.Signals(signum).name}); {kept()}", file=sys.stderr)
        return 128 + signum
    elapsed = time.perf_counter() - start
    _say_fallbacks(sim)
    if energy.warning():
        print(f"warpimpulse: warning: {energy.warning()}", file=sys.stderr)
    steps = f"{sim.step_count} steps of {dt:.6g} s"
    if sim.accuracy is not None:
        steps = (f"{sim.step_count} steps of at most {dt:.6g} s at order {sim.order} "
                 f"for an accuracy of {args.accuracy:g} m")  # fmt: skip
    print(
        f"wrote {out}: {frames} frames of {sim.model.body_count} bodies, {steps} "
        f"in {elapsed:.2f} s ({1e3 * elapsed / max(sim.step_count, 1):.3f} ms a step, output included)"
    )
    return 0


def _one_line(message, category, *_) -> None:
    """`warnings.showwarning` while a command runs: a warning (a dropped USD feature, a step over its iteration
    limit under --on-max-iterations warn) is one line, without the library's source line."""
    print(f"warpimpulse: warning: {message}", file=sys.stderr)


def _command(parser, args, rest: list[str]) -> int:
    """Run the command `args` asks for (`main` reports its errors)."""
    if args.command in ("bench", "stress"):
        from .bench.cli import main as harness_main  # the harness, imported only when asked for

        return int(harness_main(args.command, rest) or 0)
    if rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    if args.command == "preview":
        from .preview import main as preview_main

        return preview_main(args.input, args.out, args.frames, args.gif_frames)
    if args.command == "sweep":
        return _sweep(args)
    if args.command == "convert":
        return _convert(args)
    with signals_interrupt():  # SIGTERM and SIGHUP end a run as Ctrl-C does, keeping its frames
        return _simulate(args)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="warpimpulse", description="Impulse-based articulated rigid bodies on Warp")
    parser.add_argument("--version", action="version", version=f"warpimpulse {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_simulate(sub)
    _add_convert(sub)
    _add_preview(sub)
    _add_sweep(sub)
    sub.add_parser("bench", help="benchmark harness (see `warpimpulse bench --help`)", add_help=False)
    sub.add_parser("stress", help="stress suite (see `warpimpulse stress --help`)", add_help=False)
    args, rest = parser.parse_known_args(argv)
    from .simulator import SimulationError
    from .solver import SingularSystemError

    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line
            return _command(parser, args, rest)
    except (SceneError, ValueError, OSError, SingularSystemError) as err:  # bad input, found before the run
        print(f"warpimpulse: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except SimulationError as err:
        print(f"warpimpulse: stopped: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as err:  # before the run (reading the scene)
        signum = err.signum if isinstance(err, Interrupted) else signal.SIGINT
        print(f"\nwarpimpulse: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return 128 + signum


if __name__ == "__main__":
    sys.exit(main())
