"""Agent-steps per second of `BatchedAquarium.step()` (random actions, observations on), with the
original marl-aquarium 0.1.10 measured in the same run.

Points: the default config with 1, 64 and 1024 worlds; one world of about 1k, 10k and 100k agents at
the default density (16 prey per predator, 17 agents per 800 x 800 px); the same with
`fov_enabled=False`, and with `fov_enabled=False` plus unlimited view distance.
Each point: warm-up, then `--repeats` timed runs of at least `--seconds`; the median is reported
(on CUDA the step is a graph and timing is synchronised).

    python benchmarks/bench_step.py [--device cpu] [--seconds 2] [--repeats 5] [--no-original]
        [--step-kernel stages fused]

`--step-kernel` names the env's step paths to measure, each point with each ("auto", the default,
takes the fused step on worlds of one cell, "stages" a launch per stage; "fused" skips the points it
does not apply to); rows record the path that ran (`step_kernel`), and with both "stages" and
"fused" the checks give the fused step's speed-up at 1024 default worlds.

On the CPU it also times the PettingZoo `aquarium_v1.parallel_env` (one default world).
Prints a table and writes benchmarks/results/step_<device>.json. Targets: at least 1000x the
original's agent-steps/s at 1024 default worlds, per-agent time within 1.5x from 1k to 100k agents,
and the PettingZoo env at least 20x the original's env-steps/s.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.bench import density_config, timed_runs
from aquarium_warp.env import grid_dims
from aquarium_warp.records import command_line, git_info
from aquarium_warp.rollout import random_actions
from aquarium_warp.shard import fused_step

RESULTS = Path(__file__).resolve().parent / "results"


def unlimited(cfg: AquariumConfig) -> AquariumConfig:
    return dataclasses.replace(
        cfg,
        fov_enabled=False,
        prey=dataclasses.replace(cfg.prey, view_distance=math.inf),
        predator=dataclasses.replace(cfg.predator, view_distance=math.inf),
    )


def measure(
    cfg: AquariumConfig, worlds: int, device: str, seconds: float, repeats: int, step_kernel: str = "auto"
) -> dict:
    env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=0, step_kernel=step_kernel)
    gen = torch.Generator(device=env.torch_device).manual_seed(0)
    pool = [random_actions(cfg, worlds, gen, env.torch_device) for _ in range(8)]
    sync = (lambda: torch.cuda.synchronize(env.torch_device)) if env.torch_device.type == "cuda" else (lambda: None)
    for i in range(5):
        env.step(pool[i % 8], validate=False)
    sync()
    start = time.perf_counter()
    env.step(pool[0], validate=False)
    sync()
    first = time.perf_counter() - start
    per_step = timed_runs(lambda i: env.step(pool[i % 8], validate=False), sync, seconds, repeats, first)
    step_time = statistics.median(per_step)
    agents = worlds * cfg.capacity
    path = env.step_kernel
    env.close()
    return {
        "step_kernel": path,
        "worlds": worlds,
        "agents_per_world": cfg.capacity,
        "agents": agents,
        "step_ms": step_time * 1e3,
        "agent_steps_per_s": agents / step_time,
        "ns_per_agent_step": step_time / agents * 1e9,
        "runs_step_ms": [t * 1e3 for t in per_step],
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--max-agents", type=int, default=100_000)
    parser.add_argument("--no-original", action="store_true", help="skip the original marl-aquarium")
    parser.add_argument(
        "--large",
        action="store_true",
        help="add GPU-sized points: 4096 and 65536 default worlds, one world of 1M agents",
    )
    parser.add_argument(
        "--step-kernel",
        nargs="+",
        default=["auto"],
        choices=("auto", "fused", "stages"),
        help="step paths to measure at every point (default: auto)",
    )
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")

    points = [("default", AquariumConfig(), w) for w in ((1, 64, 1024, 4096, 65536) if args.large else (1, 64, 1024))]
    for label, make in (
        ("density", density_config),
        ("density fov off", lambda n: density_config(n, fov_enabled=False)),
        ("density fov off, unlimited view", lambda n: unlimited(density_config(n))),
    ):
        sizes = (1_000, 10_000, 100_000) + ((1_000_000,) if args.large else ())
        points += [(label, make(n), 1) for n in sizes if n <= args.max_agents]
    rows = []
    for label, cfg, worlds in points:
        for step_kernel in args.step_kernel:
            if step_kernel == "fused" and not fused_step("auto", grid_dims(cfg)):
                continue  # worlds of several cells: only the staged step applies
            row = {"config": label, **measure(cfg, worlds, args.device, args.seconds, args.repeats, step_kernel)}
            rows.append(row)
            print(
                f"{label:34s} {row['worlds']:6d} x {row['agents_per_world']:7d} {row['step_kernel']:6s} "
                f"{row['step_ms']:9.3f} ms  {row['agent_steps_per_s']:11.3e} agent-steps/s  "
                f"{row['ns_per_agent_step']:8.1f} ns/agent",
                flush=True,
            )

    pettingzoo = None
    if args.device == "cpu":
        from bench_pettingzoo import measure_ours

        pettingzoo = measure_ours("parallel", seconds=max(2.0, args.seconds), repeats=3, warmup=1.0)
        print(
            f"{'aquarium_v1.parallel_env (PettingZoo)':34s} {1:6d} x {17:7d}  "
            f"{1e3 / pettingzoo['env_steps_per_s']:9.3f} ms  {pettingzoo['agent_steps_per_s']:11.3e} agent-steps/s"
        )

    original = None
    if not args.no_original:
        from original_aquarium import measure_original

        original = measure_original(seconds=max(5.0, args.seconds * 2), repeats=3, which="raw")
        print(
            f"{'original marl-aquarium 0.1.10':34s} {1:6d} x {17:7d}  "
            f"{1e3 / original['env_steps_per_s']:9.3f} ms  {original['agent_steps_per_s']:11.3e} agent-steps/s"
        )

    checks = {}
    # The checks read each point's first measured path (the first --step-kernel that applies).
    by: dict = {}
    for r in rows:
        by.setdefault((r["config"], r["worlds"], r["agents_per_world"]), r)
    paths = {(r["config"], r["worlds"], r["step_kernel"]): r for r in rows}
    if ("default", 1024, "stages") in paths and ("default", 1024, "fused") in paths:
        checks["fused_step_speedup_1024_worlds"] = (
            paths[("default", 1024, "stages")]["step_ms"] / paths[("default", 1024, "fused")]["step_ms"]
        )
    if original:
        big = by[("default", 1024, 17)]["agent_steps_per_s"]
        checks["speedup_1024_worlds_vs_original"] = big / original["agent_steps_per_s"]
        checks["speedup_1024_worlds_target"] = 1000.0
        if pettingzoo:
            checks["pettingzoo_env_steps_speedup_vs_original"] = (
                pettingzoo["env_steps_per_s"] / original["env_steps_per_s"]
            )
            checks["pettingzoo_env_steps_speedup_target"] = 20.0
    for label in ("density", "density fov off", "density fov off, unlimited view"):
        series = [r for key, r in by.items() if key[0] == label]
        if len(series) >= 2:
            checks[f"per_agent_ratio_{label}"] = series[-1]["ns_per_agent_step"] / series[0]["ns_per_agent_step"]
    print("\nchecks:")
    for key, value in checks.items():
        print(f"  {key}: {value:.2f}")

    device = wp.get_device(args.device)
    result = {
        "device": args.device,
        "device_name": device.name if device.is_cuda else platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "warp": wp.__version__,
        "torch": torch.__version__,
        "git": git_info(),
        "command": command_line(argv, Path(__file__).name),
        "seconds": args.seconds,
        "repeats": args.repeats,
        "step_kernels": args.step_kernel,
        "rows": rows,
        "pettingzoo_parallel_env": pettingzoo,
        "original": original,
        "checks": checks,
    }
    out = Path(args.out) if args.out else RESULTS / f"step_{args.device.replace(':', '')}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
