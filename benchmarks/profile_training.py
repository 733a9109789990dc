"""Where one training iteration's device time goes: every kernel of one iteration of the fast loop
(`TrainingLoop.phase_times`), its launches and its device time, from torch's profiler (CUPTI).

    python benchmarks/profile_training.py --device cuda:0 --worlds 65536 --variant fused-tf32

The paper task, as `bench_training.py` trains it (`--variant`: one of its variants). The iteration
runs without CUDA graphs (`train.cuda_graphs=false`), so that each kernel is seen on its own: the
kernels and their device times are those a graph replays, the gaps between launches are not (the
table sums device time only; on the CPU, each op's own CPU time). Prints the kernels by time and writes
`profile_training_<device>_<worlds>.json` (commit, command, machine, versions, every kernel) into
`--out-dir`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench_training import VARIANTS, variant_changes

from aquarium_warp.atomic import atomic_open
from aquarium_warp.bench import parse_counts
from aquarium_warp.records import command_line, provenance
from aquarium_warp.training import Trainer, make_config


def profile(device: str, worlds: int, variant: str, warmup: int) -> tuple[list[dict], dict]:
    """The kernels of one profiled iteration after `warmup` iterations (name, launches, ms: device
    time on CUDA, the op's own CPU time on the CPU), longest first, and the iteration's phase times
    (ms, CUDA events or host timers)."""
    changes = {"train": {"num_worlds": worlds, "device": device, "quiet": True, "export": [], "iterations": warmup + 1}}
    cfg = make_config("paper", *variant_changes(variant), changes, {"train": {"cuda_graphs": False}})
    trainer = Trainer(cfg)
    trainer.train(warmup)
    activities = [torch.profiler.ProfilerActivity.CPU]
    if trainer.device.type == "cuda":
        torch.cuda.synchronize(trainer.device)
        activities.append(torch.profiler.ProfilerActivity.CUDA)
    with torch.profiler.profile(activities=activities) as prof:
        phases = trainer.runner.loop.phase_times()
        if trainer.device.type == "cuda":
            torch.cuda.synchronize(trainer.device)
    trainer.close()
    cuda = trainer.device.type == "cuda"
    # On CUDA the device's own events (kernels, copies), not the CPU ops that launched them, nor the
    # ranges annotated on the GPU's timeline (`record_function`, e.g. the optimizer's step): each
    # kernel's time counted once.
    kernels = [
        {"name": e.key, "launches": e.count, "ms": (e.device_time_total if cuda else e.self_cpu_time_total) / 1e3}
        for e in prof.key_averages()
        if (e.device_type == torch.autograd.DeviceType.CUDA) == cuda and not e.is_user_annotation
    ]
    kernels = [k for k in kernels if k["ms"] > 0]
    return sorted(kernels, key=lambda k: -k["ms"]), {k: 1e3 * v for k, v in phases.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda:0" if torch.cuda.is_available() else "cpu")
    p.add_argument("--worlds", default="65536", help="world counts, comma-separated")
    p.add_argument("--variant", default="fused-tf32", choices=sorted(VARIANTS))
    p.add_argument("--warmup", type=int, default=2, help="iterations before the profiled one")
    p.add_argument("--top", type=int, default=30, help="kernels printed")
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    p.add_argument("--out-dir", default=".", help="where the JSON goes")
    args = p.parse_args(argv)
    try:
        counts = parse_counts(args.worlds, "--worlds")
    except ValueError as error:
        p.error(str(error))
    if args.warmup < 0 or args.top < 0:
        p.error(f"--warmup={args.warmup} and --top={args.top} must be >= 0")
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for worlds in counts:
        kernels, phases = profile(args.device, worlds, args.variant, args.warmup)
        total = sum(k["ms"] for k in kernels)
        print(
            f"{worlds} worlds, {args.variant}: {len(kernels)} kernels, {total:.2f} ms; phases (ms) "
            + " ".join(f"{k} {v:.2f}" for k, v in phases.items())
        )
        for k in kernels[: args.top]:
            print(f"{k['ms']:9.3f} ms {k['launches']:6d} x  {k['name'][:100]}")
        result = {
            "benchmark": "profile_training",
            "task": "paper",
            "worlds": worlds,
            "variant": args.variant,
            "time": "device time" if args.device.startswith("cuda") else "self CPU time",
            "ms": total,
            "phase_ms": phases,
            "kernels": kernels,
            **provenance(args.device, command_line(argv, Path(sys.argv[0]).name), args.commit),
        }
        path = out_dir / f"profile_training_{args.device.replace(':', '')}_{worlds}.json"
        with atomic_open(path) as f:
            json.dump(result, f, indent=1)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
