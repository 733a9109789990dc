"""Command line: `aquarium-warp demo` (more subcommands join as the project grows)."""

from __future__ import annotations

import argparse
import sys
import time


def _demo(args) -> int:
    import torch

    from . import AquariumConfig, BatchedAquarium

    cfg = AquariumConfig(prey_count=args.prey, predator_count=args.predators, max_steps=args.max_steps)
    env = BatchedAquarium(cfg, num_worlds=args.worlds, device=args.device, seed=args.seed)
    gen = torch.Generator(device=env.torch_device).manual_seed(args.seed)
    shapes = {"prey": (args.worlds, env.prey_capacity), "predator": (args.worlds, env.predator_count)}
    print(f"aquarium-warp demo: {args.worlds} worlds x {cfg.capacity} agents on {env.device}, "
          f"random actions, {args.steps} steps")
    env.reset()
    captures = 0
    ended = 0
    episode_captures = 0
    start = time.perf_counter()
    for _ in range(args.steps):
        actions = {t: torch.randint(0, cfg.action_count, s, generator=gen, device=env.torch_device)
                   for t, s in shapes.items()}
        _, _, _, _, info = env.step(actions, validate=False)
        captures += int(info["captures"].sum())
        done = info["episode_ended"]
        ended += int(done.sum())
        episode_captures += int(info["episode_captures"][done].sum())
    elapsed = time.perf_counter() - start
    agent_steps = args.steps * args.worlds * cfg.capacity
    print(f"{'steps/s':>12} {'agent-steps/s':>15} {'captures':>10} {'captures/world-step':>20} {'episodes ended':>15}")
    print(f"{args.steps / elapsed:12.1f} {agent_steps / elapsed:15.3e} {captures:10d} "
          f"{captures / (args.steps * args.worlds):20.5f} {ended:15d}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="aquarium-warp", description="Aquarium predator-prey worlds on Warp")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="step a batch of worlds with random actions and report speed and captures")
    demo.add_argument("--worlds", type=int, default=64)
    demo.add_argument("--steps", type=int, default=500)
    demo.add_argument("--prey", type=int, default=16)
    demo.add_argument("--predators", type=int, default=1)
    demo.add_argument("--max-steps", type=int, default=3000, help="episode length")
    demo.add_argument("--device", default=None, help="'cpu', 'cuda:0'; default: CUDA when present")
    demo.add_argument("--seed", type=int, default=0)
    demo.set_defaults(run=_demo)
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except ValueError as error:
        print(f"aquarium-warp {args.command}: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
