"""Command line: `aquarium-warp demo` (speed), `aquarium-warp video` (an MP4 of heuristic or trained policies) and
`aquarium-warp bench` (the scaling benchmark suite), plus train, eval, study and sweep (training sweeps)."""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
import time

from .atomic import check_output_dir, check_output_file


def int_at_least(low: int):
    """argparse type: an integer >= `low` (any size)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be an integer >= {low}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be an integer >= {low}")
        return value

    return parse


class Interrupted(KeyboardInterrupt):
    """A signal that ended a command early: the message to print and the shell's exit code for it
    (128 + the signal's number)."""

    def __init__(self, message: str, signum: int):
        super().__init__(message)
        self.exit_code = 128 + signum


def _terminated(signum, frame) -> None:
    """SIGTERM as Ctrl-C: the command unwinds (partial files removed) instead of vanishing."""
    raise Interrupted("terminated (SIGTERM)", signum)


def plural(count: int, noun: str) -> str:
    """"1 predator", "3 predators" (nouns with a plain -s plural)."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)  # seeds: any size


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be a finite number > 0") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be a finite number > 0")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be a finite number >= 0") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be a finite number >= 0")
    return value


def _add_ray_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """`--ray [ADDRESS]` and what each Ray task holds (`aquarium_warp/ray_tasks.py`)."""
    g = parser.add_argument_group("Ray", f"run each {what} as a Ray task, on one machine or a cluster "
                                         "(pip install 'aquarium-warp[distributed]')")
    g.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help=f"run each {what} as a Ray task: on the cluster at ADDRESS ('auto': the one `ray start` "
                        "started on this machine; 'ray://HOST:10001': Ray Client), without ADDRESS on "
                        "$RAY_ADDRESS's cluster or else a new one on this machine")
    g.add_argument("--gpus-per-task", type=non_negative_float, default=None, metavar="G",
                   help="GPUs each task holds: a fraction in [0, 1] (0.25: four tasks share a GPU) or a whole "
                        "number (default 1 where the cluster has GPUs and --device is not 'cpu', else 0)")
    g.add_argument("--cpus-per-task", type=positive_float, default=None, metavar="C",
                   help="CPU cores each task holds (default 1)")
    g.add_argument("--max-retries", type=non_negative_int, default=None, metavar="R",
                   help="reruns of a task whose worker died (default 3)")


def _ray_options(args):
    """The `RayOptions` of `_add_ray_arguments`' options, or None without --ray."""
    from .ray_tasks import RayOptions

    given = {name: value for name, value in (("gpus_per_task", args.gpus_per_task),
                                             ("cpus_per_task", args.cpus_per_task),
                                             ("max_retries", args.max_retries)) if value is not None}
    if args.ray is None:
        if given:
            names = ", ".join("--" + name.replace("_", "-") for name in given)
            raise ValueError(f"{names} set the Ray tasks: give --ray too")
        return None
    options = RayOptions(address=args.ray or None, **given)
    options.validate()
    return options


def _demo(args) -> int:
    import torch

    from . import AquariumConfig, BatchedAquarium
    from .env import seed_key

    cfg = AquariumConfig(prey_count=args.prey, predator_count=args.predators, max_steps=args.max_steps)
    env = BatchedAquarium(cfg, num_worlds=args.worlds, device=args.device, seed=args.seed)
    # torch seeds are 64-bit: fold a larger seed as the env does (seeds below 2**32 are unchanged)
    gen = torch.Generator(device=env.torch_device).manual_seed(seed_key(args.seed))
    shapes = {"prey": (args.worlds, env.prey_capacity), "predator": (args.worlds, env.predator_capacity)}
    print(f"aquarium-warp demo: {args.worlds} worlds x {cfg.capacity} agents on {env.device}, "
          f"random actions, {args.steps} steps")
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
    print(f"{args.steps / elapsed:12.1f} {agent_steps / elapsed:15.3e} {captured:10d} "
          f"{captured / (args.steps * args.worlds):20.5f} {episodes_ended:15d}")
    return 0


def _video_config(args):
    """The world to film: the trained policies' own (from their metadata, as `eval` takes it; prey and
    predator files must agree), else docs/model.md's (16 prey, 1 predator, 800 x 800); `--prey`,
    `--predators`, `--width`, `--height`, `--flow` override either."""
    from . import AquariumConfig
    from .config import FlowConfig
    from .drivers import check_spec, is_heuristic

    for spec, agent_type in ((args.prey_policy, "prey"), (args.predator_policy, "predator")):
        check_spec(spec, agent_type, f"--{agent_type}-policy")
    files = [spec for spec, agent_type in ((args.prey_policy, "prey"), (args.predator_policy, "predator"))
             if not is_heuristic(spec, agent_type)]
    data = AquariumConfig().to_dict()
    if files:
        try:
            from .training.evaluate import common_policy_env
        except ImportError as error:
            raise ValueError(f"policies {files} are not heuristics; trained policy files need the training "
                             f"extra ({error})") from error
        data = common_policy_env(files, AquariumConfig()).to_dict()
    for key, value in (("prey_count", args.prey), ("predator_count", args.predators), ("width", args.width),
                       ("height", args.height)):
        if value is not None:
            data[key] = value
    width, height = float(data["width"]), float(data["height"])
    if args.flow == "uniform":
        data["flow"] = FlowConfig("uniform", velocity=(args.flow_strength, 0.0))
    elif args.flow == "vortex":  # centred, its core radius a sixth of the shorter side
        data["flow"] = FlowConfig("vortex", centre=(width / 2, height / 2), strength=args.flow_strength,
                                  core_radius=min(width, height) / 6)
    return AquariumConfig.from_dict(data)


def _video(args) -> int:
    from . import BatchedAquarium
    from .drivers import make_drivers
    from .video import check_video_path, record

    check_output_file(args.out, "--out")  # before the world is built
    check_video_path(args.out)

    cfg = _video_config(args)
    env = BatchedAquarium(cfg, num_worlds=1, device=args.device, seed=args.seed)
    drivers = make_drivers({"prey": args.prey_policy, "predator": args.predator_policy}, env, seed=args.seed)
    print(f"aquarium-warp video: {cfg.prey_count} prey ({args.prey_policy}) and "
          f"{plural(cfg.predator_count, 'predator')} ({args.predator_policy}) on {env.device}, {args.steps} steps "
          f"-> {args.out}")
    start = time.perf_counter()
    frames = record(env, drivers, args.steps, args.out, fps=args.fps, progress=not args.no_progress,
                    width_px=args.frame_width, height_px=args.frame_height, view_cones=args.view_cones,
                    hit_boxes=args.hit_boxes, velocities=args.velocities, draw_flow=args.draw_flow)
    print(f"wrote {frames} frames to {args.out} in {time.perf_counter() - start:.1f} s")
    return 0


def _add_train(sub) -> None:
    """`aquarium-warp train`: PPO with rsl-rl (arguments and handler in `training/cli.py`)."""
    from .training.cli import add_train_arguments, run_train

    train = sub.add_parser("train", help="train one team with PPO (rsl-rl) against heuristic or trained opponents")
    add_train_arguments(train)
    train.set_defaults(run=run_train)


def _add_eval(sub) -> None:
    """`aquarium-warp eval`: the paper's evaluation protocol and figures (in `training/cli.py`)."""
    from .training.cli import add_eval_arguments, run_eval

    evaluate = sub.add_parser("eval", help="evaluate trained and heuristic policies (paper protocol), "
                                           "write CSV/JSON/figures")
    add_eval_arguments(evaluate)
    evaluate.set_defaults(run=run_eval)


def _study_kwargs(args) -> dict:
    """The `SwarmSizeStudy` settings that every study subcommand has (`_add_study_run_arguments`)."""
    from .study import parse_world_size

    return dict(seeds=args.seeds, episodes_per_seed=args.episodes_per_seed, episode_steps=args.episode_steps,
                prey_policy=args.prey_policy, predator_policy=args.predator_policy, confusion=not args.no_confusion,
                predators=args.predators, world_size=parse_world_size(args.world_size),
                linking_distance=args.linking_distance, metrics_every=args.metrics_every, device=args.device,
                seed=args.seed, jobs=args.jobs, out=args.out, figures=not args.no_figures)


def _study_swarm_size(args) -> int:
    """`aquarium-warp study swarm-size`: captures, polarization and groups vs the number of prey."""
    from .number_lists import parse_list
    from .studies.common import command_line
    from .study import SwarmSizeStudy, replot_study, run_swarm_size_study

    if args.replot:
        summary = replot_study(args.out, device=args.device)
        print(f"redrew {len(summary['figures'])} figures in {args.out} from swarm_size.json")
        return 0
    ray = _ray_options(args)
    if ray is not None and args.jobs is not None:
        raise ValueError("--jobs sets the threads of a run on this machine; with --ray each setting is a task "
                         "(--cpus-per-task, --gpus-per-task)")
    if ray is not None and args.one_batch:
        raise ValueError("--one-batch runs every setting in one batch on this machine: not with --ray")
    study = SwarmSizeStudy(
        prey=[int(n) for n in parse_list(args.prey, int, "--prey")],
        fov_angles=parse_list(args.fov_angle, float, "--fov-angle") if args.fov_angle else None,
        view_distances=parse_list(args.view_distance, float, "--view-distance") if args.view_distance else None,
        constant_density=args.constant_density, reference_prey=args.reference_prey, respawn=not args.no_respawn,
        reproduction=args.reproduction, starvation_steps=args.starvation_steps, one_batch=args.one_batch,
        **_study_kwargs(args))
    print(f"aquarium-warp study swarm-size: prey {study.prey}, {study.seeds} seeds x {study.episodes_per_seed} "
          f"episode(s) of {study.episode_steps} steps, {study.prey_policy} vs {study.predator_policy} -> {study.out}")
    check_output_dir(study.out, "--out")
    summary = run_swarm_size_study(study, progress=not args.no_progress, ray=ray, command=command_line(args.argv))
    where = summary["machine"]["device_name"]
    if ray is not None:
        where = f"Ray ({len(summary['ray']['nodes'])} machine(s), {summary['ray']['settings_kept']} setting(s) kept)"
    print(f"wrote {os.path.join(study.out, 'swarm_size.csv')}, swarm_size.json and {len(summary.get('figures', []))} "
          f"figures in {summary['wall_time_s']:.1f} s on {where} ({summary['path']})")
    return 0


def _study_fov_view(args) -> int:
    """`aquarium-warp study fov-view`: captures per prey over prey FOV angle x view distance."""
    from .number_lists import parse_list
    from .studies.common import command_line
    from .study import SwarmSizeStudy, run_swarm_size_study

    fovs = parse_list(args.fov, float, "--fov")
    if any(not 0 < f <= 360 for f in fovs):
        raise ValueError(f"--fov={args.fov!r}: every angle must be in (0, 360] degrees")
    views = parse_list(args.view, float, "--view")
    if any(not 0 < v < float("inf") for v in views):
        raise ValueError(f"--view={args.view!r}: every distance must be a finite number > 0 (px)")
    study = SwarmSizeStudy(prey=[args.prey], fov_angles=fovs, view_distances=views, one_batch=not args.per_setting,
                           kind="fov-view", **_study_kwargs(args))
    print(f"aquarium-warp study fov-view: {study.prey[0]} prey, FOV {fovs} x view {views}, {study.seeds} seeds, "
          f"episodes of {study.episode_steps} steps -> {study.out}")
    check_output_dir(study.out, "--out")
    summary = run_swarm_size_study(study, progress=not args.no_progress, command=command_line(args.argv))
    print(f"wrote {os.path.join(study.out, 'fov_view.csv')}, fov_view.json and {len(summary.get('figures', []))} "
          f"figure(s) in {summary['wall_time_s']:.1f} s on {summary['machine']['device_name']} ({summary['path']})")
    return 0


def _add_study_run_arguments(p, out: str) -> None:
    """The options that every study subcommand has (`_study_kwargs` reads them)."""
    p.add_argument("--seeds", type=int, default=5, help="independent runs per setting (default 5)")
    p.add_argument("--episodes-per-seed", type=int, default=1, help="episodes per seed, run as more worlds")
    p.add_argument("--episode-steps", type=int, default=3000, help="steps per episode (default 3000, the paper's)")
    p.add_argument("--prey-policy", default="turnaway", help="'turnaway', 'random' or a trained policy file")
    p.add_argument("--predator-policy", default="naivchase", help="'naivchase', 'random' or a trained policy file")
    p.add_argument("--no-confusion", action="store_true", help="NaivChase chases the nearest visible prey "
                   "instead of a random one each step")
    p.add_argument("--predators", type=int, default=1, help="predators per world (default 1)")
    p.add_argument("--world-size", default="800x800", help="arena WIDTHxHEIGHT px (default 800x800)")
    p.add_argument("--linking-distance", type=float, default=None,
                   help="px; prey closer than this form one group (default 2.5 prey radii = 50)")
    p.add_argument("--metrics-every", type=int, default=10, help="sample the swarm metrics every K steps")
    p.add_argument("--device", default=None, help="'cpu', 'cuda:0'; default: CUDA when present")
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="seed of the batched worlds (the --seeds runs are worlds of one env)")
    p.add_argument("--jobs", type=positive_int, default=None,
                   help="settings run at once in threads, one batch per setting (default: CPU cores on the CPU, "
                        "1 on a GPU)")
    p.add_argument("--out", default=out, help=f"output directory (default {out})")
    p.add_argument("--no-figures", action="store_true", help="write CSV/JSON only, no figures")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_study(sub) -> None:
    """`aquarium-warp study swarm-size` and `study fov-view` (code in `aquarium_warp/study.py`, figures in
    `study_plots.py`), and the open questions (`_add_open_questions`)."""
    study = sub.add_parser("study", help="parameter studies of collective behaviour (swarm-size, fov-view) and the "
                                         "paper's open questions (group-hunting, many-eyes, flow)")
    kinds = study.add_subparsers(dest="study", required=True)
    p = kinds.add_parser("swarm-size", help="captures per prey (dilution), polarization and groups vs prey count",
                         description="Run every prey count and seed as batched worlds, one episode each, and "
                                     "write swarm_size.csv/json and figures into --out.")
    p.add_argument("--prey", default="4,8,...,4096",
                   help="prey counts: a comma list; '...' continues the progression (default 4,8,...,4096)")
    p.add_argument("--fov-angle", default=None, help="prey field-of-view angles to sweep, degrees (list; default 120)")
    p.add_argument("--view-distance", default=None, help="prey view distances to sweep, px (list; default 100)")
    p.add_argument("--constant-density", action="store_true", help="scale the arena with N instead of a fixed "
                   "--world-size, keeping the density of --reference-prey prey in --world-size")
    p.add_argument("--reference-prey", type=int, default=16,
                   help="with --constant-density: the prey count that --world-size is sized for (default 16)")
    p.add_argument("--no-respawn", action="store_true", help="captured prey are removed (populations shrink)")
    p.add_argument("--reproduction", action="store_true", help="prey reproduce (up to 2 N)")
    p.add_argument("--starvation-steps", type=int, default=None, help="predator starvation limit (default 3000)")
    p.add_argument("--one-batch", action="store_true", help="every setting in one batch (per-world prey counts; "
                   "every world has the slots of the largest count) instead of one batch per setting")
    _add_study_run_arguments(p, "swarm_size")
    p.add_argument("--replot", action="store_true", help="only redraw the figures from --out's swarm_size.json")
    _add_ray_arguments(p, "setting (prey count, FOV angle and view distance)")
    p.set_defaults(run=_study_swarm_size)
    p = kinds.add_parser("fov-view", help="captures per prey over prey field of view x view distance",
                         description="Run every (prey FOV angle, view distance) and seed as worlds of one batch "
                                     "(per-world parameters), one episode each, and write fov_view.csv/json and "
                                     "a heatmap into --out.")
    p.add_argument("--fov", default="60,120,240,360", help="prey field-of-view angles, degrees (list)")
    p.add_argument("--view", default="50,100,200,400", help="prey view distances, px (list)")
    p.add_argument("--prey", type=positive_int, default=32, help="prey per world (default 32)")
    p.add_argument("--per-setting", action="store_true", help="one batch per setting instead (for timing)")
    _add_study_run_arguments(p, "fov_view")
    p.set_defaults(run=_study_fov_view)
    _add_open_questions(kinds)


def _add_open_question_arguments(p, out: str, jobs: bool = True) -> None:
    """The options of every open-question study (`aquarium_warp/studies/`): seeds, device, workers, output."""
    p.add_argument("--seeds", type=positive_int, default=5, help="independent runs per setting (default 5)")
    p.add_argument("--device", default=None, help="'cpu', 'cuda:0'; default: CUDA when present")
    if jobs:
        p.add_argument("--jobs", type=positive_int, default=None,
                       help="training runs at once, each in a worker process of its own (spawned; on a GPU each "
                            "with its own CUDA context); default 4 on a GPU, 1 on the CPU")
    p.add_argument("--out", default=out, help=f"output directory (default {out})")
    p.add_argument("--no-figures", action="store_true", help="write CSV/JSON only, no figures")


def _study_group_hunting(args) -> int:
    """`aquarium-warp study group-hunting`: learning predator teams, with and without shared catch rewards."""
    from .studies.common import command_line, number_list, written
    from .studies.group_hunting import GroupHuntingStudy, run_group_hunting

    study = GroupHuntingStudy(
        predators=number_list(args.predators, int, "--predators", 1, 64),
        prey=args.prey, prey_conditions=[c.strip() for c in args.prey_conditions.split(",") if c.strip()],
        share_radii=number_list(args.share_radius, float, "--share-radius", 0.0, 1e6), seeds=args.seeds,
        worlds=args.worlds, iterations=args.iterations, train_steps=args.train_steps, eval_worlds=args.eval_worlds,
        eval_steps=args.eval_steps, hunt_radius=args.hunt_radius, sample_every=args.sample_every,
        baseline=not args.no_baseline, device=args.device, jobs=args.jobs, out=args.out, figures=not args.no_figures)
    print(f"aquarium-warp study group-hunting: predators {study.predators}, {study.prey} prey "
          f"({', '.join(study.prey_conditions)}), catch_share_radius {study.share_radii}, {study.seeds} seeds -> "
          f"{study.out}")
    check_output_dir(study.out, "--out")
    summary = run_group_hunting(study, command_line(args.argv), _ray_options(args))
    print(f"{written(summary)} ({summary['training_fraction']:.0%} of the workers' time training)")
    return 0


def _study_many_eyes(args) -> int:
    """`aquarium-warp study many-eyes`: learned prey groups, dilution vs detection."""
    from .studies.common import command_line, number_list, written
    from .studies.many_eyes import ManyEyesStudy, run_many_eyes

    study = ManyEyesStudy(
        group_sizes=number_list(args.group_sizes, int, "--group-sizes", 1, 4096),
        fov_angles=number_list(args.fov, float, "--fov", 0.0, 360.0, low_open=True), seeds=args.seeds,
        rows=args.rows, iterations=args.iterations, train_steps=args.train_steps, eval_rows=args.eval_rows,
        eval_steps=args.eval_steps, view_distance=args.view_distance, flee_angle=args.flee_angle,
        flee_distance=args.flee_distance, turn_angle=args.turn_angle, lag=args.lag, turnaway=not args.no_turnaway,
        device=args.device, jobs=args.jobs, out=args.out, figures=not args.no_figures)
    print(f"aquarium-warp study many-eyes: group sizes {study.group_sizes} x FOV {study.fov_angles}, "
          f"{study.seeds} seeds -> {study.out}")
    check_output_dir(study.out, "--out")
    summary = run_many_eyes(study, command_line(args.argv), _ray_options(args))
    print(f"{written(summary)} ({summary['training_fraction']:.0%} of the workers' time training)")
    return 0


def _study_flow(args) -> int:
    """`aquarium-warp study flow`: captures, swarm metrics and escape directions in currents."""
    from .studies.common import command_line, number_list, written
    from .studies.flow import FlowStudy, run_flow

    study = FlowStudy(
        kinds=[k.strip() for k in args.kinds.split(",") if k.strip()],
        strengths=number_list(args.strengths, float, "--strengths", 0.0, 100.0), seeds=args.seeds,
        episodes_per_seed=args.episodes_per_seed, episode_steps=args.episode_steps, prey=args.prey,
        uniform_angle=args.uniform_angle,
        predators=args.predators, prey_policy=args.prey_policy, predator_policy=args.predator_policy,
        flee_angle=args.flee_angle, flee_distance=args.flee_distance, metrics_every=args.metrics_every,
        seed=args.seed, device=args.device, out=args.out, figures=not args.no_figures)
    print(f"aquarium-warp study flow: {study.kinds} x strengths {study.strengths} px/step, {study.seeds} seeds x "
          f"{study.episodes_per_seed} episodes of {study.episode_steps} steps -> {study.out}")
    check_output_dir(study.out, "--out")
    summary = run_flow(study, command_line(args.argv))
    print(written(summary))
    return 0


def _add_open_questions(kinds) -> None:
    """`study group-hunting`, `study many-eyes` and `study flow` (code in `aquarium_warp/studies/`)."""
    p = kinds.add_parser(
        "group-hunting", help="learning predator teams of 1-4: does cooperative hunting emerge, and does the "
                              "shared catch reward cause it?",
        description="For every predator team size, prey condition (TurnAway prey, or prey co-trained with the "
                    "predators) and catch_share_radius (shared reward, or 0: the capturer alone), train --seeds runs "
                    "and evaluate them: captures per predator, joint captures, the predators' angular spread "
                    "around the capture point and their distances, at captures and at random times; NaivChase "
                    "teams as the baseline. Writes group_hunting.csv/json/png into --out.")
    p.add_argument("--predators", default="1,2,3,4", help="predator team sizes (list; default 1,2,3,4)")
    p.add_argument("--prey", type=positive_int, default=6, help="prey per world, the same at every team size "
                                                                "(default 6, the paper's)")
    p.add_argument("--prey-conditions", default="turnaway,cotrained",
                   help="comma list of 'turnaway' (predators learn against TurnAway) and 'cotrained' (both teams "
                        "learn; team both)")
    p.add_argument("--share-radius", default="100,0", help="catch_share_radius values, px (list; default 100,0: "
                                                           "shared within 100 px, and the capturer alone)")
    p.add_argument("--worlds", type=positive_int, default=1024, help="training worlds per run (default 1024)")
    p.add_argument("--iterations", type=positive_int, default=100,
                   help="PPO iterations per run, 32 steps each (default 100)")
    p.add_argument("--train-steps", type=int_at_least(2), default=500, help="episode length in training (default 500)")
    p.add_argument("--eval-worlds", type=positive_int, default=32, help="evaluation episodes per seed (default 32)")
    p.add_argument("--eval-steps", type=int_at_least(2), default=1000,
                   help="evaluation episode length (default 1000)")
    p.add_argument("--hunt-radius", type=positive_float, default=200.0,
                   help="px; predators this close to a capture take part in it (default 200, the predator's view)")
    p.add_argument("--sample-every", type=positive_int, default=10,
                   help="steps between the random-time states of the baselines (default 10)")
    p.add_argument("--no-baseline", action="store_true", help="no NaivChase teams")
    _add_open_question_arguments(p, "group_hunting")
    _add_ray_arguments(p, "training run (with its evaluations) or NaivChase baseline")
    p.set_defaults(run=_study_group_hunting)

    p = kinds.add_parser(
        "many-eyes", help="learned prey groups of 1-64 with FOVs 60-360: dilution vs earlier detection",
        description="For every prey group size and FOV angle, train --seeds prey runs (parameter sharing) against "
                    "NaivChase with the same prey-steps per run (--rows // N worlds) and evaluate them against "
                    "NaivChase with and without confusion: captures per prey next to the pure-dilution "
                    "expectation, flight initiation distance and the fraction of flight onsets with the predator "
                    "out of the prey's own view; TurnAway prey as the reference. Writes many_eyes.csv/json/png.")
    p.add_argument("--group-sizes", default="1,4,16,64", help="prey per world (list; default 1,4,16,64)")
    p.add_argument("--fov", default="60,120,240,360", help="prey field-of-view angles, degrees in (0, 360] (list)")
    p.add_argument("--rows", type=positive_int, default=4096,
                   help="learning prey per iteration: --rows // N worlds of N prey (default 4096)")
    p.add_argument("--iterations", type=positive_int, default=120,
                   help="PPO iterations per run, 32 steps each (default 120)")
    p.add_argument("--train-steps", type=int_at_least(2), default=500, help="episode length in training (default 500)")
    p.add_argument("--eval-rows", type=positive_int, default=512,
                   help="evaluation prey per seed: --eval-rows // N worlds, at least 2 (default 512)")
    p.add_argument("--eval-steps", type=int_at_least(2), default=1000,
                   help="evaluation episode length (default 1000)")
    p.add_argument("--view-distance", type=positive_float, default=100.0, help="prey view distance, px (default 100)")
    p.add_argument("--flee-angle", type=non_negative_float, default=45.0,
                   help="degrees: fleeing = velocity within this of straight away from the predator (default 45)")
    p.add_argument("--flee-distance", type=positive_float, default=200.0,
                   help="px: fleeing needs the nearest predator this close (default 200)")
    p.add_argument("--turn-angle", type=non_negative_float, default=30.0,
                   help="degrees the prey must turn over --lag steps for a flight onset (default 30)")
    p.add_argument("--lag", type=positive_int, default=5, help="steps of a flight onset's turn (default 5)")
    p.add_argument("--no-turnaway", action="store_true", help="no TurnAway reference")
    _add_open_question_arguments(p, "many_eyes")
    _add_ray_arguments(p, "training run (with its evaluations)")
    p.set_defaults(run=_study_many_eyes)

    p = kinds.add_parser(
        "flow", help="uniform currents and a vortex of growing strength: captures, swarm metrics, escape direction",
        description="Run every flow kind and strength as worlds of one batch (per-world flow), TurnAway prey vs "
                    "NaivChase by default (heuristics ignore the current) or trained policy files, and write "
                    "captures, polarization, groups and the angle between fleeing prey's velocity and the current "
                    "(flow.csv/json, flow.png, flow_escape_angles.png) into --out.")
    p.add_argument("--kinds", default="uniform,vortex",
                   help="flow kinds: 'uniform' (along --uniform-angle), 'vortex' (centred, clockwise)")
    p.add_argument("--uniform-angle", type=float, default=90.0,
                   help="direction of the uniform current, degrees from +x towards +y (default 90: +y, across the "
                        "prey's spawn heading -x)")
    p.add_argument("--strengths", default="0,0.5,1,2,3",
                   help="px per step (the vortex's at its core's edge; list; default 0,0.5,1,2,3)")
    p.add_argument("--episodes-per-seed", type=positive_int, default=10,
                   help="episodes (worlds) per seed (default 10)")
    p.add_argument("--episode-steps", type=int_at_least(2), default=3000, help="steps per episode (default 3000)")
    p.add_argument("--prey", type=positive_int, default=16, help="prey per world (default 16)")
    p.add_argument("--predators", type=positive_int, default=1, help="predators per world (default 1)")
    p.add_argument("--prey-policy", default="turnaway", help="'turnaway', 'random' or a trained policy file")
    p.add_argument("--predator-policy", default="naivchase",
                   help="'naivchase', 'naivchase-noconfusion', 'random' or a trained policy file")
    p.add_argument("--flee-angle", type=non_negative_float, default=45.0,
                   help="degrees: fleeing = velocity within this of straight away from the predator (default 45)")
    p.add_argument("--flee-distance", type=positive_float, default=200.0,
                   help="px: fleeing needs the nearest predator this close (default 200)")
    p.add_argument("--metrics-every", type=positive_int, default=10, help="sample the swarm metrics every K steps")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the batched worlds")
    _add_open_question_arguments(p, "flow_study", jobs=False)
    p.set_defaults(run=_study_flow)


def _sweep_train(args) -> int:
    """`aquarium-warp sweep train`: one training run per seed and setting (`aquarium_warp/sweep.py`)."""
    from .number_lists import parse_list
    from .sweep import TrainingSweep, parse_vary, run_training_sweep
    from .training.cli import add_train_arguments

    train = argparse.ArgumentParser()
    add_train_arguments(train)
    train_args = argparse.Namespace(**{name: getattr(args, name) for name in vars(train.parse_args([]))})
    sweep = TrainingSweep(seeds=tuple(parse_list(args.seeds, int, "--seeds", minimum=0)),
                          vary=tuple(parse_vary(text) for text in args.vary),
                          out=args.out or os.path.join("runs", f"sweep_{time.strftime('%Y%m%d-%H%M%S')}"))
    sweep.validate()
    ray = _ray_options(args)
    print(f"aquarium-warp sweep train: {len(sweep.runs())} runs ({len(sweep.seeds)} seeds"
          f"{''.join(f' x {len(v)} {k}' for k, v in sweep.vary)}) {'as Ray tasks' if ray else 'one after another'} "
          f"-> {sweep.out}")
    summary = run_training_sweep(sweep, train_args, ray)
    kept = sum(r["kept"] for r in summary["runs"])
    print(f"aquarium-warp sweep train: {len(summary['runs'])} runs ({kept} kept from before) in "
          f"{summary['wall_time_s']:.1f} s; {os.path.join(sweep.out, 'sweep.json')} lists them")
    return 0


def _add_sweep(sub) -> None:
    """`aquarium-warp sweep train` (code in `aquarium_warp/sweep.py`, Ray tasks in `ray_tasks.py`)."""
    from .training.cli import add_train_arguments

    sweep = sub.add_parser("sweep", help="many training runs: seeds x settings, here or as Ray tasks")
    kinds = sweep.add_subparsers(dest="sweep", required=True)
    p = kinds.add_parser("train", help="one `aquarium-warp train` run per seed and setting",
                         description="Train every combination of a seed (--seeds) and the varied settings "
                                     "(--vary) in a run directory of its own, --out/<setting>/seed<s>, one after "
                                     "another or as Ray tasks (--ray). A rerun with the same --out keeps the "
                                     "finished runs and resumes the started ones from their newest checkpoint. "
                                     "Every option of `aquarium-warp train` applies to each run (not --seed, "
                                     "--log-dir, --resume, --overwrite).")
    p.add_argument("--seeds", default="0", help="seeds: a comma list, '...' continues it (default 0)")
    p.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a setting to sweep, as `train --set KEY=VALUE` takes it, e.g. "
                        "train.sharing=parameter,individual (repeatable: every combination)")
    p.add_argument("--out", default=None, help="the sweep's directory: sweep.json and one directory per run "
                                               "(default runs/sweep_<time>; on Ray one that every machine sees)")
    add_train_arguments(p)
    _add_ray_arguments(p, "training run")
    p.set_defaults(run=_sweep_train)


def _add_bench(sub) -> None:
    """`aquarium-warp bench`: the scaling benchmark suite (code in `aquarium_warp/bench/`)."""
    from .bench import add_arguments, run_from_args

    bench = sub.add_parser("bench", help="scaling benchmark: agent-steps/s, stage times, memory and bandwidth vs "
                                         "agents and worlds",
                           description="Sweep agents per world and worlds; print a table and write "
                                       "scaling_<device>.json and log-log figures into --out-dir. The peers "
                                       "(--original, --vmas) are measured by the source tree's "
                                       "benchmarks/bench_scaling.py (same options).")
    add_arguments(bench)
    bench.set_defaults(run=run_from_args)


def _add_view(sub) -> None:
    """`aquarium-warp view`: the browser viewer (code in `aquarium_warp/viewer/`)."""
    from .viewer import add_arguments, run

    view = sub.add_parser("view", help="watch and steer a world live in the browser; replay pages of recordings",
                          description="Serve a page that shows one world live: play/pause, speed, overlays, "
                                      "plots, team policies and keyboard play; or, with --replay, write a page "
                                      "that plays a recorded trajectory (docs/viewer.md).")
    add_arguments(view)
    view.set_defaults(run=run)


def build_parser() -> argparse.ArgumentParser:
    """The `aquarium-warp` parser with every subcommand (`python -m aquarium_warp` is the same)."""
    from . import __version__

    parser = argparse.ArgumentParser(prog="aquarium-warp", description="Aquarium predator-prey worlds on Warp")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="step a batch of worlds with random actions and report speed and captures",
                          description="Step a batch of worlds with random actions; print steps/s, agent-steps/s "
                                      "and captures.")
    demo.add_argument("--worlds", type=positive_int, default=64, help="worlds stepped at once (default 64)")
    demo.add_argument("--steps", type=positive_int, default=500, help="steps to time (default 500)")
    demo.add_argument("--prey", type=int, default=16, help="prey per world (default 16)")
    demo.add_argument("--predators", type=int, default=1, help="predators per world (default 1)")
    demo.add_argument("--max-steps", type=int, default=3000, help="episode length")
    demo.add_argument("--device", default=None, help="'cpu', 'cuda:0'; default: CUDA when present")
    demo.add_argument("--seed", type=non_negative_int, default=0, help="seed of the worlds and the random actions")
    demo.set_defaults(run=_demo)
    video = sub.add_parser("video", help="record one world driven by heuristic or trained policies as an MP4 video")
    video.add_argument("--prey-policy", default="turnaway", help="'turnaway', 'random' or a trained policy file")
    video.add_argument("--predator-policy", default="naivchase",
                       help="'naivchase', 'random' or a trained policy file")
    video.add_argument("--steps", type=non_negative_int, default=600, help="steps to record (frames: steps + 1)")
    video.add_argument("--out", default="aquarium.mp4", help="output MP4 file (name ending in .mp4)")
    video.add_argument("--prey", type=int, default=None,
                       help="prey in the world (default: a trained policy's world, else 16)")
    video.add_argument("--predators", type=int, default=None,
                       help="predators in the world (default: a trained policy's world, else 1)")
    video.add_argument("--width", type=float, default=None,
                       help="world width, px (default: a trained policy's world, else 800)")
    video.add_argument("--height", type=float, default=None,
                       help="world height, px (default: a trained policy's world, else 800)")
    video.add_argument("--frame-width", type=int, default=None,
                       help="frame width in pixels (default: the world's, long side at most 1024)")
    video.add_argument("--frame-height", type=int, default=None, help="frame height in pixels")
    video.add_argument("--fps", type=positive_float, default=30.0, help="frames per second of the video (default 30)")
    video.add_argument("--seed", type=non_negative_int, default=0, help="seed of the world and the policies")
    video.add_argument("--device", default=None, help="'cpu', 'cuda:0'; default: CUDA when present")
    video.add_argument("--view-cones", action="store_true", help="draw each agent's field of view")
    video.add_argument("--hit-boxes", action="store_true", help="draw each agent's hit-box circle")
    video.add_argument("--velocities", action="store_true", help="draw velocity arrows (10 steps long)")
    video.add_argument("--flow", choices=("uniform", "vortex"), default=None,
                       help="a current (docs/model.md 'Flow fields'): uniform along +x, or a vortex at the centre "
                            "(core radius a sixth of the shorter side); default: the config's (none)")
    video.add_argument("--flow-strength", type=float, default=2.0,
                       help="px per step of --flow (the vortex's at its core's edge; default 2)")
    video.add_argument("--draw-flow", action="store_true", help="draw the current as arrows under the agents")
    video.add_argument("--no-progress", action="store_true", help="no progress bar")
    video.set_defaults(run=_video)
    _add_train(sub)
    _add_eval(sub)
    _add_study(sub)
    _add_sweep(sub)
    _add_bench(sub)
    _add_view(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
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
