"""Child process for ``benchmarks/original_aquarium.py``: times ONE run of the
original ``marl-aquarium==0.1.10`` environment and prints one JSON line.

This file is self-contained on purpose. It is executed with the python of the
throwaway virtual environment that holds the original package, so it must not
import anything from ``aquarium_warp`` or from the parent benchmark script.

Usage (normally only called by ``original_aquarium.py``)::

    <venv>/bin/python _original_aquarium_child.py --which raw --run 0 \
        --seconds 10 --warmup 2 [--env-kwargs '{"prey_count": 16}']

Method (same as section 13 of the behaviour reference):
  * ``random.seed(run)`` before the env is constructed (the original draws all
    its randomness from the process-global ``random`` module);
  * random actions, uniform over ``Discrete(n)``, one per live agent, drawn from
    ``numpy.random.default_rng(run)``;
  * no rendering (``render()`` is never called, ``close()`` is never called
    because it calls ``sys.exit()``);
  * warm-up of at least ``--warmup`` seconds and at least 3 steps, then a timed
    window of at least ``--seconds`` seconds and at least 3 steps;
  * when ``env.agents`` is empty (episode over) the env is reset inside the
    loop, so resets are included in the timing;
  * agent-steps = sum over timed steps of ``len(env.agents)`` before the step.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import sys
import time

RESULT_MARKER = "ORIGINAL_AQUARIUM_RESULT_JSON:"


def _versions() -> dict:
    from importlib import metadata

    out = {"python": sys.version.split()[0]}
    for dist in ("marl-aquarium", "numpy", "gymnasium", "pettingzoo", "pygame", "moviepy"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _make_env(which: str, env_kwargs: dict):
    if which == "raw":
        from marl_aquarium.env.aquarium import raw_env

        return raw_env(**env_kwargs)
    if which == "parallel":
        from marl_aquarium import aquarium_v0

        return aquarium_v0.parallel_env(**env_kwargs)
    raise ValueError(f"unknown --which {which!r} (expected 'raw' or 'parallel')")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--which", choices=("raw", "parallel"), default="raw")
    ap.add_argument("--run", type=int, default=0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--min-steps", type=int, default=3)
    ap.add_argument("--env-kwargs", default="{}", help="JSON dict of constructor kwargs")
    args = ap.parse_args()

    import numpy as np

    env_kwargs = json.loads(args.env_kwargs)

    t_import0 = time.perf_counter()
    random.seed(args.run)
    rng = np.random.default_rng(args.run)
    env = _make_env(args.which, env_kwargs)
    env.reset()
    construct_reset_s = time.perf_counter() - t_import0

    n_actions: dict[str, int] = {}
    resets = 0

    def one_step() -> int:
        nonlocal resets
        if not env.agents:
            env.reset()
            resets += 1
        agents = list(env.agents)
        n = len(agents)
        for a in agents:
            if a not in n_actions:
                n_actions[a] = int(env.action_space(a).n)
        draws = rng.random(n)
        actions = {a: int(d * n_actions[a]) for a, d in zip(agents, draws)}
        env.step(actions)
        return n

    # Warm-up.
    warm_steps = 0
    t0 = time.perf_counter()
    while True:
        one_step()
        warm_steps += 1
        if warm_steps >= args.min_steps and time.perf_counter() - t0 >= args.warmup:
            break
    warmup_s = time.perf_counter() - t0

    # Timed window (resets included).
    resets = 0
    steps = 0
    agent_steps = 0
    perf = time.perf_counter
    t0 = perf()
    while True:
        agent_steps += one_step()
        steps += 1
        if steps >= args.min_steps and perf() - t0 >= args.seconds:
            break
    elapsed = perf() - t0

    result = {
        "which": args.which,
        "run": args.run,
        "env_kwargs": env_kwargs,
        "optimize": bool(sys.flags.optimize),
        "steps": steps,
        "agent_steps": agent_steps,
        "elapsed_s": elapsed,
        "env_steps_per_s": steps / elapsed,
        "agent_steps_per_s": agent_steps / elapsed,
        "mean_agents": agent_steps / steps,
        "resets_in_window": resets,
        "warmup_steps": warm_steps,
        "warmup_s": warmup_s,
        "construct_reset_s": construct_reset_s,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "pid": os.getpid(),
        "versions": _versions(),
    }
    sys.stdout.write(RESULT_MARKER + json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
