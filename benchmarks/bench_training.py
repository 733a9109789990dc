"""End-to-end PPO training speed: agent-steps per second of `aquarium-warp train` (rollout + update),
the fast loop (`training/loop.py`) beside rsl-rl's own runner loop, measured in the same run.

The task is the paper preset's (6 prey learning against one NaivChase predator, two tanh layers of 64,
32 steps per iteration, 5 epochs x 4 mini-batches); `--worlds` varies the batch. Every point: a
trainer is built, `--warmup` iterations run (the first of the fast loop on CUDA is eager, the second
captures its graphs), then `--iterations` timed iterations (synchronised at the end). Agent-steps are
learning-team rows x steps, as the paper counts prey-steps. The fast loop's time is then split into
policy / env / storage / update (rollout / update where one CUDA graph replays the whole rollout) by
one more iteration bracketed by CUDA events (or host timers).

Beside each point: the update's floor on this card (`aquarium_warp.bench.floors`: the actor's and
critic's matrix products forward and backward over every sample of the 5 epochs at the card's float32
peak, or the bytes no update can avoid at its memory bandwidth, whichever is longer; "n/a" for a card
without peaks in its table, the CPU included) and the fraction of it reached by the update's time and by
the whole iteration's; then the rollout's floor (the actor's and critic's forward for every sample,
or the bytes the simulation, the policy and the storage must move every step) and the fraction of it
reached by the rollout's time (policy, env and storage together).

    python benchmarks/bench_training.py --device cuda:0 --worlds 256,1024,4096,16384,65536
    python benchmarks/bench_training.py --device cpu --worlds 64,256 --iterations 3

Prints a table, writes `training_<device>.json` (and `.png` with `--plot`) into `--out-dir`
(default: the current directory); the JSON records the command, the commit (`--commit` where git is
not available), the machine and the library versions, and is rewritten (atomically) after every
point, so a time limit keeps what was measured.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.atomic import atomic_open
from aquarium_warp.bench import parse_counts
from aquarium_warp.bench.floors import Floor, card_peaks, rollout_work, update_work
from aquarium_warp.device import synchronize
from aquarium_warp.records import command_line, provenance
from aquarium_warp.training import Trainer, make_config
from aquarium_warp.training.fast_path import TORCH_FLOAT32


def device_name(device: torch.device) -> str:
    return torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or platform.machine()


# Options measured beside the default (`--variants`; "default": the run config's defaults, `train.fused_mlp`
# and `train.tf32` as `training/fast_path.py` resolves them). The others start from torch's MLP in float32
# (`TORCH_FLOAT32`, "torch"): TF32 matrix products, rsl-rl's own `torch_compile_mode` (torch.compile
# of the actor and critic, fusing their elementwise work), no CUDA graphs, the fused MLP (`train.fused_mlp`:
# float32 products, and with `tf32` TF32 products), and the adaptive learning-rate schedule (its update runs
# eagerly between replayed rollouts, as a torchrun run's does).
ADAPTIVE = {"runner": {"algorithm": {"schedule": "adaptive", "desired_kl": 0.01}}}
VARIANTS = {
    "default": {},
    "torch": {},
    "tf32": {"train": {"tf32": True}},
    "compile": {"runner": {"torch_compile_mode": "default"}},
    "tf32+compile": {"train": {"tf32": True}, "runner": {"torch_compile_mode": "default"}},
    "eager": {"train": {"cuda_graphs": False}},
    "fused": {"train": {"fused_mlp": True}},
    "fused-tf32": {"train": {"fused_mlp": True, "tf32": True}},
    "adaptive": ADAPTIVE,
    "adaptive+eager": {**ADAPTIVE, "train": {"cuda_graphs": False}},
}


def variant_changes(variant: str) -> tuple[dict, ...]:
    """The run config changes of a variant (see `VARIANTS`)."""
    return ({}, {}) if variant == "default" else ({"train": TORCH_FLOAT32}, VARIANTS[variant])


def measure(
    device: str, worlds: int, sharing: str, loop: str, warmup: int, iterations: int, variant: str = "default"
) -> dict:
    changes = {
        "train": {
            "num_worlds": worlds,
            "device": device,
            "sharing": sharing,
            "loop": loop,
            "quiet": True,
            "export": [],
            "iterations": warmup + iterations + 1,
        }
    }
    cfg = make_config("paper", changes, *variant_changes(variant))
    torch.backends.cuda.matmul.allow_tf32 = False  # process-wide: a TF32 variant must not leak into the next
    trainer = Trainer(cfg)
    dev = trainer.device
    rows = trainer.vec_env.num_envs
    steps = trainer.runner_cfg["num_steps_per_env"]
    start = time.perf_counter()
    trainer.train(warmup)
    synchronize(dev)
    warmup_time = time.perf_counter() - start
    start = time.perf_counter()
    trainer.train(iterations)
    synchronize(dev)
    elapsed = time.perf_counter() - start
    point = {
        "worlds": worlds,
        "rows": rows,
        "sharing": sharing,
        "loop": loop,
        "variant": variant,
        "graphs": bool(loop == "fast" and trainer.runner.loop.graphs),
        "update_graphs": list(trainer.runner.loop.update_graphs) if loop == "fast" else [],
        "iterations": iterations,
        "seconds": elapsed,
        "warmup_seconds": warmup_time,
        "iteration_ms": 1e3 * elapsed / iterations,
        "agent_steps_per_s": rows * steps * iterations / elapsed,
    }
    measured = {"iteration": elapsed / iterations}
    rollout_measured = {}
    if loop == "fast":
        phases = trainer.runner.loop.phase_times()
        point["phase_ms"] = {k: 1e3 * v for k, v in phases.items()}
        measured["update"] = phases["update"]
        rollout_measured["rollout"] = sum(v for k, v in phases.items() if k != "update")
    peaks, tf32 = card_peaks(device_name(dev)), trainer.path.tf32
    floor = Floor(update_work(trainer.runner.alg), peaks, tf32=tf32)
    point["floor"] = floor.record(measured)
    point["floor_text"] = floor.describe()
    rollout = Floor(rollout_work(trainer.runner.alg, trainer.env.state), peaks, tf32=tf32)
    point["rollout_floor"] = rollout.record(rollout_measured)
    point["rollout_floor_text"] = rollout.describe()
    trainer.close()
    del trainer
    if dev.type == "cuda":
        torch.cuda.empty_cache()
    return point


def measure_in_subprocess(args, worlds: int, sharing: str, loop: str, variant: str) -> dict:
    """`measure` in a fresh process, as a user's run would be: no allocator, cuBLAS or graph state
    carried over from the previous point, and a failed point cannot disturb the next."""
    import subprocess

    point = json.dumps(
        {
            "device": args.device,
            "worlds": worlds,
            "sharing": sharing,
            "loop": loop,
            "warmup": args.warmup,
            "iterations": args.iterations,
            "variant": variant,
            "blas": args.blas,
        }
    )
    done = subprocess.run([sys.executable, __file__, "--point", point], capture_output=True, text=True)
    lines = [line for line in done.stdout.splitlines() if line.startswith("POINT ")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"exit {done.returncode}: {(done.stderr or done.stdout).strip()[-1500:]}")
    return json.loads(lines[-1][len("POINT ") :])


def run_point(text: str) -> int:
    spec = json.loads(text)
    blas = spec.pop("blas")
    if blas is not None:
        torch.backends.cuda.preferred_blas_library(blas)
    print("POINT " + json.dumps(measure(**spec)), flush=True)
    return 0


def loop_speedups(points: list[dict]) -> list[dict]:
    """Per world count and sharing: the fast loop's default variant over rsl-rl's loop."""
    points_ok = [q for q in points if "error" not in q]
    speedups = []
    for fast in (q for q in points_ok if q["loop"] == "fast" and q["variant"] == "default"):
        ref = [
            q
            for q in points_ok
            if q["loop"] == "rsl-rl" and q["worlds"] == fast["worlds"] and q["sharing"] == fast["sharing"]
        ]
        if ref:
            speedups.append(
                {
                    "worlds": fast["worlds"],
                    "sharing": fast["sharing"],
                    "speedup": fast["agent_steps_per_s"] / ref[0]["agent_steps_per_s"],
                }
            )
    return speedups


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) == 2 and argv[0] == "--point":
        return run_point(argv[1])
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda:0" if torch.cuda.is_available() else "cpu")
    p.add_argument(
        "--worlds",
        default="256,1024,4096,16384,65536",
        help="world counts, a comma list; '...' continues the progression",
    )
    p.add_argument("--sharing", default="parameter,individual", help="parameter and/or individual")
    p.add_argument("--loops", default="fast,rsl-rl", help="fast and/or rsl-rl")
    p.add_argument("--variants", default="default", help=f"fast-loop variants, comma-separated: {', '.join(VARIANTS)}")
    p.add_argument(
        "--rsl-rl-max-worlds", type=int, default=65536, help="measure rsl-rl's loop only up to this many worlds"
    )
    p.add_argument("--warmup", type=int, default=2, help="untimed iterations first")
    p.add_argument("--iterations", type=int, default=10, help="timed iterations")
    p.add_argument(
        "--blas",
        choices=("cublas",),
        default=None,
        help="torch.backends.cuda.preferred_blas_library for every point (default: torch's choice)",
    )
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    p.add_argument("--out-dir", default=".", help="where the JSON (and plot) go")
    p.add_argument("--plot", action="store_true", help="also write a PNG plot")
    args = p.parse_args(argv)
    try:
        worlds = parse_counts(args.worlds, "--worlds")
    except ValueError as error:
        p.error(str(error))
    for name, value in (("--warmup", args.warmup), ("--iterations", args.iterations)):
        if value < (0 if name == "--warmup" else 1):
            p.error(f"{name} must be >= {0 if name == '--warmup' else 1}")
    sharings = [s for s in args.sharing.split(",") if s]
    loops = [s for s in args.loops.split(",") if s]
    if not set(sharings) <= {"parameter", "individual"} or not set(loops) <= {"fast", "rsl-rl"}:
        p.error("--sharing takes parameter,individual and --loops takes fast,rsl-rl")
    variants = [v for v in args.variants.split(",") if v]
    if not variants or not set(variants) <= set(VARIANTS):
        p.error(f"--variants takes {', '.join(VARIANTS)}")

    from importlib.metadata import version

    import warp as wp

    result = {
        "benchmark": "bench_training",
        "task": "paper preset (6 prey vs NaivChase, 2x64 tanh, T=32, 5x4)",
        "device": args.device,
        "device_name": device_name(torch.device(args.device)),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "warp": wp.__version__,
        "rsl_rl": version("rsl-rl-lib"),
        # command, git (commit, dirty) and machine (device, driver, versions)
        **provenance(args.device, command_line(argv, Path(sys.argv[0]).name), args.commit),
        "points": [],
        "speedups": [],
    }
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"training_{args.device.replace(':', '')}"
    points = result["points"]
    header = (
        f"{'worlds':>7} {'rows':>8} {'sharing':>10} {'loop':>7} {'variant':>12} {'ms/it':>9} "
        f"{'agent-steps/s':>14} {'floor ms':>9} {'% it':>6} {'% upd':>6} {'roll fl':>8} {'% roll':>6}  phases (ms)"
    )
    print(header, flush=True)
    for w in worlds:
        for sharing in sharings:
            runs = [("fast", v) for v in variants if "fast" in loops]
            if "rsl-rl" in loops and w <= args.rsl_rl_max_worlds:
                runs.append(("rsl-rl", "default"))
            for loop, variant in runs:
                try:
                    pt = measure_in_subprocess(args, w, sharing, loop, variant)
                except Exception as error:  # noqa: BLE001  (a point that does not run here is reported, not fatal)
                    print(f"{w:>7} {'':>8} {sharing:>10} {loop:>7} {variant:>12} failed: {error!r}"[:400], flush=True)
                    pt = {
                        "worlds": w,
                        "sharing": sharing,
                        "loop": loop,
                        "variant": variant,
                        "error": repr(error)[:2000],
                    }
                else:
                    phases = " ".join(f"{k} {v:.2f}" for k, v in pt.get("phase_ms", {}).items())
                    floor, rollout = pt["floor"], pt["rollout_floor"]
                    reached = [floor.get(f"fraction_of_{k}") for k in ("iteration", "update")]
                    print(
                        f"{w:>7} {pt['rows']:>8} {sharing:>10} {loop:>7} {variant:>12} {pt['iteration_ms']:>9.2f} "
                        f"{pt['agent_steps_per_s']:>14.3e} {milliseconds(floor['seconds']):>9} "
                        + " ".join(f"{percent(r):>6}" for r in reached)
                        + f" {milliseconds(rollout['seconds']):>8} {percent(rollout.get('fraction_of_rollout')):>6}"
                        + f"  {phases}",
                        flush=True,
                    )
                points.append(pt)
                result["speedups"] = loop_speedups(points)
                with atomic_open(out_dir / f"{stem}.json") as f:  # after every point: a time limit keeps them
                    json.dump(result, f, indent=2)
    for s in result["speedups"]:
        print(f"speed-up fast / rsl-rl loop: {s['worlds']:>6} worlds {s['sharing']:>10}: {s['speedup']:.1f}x")
    points_ok = [q for q in points if "error" not in q]
    if points_ok:
        print(f"floor of the update ({points_ok[-1]['worlds']} worlds): {points_ok[-1]['floor_text']}")
        print(f"floor of the rollout ({points_ok[-1]['worlds']} worlds): {points_ok[-1]['rollout_floor_text']}")
    print(f"wrote {out_dir / (stem + '.json')}")
    if args.plot:
        plot(result, out_dir / f"{stem}.png")
    return 0


def milliseconds(seconds: float | None) -> str:
    return "n/a" if seconds is None else format(1e3 * seconds, ".2f")


def percent(fraction: float | None) -> str:
    return "-" if fraction is None else format(100 * fraction, ".1f")


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for loop, style in (("fast", "-"), ("rsl-rl", "--")):
        for sharing, marker in (("parameter", "o"), ("individual", "s")):
            pts = [
                q
                for q in result["points"]
                if q["loop"] == loop
                and q["sharing"] == sharing
                and q.get("variant", "default") == "default"
                and "error" not in q
            ]
            if pts:
                ax.plot(
                    [q["worlds"] for q in pts],
                    [q["agent_steps_per_s"] for q in pts],
                    style,
                    marker=marker,
                    label=f"{'fast loop' if loop == 'fast' else 'rsl-rl runner'}, "
                    f"{'PS' if sharing == 'parameter' else 'IL'}",
                )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("worlds (6 learning prey each)")
    ax.set_ylabel("agent-steps per second, end to end")
    ax.set_title(f"PPO training speed, {result['device_name']}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
