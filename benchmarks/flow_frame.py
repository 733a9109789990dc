"""A frame (PNG) and a short video (MP4) of a vortex world, its current drawn as arrows under the agents.

    python benchmarks/flow_frame.py --out benchmarks/results/flow          # CPU, a few seconds
    python benchmarks/flow_frame.py --out DIR --steps 300 --video           # also DIR/vortex.mp4 (imageio-ffmpeg)

docs/model.md's world (800 x 800, 16 prey turning away, one chasing predator) with a Rankine vortex at the
centre: 3 px/step at the edge of a core of radius 130 px, steady. The PNG shows the state after
`--steps` steps.
"""

from __future__ import annotations

import argparse
import os

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.config import FlowConfig
from aquarium_warp.heuristics import make_policy
from aquarium_warp.render import Renderer, save_png
from aquarium_warp.video import record

VORTEX = FlowConfig("vortex", centre=(400.0, 400.0), strength=3.0, core_radius=130.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="benchmarks/results/flow", help="output folder")
    parser.add_argument("--steps", type=int, default=120, help="steps before the frame (and of the video)")
    parser.add_argument("--size", type=int, default=400, help="frame width and height, pixels")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--video", action="store_true", help="also write vortex.mp4 of the steps")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    env = BatchedAquarium(AquariumConfig(flow=VORTEX), num_worlds=1, device="cpu", seed=args.seed)
    prey = make_policy("turnaway", env, "prey", seed=args.seed)
    predator = make_policy("naivchase", env, "predator", seed=args.seed)

    def act(_obs):
        return {"prey": prey(), "predator": predator()}

    if args.video:
        path = os.path.join(args.out, "vortex.mp4")
        record(env, act, args.steps, path, width_px=args.size, height_px=args.size, progress=False, draw_flow=True)
        print(f"wrote {path} ({os.path.getsize(path)} bytes)")
    else:
        for _ in range(args.steps):
            env.step(act(env.observations))
    frame = Renderer(env, args.size, args.size).render(0, draw_flow=True, velocities=True)
    path = os.path.join(args.out, "vortex.png")
    save_png(frame, path)
    print(f"wrote {path} ({os.path.getsize(path)} bytes) after {args.steps} steps")


if __name__ == "__main__":
    main()
