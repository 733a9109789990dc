"""End-to-end training agent-steps per second on 1, 2, ... GPUs of one host (`torchrun`, rsl-rl's
multi-GPU path), one learning team and both teams, with the update captured in CUDA graphs or eager.

Each point is `python -m torch.distributed.run --standalone --nproc_per_node=G -m aquarium_warp train
...` with `--num-worlds` worlds per rank, run for `--iterations` iterations; its speed is the median of
the `fps` column (agent-steps of every rank per second of the iteration) of rank 0's progress CSV over
the iterations after the first two (Warp compilation, warm-up). `--set KEY=VALUE` (repeatable) passes a
run setting to every point, e.g. `--set train.fused_mlp=true --set train.tf32=true`. `--modes` picks
the loops measured:

- `graphs`: rollout and update replayed from CUDA graphs, the defaults (`train.graph_update="auto"`:
  one GPU captures the update as one graph, several GPUs as graphs cut at its all-reduces, which run
  eagerly between them);
- `whole-update`: on several GPUs the update captured as one graph with its NCCL all-reduce inside
  (`train.graph_update=true`);
- `eager-update`: the rollout from CUDA graphs, the update eager (`train.graph_update=false`) - with
  `graphs`, the gain of capturing the update;
- `eager`: no graphs (`train.cuda_graphs=false`), on one GPU only (the loop before any graphs).

Every point records what its run captured (its `config.json`'s `cuda_graphs`), and its speed-up
against one GPU of the `graphs` mode and of its own mode, with the ideal (linear) speed-up and the
fraction of it reached (`aquarium_warp.bench.floors.linear_scaling`). On the CPU (gloo) only
`eager` runs, at every count.

    python benchmarks/bench_multi_gpu.py --gpus 1,2,4 --teams prey,both --out-dir DIR
    python benchmarks/bench_multi_gpu.py --device cpu --gpus 1,2 --num-worlds 16 --iterations 4   # gloo

Writes `multi_gpu_<device>.json` atomically (the command, the commit: `--commit` where git is not
available, the machine and the library versions) after every point, with the points so far, so that a
time limit that ends the script keeps what was measured; prints each point as it ends and a table at
the end. A point whose run fails or exceeds `--timeout` (a failed capture raises in the run; a run
past its time is killed with every rank) is printed with its error, kept in the JSON as such, and makes
the exit status 1.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.arguments import parse_list
from aquarium_warp.atomic import atomic_open
from aquarium_warp.bench.floors import linear_scaling
from aquarium_warp.records import command_line, provenance

# mode -> the train settings of its runs ("graphs" opts in to the captured update on several GPUs)
MODES = {
    "graphs": {"cuda_graphs": True, "graph_update": "auto"},
    "whole-update": {"cuda_graphs": True, "graph_update": True},
    "eager-update": {"cuda_graphs": True, "graph_update": False},
    "eager": {"cuda_graphs": False},
}


def process_tree(pid: int) -> list[int]:
    """`pid` and every process below it (read from Linux's /proc). torchrun starts each rank in a session
    of its own, which a signal to the launcher or its process group misses."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])  # after the command name
        except (OSError, IndexError, ValueError):  # a process that ended meanwhile
            continue
        children.setdefault(parent, []).append(int(stat.parent.name))
    tree, todo = [], [pid]
    while todo:
        tree.append(todo.pop())
        todo += children.get(tree[-1], [])
    return tree


def signal_tree(pid: int, sig: int) -> None:
    """Send `sig` to `pid` and every process below it; a hung rank would go on holding its GPU (and
    the output pipes this script reads to their end)."""
    for p in process_tree(pid):
        with contextlib.suppress(ProcessLookupError):
            os.kill(p, sig)


def run_ranks(command: list[str], env: dict, timeout: float) -> tuple[str, str, float]:
    """Run `command` (a torchrun launcher) to its end: `(stdout, stderr, seconds)`. A RuntimeError names
    a failed run with its output's end, or a run past `timeout` seconds with where its ranks waited:
    the launcher's children get SIGABRT, on which Python's faulthandler prints every thread's stack,
    then the whole tree SIGKILL."""
    started = time.perf_counter()
    env = {**env, "PYTHONFAULTHANDLER": "1"}
    with subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as run:
        try:
            stdout, stderr = run.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            # The ranks (not the launcher, which would stop them first) print their threads' stacks.
            for p in process_tree(run.pid)[1:]:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p, signal.SIGABRT)
            time.sleep(5)
            signal_tree(run.pid, signal.SIGKILL)
            stdout, stderr = run.communicate()
            raise RuntimeError(
                f"timed out after {timeout:g} s; where the ranks waited (SIGABRT):\n{stderr[-20000:]}"
            ) from None
    if run.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{stdout[-2000:]}\n{stderr[-4000:]}")
    return stdout, stderr, time.perf_counter() - started


def run_point(gpus: int, team: str, mode: str, args: argparse.Namespace) -> dict:
    """One torchrun training run; its median agent-steps/s and the graphs it captured."""
    log_dir = tempfile.mkdtemp(prefix=f"multi_{team}_{gpus}_")
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        f"--nproc_per_node={gpus}",
        "-m",
        "aquarium_warp",
        "train",
        "--team",
        team,
        "--num-worlds",
        str(args.num_worlds),
        "--iterations",
        str(args.iterations),
        "--log-dir",
        log_dir,
        "--quiet",
        "--export",
        "none",
        "--device",
        "cpu" if args.device == "cpu" else "cuda",
    ]
    for key, value in MODES[mode].items():
        command += ["--set", f"train.{key}={str(value).lower()}"]
    for setting in args.set:  # the same settings at every point (e.g. train.fused_mlp=true)
        command += ["--set", setting]
    env = {**os.environ, "NCCL_NVLS_ENABLE": "0", "OMP_NUM_THREADS": "1"}
    env.pop("WORLD_SIZE", None)
    stdout, stderr, wall = run_ranks(command, env, args.timeout)
    name = "progress.csv" if team != "both" else "progress_prey.csv"
    with open(os.path.join(log_dir, name), newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    with open(os.path.join(log_dir, "config.json"), encoding="utf-8") as f:
        saved = json.load(f)
    captured = saved["cuda_graphs"]
    fps = [float(r["fps"]) for r in rows[2:]] or [float(r["fps"]) for r in rows]
    return {
        "gpus": gpus,
        "team": team,
        "mode": mode,
        "settings": MODES[mode],
        "captured": captured,
        "fused_loss": saved.get("fused_loss"),
        "fused_act": saved.get("fused_act"),
        "iterations": len(rows),
        "agent_steps_per_s": statistics.median(fps),
        "wall_seconds": wall,
        "agent_steps": int(float(rows[-1]["agent_steps"])),
    }


def add_scaling(points: list[dict]) -> None:
    """Each point's speed-up against one GPU of the `graphs` mode and of its own mode, with the ideal."""
    for point in points:
        for key, mode in (("vs_one_graphs", "graphs"), ("vs_one_same_mode", point["mode"])):
            base = [
                q
                for q in points
                if q["team"] == point["team"] and q["gpus"] == 1 and q["mode"] == mode and "error" not in q
            ]
            ok = base and "error" not in point
            point[key] = (
                linear_scaling(point["gpus"], base[0]["agent_steps_per_s"], point["agent_steps_per_s"]) if ok else None
            )


def graph_update_gains(points: list[dict]) -> list[dict]:
    """Per team and GPU count: the update captured against the update eager (`graphs` over `eager-update`)."""
    out = []
    for point in points:
        if point["mode"] != "graphs" or "error" in point:
            continue
        eager = [
            q
            for q in points
            if q["mode"] == "eager-update"
            and q["team"] == point["team"]
            and q["gpus"] == point["gpus"]
            and "error" not in q
        ]
        if eager:
            out.append(
                {
                    "team": point["team"],
                    "gpus": point["gpus"],
                    "graphs": point["agent_steps_per_s"],
                    "eager_update": eager[0]["agent_steps_per_s"],
                    "speedup": point["agent_steps_per_s"] / eager[0]["agent_steps_per_s"],
                }
            )
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--gpus", default="1,2", help="process counts, e.g. 1,2,4,8")
    p.add_argument("--teams", default="prey,both", help="learning teams: prey, predator and/or both")
    p.add_argument("--modes", default="graphs,eager-update,eager", help=f"loops measured: {', '.join(MODES)}")
    p.add_argument("--num-worlds", type=int, default=4096, help="worlds per rank")
    p.add_argument("--iterations", type=int, default=12, help="training iterations per point")
    p.add_argument("--device", default="cuda", help="'cuda' (rank r on cuda:r) or 'cpu' (gloo)")
    p.add_argument("--timeout", type=float, default=300, help="seconds per point")
    p.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="a run setting for every point (repeatable)"
    )
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    p.add_argument("--out-dir", default=".", help="where the JSON goes")
    args = p.parse_args(argv)
    try:
        gpus = parse_list(args.gpus, int, name="--gpus", minimum=1)
    except ValueError as error:
        p.error(str(error))
    teams = [t.strip() for t in args.teams.split(",")]
    if bad := [t for t in teams if t not in ("prey", "predator", "both")]:
        p.error(f"--teams: {bad} are not teams (prey, predator, both)")
    modes = [m.strip() for m in args.modes.split(",")]
    if bad := [m for m in modes if m not in MODES]:
        p.error(f"--modes: {bad} are not modes ({', '.join(MODES)})")
    cuda = args.device != "cpu"
    if not cuda:
        modes = ["eager"]  # the CPU captures no graphs
    import torch

    record = {
        "benchmark": "multi_gpu_training",
        "device_name": torch.cuda.get_device_name(0) if cuda and torch.cuda.is_available() else "cpu",
        "settings": vars(args),
        "points": [],
        "graph_update_gains": [],
        "torch": torch.__version__,
        # command, git (commit, dirty) and machine (device, driver, versions)
        **provenance("cuda:0" if cuda else "cpu", command_line(argv, Path(__file__).name), args.commit),
    }
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"multi_gpu_{'cuda' if cuda else 'cpu'}.json"
    points = record["points"]
    for team in teams:
        for g in gpus:
            # one GPU: no eager point beside graphs, and no all-reduce to capture (whole-update = graphs)
            for mode in (m for m in modes if (m != "eager" or g == 1 or not cuda) and (m != "whole-update" or g > 1)):
                try:
                    point = run_point(g, team, mode, args)
                except RuntimeError as error:  # reported, not fatal
                    point = {"gpus": g, "team": team, "mode": mode, "error": str(error)[-20000:]}
                    print(f"{team:>5} {g} GPU{'s' if g > 1 else ' '} {mode:>12} failed:\n{point['error']}", flush=True)
                else:
                    print(
                        f"{team:>5} {g} GPU{'s' if g > 1 else ' '} {mode:>12} "
                        f"{point['agent_steps_per_s']:.3g} agent-steps/s ({point['wall_seconds']:.0f} s), "
                        f"captured {point['captured']}",
                        flush=True,
                    )
                points.append(point)
                add_scaling(points)
                record["graph_update_gains"] = graph_update_gains(points)
                with atomic_open(path) as f:  # after every point: a time limit keeps what was measured
                    json.dump(record, f, indent=2)
    gains = record["graph_update_gains"]
    print(
        f"\n{'team':>5} {'GPUs':>4} {'mode':>12} {'agent-steps/s':>14} {'vs 1 graphs':>11} {'of ideal':>8} "
        f"{'vs 1 same':>9} {'of ideal':>8}"
    )
    for q in points:
        if "error" in q:
            print(f"{q['team']:>5} {q['gpus']:>4} {q['mode']:>12} {'failed':>14}")
            continue
        cells = []
        for key in ("vs_one_graphs", "vs_one_same_mode"):
            s = q[key]
            cells += [f"{s['speedup']:.2f}x", f"{100 * s['fraction_of_ideal']:.0f}%"] if s else ["-", "-"]
        print(
            f"{q['team']:>5} {q['gpus']:>4} {q['mode']:>12} {q['agent_steps_per_s']:>14.3g} {cells[0]:>11} "
            f"{cells[1]:>8} {cells[2]:>9} {cells[3]:>8}"
        )
    for gain in gains:
        print(
            f"update captured vs eager, {gain['team']}, {gain['gpus']} GPU{'s' if gain['gpus'] > 1 else ''}: "
            f"{gain['graphs']:.3g} / {gain['eager_update']:.3g} agent-steps/s = {gain['speedup']:.2f}x"
        )
    print(f"wrote {path}")
    failed = [q for q in points if "error" in q]
    if failed:
        print(f"{len(failed)} point(s) failed: see their errors above and in the JSON", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
