"""Policies for any world: train K seeds of `--preset general-prey` and `general-predator` (and, with
`--coevolved`, `general`: both teams), evaluate them on the evaluation grid (`training/grid.py`), pick
the shipped seed of each team by the declared rule, and install it into a policy folder as `prey-any`
and `predator-any` (TorchScript and ONNX, with its training range in the index entry).

Phases (all in one call; finished trainings are kept, so a rerun trains only what is missing, and an
interrupted training, which checkpoints where it stopped, continues from its newest checkpoint):

1. Trainings: one `aquarium-warp train` process per (preset, seed), all at once (`--jobs` at most),
   each into `<out>/runs/<preset>-s<seed>/`. A population cannot train them (`train.randomize` draws per
   run), so they share the GPU as separate processes.
2. Prey grid (`grid_prey.json`, `.csv`): TurnAway, Boids, constant, random and every `general-prey`
   seed (label `prey-any`; with `--coevolved` also the co-evolved prey, label `general-prey-coevolved`)
   against NaivChase with and without target confusion, on every cell; the shipped specialists
   (`prey-a`, `-b`, `-c`) on their own world's cell only.
3. Pick the shipped prey: the seed whose largest ratio to TurnAway over the cells (both NaivChase
   kinds, means over evaluation seeds) is smallest, since the target holds in every cell.
4. Predator grid (`grid_predator.json`, `.csv`): NaivChase and every `general-predator` seed (label
   `predator-any`; `--coevolved`: `general-predator-coevolved`) against TurnAway and the picked prey.
5. Pick the shipped predator: the seed whose smallest ratio to NaivChase against TurnAway is largest.
   With `--teams none --coevolved` only `general` trains, and the grids show the co-evolved pair beside
   `--prey-any` and `--predator-any` (the shipped ones by default); nothing is picked or installed.
6. Install both (`--install DIR`, default the package's `aquarium_warp/policies/`), write
   `general_policies.json` (commands, times, picks, targets) and print the tables.

    python benchmarks/general_policies.py --device cuda:0 --seeds 0 1 2 3 4 --out runs/general
    python benchmarks/general_policies.py --teams none --coevolved --out runs/coevolved  # beside the shipped
    python benchmarks/general_policies.py --device cpu --seeds 0 1 --out /tmp/gp --set train.iterations=2 \\
        --set train.num_worlds=4 --set env.max_steps=20 --set runner.num_steps_per_env=8 --max-steps 20 \\
        --episodes 2 --eval-seeds 0 --grid-prey-counts 4,8 --install /tmp/gp/policies     # a CPU smoke run
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import time
from typing import IO

PREY, PREDATOR, BOTH = "general-prey", "general-predator", "general"
SPECIALISTS = ("prey-a", "prey-b", "prey-c")


def run_dir(out: str, preset: str, seed: int) -> str:
    return os.path.join(out, "runs", f"{preset}-s{seed}")


def exported(out: str, preset: str, seed: int, team: str, kind: str = "pt") -> str:
    """A training's exported policy file (`kind` "pt" or "onnx"); both teams: `exported/<team>/`."""
    folder = os.path.join(run_dir(out, preset, seed), "exported")
    return os.path.join(folder, team if preset == BOTH else "", f"policy.{kind}")


def train_command(out: str, preset: str, seed: int, device: str, sets: list[str]) -> list[str]:
    from aquarium_warp.training.fast_path import TORCH_FLOAT32

    command = [sys.executable, "-m", "aquarium_warp", "train", "--preset", preset, "--seed", str(seed)]
    command += ["--device", device, "--quiet", "--export", "jit,onnx", "--log-dir", run_dir(out, preset, seed)]
    # torch's float32 path, the shipped policies' (trained before the fused default); `--set` may change it
    pinned = [f"train.{name}={str(value).lower()}" for name, value in TORCH_FLOAT32.items()]
    return command + [arg for s in pinned + sets for arg in ("--set", s)]


def total_iterations(out: str, preset: str, seed: int) -> int | None:
    """The iterations a training was started for (its `config.json`), None before it started."""
    try:
        with open(os.path.join(run_dir(out, preset, seed), "config.json"), encoding="utf-8") as f:
            return int(json.load(f)["total_iterations"])
    except (OSError, ValueError, KeyError):
        return None


def finished(out: str, preset: str, seed: int) -> bool:
    """A training that ran all its iterations: its export and its last checkpoint exist. (A stopped
    training, by a signal or a time limit, also checkpoints and exports, at the iteration it stopped.)"""
    total = total_iterations(out, preset, seed)
    team = "predator" if preset == PREDATOR else "prey"
    last = os.path.join(run_dir(out, preset, seed), f"model_{total - 1}.pt") if total else ""
    return total is not None and os.path.isfile(exported(out, preset, seed, team)) and os.path.isfile(last)


def pending_command(out: str, preset: str, seed: int, device: str, sets: list[str]) -> tuple[list[str], str]:
    """The command for a training not finished yet, and how it starts: "new"; "resume" from the newest
    checkpoint of an interrupted one (on the device and with the config it was started with); or
    "restart" (`--overwrite`) of one stopped before its first checkpoint."""
    folder = run_dir(out, preset, seed)
    if glob.glob(os.path.join(folder, "model_*.pt")):
        return [sys.executable, "-m", "aquarium_warp", "train", "--resume", folder, "--quiet"], "resume"
    command = train_command(out, preset, seed, device, sets)
    if os.path.isdir(folder) and os.listdir(folder):
        return command + ["--overwrite"], "restart"
    return command, "new"


def train_all(
    out: str, presets: list[str], seeds: list[int], devices: list[str], sets: list[str], jobs: int,
    commit: str | None = None,
) -> list[dict]:  # fmt: skip
    """Every (preset, seed) training not finished yet, `jobs` processes at a time (each one's output in
    `<out>/logs/`), the k-th on `devices[k % len(devices)]`; their records, which are also appended to
    `<out>/trainings.jsonl` (the trainings of every call on `out`). A failed training stops the others."""
    pending = [(p, s) for p in presets for s in seeds if not finished(out, p, s)]
    device_of = {job: devices[k % len(devices)] for k, job in enumerate(pending)}
    running: list[tuple[dict, subprocess.Popen, IO[str]]] = []
    records: list[dict] = []
    os.makedirs(os.path.join(out, "logs"), exist_ok=True)
    try:
        while pending or running:
            while pending and len(running) < jobs:
                preset, seed = pending.pop(0)
                command, start = pending_command(out, preset, seed, device_of[(preset, seed)], sets)
                log = open(os.path.join(out, "logs", f"{preset}-s{seed}.log"), "a", encoding="utf-8")
                record = {"preset": preset, "seed": seed, "command": " ".join(command[1:]), "how": start}
                record["start"] = time.time()
                # a copy without git history: the trainings record `commit` (`records.git_info`)
                env = dict(os.environ, AQUARIUM_WARP_COMMIT=commit) if commit else None
                process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
                running.append((record, process, log))
            time.sleep(0.5)
            for entry in [r for r in running if r[1].poll() is not None]:
                record, process, log = entry
                log.close()
                running.remove(entry)
                record.update(rc=process.returncode, seconds=round(time.time() - record.pop("start"), 1))
                records.append(record)
                with open(os.path.join(out, "trainings.jsonl"), "a", encoding="utf-8") as f:  # every call's
                    f.write(json.dumps(record) + "\n")
                print(f"  trained {record['preset']} seed {record['seed']}: rc {record['rc']}, {record['seconds']} s")
                if process.returncode != 0:
                    raise RuntimeError(f"{record['command']} failed: see {log.name}")
    finally:
        for _, process, log in running:  # only the trainings this call started
            process.terminate()
            process.wait()
            log.close()
    return records


def ratios(result: dict, prey: str, predator: str, against: tuple[str, str], run: int) -> list[float]:
    """Run `run` of the (prey, predator) pairing over the `against` pairing's means, per shared cell
    (each the mean over evaluation seeds)."""
    import numpy as np

    entry = next(p for p in result["pairings"] if (p["prey"], p["predator"]) == (prey, predator))
    other = next(p for p in result["pairings"] if (p["prey"], p["predator"]) == against)
    base = {c: s["mean"] for c, s in zip(other["cells"], other["stats"])}
    values = np.asarray(entry["runs"][run]["values"]).mean(axis=1)
    return [float(v) / base[c] for c, v in zip(entry["cells"], values) if c in base and base[c] > 0]


def pick_prey(result: dict, label: str = "prey-any") -> int:
    """The run (seed index) whose largest ratio to TurnAway over the cells (against both NaivChase kinds) is
    smallest."""
    predators = [p["predator"] for p in result["pairings"] if p["prey"] == label]
    runs = len(next(p for p in result["pairings"] if p["prey"] == label)["runs"])
    worst = [
        max(max(ratios(result, label, b, ("turnaway", b), k), default=0.0) for b in predators) for k in range(runs)
    ]
    return min(range(runs), key=lambda k: worst[k])


def pick_predator(result: dict, label: str = "predator-any") -> int:
    """The run whose smallest ratio to NaivChase against TurnAway over the cells is largest."""
    runs = len(next(p for p in result["pairings"] if p["predator"] == label)["runs"])
    worst = [min(ratios(result, "turnaway", label, ("turnaway", "naivchase"), k), default=0.0) for k in range(runs)]
    return max(range(runs), key=lambda k: worst[k])


def install(folder: str, name: str, out: str, preset: str, seed: int, team: str, entry: dict) -> dict:
    """Copy the training's TorchScript and ONNX files into `folder` as `<name>.pt` / `.onnx` and add its
    index entry (its team, files, world, training range and `entry`'s provenance and evaluation)."""
    from aquarium_warp.atomic import atomic_open
    from aquarium_warp.training.export import policy_world

    os.makedirs(folder, exist_ok=True)
    stem = name.replace("-", "_")
    for kind in ("pt", "onnx"):
        shutil.copyfile(exported(out, preset, seed, team, kind), os.path.join(folder, f"{stem}.{kind}"))
    with open(os.path.join(run_dir(out, preset, seed), "config.json"), encoding="utf-8") as f:
        config = json.load(f)["config"]
    from aquarium_warp.training.config import env_config

    world = env_config({"env": policy_world(os.path.join(folder, f"{stem}.pt"))}).to_dict()
    index_path = os.path.join(folder, "index.json")
    index = {"policies": {}}
    if os.path.isfile(index_path):
        with open(index_path, encoding="utf-8") as f:
            index = json.load(f)
    index["policies"][name] = {
        "team": team,
        "file": f"{stem}.pt",
        "onnx": f"{stem}.onnx",
        **entry,
        "env": world,
        "training_range": dict(config["train"]["randomize"]),
    }
    with atomic_open(index_path) as f:
        json.dump(index, f, indent=1)
        f.write("\n")
    return index["policies"][name]


def grid_phase(args, prey: list[str], predators: list[str], base, cells, report, folder: str, **options) -> tuple:
    """The grid of `prey` against `predators` (`options`: evaluate_grid's `only`, check_targets'
    `specialists`), written to `<out>/<folder>/` with its targets; `(grid, targets)`."""
    from aquarium_warp.training.grid import check_targets, evaluate_grid, write_grid

    only, specialists = options.get("only"), options.get("specialists")
    grid = evaluate_grid(
        prey, predators, base, cells, args.episodes, args.eval_seeds, args.device, report, only=only, commit=args.commit
    )
    targets = check_targets(grid, specialists=specialists)
    write_grid(grid, os.path.join(args.out, folder), targets)
    return grid, targets


def prey_phase(args, prey_any: list[str], coevolved_prey: list[str], base, cells, report) -> tuple:
    """The prey grid (written to `<out>/grid_prey/`), its targets, the shipped seed and its spec (with the
    prey team not trained here: `prey_any` is the given `--prey-any`, no seed, and that spec)."""
    from aquarium_warp import pretrained
    from aquarium_warp.drivers import NO_CONFUSION
    from aquarium_warp.training.grid_cells import BASELINES, cell_of

    specialists = {n: cell_of(pretrained.world(n)) for n in SPECIALISTS if n in pretrained.names("prey")}
    own = {n: [c] for n, c in specialists.items() if c in cells}
    prey = list(BASELINES) + prey_any + (coevolved_prey if args.coevolved else []) + list(own)
    grid, targets = grid_phase(
        args, prey, ["naivchase", NO_CONFUSION], base, cells, report, "grid_prey", only=own, specialists=specialists
    )
    if "prey" not in args.teams:
        return grid, targets, None, prey_any[0]
    shipped = args.seeds[pick_prey(grid)]
    return grid, targets, shipped, f"prey-any={exported(args.out, PREY, shipped, 'prey')}"


def predator_phase(args, picked: str, base, cells, report) -> tuple:
    """The predator grid against TurnAway and `picked` (written to `<out>/grid_predator/`), its targets and
    the shipped seed."""
    trained = "predator" in args.teams
    predator_any = (
        [f"predator-any={exported(args.out, PREDATOR, s, 'predator')}" for s in args.seeds]
        if trained
        else [f"predator-any={args.predator_any}"]
    )
    coevolved = [f"general-predator-coevolved={exported(args.out, BOTH, s, 'predator')}" for s in args.seeds]
    predators = ["naivchase"] + predator_any + (coevolved if args.coevolved else [])
    grid, targets = grid_phase(args, ["turnaway", picked], predators, base, cells, report, "grid_predator")
    return grid, targets, args.seeds[pick_predator(grid)] if trained else None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="runs/general")
    p.add_argument(
        "--device", default="cuda:0", help="device, or a comma list the trainings take in turn (the grid: the first)"
    )
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="training seeds of each preset")
    p.add_argument("--coevolved", action="store_true", help="also train and evaluate --preset general (both teams)")
    p.add_argument(
        "--teams",
        default="prey,predator",
        help="teams to train, evaluate and install: prey, predator or both (a comma list; default both), or "
        "none with --coevolved (the co-evolved pair alone, beside --prey-any and --predator-any)",
    )
    p.add_argument(
        "--prey-any",
        default="prey-any",
        help="without the prey team: the prey policy the predator grid plays as prey-any (a shipped name or "
        "a file; default the shipped prey-any)",
    )
    p.add_argument(
        "--predator-any",
        default="predator-any",
        help="without the predator team: the predator the co-evolved predators are shown beside on the predator "
        "grid, labelled predator-any (a shipped name or a file; default the shipped predator-any)",
    )
    p.add_argument("--jobs", type=int, default=16, help="training processes at once")
    p.add_argument("--set", action="append", default=[], help="a train --set assignment for every training")
    p.add_argument("--episodes", type=int, default=50, help="grid: episodes per cell and evaluation seed")
    p.add_argument("--eval-seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--grid-prey-counts", default="6,16,32,64", help="grid: prey counts (eval --grid's option)")
    p.add_argument("--max-steps", type=int, default=3000, help="grid: steps per episode")
    p.add_argument("--install", default=None, help="policy folder to install into (default: the package's)")
    p.add_argument("--commit", default=None, help="the commit of a copy without git history")
    args = p.parse_args(argv)
    teams = [] if args.teams == "none" else [t for t in args.teams.split(",") if t]
    if not set(teams) <= {"prey", "predator"} or not (teams or args.coevolved):
        p.error(f"--teams={args.teams!r}: a comma list of prey and predator, or none with --coevolved")
    args.teams = teams
    devices = args.device.split(",")
    args.device = devices[0]

    from aquarium_warp import pretrained
    from aquarium_warp.arguments import number_list
    from aquarium_warp.atomic import atomic_open
    from aquarium_warp.records import command_line, git_info, json_safe, machine_info
    from aquarium_warp.training.grid import format_tables, grid_base
    from aquarium_warp.training.grid_cells import FOVS, SPEEDS, VIEWS, grid_cells

    start = time.time()
    presets = [preset for preset, team in ((PREY, "prey"), (PREDATOR, "predator")) if team in teams]
    presets += [BOTH] if args.coevolved else []
    train_all(args.out, presets, args.seeds, devices, args.set, args.jobs, args.commit)
    train_s = time.time() - start
    trainings = []
    if os.path.isfile(os.path.join(args.out, "trainings.jsonl")):
        with open(os.path.join(args.out, "trainings.jsonl"), encoding="utf-8") as f:
            trainings = [json.loads(line) for line in f]
    cells = grid_cells(number_list(args.grid_prey_counts, int, "--grid-prey-counts", 1), VIEWS, FOVS, SPEEDS)
    prey_any = [f"prey-any={exported(args.out, PREY, s, 'prey')}" for s in args.seeds]
    coevolved_prey = [f"general-prey-coevolved={exported(args.out, BOTH, s, 'prey')}" for s in args.seeds]
    given = prey_any if "prey" in teams else [f"prey-any={args.prey_any}"]  # trained here, or given
    base = grid_base(given).replace(max_steps=args.max_steps)
    report = lambda line: print("  " + line, flush=True)  # noqa: E731
    grid_start = time.time()
    prey_grid, prey_targets, shipped_prey = None, [], None
    picked = f"prey-any={args.prey_any}"
    if "prey" in teams or args.coevolved:
        prey_grid, prey_targets, shipped_prey, picked = prey_phase(args, given, coevolved_prey, base, cells, report)
    predator_grid, predator_targets, shipped_predator = None, [], None
    if "predator" in teams or args.coevolved:
        predator_grid, predator_targets, shipped_predator = predator_phase(args, picked, base, cells, report)
    grid_s = time.time() - grid_start
    for grid in (prey_grid, predator_grid):
        for line in format_tables(grid) if grid else []:
            print(line)
    for t in prey_targets + predator_targets:
        print(f"target {t['target']}: {'met' if t['met'] else 'FAILED'} ({t['cells']} cells)")
        for failing in t["failing"]:
            print(f"  fails in {failing}")
    git = git_info(args.commit)
    device = machine_info(args.device)
    folder = args.install or pretrained.DIRECTORY
    protocol = (
        f"captures per prey per episode on the evaluation grid ({len(cells)} cells), {args.episodes} episodes x "
        f"evaluation seeds {' '.join(map(str, args.eval_seeds))}, argmax actions, spawn_heading 'paper'"
    )
    entries = {}
    for name, preset, seed, team, rule in (
        ("prey-any", PREY, shipped_prey, "prey", pick_prey.__doc__),
        ("predator-any", PREDATOR, shipped_predator, "predator", pick_predator.__doc__),
    ):
        if team not in teams:
            continue
        entries[name] = install(
            folder,
            name,
            args.out,
            preset,
            seed,
            team,
            {
                "description": f"PPO {team} (parameter sharing) for any world of its training range (the "
                f"learned-prey recipe over randomised worlds, --preset {preset}); training seed {seed} of "
                f"{len(args.seeds)}, picked by the rule: {rule}",
                "train_command": "aquarium-warp "
                + " ".join(train_command(args.out, preset, seed, args.device, args.set)[3:]),
                "commit": git.get("commit"),
                "device": device.get("device_name"),
                "evaluation": {
                    "protocol": protocol,
                    "targets": [
                        t
                        for t in (prey_targets if team == "prey" else predator_targets)
                        if t["target"].startswith(name)
                    ],
                    "results": os.path.join(args.out, f"grid_{team}"),
                },
            },
        )
    record = {
        "command": command_line(
            ["benchmarks/general_policies.py", *(argv if argv is not None else sys.argv[1:])],
            os.path.basename(sys.executable),
        ),  # fmt: skip
        "git": git,
        "machine": device,
        "train_wall_s": round(train_s, 1),
        "grid_wall_s": round(grid_s, 1),
        "wall_s": round(time.time() - start, 1),
        "trainings": trainings,
        "shipped": {"prey-any": shipped_prey, "predator-any": shipped_predator},
        "targets": prey_targets + predator_targets,
        "installed": {name: os.path.join(folder, e["file"]) for name, e in entries.items()},
    }
    with atomic_open(os.path.join(args.out, "general_policies.json")) as f:
        json.dump(json_safe(record), f, indent=1)
    print(
        f"trainings {train_s:.0f} s, grid {grid_s:.0f} s, all {time.time() - start:.0f} s; shipped prey seed "
        f"{shipped_prey}, predator seed {shipped_predator} (None: not trained here) into {folder}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
