"""Agent-steps per second of VMAS (Vectorized Multi-Agent Simulator, pure PyTorch) on a predator-prey
scenario, measured the way `aquarium_warp.bench` measures our step: random actions, observations
on, median of repeated timed runs after warm-up, synchronised timers on CUDA.

The scenario is VMAS's `simple_tag` (the MPE predator-prey task: adversaries chase good agents
around landmarks), with the agents split like ours: about one predator ("adversary") per 16 prey
("good agents"), i.e. `predators = max(1, round(N / 17))`, `prey = N - predators`. Its other
settings are the scenario's defaults (2 landmarks, 10 physics substeps per step, discrete actions);
VMAS computes every agent's observation inside `env.step`. No episode ends (no `max_steps`), so no
resets are timed.

    python benchmarks/vmas_peer.py --device cpu --agents 17 --envs 1,16,256 [--seconds 1] [--repeats 3]

VMAS is not a dependency of aquarium-warp: `pip install vmas` (1.5.x) to use this. `measure_vmas`
is what `python benchmarks/bench_scaling.py --vmas` calls (this module is its VMAS harness,
`aquarium_warp.bench.VmasHarness`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.bench import parse_counts, split_agents, timed_runs

SCENARIO = "simple_tag"


def vmas_version() -> str | None:
    """VMAS's version, or None when it is not importable."""
    try:
        import vmas
    except Exception:  # noqa: BLE001  (any import failure means "not available")
        return None
    return getattr(vmas, "__version__", "unknown")


def measure_vmas(
    agents_per_env: int,
    envs: int,
    device: str = "cpu",
    seconds: float = 1.0,
    repeats: int = 3,
    *,
    scenario: str = SCENARIO,
    warmup_steps: int = 2,
    min_steps: int = 2,
    budget_s: float | None = None,
    seed: int = 0,
    scenario_kwargs: dict | None = None,
) -> dict:
    """Time `envs` parallel VMAS `scenario` environments of `agents_per_env` agents on `device`.

    Each timed run steps with random discrete actions (a pool of 8 action sets drawn beforehand on the
    device, as our benchmark does) until at least `seconds` and `min_steps` steps have passed; the
    median time per step over `repeats` runs is reported. `budget_s` caps a point's timed runs: when
    a single step is slow, fewer runs are made (the JSON says how many). Raises ImportError when VMAS
    is missing.
    """
    import torch
    import vmas

    prey, predators = split_agents(agents_per_env)
    kwargs = {"num_good_agents": prey, "num_adversaries": predators}
    kwargs.update(scenario_kwargs or {})
    torch_device = torch.device(device)
    cuda = torch_device.type == "cuda"
    sync = (lambda: torch.cuda.synchronize(torch_device)) if cuda else (lambda: None)
    build_start = time.perf_counter()
    env = vmas.make_env(scenario, num_envs=envs, device=device, continuous_actions=False, seed=seed, **kwargs)
    env.reset()
    sync()
    build_s = time.perf_counter() - build_start
    gen = torch.Generator(device=torch_device).manual_seed(seed)
    sizes = [space.n for space in env.action_space]
    # [envs, 1] tensors: VMAS unsqueezes 1-D actions in place, so give it the final shape.
    pool = [[torch.randint(0, n, (envs, 1), generator=gen, device=torch_device) for n in sizes] for _ in range(8)]
    obs_floats = None
    first_step_s = None
    for i in range(max(1, warmup_steps)):
        start = time.perf_counter()
        obs, _, _, _ = env.step(pool[i % 8])
        sync()
        first_step_s = time.perf_counter() - start
        obs_floats = sum(int(o.shape[-1]) for o in obs)
    runs_made = repeats
    per_run = max(seconds, first_step_s * min_steps)  # a run lasts `seconds` and `min_steps` steps at least
    if budget_s is not None and per_run * repeats > budget_s:
        runs_made = min(repeats, max(1, int(budget_s // max(per_run, 1e-9))))

    def advance(i, step=env.step, actions=pool):
        step(actions[i % 8])

    per_step = timed_runs(advance, sync, seconds, runs_made, first_step_s, min_steps)
    step_s = statistics.median(per_step)
    agents = envs * agents_per_env
    name = torch.cuda.get_device_name(torch_device) if cuda else "cpu"
    del env, pool, advance
    if cuda:
        torch.cuda.empty_cache()
    return {
        "peer": "vmas",
        "vmas": vmas_version(),
        "scenario": scenario,
        "scenario_kwargs": kwargs,
        "continuous_actions": False,
        "device": device,
        "device_name": name,
        "envs": envs,
        "agents_per_env": agents_per_env,
        "prey_per_env": prey,
        "predators_per_env": predators,
        "agents": agents,
        "step_ms": step_s * 1e3,
        "agent_steps_per_s": agents / step_s,
        "ns_per_agent_step": step_s / agents * 1e9,
        "runs_step_ms": [t * 1e3 for t in per_step],
        "runs": runs_made,
        "repeats_asked": repeats,
        "build_s": build_s,
        "first_step_ms": first_step_s * 1e3,
        "observation_floats_per_env": obs_floats,
        "torch": torch.__version__,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument(
        "--agents",
        default="17",
        help="agents per environment, a comma list; '...' continues the progression (default 17)",
    )
    parser.add_argument("--envs", default="1", help="parallel environments, a comma list (default 1)")
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--budget", type=float, default=None, help="seconds of timed runs per point at most")
    parser.add_argument("--out", default=None, help="write the points as JSON here")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    try:
        agents, envs = parse_counts(args.agents, "--agents"), parse_counts(args.envs, "--envs")
    except ValueError as error:
        parser.error(str(error))
    if vmas_version() is None:
        print("vmas is not importable: pip install vmas", file=sys.stderr)
        return 2
    rows = []
    for n in agents:
        for e in envs:
            row = measure_vmas(n, e, args.device, args.seconds, args.repeats, budget_s=args.budget)
            rows.append(row)
            print(
                f"VMAS {SCENARIO} {e:6d} envs x {n:5d} agents on {args.device}: {row['step_ms']:10.3f} ms/step  "
                f"{row['agent_steps_per_s']:11.3e} agent-steps/s",
                flush=True,
            )
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
