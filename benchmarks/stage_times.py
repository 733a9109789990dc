"""Time of each launch of the step program, for one configuration (CUDA events on GPU, wall clock on CPU).

    python benchmarks/stage_times.py --device cuda:0 --worlds 65536 [--agents 17]

Prints one line per command of `WorldShard._step_program` (median over `--repeats` steps) and the
whole step replayed as a graph. A profiling aid for the step's cost breakdown.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import torch
import warp as wp

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.bench import density_config


def command_name(command) -> str:
    launch = getattr(command, "__self__", None)
    if launch is not None and hasattr(launch, "kernel"):
        return launch.kernel.key
    return getattr(getattr(command, "func", command), "__name__", "command")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--worlds", type=int, default=1024)
    parser.add_argument("--agents", type=int, default=17, help="agents per world at the default density")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--cell-size", type=float, default=None, help="grid_cell_size (default: chosen by the env)")
    args = parser.parse_args(argv)
    cfg = AquariumConfig() if args.agents == 17 else density_config(args.agents)
    if args.cell_size is not None:
        cfg = dataclasses.replace(cfg, grid_cell_size=args.cell_size)
    env = BatchedAquarium(cfg, num_worlds=args.worlds, device=args.device, seed=0, cpu_threads=1)
    cuda = wp.get_device(env.device).is_cuda
    gen = torch.Generator(device=env.torch_device).manual_seed(0)
    actions = {"prey": torch.randint(0, 16, (args.worlds, env.prey_capacity), generator=gen, device=env.torch_device),
               "predator": torch.randint(0, 16, (args.worlds, env.predator_count), generator=gen, device=env.torch_device)}
    for _ in range(3):
        env.step(actions, validate=False)
    program = env.shards[0].programs["step"]
    times = [[] for _ in program]
    for _ in range(args.repeats):
        for i, command in enumerate(program):
            if cuda:
                start, end = wp.Event(enable_timing=True), wp.Event(enable_timing=True)
                wp.record_event(start)
                command()
                wp.record_event(end)
                wp.synchronize_device(env.device)
                times[i].append(wp.get_event_elapsed_time(start, end))
            else:
                t = time.perf_counter()
                command()
                times[i].append((time.perf_counter() - t) * 1e3)
    agents = args.worlds * cfg.capacity
    total = 0.0
    print(f"{args.worlds} worlds x {cfg.capacity} agents on {env.device}, {env._dims[0]} x {env._dims[1]} cells per world")
    for command, samples in zip(program, times):
        ms = statistics.median(samples)
        total += ms
        print(f"  {command_name(command):40s} {ms:8.4f} ms  {ms * 1e6 / agents:7.3f} ns/agent")
    print(f"  {'sum of commands':40s} {total:8.4f} ms")
    if cuda:
        runs = []  # runs of `repeats` back-to-back steps (as the graph replays them), one sync per run
        for _ in range(5):
            torch.cuda.synchronize()
            t = time.perf_counter()
            for _ in range(args.repeats):
                env.step(actions, validate=False)
            torch.cuda.synchronize()
            runs.append((time.perf_counter() - t) * 1e3 / args.repeats)
        ms = statistics.median(runs)
        print(f"  {'step() as a CUDA graph':40s} {ms:8.4f} ms  {agents / ms * 1e3:.3e} agent-steps/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
