"""Probe of the fused step (`kernels/world_step.py`) on a GPU: the step's device time (CUDA graph,
default config, random actions set once) of the staged path and of the fused path with a few
(block size, register cap) variants, at several batch sizes; and, per variant, how far the fused
step's state drifts from the staged step's over a few steps from the same reset and actions (float
contraction may differ in the last bits, which chaotic dynamics amplify).

    python benchmarks/probe_fused_gpu.py [--worlds 4096 16384 65536] [--variants 128:72 64:72 ...]
        [--steps 300] [--repeats 3] [--check-worlds 1024] [--check-steps 20] [--out probe.json]
        [--device cuda:0]

A variant is `BLOCK:REGISTERS` (shard.FUSED_BLOCK, world_step.MAX_REGISTERS; "none" for no cap).
Prints a table and writes JSON to `--out`, or to `$OUT/probe_fused_gpu.json` where OUT is set.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

import torch
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import aquarium_warp.shard as shard_module
from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.bench.timing import DeviceTimer
from aquarium_warp.kernels import world_step
from aquarium_warp.records import command_line, git_info, machine_info
from aquarium_warp.rollout import random_actions

DEFAULT_VARIANTS = ("128:72", "64:72", "256:72", "128:64", "128:96", "128:none", "32:72")


def parse_variant(text: str) -> tuple[int, int | None]:
    block, registers = text.split(":")
    return int(block), None if registers == "none" else int(registers)


def build(worlds: int, variant: tuple[int, int | None] | None, device: str, seed: int = 0) -> BatchedAquarium:
    """An env of `worlds` default worlds on the staged path (`variant` None) or the fused path with
    (block size, register cap) `variant`; the module settings are restored after the build."""
    if variant is None:
        return BatchedAquarium(AquariumConfig(), num_worlds=worlds, device=device, seed=seed, step_kernel="stages")
    saved = shard_module.FUSED_BLOCK, world_step.MAX_REGISTERS
    shard_module.FUSED_BLOCK, world_step.MAX_REGISTERS = variant
    try:
        return BatchedAquarium(AquariumConfig(), num_worlds=worlds, device=device, seed=seed, step_kernel="fused")
    finally:
        shard_module.FUSED_BLOCK, world_step.MAX_REGISTERS = saved


def step_ms(env: BatchedAquarium, steps: int, repeats: int) -> float:
    """Median device milliseconds per step of `repeats` runs of `steps` graph steps (actions set once)."""
    gen = torch.Generator(device=env.torch_device).manual_seed(0)
    env.set_actions(random_actions(env.config, env.num_worlds, gen, env.torch_device))
    for _ in range(10):  # warm-up (the first step captures the graph)
        env.step(None, validate=False)
    wp.synchronize_device(env.device)
    timer = DeviceTimer(env.device)

    def run():
        for _ in range(steps):
            env.step(None, validate=False)

    return statistics.median(timer(run) * 1e3 / steps for _ in range(repeats))


def drift(variant: tuple[int, int | None], worlds: int, steps: int, device: str) -> dict:
    """Max abs difference of every float array of the state (positions and observations named apart)
    and the count of unequal entries of the others, fused `variant` against staged, after `steps`
    steps from the same reset and actions."""
    envs = {"fused": build(worlds, variant, device, seed=11), "stages": build(worlds, None, device, seed=11)}
    gen = torch.Generator(device=envs["fused"].torch_device).manual_seed(5)
    for _ in range(steps):
        actions = random_actions(envs["fused"].config, worlds, gen, envs["fused"].torch_device)
        for env in envs.values():
            env.step(actions)
    a, b = envs["fused"].state.torch, envs["stages"].state.torch
    result: dict = {"float_max_abs": {}, "unequal": {}}
    for name in envs["fused"].state.arrays():
        x, y = getattr(a, name), getattr(b, name)
        if x.is_floating_point():
            result["float_max_abs"][name] = float((x - y).abs().max()) if x.numel() else 0.0
        else:
            result["unequal"][name] = int((x != y).sum())
    for env in envs.values():
        env.close()
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--worlds", type=int, nargs="+", default=[4096, 16384, 65536])
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS), help="BLOCK:REGISTERS")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--check-worlds", type=int, default=1024)
    parser.add_argument("--check-steps", type=int, default=20)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--device", default="cuda:0", help="cpu runs a smoke test (every variant is one lane there)")
    args = parser.parse_args(argv)
    out = args.out or (Path(os.environ["OUT"]) / "probe_fused_gpu.json" if os.environ.get("OUT") else None)

    wp.init()
    variants = {text: parse_variant(text) for text in args.variants}
    paths: dict[str, tuple[int, int | None] | None] = {"stages": None}
    paths.update({f"fused {text}": v for text, v in variants.items()})
    record: dict = {
        "device": wp.get_device(args.device).name,
        "warp": wp.config.version,
        "steps": args.steps,
        "repeats": args.repeats,
        "ms_per_step": {},
        "drift": {},
        "command": command_line(argv, Path(__file__).name),
        "git": git_info(),
        "machine": machine_info(args.device),
    }

    print(
        f"device {record['device']}, warp {record['warp']}; drift after {args.check_steps} steps of "
        f"{args.check_worlds} worlds, fused against staged:"
    )
    for name, variant in paths.items():
        if variant is None:
            continue
        d = drift(variant, args.check_worlds, args.check_steps, args.device)
        record["drift"][name] = d
        floats = d["float_max_abs"]
        print(
            f"  {name:16s} position {floats['position']:.3g}  obs_prey {floats['obs_prey']:.3g}  "
            f"obs_predator {floats['obs_predator']:.3g}  max float {max(floats.values()):.3g}  "
            f"unequal non-float entries {sum(d['unequal'].values())} "
            f"({', '.join(f'{k} {v}' for k, v in d['unequal'].items() if v)})",
            flush=True,
        )

    for worlds in args.worlds:
        row = record["ms_per_step"].setdefault(str(worlds), {})
        for name, variant in paths.items():
            env = build(worlds, variant, args.device)
            row[name] = step_ms(env, args.steps, args.repeats)
            env.close()
            print(f"  {worlds:6d} x 17  {name:16s} {row[name]:.4f} ms/step", flush=True)

    names = list(paths)
    print("\nms per step (CUDA graph, device time, median of repeats)")
    print(f"{'worlds':>8s} " + " ".join(f"{n:>14s}" for n in names))
    for worlds, row in record["ms_per_step"].items():
        print(f"{worlds:>8s} " + " ".join(f"{row[n]:14.4f}" for n in names))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(record, indent=2) + "\n")
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
