"""Per-world parameters: what they cost, and what a sweep in one batch saves (issue 18).

1. The step of W worlds of 16 prey + 1 predator with per-world parameters (every per-type value and
   the rewards drawn per world) against the same batch with the uniform config.
2. A swarm-size sweep (prey counts) and a FOV x view-distance sweep: one batch holding every setting
   (R worlds each) against one batch per setting (R worlds), wall time of construction + steps.

    python benchmarks/bench_per_world.py --device cuda:0 --out per_world.json   # H200: the full sizes
    python benchmarks/bench_per_world.py --device cpu                          # tiny check
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.device import synchronize
from aquarium_warp.per_world import Uniform
from aquarium_warp.records import command_line, git_info, machine_info


def step_time(env: BatchedAquarium, steps: int, warmup: int = 10) -> float:
    """Seconds per step, random actions written into the env's buffers (no host check)."""
    gen = torch.Generator(device=env.torch_device).manual_seed(0)
    for t in ("prey", "predator"):
        env.actions[t].copy_(
            torch.randint(0, 16, env.actions[t].shape, generator=gen, device=env.torch_device, dtype=torch.int32)
        )
    for _ in range(warmup):
        env.step(validate=False)
    synchronize(env.device)
    start = time.perf_counter()
    for _ in range(steps):
        env.step(validate=False)
    synchronize(env.device)
    return (time.perf_counter() - start) / steps


def run_batch(cfg: AquariumConfig, worlds: int, device: str, steps: int) -> float:
    """Wall time of building a batch and stepping it `steps` times."""
    synchronize(device)
    start = time.perf_counter()
    env = BatchedAquarium(cfg, worlds, device=device, seed=0)
    for _ in range(steps):
        env.step(validate=False)
    synchronize(device)
    elapsed = time.perf_counter() - start
    env.close()
    return elapsed


def per_world_config(base: AquariumConfig) -> AquariumConfig:
    """Every per-type value and the rewards drawn per world around the defaults."""

    def spread(t):
        return dataclasses.replace(
            t,
            max_speed=Uniform(0.5 * t.max_speed, 1.5 * t.max_speed),
            max_acceleration=Uniform(0.5 * t.max_acceleration, 1.5 * t.max_acceleration),
            mass=Uniform(0.5 * t.mass, 1.5 * t.mass),
            radius=Uniform(0.5 * t.radius, t.radius),
            view_distance=Uniform(0.5 * t.view_distance, t.view_distance),
            fov_angle=Uniform(60.0, 360.0),
        )

    return dataclasses.replace(
        base,
        prey=spread(base.prey),
        predator=spread(base.predator),
        prey_reward=Uniform(0.5, 2.0),
        predator_reward=Uniform(5.0, 20.0),
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--out", default="bench_per_world.json")
    args = parser.parse_args(argv)
    cpu = args.device == "cpu"
    # CPU: a tiny check of the script; GPU: the sizes.
    worlds, steps = (256, 20) if cpu else (65536, 200)
    sizes = (4, 16, 64) if cpu else (4, 16, 64, 256, 1024, 4096)
    repeats, sweep_steps = (4, 20) if cpu else (16, 200)
    fovs, views = (
        ((90.0, 180.0), (50.0, 100.0)) if cpu else ((60.0, 120.0, 180.0, 240.0, 360.0), (50.0, 100.0, 200.0, 400.0))
    )
    result: dict = {
        "device": args.device,
        "worlds": worlds,
        "agents_per_world": 17,
        "command": command_line(argv, Path(__file__).name),
        "git": git_info(),
        "machine": machine_info(args.device),
    }
    if not cpu:
        result["gpu"] = torch.cuda.get_device_name(torch.device(args.device))

    base = AquariumConfig()
    uniform = BatchedAquarium(base, worlds, device=args.device, seed=0)
    result["uniform_step_ms"] = 1e3 * step_time(uniform, steps)
    uniform.close()
    varied = BatchedAquarium(per_world_config(base), worlds, device=args.device, seed=0)
    result["per_world_step_ms"] = 1e3 * step_time(varied, steps)
    varied.close()
    result["per_world_overhead"] = result["per_world_step_ms"] / result["uniform_step_ms"] - 1.0

    world = dataclasses.replace(base, width=1600.0, height=1600.0)
    counts = tuple(n for n in sizes for _ in range(repeats))
    result["swarm_sweep"] = {
        "sizes": list(sizes),
        "worlds_per_size": repeats,
        "steps": sweep_steps,
        "one_batch_s": run_batch(dataclasses.replace(world, prey_count=counts), len(counts), args.device, sweep_steps),
        "batch_per_size_s": sum(
            run_batch(dataclasses.replace(world, prey_count=n), repeats, args.device, sweep_steps) for n in sizes
        ),
    }
    settings = [(f, v) for f in fovs for v in views]
    prey = base.prey
    sweep = dataclasses.replace(
        base,
        prey=dataclasses.replace(
            prey,
            fov_angle=tuple(f for f, _ in settings for _ in range(repeats)),
            view_distance=tuple(v for _, v in settings for _ in range(repeats)),
        ),
    )
    result["fov_view_sweep"] = {
        "fov_angles": list(fovs),
        "view_distances": list(views),
        "worlds_per_setting": repeats,
        "steps": sweep_steps,
        "one_batch_s": run_batch(sweep, len(settings) * repeats, args.device, sweep_steps),
        "batch_per_setting_s": sum(
            run_batch(
                dataclasses.replace(base, prey=dataclasses.replace(prey, fov_angle=f, view_distance=v)),
                repeats,
                args.device,
                sweep_steps,
            )
            for f, v in settings
        ),
    }

    print(f"device {args.device}: {worlds} worlds x 17 agents")
    print(f"  step, uniform config     {result['uniform_step_ms']:9.3f} ms")
    print(
        f"  step, per-world values   {result['per_world_step_ms']:9.3f} ms  "
        f"({100 * result['per_world_overhead']:+.1f}%)"
    )
    for name, one, many in (
        ("swarm-size sweep", "one_batch_s", "batch_per_size_s"),
        ("FOV x view sweep", "one_batch_s", "batch_per_setting_s"),
    ):
        entry = result["swarm_sweep" if name.startswith("swarm") else "fov_view_sweep"]
        print(
            f"  {name}: one batch {entry[one]:.2f} s, one batch per setting {entry[many]:.2f} s "
            f"({entry[many] / entry[one]:.1f}x)"
        )
    with open(args.out, "w") as f:
        json.dump(result, f, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
