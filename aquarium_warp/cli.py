"""Command line: `aquarium-warp demo` (speed), `aquarium-warp video` (an MP4 of heuristic or trained policies) and
`aquarium-warp bench` (the scaling benchmark suite), plus train, eval, study and sweep (training sweeps)."""

from __future__ import annotations

import argparse
import functools
import signal
import sys
import threading
import time
from collections.abc import Callable

from .arguments import (
    DEVICE_HELP,
    POLICY_SPECS,
    Interrupted,
    non_negative_int,
    plural,
    policy_spec,
    positive_float,
    positive_int,
)
from .atomic import check_output_file


class _DeferredParser(argparse.ArgumentParser):
    """A subcommand's parser whose options `add_options(parser)` adds on its first use (parsing it or
    its help): adding them imports the modules that own them (the studies, the benchmark suite:
    torch and Warp), which `aquarium-warp --help` and the other subcommands do without."""

    def __init__(self, *args, add_options: Callable[[argparse.ArgumentParser], None] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._add_options = add_options

    def complete(self) -> None:
        """Add the options now (once)."""
        add_options, self._add_options = self._add_options, None
        if add_options is not None:
            add_options(self)

    def parse_known_args(self, args=None, namespace=None):
        self.complete()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self.complete()
        return super().format_help()


def _terminated(signum, frame) -> None:
    """SIGTERM as Ctrl-C: the command unwinds (partial files removed) instead of vanishing."""
    raise Interrupted("terminated (SIGTERM)", signum)


def _demo(args) -> int:
    import torch

    from . import AquariumConfig, BatchedAquarium
    from .seeding import seed_key

    cfg = AquariumConfig(prey_count=args.prey, predator_count=args.predators, max_steps=args.max_steps)
    env = BatchedAquarium(cfg, num_worlds=args.worlds, device=args.device, seed=args.seed)
    # torch seeds are 64-bit: fold a larger seed as the env does (seeds below 2**32 are unchanged)
    gen = torch.Generator(device=env.torch_device).manual_seed(seed_key(args.seed))
    shapes = {"prey": (args.worlds, env.prey_capacity), "predator": (args.worlds, env.predator_capacity)}
    print(
        f"aquarium-warp demo: {plural(args.worlds, 'world')} x {cfg.capacity} agents on {env.device}, "
        f"random actions, {plural(args.steps, 'step')}"
    )
    env.reset()
    actions = {t: torch.empty(s, dtype=torch.int32, device=env.torch_device) for t, s in shapes.items()}
    # running totals stay on the device: a host read per step would put syncs into the timing
    captures = torch.zeros((), dtype=torch.int64, device=env.torch_device)
    ended = torch.zeros((), dtype=torch.int64, device=env.torch_device)
    start = time.perf_counter()
    for _ in range(args.steps):
        for t, s in shapes.items():
            torch.randint(0, cfg.action_count, s, generator=gen, out=actions[t])
        _, _, _, _, info = env.step(actions, validate=False)
        captures += info["captures"].sum()
        ended += info["episode_ended"].sum()
    captured, episodes_ended = int(captures), int(ended)  # waits for the last step
    elapsed = time.perf_counter() - start
    agent_steps = args.steps * args.worlds * cfg.capacity
    print(f"{'steps/s':>12} {'agent-steps/s':>15} {'captures':>10} {'captures/world-step':>20} {'episodes ended':>15}")
    print(
        f"{args.steps / elapsed:12.1f} {agent_steps / elapsed:15.3e} {captured:10d} "
        f"{captured / (args.steps * args.worlds):20.5f} {episodes_ended:15d}"
    )
    return 0


def _video_config(args):
    """The world to film: the trained policies' own (from their metadata, as `eval` takes it; prey and
    predator files must agree), else docs/model.md's (16 prey, 1 predator, 800 x 800); `--prey`,
    `--predators`, `--width`, `--height`, `--flow` override either."""
    from .config import FlowConfig
    from .drivers import check_spec, teams_world

    specs = {"prey": args.prey_policy, "predator": args.predator_policy}
    for agent_type, spec in specs.items():
        check_spec(spec, agent_type, f"--{agent_type}-policy")
    cfg = teams_world(specs, prey_count=args.prey, predator_count=args.predators, width=args.width, height=args.height)
    width, height = float(cfg.width), float(cfg.height)
    if args.flow == "uniform":
        cfg = cfg.replace(flow=FlowConfig("uniform", velocity=(args.flow_strength, 0.0)))
    elif args.flow == "vortex":  # centred, its core radius a sixth of the shorter side
        cfg = cfg.replace(
            flow=FlowConfig(
                "vortex",
                centre=(width / 2, height / 2),
                strength=args.flow_strength,
                core_radius=min(width, height) / 6,
            )
        )
    return cfg


def _video(args) -> int:
    from . import BatchedAquarium
    from .drivers import make_drivers
    from .video import check_video_path, record

    check_output_file(args.out, "--out")  # before the world is built
    check_video_path(args.out)

    cfg = _video_config(args)
    env = BatchedAquarium(cfg, num_worlds=1, device=args.device, seed=args.seed)
    drivers = make_drivers({"prey": args.prey_policy, "predator": args.predator_policy}, env, seed=args.seed)
    print(
        f"aquarium-warp video: {cfg.prey_count} prey ({args.prey_policy}) and "
        f"{plural(cfg.predator_count, 'predator')} ({args.predator_policy}) on {env.device}, "
        f"{plural(args.steps, 'step')} -> {args.out}"
    )
    start = time.perf_counter()
    frames = record(
        env,
        drivers,
        args.steps,
        args.out,
        fps=args.fps,
        progress=not args.no_progress,
        width_px=args.frame_width,
        height_px=args.frame_height,
        view_cones=args.view_cones,
        hit_boxes=args.hit_boxes,
        velocities=args.velocities,
        draw_flow=args.draw_flow,
    )
    print(f"wrote {frames} frames to {args.out} in {time.perf_counter() - start:.1f} s")
    return 0


def _add_train(sub) -> None:
    """`aquarium-warp train`: PPO with rsl-rl (arguments and handler in `training/cli.py`)."""
    from .training.cli import add_train_arguments, run_train

    train = sub.add_parser("train", help="train one team with PPO (rsl-rl) against heuristic or trained opponents")
    add_train_arguments(train)
    train.set_defaults(run=functools.partial(run_train, attach=_attach_viewer))


def _attach_viewer(env, port: int):
    """`train --view`: the viewer's page on the training worlds (the viewer extra, imported when asked)."""
    from .viewer import attach

    return attach(env, port=port)


def _add_eval(sub) -> None:
    """`aquarium-warp eval`: the paper's evaluation protocol and figures (in `training/cli.py`)."""
    from .training.cli import add_eval_arguments, run_eval

    evaluate = sub.add_parser(
        "eval", help="evaluate trained and heuristic policies (paper protocol), write CSV/JSON/figures"
    )
    add_eval_arguments(evaluate)
    evaluate.set_defaults(run=run_eval)


def _add_study(sub) -> None:
    """`aquarium-warp study <name>`: each study of `aquarium_warp.studies.STUDIES` owns its options and handler."""
    sub.add_parser(
        "study",
        help="parameter studies of collective behaviour (swarm-size, fov-view), the "
        "paper's open questions (group-hunting, many-eyes, flow) and the swarm "
        "study (swarm)",
        add_options=_study_options,
    )


def _study_options(study) -> None:
    """`study`'s subcommands, one a study (importing every study's module)."""
    from .studies import STUDIES

    kinds = study.add_subparsers(dest="study", required=True)
    for name, module in STUDIES.items():
        p = kinds.add_parser(name, help=module.HELP, description=module.DESCRIPTION)
        module.add_arguments(p)
        p.set_defaults(run=module.run)


def _add_sweep(sub) -> None:
    """`aquarium-warp sweep train` (options and handler in `training/sweep.py`)."""
    from .training import sweep as training_sweep

    sweep = sub.add_parser("sweep", help="many training runs: seeds x settings, here or as Ray tasks")
    kinds = sweep.add_subparsers(dest="sweep", required=True)
    p = kinds.add_parser("train", help=training_sweep.HELP, description=training_sweep.DESCRIPTION)
    training_sweep.add_arguments(p)
    p.set_defaults(run=training_sweep.run)


def _add_bench(sub) -> None:
    """`aquarium-warp bench`: the scaling benchmark suite (code in `aquarium_warp/bench/`)."""
    sub.add_parser(
        "bench",
        help="scaling benchmark: agent-steps/s, stage times, memory and bandwidth vs agents and worlds",
        description="Sweep agents per world and worlds; print a table and write "
        "scaling_<device>.json and log-log figures into --out-dir. The peers "
        "(--original, --vmas) are measured by the source tree's "
        "benchmarks/bench_scaling.py (same options).",
        add_options=_bench_options,
    )


def _bench_options(bench) -> None:
    """`bench`'s options (importing the suite)."""
    from .bench import add_arguments, run_from_args

    add_arguments(bench)
    bench.set_defaults(run=run_from_args)


def _add_view(sub) -> None:
    """`aquarium-warp view`: the browser viewer (code in `aquarium_warp/viewer/`)."""
    from .viewer import add_arguments, run

    view = sub.add_parser(
        "view",
        help="watch and steer a world live in the browser; replay pages of recordings",
        description="Serve a page that shows one world live: play/pause, speed, overlays, "
        "plots, team policies and keyboard play; or, with --replay, write a page "
        "that plays a recorded trajectory (docs/viewer.md).",
    )
    add_arguments(view)
    view.set_defaults(run=run)


def build_parser(deferred: bool = False) -> argparse.ArgumentParser:
    """The `aquarium-warp` parser with every subcommand (`python -m aquarium_warp` is the same).
    `deferred` (the command line's): the study and bench subcommands add their options when used."""
    from . import __version__

    parser = argparse.ArgumentParser(prog="aquarium-warp", description="Aquarium predator-prey worlds on Warp")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_DeferredParser)
    demo = sub.add_parser(
        "demo",
        help="step a batch of worlds with random actions and report speed and captures",
        description="Step a batch of worlds with random actions; print steps/s, agent-steps/s and captures.",
    )
    demo.add_argument("--worlds", type=positive_int, default=64, help="worlds stepped at once (default 64)")
    demo.add_argument("--steps", type=positive_int, default=500, help="steps to time (default 500)")
    demo.add_argument("--prey", type=int, default=16, help="prey per world (default 16)")
    demo.add_argument("--predators", type=int, default=1, help="predators per world (default 1)")
    demo.add_argument("--max-steps", type=int, default=3000, help="episode length")
    demo.add_argument("--device", default=None, help=DEVICE_HELP)
    demo.add_argument("--seed", type=non_negative_int, default=0, help="seed of the worlds and the random actions")
    demo.set_defaults(run=_demo)
    video = sub.add_parser("video", help="record one world driven by heuristic or trained policies as an MP4 video")
    video.add_argument(
        "--prey-policy", default="turnaway", type=policy_spec("prey"), help=f"{POLICY_SPECS['prey']} (default turnaway)"
    )
    video.add_argument(
        "--predator-policy",
        default="naivchase",
        type=policy_spec("predator"),
        help=f"{POLICY_SPECS['predator']} (default naivchase)",
    )
    video.add_argument("--steps", type=non_negative_int, default=600, help="steps to record (frames: steps + 1)")
    video.add_argument("--out", default="aquarium.mp4", help="output MP4 file (name ending in .mp4)")
    video.add_argument(
        "--prey", type=int, default=None, help="prey in the world (default: a trained policy's world, else 16)"
    )
    video.add_argument(
        "--predators", type=int, default=None, help="predators in the world (default: a trained policy's world, else 1)"
    )
    video.add_argument(
        "--width", type=float, default=None, help="world width, px (default: a trained policy's world, else 800)"
    )
    video.add_argument(
        "--height", type=float, default=None, help="world height, px (default: a trained policy's world, else 800)"
    )
    video.add_argument(
        "--frame-width",
        type=int,
        default=None,
        help="frame width in pixels (default: the world's, long side at most 1024)",
    )
    video.add_argument("--frame-height", type=int, default=None, help="frame height in pixels")
    video.add_argument("--fps", type=positive_float, default=30.0, help="frames per second of the video (default 30)")
    video.add_argument("--seed", type=non_negative_int, default=0, help="seed of the world and the policies")
    video.add_argument("--device", default=None, help=DEVICE_HELP)
    video.add_argument("--view-cones", action="store_true", help="draw each agent's field of view")
    video.add_argument("--hit-boxes", action="store_true", help="draw each agent's hit-box circle")
    video.add_argument("--velocities", action="store_true", help="draw velocity arrows (10 steps long)")
    video.add_argument(
        "--flow",
        choices=("uniform", "vortex"),
        default=None,
        help="a current (docs/model.md 'Flow fields'): uniform along +x, or a vortex at the centre "
        "(core radius a sixth of the shorter side); default: the config's (none)",
    )
    video.add_argument(
        "--flow-strength",
        type=float,
        default=2.0,
        help="px per step of --flow (the vortex's at its core's edge; default 2)",
    )
    video.add_argument("--draw-flow", action="store_true", help="draw the current as arrows under the agents")
    video.add_argument("--no-progress", action="store_true", help="no progress bar")
    video.set_defaults(run=_video)
    _add_train(sub)
    _add_eval(sub)
    _add_study(sub)
    _add_sweep(sub)
    _add_bench(sub)
    _add_view(sub)
    if not deferred:
        for command in sub.choices.values():
            command.complete()
    return parser


def main(argv=None) -> int:
    parser = build_parser(deferred=True)
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command as given (the studies record it)
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminated) if main_thread else None
    try:
        return args.run(args)
    except ValueError as error:
        print(f"aquarium-warp {args.command}: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # a full disk, a file that cannot be read or written: its path and the cause
        from .atomic import describe_os_error

        print(f"aquarium-warp {args.command}: {describe_os_error(error)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as error:  # Ctrl-C, SIGTERM (train: Interrupted says how to resume)
        print(f"aquarium-warp {args.command}: {str(error) or 'interrupted'}", file=sys.stderr)
        return getattr(error, "exit_code", 130)
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
