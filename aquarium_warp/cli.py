"""Command line: `aquarium-warp demo` (speed) and `aquarium-warp video` (an MP4 of heuristic policies)."""

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


def _video(args) -> int:
    from . import AquariumConfig, BatchedAquarium
    from .heuristics import make_policy
    from .video import record

    cfg = AquariumConfig(width=args.width, height=args.height, prey_count=args.prey,
                         predator_count=args.predators)
    env = BatchedAquarium(cfg, num_worlds=1, device=args.device, seed=args.seed)
    prey = make_policy(args.prey_policy, env, "prey", seed=args.seed)
    predator = make_policy(args.predator_policy, env, "predator", seed=args.seed)
    print(f"aquarium-warp video: {args.prey} prey ({args.prey_policy}) and {args.predators} predators "
          f"({args.predator_policy}) on {env.device}, {args.steps} steps -> {args.out}")
    start = time.perf_counter()
    frames = record(env, lambda obs: {"prey": prey(), "predator": predator()}, args.steps, args.out,
                    fps=args.fps, progress=not args.no_progress, width_px=args.frame_width,
                    height_px=args.frame_height, view_cones=args.view_cones, hit_boxes=args.hit_boxes,
                    velocities=args.velocities)
    print(f"wrote {frames} frames to {args.out} in {time.perf_counter() - start:.1f} s")
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
    video = sub.add_parser("video", help="record one world driven by heuristic policies as an MP4 video")
    video.add_argument("--prey-policy", default="turnaway", help="'turnaway' or 'random'")
    video.add_argument("--predator-policy", default="naivchase", help="'naivchase' or 'random'")
    video.add_argument("--steps", type=int, default=600, help="steps to record (frames: steps + 1)")
    video.add_argument("--out", default="aquarium.mp4", help="output MP4 file")
    video.add_argument("--prey", type=int, default=16)
    video.add_argument("--predators", type=int, default=1)
    video.add_argument("--width", type=float, default=800.0, help="world width, px")
    video.add_argument("--height", type=float, default=800.0, help="world height, px")
    video.add_argument("--frame-width", type=int, default=None,
                       help="frame width in pixels (default: the world's, long side at most 1024)")
    video.add_argument("--frame-height", type=int, default=None, help="frame height in pixels")
    video.add_argument("--fps", type=float, default=30.0)
    video.add_argument("--seed", type=int, default=0)
    video.add_argument("--device", default=None, help="'cpu', 'cuda:0'; default: CUDA when present")
    video.add_argument("--view-cones", action="store_true", help="draw each agent's field of view")
    video.add_argument("--hit-boxes", action="store_true", help="draw each agent's hit-box circle")
    video.add_argument("--velocities", action="store_true", help="draw velocity arrows (10 steps long)")
    video.add_argument("--no-progress", action="store_true", help="no progress bar")
    video.set_defaults(run=_video)
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except ValueError as error:
        print(f"aquarium-warp {args.command}: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
