"""Arguments and handlers of `aquarium-warp train` and `aquarium-warp eval` (wired in `aquarium_warp/cli.py`).

Heavy imports (torch, rsl_rl, matplotlib) happen inside the handlers, so `aquarium-warp --help`
stays fast and works without the training extras.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from ..agent_types import TYPES
from ..arguments import (
    DEVICE_HELP,
    POLICY_SPECS,
    Interrupted,
    add_options,
    from_options,
    int_at_least,
    number,
    number_list,
    option,
    plural,
    policy_spec,
    positive_float,
)
from ..atomic import check_output_dir
from .config import (
    ALGORITHM_RANGES,
    CRITICS,
    LR_SCHEDULES,
    POOL_SAMPLING,
    PRESETS,
    SHARING,
    TRAIN_DEFAULTS,
    UPDATE_SCHEDULES,
)
from .grid_cells import BASELINES, FOVS, NAIVCHASE, PREY_COUNTS, SPEEDS, UNLIMITED, VIEWS, Cell, grid_cells

PRESET_NAMES = tuple(PRESETS)


def _hidden_dims(text: str) -> list[int]:
    try:
        dims = [int(x) for x in text.replace(" ", "").split(",") if x]
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"hidden dims {text!r}: expected comma-separated integers") from error
    if not dims or min(dims) < 1:
        raise argparse.ArgumentTypeError(f"hidden dims {text!r}: expected positive integers")
    return dims


def _algorithm(name: str):
    """argparse type of the PPO coefficient `name`: the range `config.validate` checks."""
    return number(*ALGORITHM_RANGES[name])


# --------------------------------------------------------------------------------------------- train
# The flags that each set one config entry as given, by group: (flag, the entry's dotted key, argparse
# settings, help). The parser and `_train_changes` are built from this table; a train.* flag's help ends
# with its `TRAIN_DEFAULTS` value (the default preset's), and a choice flag takes training/config.py's list.
CONFIG_FLAGS: dict[str, tuple[tuple[str, str, dict, str], ...]] = {
    "run": (
        (
            "--team",
            "train.team",
            {"choices": (*TYPES, "both")},
            "the learning team; 'both': one PPO learner per team in the same worlds",
        ),
        (
            "--sharing",
            "train.sharing",
            {"choices": SHARING},
            "Parameter Sharing (one network) or Individual Learning (one per slot)",
        ),
        ("--num-worlds", "train.num_worlds", {"type": int_at_least(1)}, "worlds stepped in parallel"),
        ("--device", "train.device", {}, DEVICE_HELP),
        ("--seed", "train.seed", {"type": int_at_least(0)}, "seed of the worlds and the networks"),
        ("--iterations", "train.iterations", {"type": int_at_least(0)}, "total PPO iterations of the run"),
        (
            "--episodes",
            "train.episodes",
            {"type": positive_float},
            "total world episodes instead of --iterations (the paper: 4000)",
        ),
        ("--export", "train.export", {}, "formats exported after training: 'jit,onnx', 'none'"),
        (
            "--quiet",
            "train.quiet",
            {"action": "store_true", "default": None},
            "a progress bar instead of rsl-rl's per-iteration report",
        ),
        (
            "--critic",
            "train.critic",
            {"choices": CRITICS},
            "what each learner's critic sees besides the agent's observation (MAPPO's centralised critic; actors "
            "stay local): nothing (local), the team's joint observation (team) or the world state (world)",
        ),
        (
            "--video-every",
            "train.video_every",
            {"type": int_at_least(0), "metavar": "N"},
            "every N iterations a rendered evaluation episode of one world into the log (TensorBoard Video/episode; "
            "0: none)",
        ),
        ("--video-steps", "train.video_steps", {"type": int_at_least(1)}, "steps of that episode"),
    ),
    "both teams learning (--team both)": (
        (
            "--update-schedule",
            "train.update_schedule",
            {"choices": UPDATE_SCHEDULES},
            "both learners update every iteration (simultaneous), or take turns while the other is frozen "
            "(alternating)",
        ),
        (
            "--alternate-every",
            "train.alternate_every",
            {"type": int_at_least(1), "metavar": "K"},
            "alternating: iterations per turn, prey first",
        ),
        (
            "--pool-every",
            "train.pool_every",
            {"type": int_at_least(0), "metavar": "N"},
            "snapshot each team's actor into its opponent pool every N iterations (fictitious self-play; 0: no pool)",
        ),
        ("--pool-size", "train.pool_size", {"type": int_at_least(1)}, "snapshots kept per team"),
        (
            "--pool-sampling",
            "train.pool_sampling",
            {"choices": POOL_SAMPLING},
            "which snapshot a world draws when its episode ends: uniform, or latest-biased (weights 1..n from the "
            "oldest to the newest)",
        ),
        (
            "--pool-fraction",
            "train.pool_fraction",
            {"type": number("a number in [0, 0.5]", lambda v: 0 <= v <= 0.5)},
            "fraction of worlds in which each team plays against the other team's snapshots (per team: --set "
            "teams.<team>.pool_fraction=F, both at most 1)",
        ),
    ),
    "environment": (
        ("--prey", "env.prey_count", {"type": int}, "prey per world"),
        ("--predators", "env.predator_count", {"type": int}, "predators per world"),
        ("--max-steps", "env.max_steps", {"type": int}, "episode length"),
        ("--width", "env.width", {"type": float}, "world width, px"),
        ("--height", "env.height", {"type": float}, "world height, px"),
    ),
    "PPO": (
        ("--num-steps-per-env", "runner.num_steps_per_env", {"type": int_at_least(1)}, "rollout length per iteration"),
        ("--save-interval", "runner.save_interval", {"type": int_at_least(1)}, "checkpoint every N iterations"),
        (
            "--learning-rate",
            "train.actor_lr",
            {"type": positive_float, "aliases": ("--actor-lr",), "dest": "actor_lr"},
            "actor learning rate (rsl-rl's learning_rate)",
        ),
        (
            "--critic-lr",
            "train.critic_lr",
            {"type": positive_float},
            "critic learning rate (applied as a factor critic_lr/actor_lr on the critic's group)",
        ),
        ("--gamma", "runner.algorithm.gamma", {"type": _algorithm("gamma")}, "discount factor, in [0, 1]"),
        ("--lam", "runner.algorithm.lam", {"type": _algorithm("lam")}, "GAE lambda, in [0, 1]"),
        ("--clip", "runner.algorithm.clip_param", {"type": _algorithm("clip_param")}, "PPO clip parameter, in (0, 1]"),
        (
            "--entropy",
            "runner.algorithm.entropy_coef",
            {"type": _algorithm("entropy_coef")},
            "entropy coefficient, >= 0",
        ),
        (
            "--value-loss-coef",
            "runner.algorithm.value_loss_coef",
            {"type": _algorithm("value_loss_coef")},
            "weight of the value loss",
        ),
        (
            "--epochs",
            "runner.algorithm.num_learning_epochs",
            {"type": int_at_least(1)},
            "learning epochs per iteration",
        ),
        ("--minibatches", "runner.algorithm.num_mini_batches", {"type": int_at_least(1)}, "mini-batches per epoch"),
        (
            "--max-grad-norm",
            "runner.algorithm.max_grad_norm",
            {"type": _algorithm("max_grad_norm")},
            "gradient norm clip",
        ),
        (
            "--schedule",
            "runner.algorithm.schedule",
            {"choices": LR_SCHEDULES},
            "learning rate: fixed, or adapted to keep the KL near --desired-kl",
        ),
        (
            "--desired-kl",
            "runner.algorithm.desired_kl",
            {"type": _algorithm("desired_kl")},
            "KL target of the adaptive schedule",
        ),
        ("--reward-scale", "train.reward_scale", {"type": positive_float}, "factor on the rewards PPO sees"),
    ),
}


def _flag_help(key: str, text: str) -> str:
    """`text`, ending with the train setting's default where it has one to show."""
    section, _, name = key.partition(".")
    default = TRAIN_DEFAULTS.get(name) if section == "train" else None
    if default is None or isinstance(default, bool):
        return text
    shown = (
        ",".join(default) if isinstance(default, list) else f"{default:g}" if isinstance(default, float) else default
    )
    return f"{text} (default {shown})"


def _dest(flag: str, settings: dict) -> str:
    """The attribute of a `CONFIG_FLAGS` flag in the parsed arguments."""
    return settings.get("dest") or flag[2:].replace("-", "_")


def _add_config_flags(group, name: str) -> None:
    """The `CONFIG_FLAGS` of group `name`."""
    for flag, key, settings, text in CONFIG_FLAGS[name]:
        settings = {"default": None, **settings, "dest": _dest(flag, settings)}
        aliases = settings.pop("aliases", ())
        group.add_argument(flag, *aliases, help=_flag_help(key, text), **settings)


def add_train_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--preset",
        choices=PRESET_NAMES,
        default=None,
        help="base configuration (default: 'default'; 'paper': section 5 of the paper)",
    )
    p.add_argument(
        "--config",
        default=None,
        help="JSON or YAML file with sections env / train / runner (and optionally 'preset'); flags override it",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config entry, e.g. runner.algorithm.num_mini_batches=8 (repeatable); "
        "one team's learner: teams.<prey|predator>.<sharing|actor_lr|critic_lr|reward_scale|"
        "critic|pool_fraction>=V or teams.<team>.runner.<algorithm|actor|critic>.KEY=V",
    )
    g = p.add_argument_group("run")
    g.add_argument(
        "--predator-policy",
        default=None,
        type=policy_spec("predator"),
        help=f"predators when training prey: {POLICY_SPECS['predator']} (default naivchase)",
    )
    g.add_argument(
        "--prey-policy",
        default=None,
        type=policy_spec("prey"),
        help=f"prey when training predators: {POLICY_SPECS['prey']} (default random)",
    )
    g.add_argument(
        "--runs",
        type=int_at_least(1),
        default=1,
        metavar="K",
        help="train K runs in one process, seeded --seed, --seed + 1, ...: each writes <log-dir>/run-<k>/ as if "
        "trained alone (checkpoints, progress.csv, TensorBoard, export); default 1",
    )
    g.add_argument("--log-dir", default=None, help="run directory (default: runs/<team>_<sharing>_<time>)")
    g.add_argument(
        "--resume",
        default=None,
        metavar="PATH",
        help="continue a run from a checkpoint model_<i>.pt or the newest one in a run directory",
    )
    g.add_argument(
        "--overwrite",
        action="store_true",
        help="start a new run in a --log-dir that holds an earlier one, removing its checkpoints, logs "
        "and exports (default: such a directory is refused)",
    )
    g.add_argument(
        "--randomize",
        action="append",
        default=[],
        metavar="FIELD=LOW:HIGH",
        help="domain randomisation: each world's FIELD (e.g. prey_max_speed, prey_count) drawn from "
        "[LOW, HIGH] (or FIELD=A,B,C: from the values) at every reset; repeatable",
    )
    g.add_argument(
        "--no-random-ep-len",
        action="store_true",
        help="start every world at step 0 (default: spread the worlds' truncations)",
    )
    g.add_argument(
        "--view",
        nargs="?",
        const=8765,
        default=None,
        type=int_at_least(0),
        metavar="PORT",
        help="show the training worlds in the browser while training (aquarium-warp view's page, "
        "served on 127.0.0.1:PORT, default 8765; needs the viewer extra)",
    )
    g.add_argument(
        "--verbose",
        action="store_true",
        help="print where the start-up of a run went (not with --runs): imports, config, env build, policy and "
        "runner, first iteration, graph capture",
    )
    _add_config_flags(g, "run")
    _add_config_flags(p.add_argument_group("both teams learning (--team both)"), "both teams learning (--team both)")
    _add_config_flags(p.add_argument_group("environment"), "environment")
    a = p.add_argument_group("PPO")
    _add_config_flags(a, "PPO")
    a.add_argument("--hidden-dims", type=_hidden_dims, default=None, help="e.g. 64,64 (actor and critic)")
    a.add_argument("--activation", default=None, help="e.g. tanh, elu, relu")


def _train_changes(args) -> dict:
    """The config changes given by flags (None where a flag was not given)."""
    if args.iterations is not None and args.episodes is not None:
        raise ValueError("--iterations and --episodes both set the run's length: give one of them")
    changes: dict = {"train": {}, "env": {}, "runner": {}}
    for flags in CONFIG_FLAGS.values():
        for flag, key, settings, _ in flags:
            value = getattr(args, _dest(flag, settings))
            if value is not None:
                *path, name = key.split(".")
                section = changes
                for part in path:
                    section = section.setdefault(part, {})
                section[name] = value
    train = changes["train"]
    if args.no_random_ep_len:
        train["init_at_random_ep_len"] = False
    if args.randomize:
        train["randomize"] = dict(s.partition("=")[::2] for s in args.randomize)  # checked by validate()
    models = {
        k: v for k, v in {"hidden_dims": args.hidden_dims, "activation": args.activation}.items() if v is not None
    }
    if models:
        changes["runner"].update(actor=dict(models), critic=dict(models))
    if args.iterations is not None:
        train["episodes"] = None  # an explicit iteration count wins over a preset's episodes
    return {k: v for k, v in changes.items() if v}


def _opponent_change(args, team: str) -> dict:
    if team == "both" and (args.prey_policy is not None or args.predator_policy is not None):
        raise ValueError(
            "--prey-policy / --predator-policy set the other team of a one-team run; with --team both both teams learn"
        )
    if team == "prey" and args.prey_policy is not None:
        raise ValueError("--prey-policy sets the prey when training predators; with --team prey use --predator-policy")
    if team == "predator" and args.predator_policy is not None:
        raise ValueError(
            "--predator-policy sets the predators when training prey; with --team predator use --prey-policy"
        )
    spec = args.predator_policy if team == "prey" else args.prey_policy
    return {"train": {"opponent": spec}} if spec is not None else {}


def _check_logger_package(logger) -> None:
    """rsl-rl needs the wandb package only when the run writes its first log: say so before the run."""
    name = logger.get("class_name", "") if isinstance(logger, dict) else str(logger)
    if "wandb" in name.lower() and importlib.util.find_spec("wandb") is None:
        raise ValueError(f"runner.logger={logger!r} needs the wandb package: pip install 'aquarium-warp[wandb]'")


def _silent(*args, **kwargs) -> None:
    """`print` on the ranks other than 0 of a torchrun run."""


def run_train(args, *, attach: Callable[..., Any]) -> int:
    """`aquarium-warp train`. `attach(env, port=PORT)` shows the training worlds in the browser (the
    viewer's `attach`, which the command line passes in: training does not import the viewer) for
    `--view`. `--verbose`: the start-up's stages and their seconds, printed after the run."""
    began = start = time.perf_counter()
    from . import trainer as _  # noqa: F401  (torch, Warp, rsl-rl: the start-up's imports)
    from .population import is_population
    from .run_dir import claim_run_directory

    startup = {"imports": time.perf_counter() - start}
    start = time.perf_counter()
    changes = _train_changes(args)
    if args.resume and args.overwrite:
        raise ValueError("--overwrite starts a new run; --resume continues one: give one of them")
    if args.log_dir is not None:
        check_output_dir(args.log_dir, "--log-dir")
    if args.runs > 1 or (args.resume and os.path.isdir(args.resume) and is_population(args.resume)):
        return run_population(args, changes)
    # torchrun: rank 0 owns the run directory (the other ranks write nothing there)
    owner = int(os.environ.get("RANK", "0")) == 0
    run_dir = None
    if args.resume:
        log_dir = args.log_dir
        if log_dir is None and os.path.exists(args.resume):  # the checkpoint's run (Trainer.resume's default)
            log_dir = args.resume if os.path.isdir(args.resume) else os.path.dirname(os.path.abspath(args.resume))
        _check_resume_options(args, changes)
        if owner and log_dir is not None:
            run_dir = claim_run_directory(log_dir, resume=True)
    else:
        config = train_config(args)
        if args.log_dir is None and int(os.environ.get("WORLD_SIZE", "1")) > 1:
            raise ValueError("--log-dir is required under torchrun: every process must name the same run directory")
        log_dir = args.log_dir or os.path.join(
            "runs", f"{config['train']['team']}_{config['train']['sharing']}_{time.strftime('%Y%m%d-%H%M%S')}"
        )
        if owner:
            run_dir = claim_run_directory(log_dir, overwrite=args.overwrite)
    startup["config"] = time.perf_counter() - start
    try:  # every refusal from here on releases the claimed directory
        trainer = _resumed(args, changes, log_dir) if args.resume else _new_run(config, log_dir)
        say = print if trainer.rank == 0 else _silent
        viewer = None
        try:
            if args.view is not None and trainer.rank == 0:
                viewer = attach(trainer.env, port=args.view)
                say(f"aquarium-warp train: the training worlds are on {viewer.url}")
            finish_training(trainer, say)
            if args.verbose:
                say(f"aquarium-warp train: start-up {_breakdown(startup, trainer, time.perf_counter() - began)}")
        finally:
            if viewer is not None:
                viewer.close()
            trainer.close()
    finally:
        if run_dir is not None:
            run_dir.release()
    return 0


def _breakdown(startup: dict[str, float], trainer, whole: float) -> str:
    """`--verbose`'s line: the start-up stages of the CLI (`startup`) and the trainer (`Trainer.startup`; the
    first iteration's includes the training loop's and the logger's set-up), their sum, the host time of
    the CUDA graph captures (in the iterations after the first), and the `whole` run's seconds (from the
    imports to the export)."""
    stages = {**startup, **trainer.startup}
    total = sum(stages.values())
    loop = trainer.runner.loop
    if loop is not None and loop.graphs:
        stages["graph capture"] = loop.capture_seconds
    listed = ", ".join(f"{k} {v:.2f} s" for k, v in stages.items())
    return f"{total:.2f} s to the first iteration's end ({listed}); the whole run {whole:.2f} s"


def run_population(args, changes: dict) -> int:
    """`train --runs K` (K > 1), or `--resume` of a population's directory (`population.py`)."""
    from .population import Population, resume_population, run_configs
    from .run_dir import claim_run_directory

    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        raise ValueError("--runs trains a population in one process; torchrun's several processes train one run")
    if args.resume:
        given_train = {k for k in changes.get("train", {}) if k not in ("iterations", "episodes", "export", "quiet")}
        if (
            args.runs > 1
            or given_train
            or args.set
            or args.config
            or args.preset
            or args.prey_policy
            or args.predator_policy
        ):
            raise ValueError(
                "--resume continues a population with its saved configs: only --iterations, --episodes, --export "
                "and --quiet may be given with it"
            )
        log_dir = args.log_dir or args.resume
        if os.path.abspath(log_dir) != os.path.abspath(args.resume):
            raise ValueError(f"--log-dir {log_dir!r}: a population resumes in its own directory {args.resume!r}")
        run_dir = claim_run_directory(log_dir, resume=True)
        try:
            population = resume_population(log_dir, {"train": changes.get("train", {})})
        except BaseException:
            run_dir.release()
            raise
        print(f"aquarium-warp train: {population.path.line()}")
        print(
            f"aquarium-warp train: resumed the population in {log_dir} at iteration {population.iteration} "
            f"({plural(sum(population.active), 'run')} training)"
        )
    else:
        config = train_config(args)
        log_dir = args.log_dir or os.path.join(
            "runs",
            f"{config['train']['team']}_{config['train']['sharing']}_x{args.runs}_{time.strftime('%Y%m%d-%H%M%S')}",
        )
        run_dir = claim_run_directory(log_dir, overwrite=args.overwrite)
        try:
            population = Population(run_configs(config, args.runs), log_dir=log_dir)
        except BaseException:
            run_dir.release()
            raise
        v = population.vec_env
        print(f"aquarium-warp train: {population.path.line()}")
        print(
            f"aquarium-warp train: {plural(population.K, 'run')} of {config['train']['team']} ({v.slots} slots) vs "
            f"{population.configs[0]['train']['opponent']} on {population.env.device}, seeds "
            f"{population.seeds[0]}..{population.seeds[-1]}, {population.env.num_worlds // population.K} worlds "
            f"each, {max(population.totals)} iterations, {'stacked' if population.stacked else 'one run after another'}"
            f" -> {log_dir}/run-<k>"
        )
    try:
        start, first = time.perf_counter(), population.iteration
        population.train()
        print(
            f"aquarium-warp train: {plural(population.iteration - first, 'iteration')} of "
            f"{plural(population.K, 'run')} in {time.perf_counter() - start:.1f} s; each run's files in "
            f"{log_dir}/run-<k>"
        )
        for k, why in sorted(population.stopped.items()):
            print(f"  run {k} stopped early: {why}")
        if population.configs[0]["train"]["export"]:
            for k in range(population.K):
                if k not in population.stopped:
                    population.export(k)
            print(f"  exported: {log_dir}/run-<k>/exported/")
        if population.stop.signum is not None:
            raise Interrupted(
                f"stopped by {population.stop.name} after iteration {population.iteration}; continue with: "
                f"aquarium-warp train --resume {log_dir}",
                population.stop.signum,
            )
    finally:
        population.close()
        run_dir.release()
    return 0


def _check_resume_options(args, changes: dict) -> None:
    """A resumed run keeps its saved config: the flags that would change it are refused."""
    given = {k: v for k, v in changes.items() if k != "train"}
    given_train = {
        k
        for k in changes.get("train", {})
        if k not in ("iterations", "episodes", "export", "quiet", "video_every", "video_steps")
    }
    if given or given_train or args.set or args.config or args.preset or args.prey_policy or args.predator_policy:
        raise ValueError(
            "--resume continues a run with its saved config: only --iterations, --episodes, "
            "--export, --quiet, --video-every and --video-steps may be given with it"
        )


def _resumed(args, changes: dict, log_dir: str | None):
    """`train --resume`'s trainer, announced."""
    from .trainer import Trainer

    trainer = Trainer.resume(args.resume, log_dir=log_dir, changes={"train": changes.get("train", {})})
    _check_logger_package(trainer.config["runner"]["logger"])
    if trainer.rank == 0:
        print(f"aquarium-warp train: {trainer.path.line()}")
        print(
            f"aquarium-warp train: resumed {args.resume} at iteration {trainer.iteration} of "
            f"{trainer.total_iterations} (log dir {trainer.log_dir})"
        )
    return trainer


def _new_run(config: dict, log_dir: str):
    """A new run's trainer, announced."""
    from .config import team_settings, total_iterations
    from .trainer import Trainer

    trainer = Trainer(config, log_dir=log_dir)
    if trainer.rank == 0:
        learners = " and ".join(
            f"{t} ({team_settings(config, t)['sharing']} sharing, {plural(trainer.vec_envs[t].slots, 'slot')})"
            for t in trainer.teams
        )
        against = "" if trainer.opponent is None else f" vs {trainer.config['train']['opponent']}"
        ranks = f" (x{trainer.world_size} processes)" if trainer.world_size > 1 else ""
        print(f"aquarium-warp train: {trainer.path.line()}")
        print(
            f"aquarium-warp train: {learners}{against} on {trainer.env.device}, "
            f"{plural(trainer.env.num_worlds, 'world')}{ranks}, {plural(total_iterations(config), 'iteration')} "
            f"-> {log_dir}"
        )
    return trainer


def train_config(args, sets: Sequence[str] = ()) -> dict:
    """The run config of `aquarium-warp train`'s options `args` (a new run, not --resume): the preset,
    --config's file, the flags, the --set assignments, then `sets` (a sweep's settings), and the
    opponent flags. Refuses a logger whose package is missing."""
    from .config import deep_update, make_config, parse_assignment

    file_cfg = _read_config_file(args.config) if args.config else {}
    # Popped and checked whether or not --preset overrides it: "preset" is no config section.
    file_preset = file_cfg.pop("preset", None)
    if file_preset is not None and (not isinstance(file_preset, str) or file_preset not in PRESETS):
        raise ValueError(f"--config {args.config}: preset {file_preset!r} is unknown: choose one of {sorted(PRESETS)}")
    preset = args.preset or file_preset or "default"
    merged = deep_update(deep_update({}, file_cfg), _train_changes(args))
    for s in [*args.set, *sets]:
        deep_update(merged, parse_assignment(s))
    team = merged.get("train", {}).get("team") or make_config(preset)["train"]["team"]
    deep_update(merged, _opponent_change(args, team))
    config = make_config(preset, merged)
    _check_logger_package(config["runner"]["logger"])
    return config


def finish_training(trainer, say) -> None:
    """Train the rest of the run and export it; on SIGINT or SIGTERM (`stop.py`) the run stops at an
    iteration boundary, checkpointed and exported, and `Interrupted` says how to resume."""
    start, first = time.perf_counter(), trainer.iteration
    trainer.train()
    ran = trainer.iteration - first
    # torchrun: the ranks hold the same parameters; rank 0 exports them.
    paths = trainer.export() if trainer.config["train"]["export"] and trainer.rank == 0 else {}
    resumed = f", resumed at {first}" if first else ""
    if ran == 0:
        say(
            f"aquarium-warp train: no iterations to run ({trainer.iteration} of {trainer.total_iterations} done"
            f"{resumed}); no checkpoint written, run config in {trainer.log_dir}"
        )
    else:
        say(
            f"aquarium-warp train: {plural(ran, 'iteration')} in {time.perf_counter() - start:.1f} s "
            f"({trainer.iteration} of {trainer.total_iterations} done{resumed}); checkpoints, progress CSV and "
            f"TensorBoard logs in {trainer.log_dir}"
        )
    for key, value in paths.items():
        for fmt, path in value.items() if isinstance(value, dict) else [(key, value)]:
            say(f"  exported {fmt}: {path}")
    if trainer.stop.signum is not None:
        raise Interrupted(
            f"stopped by {trainer.stop.name} after iteration {trainer.iteration} of "
            f"{trainer.total_iterations}; continue with: aquarium-warp train --resume "
            f"{trainer.log_dir}",
            trainer.stop.signum,
        )


def _read_config_file(path: str) -> dict:
    """`load_config_file`, its failures one line naming --config, the path and the cause."""
    from .config import load_config_file

    try:
        from yaml import YAMLError
    except ImportError:  # without PyYAML a .yaml file is refused by load_config_file's import
        YAMLError = ValueError
    try:
        return load_config_file(path)
    except OSError as error:
        raise ValueError(f"--config {path}: cannot read it ({error.strerror or error})") from None
    except ValueError as error:  # json.JSONDecodeError is one; our own messages name the path already
        message = str(error) if str(error).startswith(path) else f"--config {path}: not valid JSON ({error})"
        raise ValueError(message) from None
    except YAMLError as error:
        first = (str(error).strip().splitlines() or [""])[0]
        raise ValueError(f"--config {path}: not valid YAML ({type(error).__name__}: {first})") from None


# ---------------------------------------------------------------------------------------------- eval
# What each kind of `eval` run plays where --prey, --predator, --episodes and --seeds are not given (the
# help texts are written from it): eval and cross-play the paper's protocol, the grid its baselines.
PAPER_PROTOCOL = {"episodes": 200, "seeds": (0, 1, 2, 3, 4)}
EVAL_RUNS: dict[str, dict] = {
    "eval": {"prey": ("random", "turnaway"), "predator": ("naivchase",), **PAPER_PROTOCOL},
    "cross-play": {"prey": ("random", "turnaway"), "predator": (*NAIVCHASE, "random"), **PAPER_PROTOCOL},
    "grid": {"prey": BASELINES, "predator": NAIVCHASE, "episodes": 50, "seeds": (0, 1, 2)},
}


def _words(values) -> str:
    return " ".join(map(str, values))


@dataclasses.dataclass
class EvalOptions:
    """The options of `aquarium-warp eval` (each written once, on its field; None: the kind of run's
    `EVAL_RUNS` entry)."""

    prey: list[str] | None = dataclasses.field(
        default=None,
        metadata=option(
            f"prey policies: {POLICY_SPECS['prey']} (exported or a checkpoint), each optionally LABEL=SPEC; "
            f"specs sharing a label are pooled (default: {_words(EVAL_RUNS['eval']['prey'])})",
            type=policy_spec("prey"),
            nargs="*",
            metavar="SPEC",
        ),
    )
    predator: list[str] | None = dataclasses.field(
        default=None,
        metadata=option(
            f"predator policies: {POLICY_SPECS['predator']} (default: {_words(EVAL_RUNS['eval']['predator'])})",
            type=policy_spec("predator"),
            nargs="*",
            metavar="SPEC",
        ),
    )
    episodes: int | None = dataclasses.field(
        default=None,
        metadata=option(
            f"episodes per seed (default {EVAL_RUNS['eval']['episodes']}, the paper's; --grid: "
            f"{EVAL_RUNS['grid']['episodes']} per cell)",
            type=int,
        ),
    )
    seeds: list[int] | None = dataclasses.field(
        default=None,
        metadata=option(
            f"evaluation seeds, a list such as 0 1 2 (default {_words(EVAL_RUNS['eval']['seeds'])}, the paper's "
            f"{len(EVAL_RUNS['eval']['seeds'])}; --grid: {_words(EVAL_RUNS['grid']['seeds'])})",
            type=int,
            nargs="+",
        ),
    )
    preset: str | None = dataclasses.field(
        default=None,
        metadata=option(
            "take the world from a preset (default: a trained policy's own world, else docs/model.md's)",
            choices=PRESET_NAMES,
        ),
    )
    sets: list[str] = dataclasses.field(
        default_factory=list,
        metadata=option("override a world setting", flag="--set", repeated=True, metavar="env.KEY=VALUE"),
    )
    prey_count: int | None = dataclasses.field(
        default=None, metadata=option("prey per world (default: the world's)", type=int)
    )
    predator_count: int | None = dataclasses.field(
        default=None, metadata=option("predators per world (default: the world's)", type=int)
    )
    max_steps: int | None = dataclasses.field(default=None, metadata=option("episode length (paper: 3000)", type=int))
    device: str | None = dataclasses.field(default=None, metadata=option(DEVICE_HELP))
    max_worlds: int = dataclasses.field(default=1024, metadata=option("episodes run in parallel at most", type=int))
    stochastic: bool = dataclasses.field(
        default=False, metadata=option("trained policies sample actions (default: argmax)")
    )
    blind: list[str] = dataclasses.field(
        default_factory=list,
        metadata=option(
            "neighbour ablation: TEAM's trained policies act with their TYPE slots empty (e.g. prey=prey: "
            "learned prey that see no other prey); heuristics are unaffected",
            repeated=True,
            metavar="TEAM=TYPE",
        ),
    )
    out: str = dataclasses.field(default="eval_results", metadata=option("output directory (CSV, JSON, figures)"))
    curves: list[str] = dataclasses.field(
        default_factory=list,
        metadata=option(
            "also plot training curves of these runs (mean and std band over runs per label); a run of both "
            "teams: its run/progress_prey.csv or run/progress_predator.csv",
            nargs="*",
            metavar="LABEL=RUNDIR_GLOB",
        ),
    )
    smooth: int = dataclasses.field(
        default=1,
        metadata=option(
            "training curves: moving average over N iterations", type=int_at_least(1), metavar="N", shown="1: none"
        ),
    )
    figures: bool = dataclasses.field(default=True, metadata=option("no matplotlib figures", negated=True))
    grid: bool = dataclasses.field(
        default=False,
        metadata=option(
            "every prey x predator pairing over a grid of worlds, each pairing one batch of per-world values "
            f"(default prey: {_words(EVAL_RUNS['grid']['prey'])}; predators: {_words(EVAL_RUNS['grid']['predator'])}): "
            "grid.json, grid.csv and the general policies' targets (docs/general-policies.md)"
        ),
    )
    cross_play: bool = dataclasses.field(
        default=False,
        metadata=option(
            "every prey policy against every predator policy (globs such as 'run/model_*.pt' expand to every "
            f"checkpoint; default predators: {_words(EVAL_RUNS['cross-play']['predator'])}): "
            "cross_play.csv/json, an Elo rating and heatmaps"
        ),
    )

    @property
    def kind(self) -> str:
        """The kind of run: "grid", "cross-play" or "eval" (`EVAL_RUNS`)."""
        return "grid" if self.grid else "cross-play" if self.cross_play else "eval"

    @property
    def episodes_per_seed(self) -> int:
        return EVAL_RUNS[self.kind]["episodes"] if self.episodes is None else self.episodes

    @property
    def evaluation_seeds(self) -> list[int]:
        return list(EVAL_RUNS[self.kind]["seeds"]) if self.seeds is None else self.seeds


@dataclasses.dataclass
class GridCells:
    """The options of `aquarium-warp eval --grid`'s cells (`grid_cells.grid_cells`)."""

    grid_prey_counts: list[int] = dataclasses.field(
        default_factory=lambda: list(PREY_COUNTS),
        metadata=option(
            "grid: prey counts", parse=lambda text, flag: number_list(text, int, flag, 1), metavar="N,N,..."
        ),
    )
    grid_views: list[float] = dataclasses.field(
        default_factory=lambda: list(VIEWS),
        metadata=option(
            f"grid: prey view distances in px ({UNLIMITED:g}: unlimited on the default torus)",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, low_open=True),
            metavar="PX,PX,...",
        ),
    )
    grid_fovs: list[float] = dataclasses.field(
        default_factory=lambda: list(FOVS),
        metadata=option(
            "grid: prey fields of view",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, 360.0, low_open=True),
            metavar="DEG,...",
        ),
    )
    grid_speeds: list[float] = dataclasses.field(
        default_factory=lambda: list(SPEEDS),
        metadata=option(
            "grid: predator top speeds",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, low_open=True),
            metavar="V,V,...",
        ),
    )

    def cells(self) -> list[Cell]:
        return grid_cells(self.grid_prey_counts, self.grid_views, self.grid_fovs, self.grid_speeds)


def add_eval_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, EvalOptions)
    add_options(p.add_argument_group("grid (--grid)"), GridCells)


def run_eval(args) -> int:
    from .evaluate import evaluate_policies, write_results
    from .plots import plot_distributions, plot_training_curves

    options = from_options(EvalOptions, args)
    if options.grid and (options.cross_play or options.curves):
        raise ValueError("--grid runs on its own: without --cross-play and --curves")
    if options.grid:
        return run_grid(options, from_options(GridCells, args))

    if options.cross_play and options.curves:
        raise ValueError("--curves is not drawn with --cross-play: run eval --curves on its own")
    curves = _curves(options.curves)
    _blind(options.blind)  # a malformed one is refused before anything is written
    if curves and not options.figures:
        raise ValueError(
            "--curves draws a figure (training_curves.png), which --no-figures leaves out: give one of them"
        )
    os.makedirs(check_output_dir(options.out, "--out"), exist_ok=True)  # before any episode runs
    if options.cross_play:
        return run_cross_play(options)
    outputs = []
    evaluate = (
        options.prey != []
        and options.predator != []
        and not (options.curves and options.prey is None and options.predator is None)
    )
    if evaluate:
        prey = options.prey if options.prey is not None else list(EVAL_RUNS["eval"]["prey"])
        predator = options.predator if options.predator is not None else list(EVAL_RUNS["eval"]["predator"])
        env = _eval_world(options, prey + predator)
        print(
            f"aquarium-warp eval: {len(prey)} prey x {len(predator)} predator policies, "
            f"{plural(options.episodes_per_seed, 'episode')} x {plural(len(options.evaluation_seeds), 'seed')}, "
            f"{env.prey_count} prey, {plural(env.predator_count, 'predator')}, {plural(env.max_steps, 'step')}"
        )
        start = time.perf_counter()
        result = evaluate_policies(
            prey,
            predator,
            env,
            episodes=options.episodes_per_seed,
            seeds=options.evaluation_seeds,
            device=options.device,
            max_worlds=options.max_worlds,
            deterministic=not options.stochastic,
            progress=lambda m: print("  " + m),
            blind_to=_blind(options.blind),
        )
        paths = write_results(result, options.out)
        outputs += list(paths.values())
        print(f"{'prey':>16} {'predator':>12} {'captures/prey':>20} {'reward/prey':>22}")
        for row in result["summary"]:
            print(
                f"{row['prey_policy']:>16} {row['predator_policy']:>12} "
                f"{row['captures_per_prey_mean']:10.3f} +- {row['captures_per_prey_std']:6.3f} "
                f"{row['reward_per_prey_mean']:12.1f} +- {row['reward_per_prey_std']:6.1f}"
            )
        print(f"  ({time.perf_counter() - start:.1f} s; mean +- std over seeds of the per-seed means)")
        if options.figures:
            outputs.append(plot_distributions(result, os.path.join(options.out, "distributions.png")))
    if curves:
        with warnings.catch_warnings(record=True) as notes:  # e.g. why a curve is empty
            warnings.simplefilter("always")
            outputs.append(
                plot_training_curves(curves, os.path.join(options.out, "training_curves.png"), smooth=options.smooth)
            )
        for note in notes:
            print(f"  note: {note.message}")
    for path in outputs:
        print(f"  wrote {path}")
    return 0


def _curves(items: list[str]) -> dict[str, list[str]]:
    """`--curves [LABEL=]PATTERN` options as `{label: [patterns]}`, refused in one line where a pattern
    matches no run directory or progress CSV (`plots.plot_training_curves` reads them)."""
    import glob

    curves: dict[str, list[str]] = {}
    for item in items:
        label, _, pattern = item.partition("=") if "=" in item else (os.path.basename(item.rstrip("/")), "", item)
        if not any(
            os.path.isdir(d) or (d.endswith(".csv") and os.path.isfile(d)) for d in (glob.glob(pattern) or [pattern])
        ):
            raise ValueError(f"--curves {item!r}: no run directory or progress CSV matches {pattern!r}")
        curves.setdefault(label, []).append(pattern)
    return curves


def _blind(items: list[str]) -> dict[str, str]:
    """`--blind TEAM=TYPE` options as `{team: type}`, refused in one line when malformed or repeated."""
    out: dict[str, str] = {}
    for item in items:
        team, _, kind = item.partition("=")
        if team not in TYPES or kind not in TYPES:
            raise ValueError(
                f"--blind {item!r}: expected TEAM=TYPE with TEAM and TYPE each {' or '.join(map(repr, TYPES))}"
            )
        if team in out:
            raise ValueError(f"--blind names {team!r} twice")
        out[team] = kind
    return out


def _eval_world(options: EvalOptions, specs):
    """`eval`'s world: `--preset`, else the policies' (`drivers.common_world`), with `--set` and the count
    options applied."""
    from ..config import AquariumConfig
    from ..drivers import common_world
    from .config import deep_update, env_config, make_config, parse_assignment

    base = env_config(make_config(options.preset)) if options.preset else common_world(specs, AquariumConfig())
    changes: dict[str, Any] = {}
    for s in options.sets:
        change = parse_assignment(s)
        if set(change) != {"env"}:
            raise ValueError(f"--set {s!r}: eval takes env.* settings only")
        deep_update(changes, change["env"])
    for key, value in (
        ("prey_count", options.prey_count),
        ("predator_count", options.predator_count),
        ("max_steps", options.max_steps),
    ):
        if value is not None:
            changes[key] = value
    return env_config({"env": deep_update(base.to_dict(), changes)})


def run_grid(options: EvalOptions, grid: GridCells) -> int:
    """`aquarium-warp eval --grid`: every pairing over the grid's cells, its tables, files and targets."""
    from ..pretrained import GENERAL, names, world
    from .grid import check_targets, evaluate_grid, format_tables, grid_base, write_grid
    from .grid_cells import cell_of

    if options.episodes_per_seed < 1:
        raise ValueError(f"--episodes={options.episodes_per_seed} must be an integer >= 1")
    if options.stochastic or options.blind:
        raise ValueError("--grid evaluates argmax actions of whole observations: without --stochastic and --blind")
    if options.prey_count is not None or options.predator_count is not None:
        raise ValueError("--grid takes its prey counts from --grid-prey-counts and the predator count from the world")
    cells = grid.cells()
    prey = options.prey or list(EVAL_RUNS["grid"]["prey"])
    predator = options.predator or list(EVAL_RUNS["grid"]["predator"])
    base = grid_base(
        prey + predator, _eval_world(options, []) if options.preset or options.sets or options.max_steps else None
    )
    worlds = len(cells) * len(options.evaluation_seeds) * options.episodes_per_seed
    print(
        f"aquarium-warp eval --grid: {len(prey)} prey x {len(predator)} predator policies, {len(cells)} cells x "
        f"{plural(len(options.evaluation_seeds), 'seed')} x {plural(options.episodes_per_seed, 'episode')} "
        f"({worlds} worlds per pairing), {plural(base.max_steps, 'step')}"
    )
    os.makedirs(check_output_dir(options.out, "--out"), exist_ok=True)
    start = time.perf_counter()
    result = evaluate_grid(
        prey,
        predator,
        base,
        cells,
        options.episodes_per_seed,
        options.evaluation_seeds,
        options.device,
        progress=lambda m: print("  " + m),
    )
    specialists = {n: cell_of(world(n)) for n in names("prey") if n != GENERAL["prey"]}
    targets = check_targets(result, specialists=specialists)
    for line in format_tables(result):
        print(line)
    for t in targets:
        print(f"  target {t['target']}: {'met' if t['met'] else 'FAILED'} ({t['cells']} cells)")
        for failing in t["failing"]:
            print(f"    fails in {failing}")
    print(f"  ({time.perf_counter() - start:.1f} s; mean ± 95% interval per cell)")
    for path in write_grid(result, options.out, targets).values():
        print(f"  wrote {path}")
    return 0


def run_cross_play(options: EvalOptions) -> int:
    """`aquarium-warp eval --cross-play`: the matrix, its files, rating and heatmaps."""
    from .cross_play import cross_play, expand_specs, write_cross_play
    from .plots import plot_cross_play

    prey = expand_specs(options.prey or list(EVAL_RUNS["cross-play"]["prey"]))
    predator = expand_specs(options.predator or list(EVAL_RUNS["cross-play"]["predator"]))
    env = _eval_world(options, prey + predator)
    print(
        f"aquarium-warp eval --cross-play: {len(prey)} prey x {len(predator)} predator policies, "
        f"{plural(options.episodes_per_seed, 'episode')} x {plural(len(options.evaluation_seeds), 'seed')}, "
        f"{env.prey_count} prey, {plural(env.predator_count, 'predator')}, {plural(env.max_steps, 'step')}"
    )
    start = time.perf_counter()
    result = cross_play(
        prey,
        predator,
        env,
        episodes=options.episodes_per_seed,
        seeds=options.evaluation_seeds,
        device=options.device,
        max_worlds=options.max_worlds,
        deterministic=not options.stochastic,
        blind_to=_blind(options.blind),
    )
    outputs = list(write_cross_play(result, options.out).values())
    cp = result["cross_play"]
    print("captures per prey per episode (mean over seeds; rows: prey, columns: predators)")
    first = max(len(a) for a in cp["prey"] + ["rating"])
    widths = [max(10, len(b) + 2) for b in cp["predator"]]
    print(" " * first + "".join(f"{b:>{w}}" for b, w in zip(cp["predator"], widths)) + f"{'rating':>9}")
    for i, a in enumerate(cp["prey"]):
        cells = "".join(f"{v:{w}.3f}" for v, w in zip(cp["matrices"]["captures_per_prey"]["mean"][i], widths))
        print(f"{a:>{first}}{cells}{result['rating']['prey'][a]:9.0f}")
    print(
        f"{'rating':>{first}}"
        + "".join(f"{result['rating']['predator'][b]:{w}.0f}" for b, w in zip(cp["predator"], widths))
    )
    print(f"  ({time.perf_counter() - start:.1f} s; Elo ratings from the prey survival matrix)")
    if options.figures:
        for metric in ("captures_per_prey", "prey_survival"):
            outputs.append(plot_cross_play(result, os.path.join(options.out, f"cross_play_{metric}.png"), metric))
    for path in outputs:
        print(f"  wrote {path}")
    return 0
