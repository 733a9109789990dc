"""Env-steps per second of the native vector envs (`AquariumVectorEnv`, `AquariumSB3VecEnv`) next to the
SuperSuit path (`pettingzoo_env_to_vec_env_v1` + `concat_vec_envs_v1` over `aquarium_v1.parallel_env`),
measured in the same run on the same CPU.

Method: the default config (16 prey + 1 predator: 17 rows per world, every agent a row) with
`max_steps=--max-steps` (episode ends and resets happen inside the timed window), `--worlds` worlds per
vector env, random actions drawn beforehand (`numpy.random.default_rng(run)`, one table of 64 action
vectors cycled), a warm-up of at least `--warmup` seconds, then a timed window of at least `--seconds`.
An env-step is one row's step (what SB3 counts in `num_timesteps`): env-steps/s = rows x steps / s.
`--repeats` runs per path (a fresh vector env each, seed = run), median reported.

Paths: native Gymnasium `VectorEnv` (numpy), native SB3 `VecEnv`, SuperSuit in-process with
`base_class="gymnasium"` and `"stable_baselines3"`, and SuperSuit with `num_cpus=2` (two processes,
SB3 base class; SuperSuit's default route to SB3 on a multi-core machine).

    python benchmarks/bench_vector_envs.py [--worlds 4 64] [--seconds 3] [--repeats 3] [--warmup 1] [--out PATH]

Prints a table and writes benchmarks/results/vector_envs_cpu/vector_envs_cpu.json.
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
from aquarium_warp import AquariumConfig, aquarium_v1  # noqa: E402
from aquarium_warp.records import command_line, git_info, machine_info  # noqa: E402

RESULTS = HERE / "results" / "vector_envs_cpu"
PATHS = ("native gymnasium", "native sb3", "supersuit gymnasium", "supersuit sb3", "supersuit sb3 2 procs")


def make(path: str, worlds: int, max_steps: int, seed: int):
    """(vector env, step function taking an action vector, rows)."""
    if path.startswith("native"):
        cfg = AquariumConfig(max_steps=max_steps)
        if path == "native gymnasium":
            from aquarium_warp.interop.gymnasium import AquariumVectorEnv

            vec = AquariumVectorEnv(cfg, num_worlds=worlds)
            vec.reset(seed=seed)
            return vec, vec.step, vec.num_envs
        from aquarium_warp.interop.sb3 import AquariumSB3VecEnv

        vec = AquariumSB3VecEnv(cfg, num_worlds=worlds)
        vec.seed(seed)
        vec.reset()
        return vec, vec.step, vec.num_envs
    import supersuit as ss

    base = "gymnasium" if "gymnasium" in path else "stable_baselines3"
    cpus = 2 if "2 procs" in path else 0
    env = aquarium_v1.parallel_env(max_cycles=max_steps)
    vec = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), worlds, num_cpus=cpus, base_class=base)
    if base == "gymnasium":
        vec.reset(seed=seed)
    else:
        vec.venv.reset(seed=seed)
    return vec, vec.step, vec.num_envs


def measure(path: str, worlds: int, max_steps: int, seconds: float, warmup: float, run: int) -> dict:
    vec, step, rows = make(path, worlds, max_steps, seed=run)
    try:
        actions = np.random.default_rng(run).integers(0, 16, (64, rows))
        perf, k = time.perf_counter, 0
        t0 = perf()
        while k < 3 or perf() - t0 < warmup:
            step(actions[k % 64])
            k += 1
        steps, t0 = 0, perf()
        while steps < 3 or perf() - t0 < seconds:
            step(actions[steps % 64])
            steps += 1
        elapsed = perf() - t0
    finally:
        vec.close()
    return {
        "steps": steps,
        "rows": rows,
        "elapsed_s": elapsed,
        "env_steps_per_s": rows * steps / elapsed,
        "vector_steps_per_s": steps / elapsed,
    }


def _versions() -> dict:
    from importlib import metadata

    out = {}
    for dist in (
        "aquarium-warp",
        "warp-lang",
        "torch",
        "numpy",
        "gymnasium",
        "pettingzoo",
        "SuperSuit",
        "stable_baselines3",
    ):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, nargs="+", default=[4, 64], help="worlds per vector env")
    parser.add_argument("--max-steps", type=int, default=500, help="episode length (steps)")
    parser.add_argument("--seconds", type=float, default=3.0, help="timed window per run (s)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per path (median reported)")
    parser.add_argument("--warmup", type=float, default=1.0, help="warm-up per run (s)")
    parser.add_argument(
        "--paths",
        nargs="+",
        default=list(PATHS),
        choices=PATHS,
        metavar="PATH",
        help=f"paths to measure (default: all of {PATHS})",
    )
    parser.add_argument("--out", default=str(RESULTS / "vector_envs_cpu.json"))
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if any(w < 1 for w in args.worlds):
        parser.error(f"--worlds must be >= 1, got {args.worlds}")
    if args.max_steps < 1:
        parser.error(f"--max-steps must be >= 1, got {args.max_steps}")

    load_before = os.getloadavg()
    results = []
    for worlds in args.worlds:
        for path in args.paths:
            runs = [
                measure(path, worlds, args.max_steps, args.seconds, args.warmup, run) for run in range(args.repeats)
            ]
            median = statistics.median(r["env_steps_per_s"] for r in runs)
            results.append(
                {"path": path, "worlds": worlds, "rows": runs[0]["rows"], "env_steps_per_s": median, "runs": runs}
            )
            print(f"  measured {path} x {worlds} worlds: {median:,.0f} env-steps/s", file=sys.stderr)
    load_after = os.getloadavg()

    print(
        f"\nVector envs, default config (16 prey + 1 predator = 17 rows per world), max_steps={args.max_steps}, "
        f"CPU, random actions ({args.repeats} runs x {args.seconds:g} s, median)"
    )
    header = f"{'path':24s} {'worlds':>6s} {'rows':>6s} {'env-steps/s':>13s} {'vs supersuit sb3':>17s}"
    print(header)
    print("-" * len(header))
    for r in results:
        base = next(
            (x["env_steps_per_s"] for x in results if x["worlds"] == r["worlds"] and x["path"] == "supersuit sb3"), None
        )
        r["vs_supersuit_sb3"] = r["env_steps_per_s"] / base if base else None
        ratio = f"{r['vs_supersuit_sb3']:16.1f}x" if base else f"{'-':>17s}"
        print(f"{r['path']:24s} {r['worlds']:6d} {r['rows']:6d} {r['env_steps_per_s']:13,.0f} {ratio}")
    print(f"load average (1, 5, 15 min) before {load_before}, after {load_after}")

    result = {
        "benchmark": "native vector envs (Gymnasium VectorEnv, SB3 VecEnv) vs SuperSuit over aquarium_v1, CPU",
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "git": git_info(),
        "command": command_line(
            [os.path.relpath(__file__, HERE.parent), *(argv if argv is not None else sys.argv[1:])], "python"
        ),
        "method": {
            "seconds": args.seconds,
            "repeats": args.repeats,
            "warmup_s_min": args.warmup,
            "max_steps": args.max_steps,
            "config": "AquariumConfig() defaults but max_steps",
            "env_step": "one row (agent) step; env-steps/s = rows x vector steps / s",
            "actions": "numpy default_rng(run).integers(0, 16, (64, rows)), cycled",
            "statistic": "median over runs",
            "resets_included": True,
        },
        "machine": machine_info("cpu"),
        "loadavg_before": list(load_before),
        "loadavg_after": list(load_after),
        "versions": _versions(),
        "results": results,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
