"""Training configurations: presets, file loading, overrides, and the rsl-rl runner config built from them.

A run configuration is a dict with three sections:

- `env`: `AquariumConfig` fields that differ from docs/model.md's defaults (`prey` / `predator` may hold
  a dict of per-type fields).
- `train`: what this package adds around rsl-rl (see `TRAIN_DEFAULTS`).
- `runner`: rsl-rl's `OnPolicyRunner` config (num_steps_per_env, save_interval, algorithm, actor,
  critic, ...). The class names, the categorical distribution's size, Individual Learning's per-slot
  models and the learning-rate ratio are filled in by `runner_config()`.
- `teams` (optional): per-team blocks `{"prey": {...}, "predator": {...}}` that override, for that
  team's learner, the `train` settings of `TEAM_KEYS` (sharing, learning rates, reward scale, critic,
  pool fraction) and, under `runner`, its `algorithm` / `actor` / `critic` entries. With
  `train.team = "both"` each team has its own learner (own PPO, storage, optimizer, normaliser).

Presets (`PRESETS`): `default`, `paper` (section 5 of the paper), `tiny` (small CPU runs and tests),
`learned-prey-a`, `learned-prey-b`, `learned-prey-c` (the learned-prey recipe in worlds A, B and C),
`swarm` (the swarm scenario, where learned prey aggregate: docs/studies/swarm.md), `general-prey`,
`general-predator` and `general` (both teams): policies for any world of `GENERAL_RANGES`, drawn per
world at every episode end (docs/general-policies.md).
Every preset is the default config deep-updated with the preset's entries.

The paper's two learning rates. rsl-rl has one optimizer and one learning rate. `train.actor_lr` is
rsl-rl's `learning_rate`; `train.critic_lr` becomes `algorithm.critic_lr_scale = critic_lr / actor_lr`,
a per-group factor of `AquariumPPO`'s optimizer (see `ppo.py`: scaling the value-loss coefficient
instead would not work with Adam, which cancels constant gradient factors).
"""

from __future__ import annotations

import copy
import json
import math
from typing import Any

from ..agent_types import TYPES
from ..checks import is_int, is_real
from ..config import AquariumConfig
from .randomize import parse_spec

DISTRIBUTION = "aquarium_warp.training.distribution:CategoricalDistribution"
PPO_CLASS = "aquarium_warp.training.ppo:AquariumPPO"
MLP_MODEL = "MLPModel"
IL_MODEL = "aquarium_warp.training.models:IndividualMLPModel"
FUSED_MODEL = "aquarium_warp.training.fused_mlp:FusedMLPModel"
FUSED_IL_MODEL = "aquarium_warp.training.fused_mlp:FusedIndividualMLPModel"
TORCH_MLP_MODELS = (MLP_MODEL, "rsl_rl.models:MLPModel")  # rsl-rl's MLP model, by either of its names
SHARING = ("parameter", "individual")

TRAIN_DEFAULTS: dict[str, Any] = {
    "team": "prey",  # the learning team: "prey", "predator" or "both" (one learner per team)
    "opponent": None,  # the other team: a heuristic name or a policy file; None: naivchase / random
    "opponent_deterministic": True,  # trained opponents: argmax (True) or sampled actions
    "num_worlds": 1024,
    "device": None,  # None: "cuda:0" when CUDA is available, else "cpu"
    "seed": 0,
    "iterations": 300,  # total PPO iterations of the run (a resumed run continues up to it)
    "episodes": None,  # if set: iterations = ceil(episodes * max_steps / (worlds * steps per env))
    "sharing": "parameter",  # "parameter" (one shared network) or "individual" (one per agent slot)
    "actor_lr": 1e-3,
    "critic_lr": None,  # None: the actor's rate
    "reward_scale": 0.01,  # rewards given to PPO are scaled; logged episode rewards are not
    "init_at_random_ep_len": True,  # spread the worlds' truncations (episode_length_buf setter)
    "export": ["jit", "onnx"],  # formats exported at the end of training: "jit", "onnx"
    "quiet": False,  # tqdm progress bar instead of the per-iteration line
    "loop": "fast",  # "fast": training/loop.py (no host syncs; CUDA graphs); "rsl-rl": its runner's loop
    "cuda_graphs": True,  # the fast loop replays CUDA graphs on CUDA devices where the model allows
    # with cuda_graphs, the PPO update too: "auto" (one graph in one process; on several ranks graphs cut at each
    # gradient all-reduce, which runs eagerly between them), true (one graph; several NCCL ranks capture the
    # all-reduce inside it) or false (eager)
    "graph_update": "auto",
    "metrics_every": 10,  # swarm metrics (Swarm/* in the log) sampled every N steps; 0: none
    # The matrix path (fast_path.py): true, false or "auto". fused_mlp: actor and critic MLPs, the PPO loss and the
    # rollout step as the fused Triton kernels (fused_mlp.py, fused_ppo.py); "auto": on CUDA where Triton imports
    # and the kernels serve the config. tf32: CUDA matrix products in TF32 (~1e-3 relative error); "auto": with
    # the fused MLP on CUDA. "auto" is the default: the declared follow-up (benchmarks/fused_default_followup.md)
    # found the fused path with TF32 equivalent to torch's float32 on new seeds and pooled with the first check.
    "tf32": "auto",
    "fused_mlp": "auto",
    "critic": "local",  # the critic's input (MAPPO): "local", "team" or "world" (see CRITICS)
    # Both teams learning (team "both"):
    "update_schedule": "simultaneous",  # "simultaneous", or "alternating": one team learns, the other is frozen
    "alternate_every": 10,  # alternating: iterations per turn (prey first)
    "pool_every": 0,  # snapshot each team's actor into its opponent pool every N iterations; 0: no pool
    "pool_size": 8,  # snapshots kept per team (the oldest is replaced)
    "pool_sampling": "uniform",  # which snapshot a world draws: "uniform" or "latest" (weights 1..size by age)
    "pool_fraction": 0.2,  # fraction of worlds in which a team plays against the other team's snapshots
    "video_every": 0,  # every N iterations a rendered evaluation episode into the log (0: none)
    "video_steps": 200,  # steps of that episode
    "randomize": {},  # {field: "low:high" or "a,b,c"}: per-world values drawn at every world's reset
}
LOOPS = ("fast", "rsl-rl")
# What the critic sees besides the agent's own observation (rsl-rl's "critic" observation set):
# "local": nothing (the actor's input); "team": the team's joint observation (every slot of the
# world, slot order); "world": the world state (`world_state.WorldState`). Actors stay local.
CRITICS = ("local", "team", "world")
UPDATE_SCHEDULES = ("simultaneous", "alternating")
POOL_SAMPLING = ("uniform", "latest")
# The PPO learning-rate schedules (runner.algorithm.schedule): fixed, or adapted to a KL target (rsl-rl's).
LR_SCHEDULES = ("fixed", "adaptive")
# `train` settings a `teams.<team>` block may override for that team's learner, and its runner entries.
TEAM_KEYS = ("sharing", "actor_lr", "critic_lr", "reward_scale", "critic", "pool_fraction", "runner")
TEAM_RUNNER_KEYS = ("algorithm", "actor", "critic")

RUNNER_DEFAULTS = {
    "num_steps_per_env": 32,
    "save_interval": 50,
    "check_for_nan": False,
    "logger": "tensorboard",
    "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
    "algorithm": {
        "class_name": PPO_CLASS,
        "num_learning_epochs": 5,
        "num_mini_batches": 4,
        "clip_param": 0.2,
        "gamma": 0.99,
        "lam": 0.95,
        "value_loss_coef": 1.0,
        "entropy_coef": 0.01,
        "max_grad_norm": 1.0,
        "use_clipped_value_loss": False,
        "schedule": "fixed",
        "desired_kl": 0.01,
        "normalize_advantage_per_mini_batch": False,
    },
    "actor": {
        "class_name": MLP_MODEL,
        "hidden_dims": [64, 64],
        "activation": "tanh",
        "obs_normalization": False,
        "distribution_cfg": {"class_name": DISTRIBUTION, "init_logit_scale": 0.01},
    },
    "critic": {
        "class_name": MLP_MODEL,
        "hidden_dims": [64, 64],
        "activation": "tanh",
        "obs_normalization": False,
    },
}

PRESETS: dict[str, dict[str, Any]] = {  # name -> changes to the defaults (a nested run config)
    "default": {},
    # Section 5: prey trained with PPO against one NaivChase predator; docs/model.md's world otherwise.
    # From the paper's table: gamma, lambda, clip, entropy weight, actor/critic learning rates; 4000
    # episodes of 3000 steps. Not given by the paper (our choices): the networks (two tanh layers of
    # 64, separate actor and critic), epochs, mini-batches, gradient clipping, the reward scale, and
    # the batch: many worlds in parallel instead of its 2048-sample batches.
    "paper": {
        "env": {"prey_count": 6, "predator_count": 1},
        "train": {
            "team": "prey",
            "opponent": "naivchase",
            "num_worlds": 1024,
            "episodes": 4000,
            "actor_lr": 1e-3,
            "critic_lr": 3e-3,
        },
        "runner": {
            "algorithm": {
                "gamma": 0.99,
                "lam": 0.95,
                "clip_param": 0.1,
                "entropy_coef": 0.001,
                "num_learning_epochs": 5,
                "num_mini_batches": 4,
                "schedule": "fixed",
                "max_grad_norm": 0.5,
            }
        },
    },
    # The learned-prey recipe (benchmarks/learned_prey.py, results in benchmarks/results/learned_prey_ego/):
    # the paper's task with egocentric observations (world actions), random spawn headings, entropy
    # weight 0.01 and 4x the paper's budget, in world A (the paper's prey view), B (360 degrees, 200 px)
    # or C (360 degrees, unlimited). Filled in below from "paper".
    # A small world for CPU runs and the tests: 4 prey and a NaivChase predator on 400 x 400 px.
    "tiny": {
        "env": {"width": 400.0, "height": 400.0, "prey_count": 4, "predator_count": 1, "max_steps": 200},
        "train": {"num_worlds": 32, "iterations": 100, "actor_lr": 3e-3, "device": "cpu"},
        "runner": {
            "num_steps_per_env": 32,
            "save_interval": 25,
            "algorithm": {"num_learning_epochs": 4, "num_mini_batches": 4, "entropy_coef": 0.003},
        },
    },
}


# The learned-prey recipe's changes to a run config (docs/learned-prey.md): egocentric observations
# (world actions), random spawn headings and entropy weight 0.01. The learned-prey presets, the swarm
# study and the many-eyes and group-hunting studies' `--recipe` take it from here.
LEARNED_PREY_RECIPE: dict[str, dict[str, Any]] = {
    "env": {"observation_frame": "ego", "spawn_heading": "random"},
    "runner": {"algorithm": {"entropy_coef": 0.01}},
}

# World A, B and C's prey views (benchmarks/learned_prey.py's WORLDS).
LEARNED_PREY_VIEWS = {
    "a": {},
    "b": {"fov_angle": 360, "view_distance": 200},
    "c": {"fov_angle": 360, "view_distance": 10000},
}


def deep_update(base: dict, changes: dict) -> dict:
    """`base` updated in place with `changes`, recursing into dicts present in both."""
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            deep_update(base[key], value)
        else:
            base[key] = copy.deepcopy(value)
    return base


for _world, _view in LEARNED_PREY_VIEWS.items():
    _recipe = deep_update(copy.deepcopy(PRESETS["paper"]), copy.deepcopy(LEARNED_PREY_RECIPE))
    if _view:
        _recipe["env"]["prey"] = dict(_view)
    _recipe["train"]["episodes"] = 16000
    PRESETS[f"learned-prey-{_world}"] = _recipe


# The swarm scenario (docs/studies/swarm.md): where learned prey aggregate. The swarm study's
# `confusion-strong` condition: 32 prey that see 360 degrees and 200 px, capture confusion c = 64
# within 100 px (a contact catches a prey with 1 / (1 + 64 k), k its prey neighbours), NaivChase
# without target confusion, the learned-prey recipe, 500 iterations of 256 worlds.
PRESETS["swarm"] = deep_update(
    copy.deepcopy(PRESETS["learned-prey-b"]),
    {
        "env": {"prey_count": 32, "capture_confusion": 64.0, "confusion_radius": 100.0},
        "train": {"opponent": "naivchase-noconfusion", "num_worlds": 256, "iterations": 500, "episodes": None},
    },
)


# Randomised worlds (docs/general-policies.md): prey and predators for any world of these ranges, drawn
# per world at every episode end (`train.randomize`) on the learned-prey recipe (ego observations, world
# actions, random spawn headings, entropy 0.01), so every world shares one observation interface: the
# same 1 predator slot and 3 prey slots in a world of 4 prey as in one of 64. The batch holds the
# largest prey count (64 slots); a world's live count is its draw. Prey views are listed values: a
# geometric series 100-400 px (what matters is the view against the predator's approach) plus
# "unlimited", 10,000 px: on the 800 x 800 torus no agent is farther than the half diagonal (566 px),
# and the observed distances are normalised by min(view, half diagonal), so every view of 566 px or more
# is this same world. FOV in 60-degree steps and capture confusion c in {0, 16} (within 100 px) are
# listed too, so that the evaluation grid's values (100, 200 px, unlimited; 120, 240, 360 degrees) are
# trained worlds and not the edge of a range; predator speed is drawn uniformly.
GENERAL_RANGES = {
    "prey_count": "4:64",
    "prey_view_distance": "100,141,200,283,400,10000",
    "prey_fov_angle": "120,180,240,300,360",
    "predator_max_speed": "4.5:6",
    "capture_confusion": "0,16",
}
# The budget: 1,000 iterations of 256 worlds x 32 steps (~280 M live prey-steps for the prey, the learned-prey
# recipe's, in two thirds of its 1,465 updates). A first run at 500 iterations left the prey's curves still
# falling and both teams further from their targets; wider networks (128 x 128) with 2x the prey's worlds or
# 4x the predator's did no better (docs/general-policies.md, benchmarks/results/general_recipe_pilots_h200x4/).
_GENERAL = deep_update(
    copy.deepcopy(PRESETS["learned-prey-a"]),
    {
        "env": {"prey_count": 64, "confusion_radius": 100.0},
        "train": {"num_worlds": 256, "iterations": 1000, "episodes": None, "randomize": GENERAL_RANGES},
    },
)
# Prey against NaivChase with and without target confusion (half the worlds each).
PRESETS["general-prey"] = deep_update(copy.deepcopy(_GENERAL), {"train": {"opponent": "naivchase-mixed"}})
# One predator against TurnAway prey; 1,024 worlds, since a world gives one predator row per step.
PRESETS["general-predator"] = deep_update(
    copy.deepcopy(_GENERAL), {"train": {"team": "predator", "opponent": "turnaway", "num_worlds": 1024}}
)
# Both teams learning in the same randomised worlds (co-evolution, one learner per team).
PRESETS["general"] = deep_update(copy.deepcopy(_GENERAL), {"train": {"team": "both", "opponent": None}})
GENERAL_PRESETS = ("general-prey", "general-predator", "general")


def default_config() -> dict:
    return {"env": {}, "train": copy.deepcopy(TRAIN_DEFAULTS), "runner": copy.deepcopy(RUNNER_DEFAULTS)}


def make_config(preset: str = "default", *overrides: dict) -> dict:
    """The `preset` config deep-updated with each of `overrides` in turn (validated)."""
    if preset not in PRESETS:
        raise ValueError(f"preset={preset!r} is unknown: choose one of {sorted(PRESETS)}")
    config = deep_update(default_config(), PRESETS[preset])
    for changes in overrides:
        if changes:
            deep_update(config, changes)
    validate(config)
    return config


def load_config_file(path: str) -> dict:
    """A (partial) config from a JSON or YAML file (YAML needs PyYAML)."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    if path.endswith((".yaml", ".yml")):
        import yaml

        data = yaml.safe_load(text)
    else:
        data = json.loads(text)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a config file must hold a mapping with sections env / train / runner / teams")
    unknown = [k for k in data if k not in ("env", "train", "runner", "teams", "preset")]
    if unknown:
        raise ValueError(f"{path}: unknown sections {unknown}; allowed: env, train, runner, teams, preset")
    return data


def parse_assignment(text: str) -> dict:
    """`"runner.algorithm.gamma=0.98"` -> `{"runner": {"algorithm": {"gamma": 0.98}}}` (value parsed
    as JSON where possible, else kept as a string)."""
    if "=" not in text:
        raise ValueError(f"--set {text!r}: expected KEY.PATH=VALUE")
    key, raw = text.split("=", 1)
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    parts = [p for p in key.strip().split(".") if p]
    if not parts or parts[0] not in ("env", "train", "runner", "teams"):
        raise ValueError(f"--set {text!r}: the key must start with env., train., runner. or teams.")
    out: dict = {}
    node = out
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return out


def env_config(config: dict) -> AquariumConfig:
    """The `AquariumConfig` of a run config (docs/model.md defaults updated with `config["env"]`)."""
    data = AquariumConfig().to_dict()
    deep_update(data, config.get("env", {}))
    return AquariumConfig.from_dict(data)


def learning_teams(config: dict) -> tuple[str, ...]:
    """The teams that learn: `("prey", "predator")` for `train.team = "both"`, else the one team."""
    team = config["train"]["team"]
    return TYPES if team == "both" else (team,)


def team_settings(config: dict, team: str) -> dict:
    """The `train` settings of `team`'s learner: `train` with its `teams.<team>` block's overrides
    (without the block's `runner` entries, see `team_runner`)."""
    block = (config.get("teams") or {}).get(team) or {}
    return {**config["train"], **{k: v for k, v in block.items() if k != "runner"}}


def team_runner(config: dict, team: str) -> dict:
    """The `runner` section for `team`'s learner: `runner` deep-updated with `teams.<team>.runner`."""
    block = (config.get("teams") or {}).get(team) or {}
    return deep_update(copy.deepcopy(config["runner"]), block.get("runner") or {})


def _validate_team_settings(settings: dict, where: str) -> None:
    """The per-team `train` settings (`TEAM_KEYS`) present in `settings`; errors name `where.<key>`."""
    if "sharing" in settings and settings["sharing"] not in SHARING:
        raise ValueError(f"{where}.sharing={settings['sharing']!r} must be one of {SHARING}")
    for name in ("actor_lr", "reward_scale"):
        if name in settings and (not is_real(settings[name]) or not 0 < settings[name] < math.inf):
            raise ValueError(f"{where}.{name}={settings[name]!r} must be a finite number > 0")
    lr = settings.get("critic_lr")
    if lr is not None and (not is_real(lr) or not 0 < lr < math.inf):
        raise ValueError(f"{where}.critic_lr={lr!r} must be None or a finite number > 0")
    if "critic" in settings and settings["critic"] not in CRITICS:
        raise ValueError(f"{where}.critic={settings['critic']!r} must be one of {CRITICS}")
    fraction = settings.get("pool_fraction", 0.0)
    if not is_real(fraction) or not 0 <= fraction <= 1:
        raise ValueError(f"{where}.pool_fraction={fraction!r} must be a number in [0, 1]")


def _validate_algorithm(algorithm: dict, where: str) -> None:
    """PPO settings present in `algorithm` (`where`: "runner.algorithm" or a team block's)."""
    # Checked here: rsl-rl would only fail on 0 (ZeroDivisionError) after the first rollout.
    for name in ("num_learning_epochs", "num_mini_batches"):
        if name in algorithm and (not is_int(algorithm[name]) or algorithm[name] < 1):
            raise ValueError(f"{where}.{name}={algorithm[name]!r} must be an integer >= 1")
    # NaN or out-of-range coefficients fail only deep inside sampling or the update (or not at all).
    for name, (allowed, ok) in ALGORITHM_RANGES.items():
        if name == "desired_kl" and algorithm.get(name) is None:
            continue  # rsl-rl's "no KL target" (the fixed schedule)
        if name in algorithm and (not is_real(algorithm[name]) or not ok(algorithm[name])):
            raise ValueError(f"{where}.{name}={algorithm[name]!r} must be {allowed}")


def _check_runner_sections(runner: dict, where: str) -> None:
    """The model and algorithm entries of a runner block (`where`) must be mappings."""
    for part in ("algorithm", "actor", "critic"):
        if part in runner and not isinstance(runner[part], dict):
            raise ValueError(f"{where}.{part}={runner[part]!r} must be a mapping of settings")


def _validate_teams_section(config: dict) -> None:
    teams = config.get("teams")
    if teams is None:
        return
    if not isinstance(teams, dict) or any(t not in TYPES for t in teams):
        raise ValueError(f"teams={teams!r} must map team names {TYPES} to settings blocks")
    for team, block in teams.items():
        if block is None:
            continue
        if not isinstance(block, dict):
            raise ValueError(f"teams.{team}={block!r} must be a mapping of settings {TEAM_KEYS}")
        unknown = [k for k in block if k not in TEAM_KEYS]
        if unknown:
            raise ValueError(f"unknown teams.{team} settings {unknown}; known: {list(TEAM_KEYS)}")
        _validate_team_settings(block, f"teams.{team}")
        runner = block.get("runner") or {}
        if not isinstance(runner, dict) or any(k not in TEAM_RUNNER_KEYS for k in runner):
            raise ValueError(
                f"teams.{team}.runner={runner!r} may set only {list(TEAM_RUNNER_KEYS)} "
                f"(the rollout length and checkpoints are common: set them under runner)"
            )
        _check_runner_sections(runner, f"teams.{team}.runner")
        _validate_algorithm(runner.get("algorithm") or {}, f"teams.{team}.runner.algorithm")


def validate(config: dict) -> None:
    train = config["train"]
    unknown = [k for k in train if k not in TRAIN_DEFAULTS]
    if unknown:
        raise ValueError(f"unknown train settings {unknown}; known: {sorted(TRAIN_DEFAULTS)}")
    env_config(config)  # validates the env section
    if train["team"] not in TYPES + ("both",):
        raise ValueError(f"train.team={train['team']!r} must be 'prey', 'predator' or 'both'")
    _validate_team_settings(train, "train")
    for name in ("num_worlds", "iterations"):
        v = train[name]
        if not is_int(v) or v < (1 if name == "num_worlds" else 0):
            raise ValueError(f"train.{name}={v!r} must be an integer >= {1 if name == 'num_worlds' else 0}")
    if not is_int(train["seed"]) or not 0 <= train["seed"] < 2**63 - 2**16:
        # torch seeds are 64-bit, and distributed runs add their rank
        raise ValueError(f"train.seed={train['seed']!r} must be an integer in [0, 2**63 - 2**16)")
    if train["episodes"] is not None and (not is_real(train["episodes"]) or train["episodes"] <= 0):
        raise ValueError(f"train.episodes={train['episodes']!r} must be None or a number > 0")
    if train["loop"] not in LOOPS:
        raise ValueError(f"train.loop={train['loop']!r} must be one of {LOOPS}")
    for name, low, meaning in (
        ("metrics_every", 0, " (0: no swarm metrics)"),
        ("alternate_every", 1, ""),
        ("pool_every", 0, " (0: no opponent pool)"),
        ("pool_size", 1, ""),
        ("video_every", 0, " (0: no videos)"),
        ("video_steps", 1, ""),
    ):
        if not is_int(train[name]) or not low <= train[name] <= 2**31 - 1:
            raise ValueError(f"train.{name}={train[name]!r} must be an integer in [{low}, 2**31 - 1]{meaning}")
    if not isinstance(train["cuda_graphs"], bool):
        raise ValueError(f"train.cuda_graphs={train['cuda_graphs']!r} must be true or false")
    for name in ("fused_mlp", "tf32"):
        if not (isinstance(train[name], bool) or train[name] == "auto"):
            raise ValueError(
                f"train.{name}={train[name]!r} must be true, false or 'auto' (the fused path on CUDA with Triton)"
            )
    if train["fused_mlp"] is True:
        from .fast_path import triton_imports  # (it imports this module)

        if not triton_imports():
            raise ValueError(
                "train.fused_mlp=true needs Triton, which does not import here (the fused extra: "
                "pip install -e \".[fused]\"; CUDA builds of torch bring it); false or 'auto' train without it"
            )
    if not (isinstance(train["graph_update"], bool) or train["graph_update"] == "auto"):
        raise ValueError(
            f"train.graph_update={train['graph_update']!r} must be true or false, or 'auto' "
            "(captured in one process, eager on several ranks)"
        )
    if train["update_schedule"] not in UPDATE_SCHEDULES:
        raise ValueError(f"train.update_schedule={train['update_schedule']!r} must be one of {UPDATE_SCHEDULES}")
    if train["pool_sampling"] not in POOL_SAMPLING:
        raise ValueError(f"train.pool_sampling={train['pool_sampling']!r} must be one of {POOL_SAMPLING}")
    if not isinstance(train["randomize"], dict):
        raise ValueError(f"train.randomize={train['randomize']!r} must be a mapping field -> 'low:high' or 'a,b,c'")
    for field, spec in train["randomize"].items():
        parse_spec(f"{field}={spec}")
    export = train["export"]
    if isinstance(export, str):
        train["export"] = export = [] if export in ("", "none") else [e.strip() for e in export.split(",")]
    elif not isinstance(export, (list, tuple)):
        raise ValueError(f"train.export={export!r} must be a comma-separated string or a list of formats (jit, onnx)")
    bad = [e for e in export if e not in ("jit", "onnx")]
    if bad:
        raise ValueError(f"train.export has unknown formats {bad}; allowed: jit, onnx")
    runner = config["runner"]
    _check_runner_sections(runner, "runner")
    _validate_teams_section(config)
    for name in ("num_steps_per_env", "save_interval"):
        v = runner.get(name)
        if not is_int(v) or v < 1:
            raise ValueError(f"runner.{name}={v!r} must be an integer >= 1")
    algorithm = runner.get("algorithm", {})
    for name in ("num_learning_epochs", "num_mini_batches"):
        if not is_int(algorithm.get(name)):  # required (a team block may only override them)
            raise ValueError(f"runner.algorithm.{name}={algorithm.get(name)!r} must be an integer >= 1")
    _validate_algorithm(algorithm, "runner.algorithm")
    both = train["team"] == "both"
    if both and train["loop"] != "fast":
        raise ValueError("train.team='both' needs train.loop='fast' (rsl-rl's runner drives one learner)")
    if both and train["opponent"] is not None:
        raise ValueError(
            f"train.opponent={train['opponent']!r} sets the other team of a one-team run; with "
            f"train.team='both' every team learns"
        )
    if train["pool_every"] and not both:
        raise ValueError("train.pool_every > 0 (an opponent pool of past snapshots) needs train.team='both'")
    teams = learning_teams(config)
    if train["pool_every"] and sum(team_settings(config, t)["pool_fraction"] for t in teams) > 1:
        raise ValueError(
            "the pool fractions of both teams (train.pool_fraction or teams.<team>.pool_fraction) "
            "must add up to at most 1: a world plays at most one team's snapshots"
        )
    for team in teams:
        _validate_team_models(config, team)


def _validate_team_models(config: dict, team: str) -> None:
    """Individual Learning and the opponent pool need feed-forward models; errors name the settings."""
    block = (config.get("teams") or {}).get(team) or {}
    runner = team_runner(config, team)
    settings = team_settings(config, team)
    fused = config["train"]["fused_mlp"] is True  # ("auto" takes torch's path for other models)
    for part in ("actor", "critic"):
        class_name = runner.get(part, {}).get("class_name", MLP_MODEL)
        if fused and class_name not in TORCH_MLP_MODELS:
            raise ValueError(
                "train.fused_mlp serves rsl-rl's MLPModel (parameter sharing or Individual Learning), not "
                f"{part} class_name={class_name!r}"
            )
        if not _is_recurrent_model(class_name):
            continue
        model = f"teams.{team}.runner.{part}" if part in (block.get("runner") or {}) else f"runner.{part}"
        if settings["sharing"] == "individual":
            sharing = f"teams.{team}.sharing" if "sharing" in block else "train.sharing"
            raise ValueError(
                f"{sharing}='individual' does not support recurrent models "
                f"({model}.class_name={class_name!r}): use {sharing}='parameter' or a "
                f"feed-forward model"
            )
        if part == "actor" and config["train"]["pool_every"]:
            raise ValueError(
                f"train.pool_every > 0 needs feed-forward actors (snapshots act without hidden "
                f"states), not {model}.class_name={class_name!r}"
            )


def _is_recurrent_model(class_name) -> bool:
    """Whether an rsl-rl model class (a class, or a name rsl-rl resolves) is recurrent; a name that
    does not resolve is left for rsl-rl to report."""
    from rsl_rl.utils import resolve_callable

    from . import _rsl  # noqa: F401

    try:
        model_class = resolve_callable(class_name)
    except Exception:  # noqa: BLE001 - any failure to resolve is rsl-rl's to report, with its message
        return False
    return bool(getattr(model_class, "is_recurrent", False))


# PPO coefficients (absent ones take rsl-rl's defaults): {name: (allowed range, test of a real value)};
# the train command's options check the same ranges.
ALGORITHM_RANGES = {
    "gamma": ("a number in [0, 1]", lambda v: 0 <= v <= 1),
    "lam": ("a number in [0, 1]", lambda v: 0 <= v <= 1),
    "clip_param": ("a number in (0, 1]", lambda v: 0 < v <= 1),
    "entropy_coef": ("a finite number >= 0", lambda v: 0 <= v < math.inf),
    "value_loss_coef": ("a finite number >= 0", lambda v: 0 <= v < math.inf),
    "max_grad_norm": ("a finite number > 0", lambda v: 0 < v < math.inf),
    "desired_kl": ("a finite number > 0", lambda v: 0 < v < math.inf),
}


# The train settings a resumed run may change (`Trainer.resume`): how long it runs, what it prints and
# exports, and how its iterations are computed, none of which is in the state it continues.
RESUMABLE_SETTINGS = (
    "iterations",
    "episodes",
    "quiet",
    "export",
    "loop",
    "cuda_graphs",
    "graph_update",
    "tf32",
    "fused_mlp",
    "video_every",
    "video_steps",
)


def flat_config(config: dict) -> dict:
    """A nested config as `{"env.prey.view_distance": value, ...}`, its values as JSON writes them (a
    config read back from config.json equals its run's)."""
    out: dict = {}

    def walk(value, prefix: str) -> None:
        if isinstance(value, dict) and value:
            for k, v in value.items():
                walk(v, f"{prefix}.{k}" if prefix else str(k))
        else:
            out[prefix] = value

    walk(json.loads(json.dumps(config, default=str)), "")
    return out


def config_difference(a: dict, b: dict, ignore: tuple[str, ...] = ()) -> str | None:
    """The first dotted key whose value differs between the run configs `a` and `b` (`flat_config`), or
    None; the train settings `ignore` are left out."""

    def flat(config: dict) -> dict:
        return {k: v for k, v in flat_config(config).items() if not (k.startswith("train.") and k[6:] in ignore)}

    fa, fb = flat(a), flat(b)
    missing = object()
    return next((k for k in sorted(fa.keys() | fb.keys()) if fa.get(k, missing) != fb.get(k, missing)), None)


def default_opponent(team: str) -> str:
    return "naivchase" if team == "prey" else "random"


def total_iterations(config: dict) -> int:
    """`train.iterations`, or the iterations that cover `train.episodes` world episodes."""
    train = config["train"]
    if train.get("episodes") is None:
        return int(train["iterations"])
    steps = train["episodes"] * env_config(config).max_steps
    per_iteration = train["num_worlds"] * config["runner"]["num_steps_per_env"]
    return max(1, math.ceil(steps / per_iteration))


def runner_config(
    config: dict, slots: int, action_count: int, device_type: str = "cpu", team: str | None = None
) -> dict:
    """rsl-rl's runner config of `team`'s learner (default: the one learning team) for a run config,
    given that team's slots per world, the number of discrete actions and the device type ("cpu" or
    "cuda"); the actor and critic are the fused kernels' models where `fast_path.resolve_fast_path` takes
    the fused MLP."""
    from .fast_path import resolve_fast_path  # (it imports this module)

    team = config["train"]["team"] if team is None else team
    train = team_settings(config, team)
    runner = team_runner(config, team)
    alg = runner.setdefault("algorithm", {})
    alg.setdefault("class_name", PPO_CLASS)
    if device_type == "cuda" and train["loop"] == "fast":
        # The fast loop captures the optimizer step in a CUDA graph (also built so without graphs, so
        # that both run the same optimizer arithmetic).
        alg["capturable_optimizer"] = True
    alg["learning_rate"] = float(train["actor_lr"])
    critic_lr = train["critic_lr"] if train["critic_lr"] is not None else train["actor_lr"]
    if "critic_lr_scale" not in alg:
        alg["critic_lr_scale"] = float(critic_lr) / float(train["actor_lr"])
    if train["critic"] != "local":  # the centralised critic: own observation + the team's or world's
        runner["obs_groups"] = {"actor": ["policy"], "critic": ["policy", train["critic"]]}
    actor, critic = runner["actor"], runner["critic"]
    dist = actor.setdefault("distribution_cfg", {"class_name": DISTRIBUTION})
    dist.setdefault("class_name", DISTRIBUTION)
    dist["num_categories"] = int(action_count)
    individual = train["sharing"] == "individual"
    if resolve_fast_path(config, device_type).fused_mlp:
        actor["class_name"] = critic["class_name"] = FUSED_IL_MODEL if individual else FUSED_MODEL
    if individual:
        for model in (actor, critic):
            if model.get("class_name", MLP_MODEL) in TORCH_MLP_MODELS:
                model["class_name"] = IL_MODEL
            model["num_agents"] = int(slots)
        alg["minibatch_group_size"] = int(slots)
    return runner
