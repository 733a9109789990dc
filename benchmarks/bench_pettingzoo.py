"""Env-steps per second of the PettingZoo environment (`aquarium_v1`), next to the original
marl-aquarium 0.1.10 measured in the same run.

Method (the same as the original's, `benchmarks/_original_aquarium_child.py`): the default config on
the CPU, random actions uniform over `Discrete(16)` drawn from `numpy.random.default_rng(run)` (one per
live agent), no rendering, warm-up of at least `--warmup` seconds, then a timed window of at least
`--seconds`; episode-end resets happen inside the window; agent-steps = live agents summed over steps.
`--repeats` runs per entry point, median reported (ours run in this process, the original in fresh
processes of its own virtual environment, see `benchmarks/original_aquarium.py`).

Entry points:
- `aquarium_v1.parallel_env()` (the raw ParallelEnv) -- the target is 20x the original's `raw_env`;
- `aquarium_v1.env()` (AEC: parallel_to_aec plus wrappers), looping over `agent_selection` / `last()`
  / `step()` as `agent_iter()` does; an env-step is one full cycle of the live agents;
- the original's `raw_env` and `aquarium_v0.parallel_env` (its parallel -> AEC -> parallel round trip).

A breakdown of one parallel env-step follows: time inside `BatchedAquarium.step` (timed by wrapping it),
drawing the random actions, and the rest (the wrapper's own Python work). Last, the time of a parallel
`reset()`, seeded (`reset(seed=k)`, a new seed each time) and unseeded (`reset()`, whose simulation
seed comes from the sequence of the last seed): the target is a seeded reset under 0.1 ms.

    python benchmarks/bench_pettingzoo.py [--seconds 5] [--repeats 3] [--warmup 2] [--no-original] [--out PATH]

Prints a table and writes benchmarks/results/pettingzoo_cpu.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
from aquarium_warp import aquarium_v1  # noqa: E402
from aquarium_warp.records import command_line, git_info, machine_info  # noqa: E402

RESULTS = HERE / "results"
TARGET_SPEEDUP = 20.0
TARGET_SEEDED_RESET_US = 100.0


class _CountingStep:
    """Wraps `BatchedAquarium.step` on one instance: counts calls and, optionally, times them."""

    def __init__(self, aquarium, timed: bool):
        self.inner = aquarium.step
        self.calls = 0
        self.seconds = 0.0
        self.timed = timed
        aquarium.step = self

    def __call__(self, *args, **kwargs):
        self.calls += 1
        if not self.timed:
            return self.inner(*args, **kwargs)
        t0 = time.perf_counter()
        try:
            return self.inner(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t0


def _parallel_loop(env, rng):
    n_actions = env.config.action_count

    def one_step() -> int:
        if not env.agents:
            env.reset()
        agents = env.agents
        draws = rng.random(len(agents))
        env.step({a: int(d * n_actions) for a, d in zip(agents, draws)})
        return len(agents)

    return one_step


def _aec_loop(env, rng, counter):
    n_actions = env.unwrapped.config.action_count

    def one_step() -> int:
        """Agent turns up to and including the next underlying env-step."""
        turns = 0
        start = counter.calls
        while counter.calls == start:
            if not env.agents:
                env.reset()
            _, _, terminated, truncated, _ = env.last()
            if terminated or truncated:
                env.step(None)
            else:
                env.step(int(rng.random() * n_actions))
                turns += 1
        return turns

    return one_step


def _time_loop(one_step, seconds: float, warmup: float, min_steps: int = 3) -> dict:
    steps, t0 = 0, time.perf_counter()
    while steps < min_steps or time.perf_counter() - t0 < warmup:
        one_step()
        steps += 1
    steps = agent_steps = 0
    perf = time.perf_counter
    t0 = perf()
    while True:
        agent_steps += one_step()
        steps += 1
        if steps >= min_steps and perf() - t0 >= seconds:
            break
    elapsed = perf() - t0
    return {
        "steps": steps,
        "agent_steps": agent_steps,
        "elapsed_s": elapsed,
        "env_steps_per_s": steps / elapsed,
        "agent_steps_per_s": agent_steps / elapsed,
        "mean_agents": agent_steps / steps,
    }


def measure_ours(which: str, seconds: float, repeats: int, warmup: float) -> dict:
    runs = []
    for run in range(repeats):
        rng = np.random.default_rng(run)
        t0 = time.perf_counter()
        if which == "parallel":
            env = aquarium_v1.parallel_env(seed=run)
            env.reset(seed=run)
            one_step = _parallel_loop(env, rng)
        else:
            env = aquarium_v1.env(seed=run)
            env.reset(seed=run)
            one_step = _aec_loop(env, rng, _CountingStep(env.unwrapped.aquarium, timed=False))
        construct_reset_s = time.perf_counter() - t0
        r = _time_loop(one_step, seconds, warmup)
        r.update(run=run, construct_reset_s=construct_reset_s)
        runs.append(r)
        env.close()
    return {
        "which": which,
        "entry_point": f"aquarium_warp.aquarium_v1.{'parallel_env' if which == 'parallel' else 'env'}",
        "env_steps_per_s": statistics.median(r["env_steps_per_s"] for r in runs),
        "agent_steps_per_s": statistics.median(r["agent_steps_per_s"] for r in runs),
        "runs": runs,
    }


def breakdown(steps: int = 20000) -> dict:
    """Microseconds per parallel env-step: inside BatchedAquarium.step, drawing actions, the rest."""
    env = aquarium_v1.parallel_env(seed=0)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    one_step = _parallel_loop(env, rng)
    for _ in range(500):
        one_step()
    timer = _CountingStep(env.aquarium, timed=True)
    t0 = time.perf_counter()
    for _ in range(steps):
        one_step()
    total = time.perf_counter() - t0
    # Drawing the actions alone (the same dict comprehension as the loop).
    agents, n_actions = list(env.possible_agents), env.config.action_count
    t1 = time.perf_counter()
    for _ in range(steps):
        draws = rng.random(len(agents))
        {a: int(d * n_actions) for a, d in zip(agents, draws)}
    actions = time.perf_counter() - t1
    # The bare simulator step, for reference (1 world, no validation, fixed actions).
    aq = env.aquarium
    aq.step = timer.inner
    bare_actions = {t: a.clone() for t, a in aq.actions.items()}  # the last actions, as host tensors
    t2 = time.perf_counter()
    for i in range(steps):
        if i % (aq.config.max_steps - 1) == 0:  # i = 0 included: the loop starts from a fresh reset
            aq.reset()
        aq.step(bare_actions, validate=False)
    bare = time.perf_counter() - t2
    env.close()
    us = 1e6 / steps
    out = {
        "steps": steps,
        "total_us": total * us,
        "batched_step_us": timer.seconds * us,
        "actions_us": actions * us,
        "bare_batched_step_us": bare * us,
    }
    out["wrapper_us"] = out["total_us"] - out["batched_step_us"] - out["actions_us"]
    return out


def reset_times(resets: int = 5000) -> dict:
    """Microseconds per parallel `reset()`: seeded with a new seed each time, and unseeded. Both start
    the episode of a new simulation seed (the unseeded one draws it from the last seed's sequence)."""
    env = aquarium_v1.parallel_env(seed=0)
    for k in range(200):  # warm-up
        env.reset(seed=k)
        env.reset()
    t0 = time.perf_counter()
    for k in range(resets):
        env.reset(seed=k)
    seeded = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(resets):
        env.reset()
    unseeded = time.perf_counter() - t0
    env.close()
    return {"resets": resets, "seeded_us": seeded / resets * 1e6, "unseeded_us": unseeded / resets * 1e6}


def _loadavg():
    try:
        return list(os.getloadavg())
    except OSError:
        return None


def _versions() -> dict:
    from importlib import metadata

    out = {}
    for dist in ("aquarium-warp", "warp-lang", "torch", "numpy", "gymnasium", "pettingzoo"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="timed window per run (s)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per entry point (median reported)")
    parser.add_argument("--warmup", type=float, default=2.0, help="warm-up per run (s)")
    parser.add_argument("--no-original", action="store_true", help="skip the original marl-aquarium")
    parser.add_argument("--out", default=str(RESULTS / "pettingzoo_cpu.json"))
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")

    load_before = _loadavg()
    ours = {w: measure_ours(w, args.seconds, args.repeats, args.warmup) for w in ("parallel", "aec")}
    parts = breakdown()
    resets = reset_times()
    original, original_error = {}, None
    if not args.no_original:
        from original_aquarium import OriginalRunError, OriginalSetupError, measure_original

        try:
            for w in ("raw", "parallel"):
                original[w] = measure_original(seconds=args.seconds, repeats=args.repeats, which=w, warmup=args.warmup)
        except (OriginalSetupError, OriginalRunError) as error:
            original_error = str(error)
            print(f"original marl-aquarium not measured: {error}", file=sys.stderr)
    load_after = _loadavg()

    rows = [(r["entry_point"], r) for r in ours.values()] + [(r["entry_point"], r) for r in original.values()]
    base = original.get("raw", {}).get("env_steps_per_s")
    print(
        f"\nPettingZoo env, default config (16 prey + 1 predator), CPU, random actions, no rendering "
        f"({args.repeats} runs x {args.seconds:g} s, median)"
    )
    header = (
        f"{'entry point':44s} {'env-steps/s':>12s} {'agent-steps/s':>14s} {'vs original raw':>16s}  runs (env-steps/s)"
    )
    print(header)
    print("-" * len(header))
    for name, r in rows:
        ratio = f"{r['env_steps_per_s'] / base:15.1f}x" if base else f"{'-':>16s}"
        per_run = ", ".join(f"{x['env_steps_per_s']:.0f}" for x in r["runs"])
        print(f"{name:44s} {r['env_steps_per_s']:12.1f} {r['agent_steps_per_s']:14.0f} {ratio}  {per_run}")
    print(
        f"\nper parallel env-step ({parts['steps']} steps): {parts['total_us']:.1f} us = BatchedAquarium.step "
        f"{parts['batched_step_us']:.1f} us + drawing actions {parts['actions_us']:.1f} us + wrapper "
        f"{parts['wrapper_us']:.1f} us  (bare BatchedAquarium.step loop: {parts['bare_batched_step_us']:.1f} us)"
    )
    print(
        f"parallel reset(): seeded {resets['seeded_us']:.1f} us, unseeded {resets['unseeded_us']:.1f} us "
        f"(mean of {resets['resets']}; target for seeded: < {TARGET_SEEDED_RESET_US:g} us)"
    )
    checks = {
        "seeded_reset_us": resets["seeded_us"],
        "target_seeded_reset_us": TARGET_SEEDED_RESET_US,
        "seeded_reset_target_met": resets["seeded_us"] < TARGET_SEEDED_RESET_US,
    }
    if base:
        checks.update(
            {
                "speedup_parallel_vs_original_raw": ours["parallel"]["env_steps_per_s"] / base,
                "speedup_aec_vs_original_raw": ours["aec"]["env_steps_per_s"] / base,
                "target_speedup": TARGET_SPEEDUP,
            }
        )
        checks["target_met"] = checks["speedup_parallel_vs_original_raw"] >= TARGET_SPEEDUP
        print(
            f"parallel_env: {checks['speedup_parallel_vs_original_raw']:.1f}x the original raw_env "
            f"(target {TARGET_SPEEDUP:g}x: {'met' if checks['target_met'] else 'MISSED'})"
        )
    print(f"load average (1, 5, 15 min) before {load_before}, after {load_after}")

    result = {
        "benchmark": "aquarium_v1 PettingZoo env vs original marl-aquarium 0.1.10, CPU, default config, "
        "random actions, no rendering",
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "git": git_info(),
        "command": command_line(argv, Path(__file__).name),
        "method": {
            "seconds": args.seconds,
            "repeats": args.repeats,
            "warmup_s_min": args.warmup,
            "min_steps": 3,
            "ours": "in this process, one fresh env per run, seed=run, actions numpy default_rng(run)",
            "original": "benchmarks/original_aquarium.measure_original (fresh process per run)",
            "resets_included": True,
            "statistic": "median over runs",
            "aec_env_step": "one underlying ParallelEnv step (a full cycle of the live agents)",
        },
        "machine": machine_info("cpu"),
        "loadavg_before": load_before,
        "loadavg_after": load_after,
        "versions": _versions(),
        "ours": ours,
        "breakdown_us_per_parallel_step": parts,
        "reset_us": resets,
        "original": original or None,
        "original_error": original_error,
        "checks": checks,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
