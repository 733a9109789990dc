"""End-to-end training agent-steps per second on 1, 2, ... GPUs of one host (`torchrun`, rsl-rl's
multi-GPU path), one learning team and both teams.

Each point is `python -m torch.distributed.run --standalone --nproc_per_node=G -m aquarium_warp train
...` with `--num-worlds` worlds per rank, run for `--iterations` iterations; its speed is the median of
the `fps` column (agent-steps of every rank per second of the iteration) of rank 0's progress CSV over
the iterations after the first two (Warp compilation, warm-up). On GPUs every count runs the default
loop (`train.cuda_graphs=true`: one process captures the rollout and the update, several processes the
rollout only, their update with its all-reduce eager, since 3fc8de5), and one GPU runs once more
eagerly (`train.cuda_graphs=false`); each point's speed-up is given against both one-GPU runs.

    python benchmarks/bench_multi_gpu.py --gpus 1,2 --teams prey,both --out-dir DIR
    python benchmarks/bench_multi_gpu.py --device cpu --gpus 1,2 --num-worlds 16 --iterations 4   # gloo

Writes `multi_gpu_<device>.json` and prints a table.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.arguments import parse_list
from aquarium_warp.records import command_line, git_info, machine_info


def run_point(gpus: int, team: str, graphs: bool, args: argparse.Namespace) -> dict:
    """One torchrun training run; its median agent-steps/s."""
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
        "--device",
        "cpu" if args.device == "cpu" else "cuda",
        "--set",
        f"train.cuda_graphs={'true' if graphs else 'false'}",
    ]
    env = {**os.environ, "NCCL_NVLS_ENABLE": "0", "OMP_NUM_THREADS": "1"}
    env.pop("WORLD_SIZE", None)
    started = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=args.timeout)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
    name = "progress.csv" if team != "both" else "progress_prey.csv"
    with open(os.path.join(log_dir, name), newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    fps = [float(r["fps"]) for r in rows[2:]] or [float(r["fps"]) for r in rows]
    return {
        "gpus": gpus,
        "team": team,
        "cuda_graphs": graphs,
        "iterations": len(rows),
        "agent_steps_per_s": statistics.median(fps),
        "wall_seconds": wall,
        "agent_steps": int(float(rows[-1]["agent_steps"])),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--gpus", default="1,2", help="process counts, e.g. 1,2,4,8")
    p.add_argument("--teams", default="prey,both", help="learning teams: prey, predator and/or both")
    p.add_argument("--num-worlds", type=int, default=4096, help="worlds per rank")
    p.add_argument("--iterations", type=int, default=12, help="training iterations per point")
    p.add_argument("--device", default="cuda", help="'cuda' (rank r on cuda:r) or 'cpu' (gloo)")
    p.add_argument("--timeout", type=float, default=300, help="seconds per point")
    p.add_argument("--out-dir", default=".", help="where the JSON goes")
    args = p.parse_args(argv)
    try:
        gpus = parse_list(args.gpus, int, name="--gpus", minimum=1)
    except ValueError as error:
        p.error(str(error))
    teams = [t.strip() for t in args.teams.split(",")]
    if bad := [t for t in teams if t not in ("prey", "predator", "both")]:
        p.error(f"--teams: {bad} are not teams (prey, predator, both)")
    import torch

    points = []
    for team in teams:
        for g in gpus:
            cuda = args.device != "cpu"
            for graphs in (True, False) if g == 1 and cuda else (True,) if cuda else (False,):
                point = run_point(g, team, graphs, args)
                points.append(point)
                print(
                    f"{team:>5} {g} GPU{'s' if g > 1 else ' '} graphs={str(graphs):5} "
                    f"{point['agent_steps_per_s']:.3g} agent-steps/s ({point['wall_seconds']:.0f} s)",
                    flush=True,
                )
    for point in points:
        for key, graphs in (("speedup_vs_one_eager", False), ("speedup_vs_one_graphs", True)):
            base = [q for q in points if q["team"] == point["team"] and q["gpus"] == 1 and q["cuda_graphs"] == graphs]
            point[key] = point["agent_steps_per_s"] / base[0]["agent_steps_per_s"] if base else None
    name = torch.cuda.get_device_name(0) if args.device != "cpu" and torch.cuda.is_available() else "cpu"
    result = {
        "benchmark": "multi_gpu_training",
        "device_name": name,
        "settings": vars(args),
        "points": points,
        "torch": torch.__version__,
        "command": command_line(argv, Path(__file__).name),
        "git": git_info(),
        "machine": machine_info("cpu" if args.device == "cpu" else "cuda:0"),
    }
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"multi_gpu_{'cpu' if args.device == 'cpu' else 'cuda'}.json"
    path.write_text(json.dumps(result, indent=2))
    print(f"\n{'team':>5} {'GPUs':>4} {'graphs':>6} {'agent-steps/s':>14} {'vs 1 eager':>10} {'vs 1 graphs':>11}")
    for q in points:
        ratios = [f"{q[k]:.2f}" if q[k] else "-" for k in ("speedup_vs_one_eager", "speedup_vs_one_graphs")]
        print(
            f"{q['team']:>5} {q['gpus']:>4} {str(q['cuda_graphs']):>6} {q['agent_steps_per_s']:>14.3g} "
            f"{ratios[0]:>10} {ratios[1]:>11}"
        )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
