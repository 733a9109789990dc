"""Time of each launch of the step program, for one configuration (CUDA events on GPU, wall clock on CPU).

    python benchmarks/stage_times.py --device cuda:0 --worlds 65536 [--agents 17] [--step-kernel stages]

Prints one line per command of `WorldShard.step_program` (median over `--repeats` steps) and the
whole step replayed as a graph. A profiling aid for the step's cost breakdown: worlds of one cell
take the fused step (one command) unless `--step-kernel stages` asks for a launch per stage.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import torch
import warp as wp

from aquarium_warp import BatchedAquarium
from aquarium_warp.bench import command_name, density_config
from aquarium_warp.rollout import random_actions


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--worlds", type=int, default=1024)
    parser.add_argument("--agents", type=int, default=17, help="agents per world at the default density")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--cell-size", type=float, default=None, help="grid_cell_size (default: chosen by the env)")
    parser.add_argument(
        "--step-kernel",
        default="auto",
        choices=("auto", "fused", "stages"),
        help="the env's step_kernel option (default auto: fused on worlds of one cell)",
    )
    args = parser.parse_args(argv)
    if args.worlds < 1:
        parser.error(f"--worlds must be >= 1, got {args.worlds}")
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    cfg = density_config(args.agents)  # 17 agents: the default config
    if args.cell_size is not None:
        cfg = dataclasses.replace(cfg, grid_cell_size=args.cell_size)
    env = BatchedAquarium(
        cfg, num_worlds=args.worlds, device=args.device, seed=0, cpu_threads=1, step_kernel=args.step_kernel
    )
    cuda = wp.get_device(env.device).is_cuda
    gen = torch.Generator(device=env.torch_device).manual_seed(0)
    actions = random_actions(cfg, args.worlds, gen, env.torch_device)
    for _ in range(3):
        env.step(actions, validate=False)
    program = env.shards[0].programs["step"]
    times = [[] for _ in program]
    stream = wp.get_stream(env.device) if cuda else None  # the recorded launches run on the env device's stream
    for _ in range(args.repeats):
        for i, command in enumerate(program):
            if cuda:
                start, end = wp.Event(env.device, enable_timing=True), wp.Event(env.device, enable_timing=True)
                stream.record_event(start)
                command()
                stream.record_event(end)
                wp.synchronize_device(env.device)
                times[i].append(wp.get_event_elapsed_time(start, end))
            else:
                t = time.perf_counter()
                command()
                times[i].append((time.perf_counter() - t) * 1e3)
    agents = args.worlds * cfg.capacity
    total = 0.0
    print(
        f"{args.worlds} worlds x {cfg.capacity} agents on {env.device}, "
        f"{env.grid_dims[0]} x {env.grid_dims[1]} cells per world"
    )
    for command, samples in zip(program, times):
        ms = statistics.median(samples)
        total += ms
        print(f"  {command_name(command):40s} {ms:8.4f} ms  {ms * 1e6 / agents:7.3f} ns/agent")
    print(f"  {'sum of commands':40s} {total:8.4f} ms")
    if cuda:
        runs = []  # runs of `repeats` back-to-back steps (as the graph replays them), one sync per run
        for _ in range(5):
            torch.cuda.synchronize(env.torch_device)
            t = time.perf_counter()
            for _ in range(args.repeats):
                env.step(actions, validate=False)
            torch.cuda.synchronize(env.torch_device)
            runs.append((time.perf_counter() - t) * 1e3 / args.repeats)
        ms = statistics.median(runs)
        print(f"  {'step() as a CUDA graph':40s} {ms:8.4f} ms  {agents / ms * 1e3:.3e} agent-steps/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
