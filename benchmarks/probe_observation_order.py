"""Probe of the observation pass's observer order in large worlds on a GPU (issue #20): the step's
device time (CUDA graph, `density_config` worlds, random actions set once) with observers in slot
order and in the cell lists' order (`shard.observers_in_cell_order`), for a few (block size,
register cap) variants, at several world sizes; and how far the two orders' states differ after a
few steps from the same reset and actions (each observer's arithmetic is the same in both).

    python benchmarks/probe_observation_order.py [--agents 1000 1024 10000 100000 1000000]
        [--variants slot:128:72 cell:128:72 ...] [--steps 200] [--repeats 3] [--check-agents 100000]
        [--check-steps 20] [--out probe.json] [--device cuda:0]

A variant is `ORDER:BLOCK:REGISTERS` (ORDER slot or cell; shard.OBSERVATION_BLOCK,
observation.MAX_REGISTERS, "none" for no cap). Prints a table and writes JSON to `--out`, or to
`$OUT/probe_observation_order.json` where OUT is set.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import torch
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import aquarium_warp.shard as shard_module
from aquarium_warp import BatchedAquarium
from aquarium_warp.bench import density_config, random_actions
from aquarium_warp.kernels import observation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from probe_fused_gpu import step_ms

DEFAULT_VARIANTS = ("slot:128:72", "cell:128:72", "cell:64:72", "cell:256:72", "cell:128:64", "cell:128:96",
                    "cell:128:none")


def parse_variant(text: str) -> tuple[bool, int, int | None]:
    order, block, registers = text.split(":")
    if order not in ("slot", "cell"):
        raise SystemExit(f"variant {text!r}: the order must be slot or cell")
    return order == "cell", int(block), None if registers == "none" else int(registers)


def build(agents: int, variant: tuple[bool, int, int | None], device: str, seed: int = 0) -> BatchedAquarium:
    """One world of `agents` agents at the default density with observers in the order, block size and
    register cap of `variant`; the module settings are restored after the build."""
    cell_order, block, registers = variant
    saved = shard_module.observers_in_cell_order, shard_module.OBSERVATION_BLOCK, observation.MAX_REGISTERS
    shard_module.observers_in_cell_order = lambda cuda: cell_order
    shard_module.OBSERVATION_BLOCK, observation.MAX_REGISTERS = block, registers
    try:
        return BatchedAquarium(density_config(agents), num_worlds=1, device=device, seed=seed)
    finally:
        shard_module.observers_in_cell_order, shard_module.OBSERVATION_BLOCK, observation.MAX_REGISTERS = saved


def difference(variant: tuple[bool, int, int | None], agents: int, steps: int, device: str) -> dict:
    """Unequal entries of every array of the state, `variant` against slot order (block 128, cap 72),
    after `steps` steps from the same reset and actions."""
    envs = {"variant": build(agents, variant, device, seed=11),
            "slot": build(agents, (False, 128, 72), device, seed=11)}
    gen = torch.Generator(device=envs["slot"].torch_device).manual_seed(5)
    for _ in range(steps):
        actions = random_actions(envs["slot"].config, 1, gen, envs["slot"].torch_device)
        for env in envs.values():
            env.step(actions)
    a, b = envs["variant"].state.torch, envs["slot"].state.torch
    unequal = {name: int((getattr(a, name) != getattr(b, name)).sum()) for name in envs["slot"].state.arrays()}
    for env in envs.values():
        env.close()
    return unequal


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agents", type=int, nargs="+", default=[1000, 1024, 10_000, 100_000, 1_000_000])
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS), help="ORDER:BLOCK:REGISTERS")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--check-agents", type=int, default=100_000)
    parser.add_argument("--check-steps", type=int, default=20)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--device", default="cuda:0", help="cpu runs a smoke test (no warps there)")
    args = parser.parse_args()
    out = args.out or (Path(os.environ["OUT"]) / "probe_observation_order.json" if os.environ.get("OUT") else None)

    wp.init()
    variants = {text: parse_variant(text) for text in args.variants}
    record: dict = {"device": wp.get_device(args.device).name, "warp": wp.config.version, "steps": args.steps,
                    "repeats": args.repeats, "ms_per_step": {}, "unequal_vs_slot_order": {}}
    print(f"device {record['device']}, warp {record['warp']}; unequal entries after {args.check_steps} steps of "
          f"one world of {args.check_agents} agents, against slot order:")
    for text, variant in variants.items():
        if variant[0]:
            unequal = difference(variant, args.check_agents, args.check_steps, args.device)
            record["unequal_vs_slot_order"][text] = unequal
            print(f"  {text:16s} {sum(unequal.values())} ({', '.join(f'{k} {v}' for k, v in unequal.items() if v)})",
                  flush=True)

    for agents in args.agents:
        row = record["ms_per_step"].setdefault(str(agents), {})
        for text, variant in variants.items():
            env = build(agents, variant, args.device)
            row[text] = step_ms(env, args.steps, args.repeats)
            env.close()
            print(f"  {agents:8d} agents  {text:16s} {row[text]:.4f} ms/step", flush=True)

    names = list(variants)
    print("\nms per step of one world (CUDA graph, device time, median of repeats)")
    print(f"{'agents':>8s} " + " ".join(f"{n:>14s}" for n in names))
    for agents, row in record["ms_per_step"].items():
        print(f"{agents:>8s} " + " ".join(f"{row[n]:14.4f}" for n in names))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(record, indent=2) + "\n")
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
