"""Populations against separate processes: runs per hour and agent-steps per second of K trainings in
one process (`training/population.py`) beside the same trainings as separate processes, measured in
the same run on the same card.

Rate points (the default): for each K of `--runs`, a population of K runs of `--preset` (each
`--worlds` worlds) runs `--warmup` untimed iterations (CUDA graphs are captured there), then
`--iterations` timed ones; agent-steps are the learning team's rows x steps of all runs. The update's
and the rollout's floors on this card (`aquarium_warp/bench/floors.py`, as `bench_training.py` gives them; the
population's work is K runs' samples) and the fraction reached. Beside them, the separate processes:
`--separate P` processes of one run each (as `--per-gpu P` runs a study's trainings), each warmed up
and then training for `--seconds` of wall time in one common window; their summed rate is what P
processes at a time reach, whatever K. Runs per hour count the preset's whole budget
(`total_iterations`) at the measured rates,
without start-up; `--whole` measures whole trainings with it.

Whole points (`--whole`): `aquarium-warp train --preset P --runs K` as a user runs it (start-up,
compilation, checkpoints, export included), wall time from launch to exit; beside it, `--separate P`
processes of `aquarium-warp train --preset P` (one run each) at a time, `--whole-separate N` runs in
all, wall time per batch; runs per hour of both.

    python benchmarks/bench_population.py --device cuda:0 --preset learned-prey-b --runs 1,4,16,64,256 \\
        --set train.fused_mlp=true --set train.tf32=true --separate 3
    python benchmarks/bench_population.py --device cuda:0 --preset swarm --whole --runs 64 --separate 3
    python benchmarks/bench_population.py --device cpu --preset tiny --runs 1,4 --separate 2 --iterations 2

Prints a table and writes `population_<device>[_whole].json` into `--out-dir`, with the command, the
commit, the machine and the versions, rewritten after every point.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench_training import device_name, milliseconds, percent  # (benchmarks/ is on the path)

from aquarium_warp.atomic import atomic_open
from aquarium_warp.bench import parse_counts
from aquarium_warp.bench.floors import Floor, card_peaks, rollout_work, update_work
from aquarium_warp.device import synchronize
from aquarium_warp.records import command_line, provenance
from aquarium_warp.training import Trainer, make_config
from aquarium_warp.training.config import parse_assignment, total_iterations
from aquarium_warp.training.population import Population, run_configs


def config_of(preset: str, device: str, worlds: int, sets: list[str], iterations: int) -> dict:
    changes: dict = {}
    from aquarium_warp.training.config import deep_update

    for s in sets:
        deep_update(changes, parse_assignment(s))
    config = make_config(preset, changes)
    config["train"].update(device=device, num_worlds=worlds, quiet=True, export=[], iterations=iterations)
    config["train"]["episodes"] = None
    return config


def population_rate(args, runs: int) -> dict:
    """One rate point: a population of `runs` runs (see the module doc)."""
    config = config_of(args.preset, args.device, args.worlds, args.set, args.warmup + args.iterations)
    budget = total_iterations(make_config(args.preset))
    population = Population(run_configs(config, runs))
    population.train(args.warmup)  # the first iteration eager, the graphs captured in the second
    dev = population.device
    synchronize(dev)
    start = time.perf_counter()
    population.train(args.iterations)
    synchronize(dev)
    elapsed = time.perf_counter() - start
    steps = population.runner_cfgs[0]["num_steps_per_env"]
    rows = population.vec_env.num_envs
    point = {
        "runs": runs,
        "worlds_per_run": args.worlds,
        "rows": rows,
        "learner": "stacked" if population.stacked else "per-run",
        "fused": population.learner.fused_loss is not None if population.stacked else False,
        "iterations": args.iterations,
        "iteration_ms": 1e3 * elapsed / args.iterations,
        "agent_steps_per_s": rows * steps * args.iterations / elapsed,
        "runs_per_hour": runs * 3600.0 / (budget * elapsed / args.iterations),
        "budget_iterations": budget,
    }
    if population.stacked:
        phases = population.loop.phase_times()
        point["phase_ms"] = {k: 1e3 * v for k, v in phases.items()}
        peaks, tf32 = card_peaks(device_name(dev)), population.path.tf32
        alg = population.learner
        floor = Floor(update_work(alg), peaks, tf32=tf32)
        point["floor"] = floor.record({"iteration": elapsed / args.iterations, "update": phases["update"]})
        rollout = Floor(rollout_work(alg, population.env.state), peaks, tf32=tf32)
        point["rollout_floor"] = rollout.record({"rollout": sum(v for k, v in phases.items() if k != "update")})
    population.close()
    del population
    if dev.type == "cuda":
        torch.cuda.empty_cache()
    return point


def single_rate(args, barrier: str, index: int) -> dict:
    """One run alone (`Trainer`), as one of the separate processes: warm, it waits at the barrier (a
    folder where each process says it is ready) until all are, then trains `--seconds` of wall time
    (whole iterations), so the processes' timed windows overlap."""
    config = config_of(args.preset, args.device, args.worlds, args.set, 10**6)
    trainer = Trainer(config)
    trainer.train(args.warmup)
    synchronize(trainer.device)
    open(os.path.join(barrier, f"ready-{index}"), "w").close()
    while len(os.listdir(barrier)) < args.separate:
        time.sleep(0.01)
    start, done = time.perf_counter(), 0
    while time.perf_counter() - start < args.seconds:
        trainer.train(1)
        done += 1
    synchronize(trainer.device)
    elapsed = time.perf_counter() - start
    rows, steps = trainer.vec_env.num_envs, trainer.runner_cfg["num_steps_per_env"]
    trainer.close()
    return {"seconds": elapsed, "iterations": done, "agent_steps_per_s": rows * steps * done / elapsed,
            "window": [time.time() - elapsed, time.time()]}  # fmt: skip


def separate_rates(args) -> dict:
    """`--separate P` processes of one run each, timed over one common window; their summed rate."""
    import tempfile

    barrier = tempfile.mkdtemp(prefix="bench-population-")
    procs = [subprocess.Popen([sys.executable, __file__, "--single", barrier, str(i), *sys.argv[1:]],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(args.separate)]  # fmt: skip
    results = []
    for proc in procs:
        out, err = proc.communicate()
        lines = [line for line in out.splitlines() if line.startswith("SINGLE ")]
        if proc.returncode != 0 or not lines:
            raise RuntimeError(f"a separate process failed (exit {proc.returncode}): {err.strip()[-1500:]}")
        results.append(json.loads(lines[-1][len("SINGLE ") :]))
    budget = total_iterations(make_config(args.preset))
    rate = sum(r["agent_steps_per_s"] for r in results)
    per_run = sum(r["seconds"] / r["iterations"] for r in results) / len(results)  # seconds per iteration
    return {
        "processes": args.separate,
        "agent_steps_per_s": rate,
        "each": results,
        "runs_per_hour": args.separate * 3600.0 / (budget * per_run),
    }


def whole(args, runs: int, out_dir: Path) -> dict:
    """`--whole`: K runs as one command, and the same preset's runs as separate commands (see the doc)."""
    sets = [x for s in args.set for x in ("--set", s)]
    base = [sys.executable, "-m", "aquarium_warp", "train", "--preset", args.preset, "--device", args.device,
            "--quiet", *sets]  # fmt: skip
    work = out_dir / "whole-runs"
    start = time.perf_counter()
    done = subprocess.run([*base, "--runs", str(runs), "--log-dir", str(work / f"population-{runs}"), "--overwrite"],
                          capture_output=True, text=True)  # fmt: skip
    together = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"the population failed: {done.stderr.strip()[-1500:]}")
    point = {"runs": runs, "population_seconds": together, "population_runs_per_hour": runs * 3600.0 / together}
    if args.whole_separate:
        batches, n = [], 0
        while n < args.whole_separate:
            batch = min(args.separate, args.whole_separate - n)
            start = time.perf_counter()
            procs = [subprocess.Popen([*base, "--seed", str(n + i), "--log-dir", str(work / f"alone-{n + i}"),
                                       "--overwrite"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                     for i in range(batch)]  # fmt: skip
            for proc in procs:
                _, err = proc.communicate()
                if proc.returncode != 0:
                    raise RuntimeError(f"a separate run failed: {err.strip()[-1500:]}")
            batches.append(time.perf_counter() - start)
            n += batch
        point["separate_batches_seconds"] = batches
        point["separate_runs"] = n
        point["separate_runs_per_hour"] = n * 3600.0 / sum(batches)
    return point


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    single = bool(argv) and argv[0] == "--single"  # one of the separate processes: --single BARRIER INDEX ...
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda:0" if torch.cuda.is_available() else "cpu")
    p.add_argument("--preset", default="learned-prey-b", help="each run's preset (default: the learned-prey recipe)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config changes of every run")
    p.add_argument("--worlds", type=int, default=None, help="worlds per run (default: the preset's)")
    p.add_argument("--runs", default="1,4,16,64,256", help="population sizes K, a comma list")
    p.add_argument("--separate", type=int, default=3, help="separate processes at a time (0: none)")
    p.add_argument("--warmup", type=int, default=3, help="untimed iterations first")
    p.add_argument("--iterations", type=int, default=10, help="timed iterations")
    p.add_argument("--whole", action="store_true", help="time whole trainings instead (see the doc)")
    p.add_argument("--whole-separate", type=int, default=0, help="--whole: separate runs to time, in batches")
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    p.add_argument("--out-dir", default=".", help="where the JSON goes")
    p.add_argument("--seconds", type=float, default=20.0, help="wall time the separate processes train, together")
    args = p.parse_args(argv[3:] if single else argv)
    if args.worlds is None:
        args.worlds = int(make_config(args.preset)["train"]["num_worlds"])
    try:
        counts = parse_counts(args.runs, "--runs")
    except ValueError as error:
        p.error(str(error))
    if single:
        print("SINGLE " + json.dumps(single_rate(args, argv[1], int(argv[2]))), flush=True)
        return 0
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {
        "benchmark": "bench_population",
        "preset": args.preset,
        "sets": args.set,
        "worlds_per_run": args.worlds,
        "device_name": device_name(torch.device(args.device)),
        **provenance(args.device, command_line(argv, Path(sys.argv[0]).name), args.commit),
        "points": [],
    }
    stem = f"population_{args.device.replace(':', '')}" + ("_whole" if args.whole else "")

    def write() -> None:
        with atomic_open(out_dir / f"{stem}.json") as f:
            json.dump(result, f, indent=2)

    if args.whole:
        print(f"{'runs':>5} {'population s':>13} {'runs/h':>9} {'separate s':>24} {'runs/h':>9}", flush=True)
        for k in counts:
            pt = whole(args, k, out_dir)
            result["points"].append(pt)
            write()
            sep = pt.get("separate_batches_seconds", [])
            print(
                f"{k:>5} {pt['population_seconds']:>13.1f} {pt['population_runs_per_hour']:>9.0f} "
                f"{' '.join(f'{s:.1f}' for s in sep):>24} {pt.get('separate_runs_per_hour', 0):>9.0f}",
                flush=True,
            )
        return 0
    if args.separate:
        result["separate"] = separate_rates(args)
        write()
        sep = result["separate"]
        print(
            f"separate: {sep['processes']} processes at a time, {sep['agent_steps_per_s']:.3e} agent-steps/s, "
            f"{sep['runs_per_hour']:.0f} runs/h (budget {total_iterations(make_config(args.preset))} iterations)"
        )
    print(
        f"{'runs':>5} {'rows':>9} {'ms/it':>9} {'agent-steps/s':>14} {'runs/h':>9} {'x sep':>6} {'floor ms':>9} "
        f"{'% it':>6} {'% upd':>6} {'roll fl':>8} {'% roll':>6}",
        flush=True,
    )
    for k in counts:
        try:
            pt = population_rate(args, k)
        except Exception as error:  # noqa: BLE001  (a point that does not fit is reported, not fatal)
            pt = {"runs": k, "error": repr(error)[:2000]}
            print(f"{k:>5} failed: {error!r}"[:400], flush=True)
        else:
            floor, roll = pt.get("floor", {}), pt.get("rollout_floor", {})
            ratio = pt["agent_steps_per_s"] / result["separate"]["agent_steps_per_s"] if args.separate else float("nan")
            print(
                f"{k:>5} {pt['rows']:>9} {pt['iteration_ms']:>9.2f} {pt['agent_steps_per_s']:>14.3e} "
                f"{pt['runs_per_hour']:>9.0f} {ratio:>6.2f} {milliseconds(floor.get('seconds')):>9} "
                f"{percent(floor.get('fraction_of_iteration')):>6} {percent(floor.get('fraction_of_update')):>6} "
                f"{milliseconds(roll.get('seconds')):>8} {percent(roll.get('fraction_of_rollout')):>6}",
                flush=True,
            )
        result["points"].append(pt)
        write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
