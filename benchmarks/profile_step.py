"""Nsight Compute profile of one step: per kernel time, DRAM and L2 traffic, issue and occupancy.

    python benchmarks/profile_step.py --worlds 1 --agents 1000000 [--ncu /usr/local/cuda/bin/ncu]
    python benchmarks/profile_step.py --worlds 1024 --agents 17 --step-kernel fused   # or stages

Runs itself under `ncu` (CUDA only): the child builds the environment, takes warm-up steps, and
then runs the step's launches once, eagerly, between cudaProfilerStart and cudaProfilerStop, so
exactly one step is profiled. Caches are not flushed between kernels and clocks are not locked, so
each kernel sees the caches its predecessors left, as in the graph replay. Prints a table, and the
measured DRAM bytes per agent-step next to `step_byte_model`'s count; writes
`profile_<device>_<worlds>x<agents>[_<step kernel>].json` to `--out-dir` (`--step-kernel`: the env's
option; "auto", the default, takes the fused step on worlds of one cell).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
METRICS = {  # ncu metric: key in the results
    "gpu__time_duration.sum": "time_ns",
    "dram__bytes_read.sum": "dram_read_bytes",
    "dram__bytes_write.sum": "dram_write_bytes",
    "lts__t_bytes.sum": "l2_bytes",
    "smsp__inst_executed.sum": "warp_instructions",
    "smsp__issue_active.avg.pct_of_peak_sustained_active": "issue_active_pct",
    "sm__warps_active.avg.pct_of_peak_sustained_active": "occupancy_pct",
    "smsp__thread_inst_executed_per_inst_executed.ratio": "threads_per_instruction",
    "launch__registers_per_thread": "registers",
}


def child(args) -> int:
    """Warm up, then one eager step between cudaProfilerStart/Stop."""
    import torch
    import warp as wp

    from aquarium_warp import BatchedAquarium
    from aquarium_warp.bench import density_config
    from aquarium_warp.rollout import random_actions

    cfg = density_config(args.agents)
    env = BatchedAquarium(
        cfg, num_worlds=args.worlds, device=args.device, seed=0, cpu_threads=1, step_kernel=args.step_kernel
    )
    gen = torch.Generator(device=env.torch_device).manual_seed(0)
    actions = random_actions(cfg, args.worlds, gen, env.torch_device)
    for _ in range(3):
        env.step(actions, validate=False)
    wp.synchronize_device(env.device)
    torch.cuda.profiler.start()
    env.shards[0].run("step")
    wp.synchronize_device(env.device)
    torch.cuda.profiler.stop()
    return 0


def kernel_label(name: str) -> str:
    """Warp's `<key>_<hash>_cuda_kernel_forward` as `<key>`; CUB's templates as their kernel name."""
    match = re.match(r"(.+?)_[0-9a-f]{8}_cuda_kernel_forward", name)
    if match:
        return match.group(1)
    match = re.match(r"void (?:\w+::)*(\w+)<", name)
    return match.group(1) if match else name[:40]


def parse_ncu_csv(text: str) -> list[dict]:
    """Rows of `ncu --csv --page raw` (a header row, a units row, then one row per kernel)."""
    lines = [line for line in text.splitlines() if line.startswith('"')]
    rows = list(csv.reader(lines))
    if len(rows) < 3:
        raise RuntimeError("ncu profiled no kernel:\n" + text[-2000:])
    header, units = rows[0], rows[1]
    scale = {
        "byte": 1,
        "Kbyte": 1e3,
        "Mbyte": 1e6,
        "Gbyte": 1e9,
        "ns": 1,
        "us": 1e3,
        "usecond": 1e3,
        "msecond": 1e6,
        "nsecond": 1,
    }
    kernels = []
    for row in rows[2:]:
        values = dict(zip(header, row))
        entry = {"kernel": kernel_label(values["Kernel Name"])}
        for metric, key in METRICS.items():
            unit = units[header.index(metric)]
            if key.endswith(("_ns", "_bytes")) and unit not in scale:
                raise RuntimeError(f"unexpected unit {unit!r} of {metric}")
            entry[key] = float(values[metric].replace(",", "")) * scale.get(unit, 1)
        kernels.append(entry)
    return kernels


def summarize(kernels: list[dict], agents: int, model_bytes: float, copy_bandwidth: float | None) -> dict:
    time_s = sum(k["time_ns"] for k in kernels) * 1e-9
    dram = sum(k["dram_read_bytes"] + k["dram_write_bytes"] for k in kernels)
    result = {
        "kernel_time_ms": time_s * 1e3,
        "dram_bytes_per_agent_step": dram / agents,
        "model_bytes_per_agent_step": model_bytes,
        "dram_over_model": dram / agents / model_bytes,
        "dram_bandwidth_tb_s": dram / time_s / 1e12,
        "l2_bytes_per_agent_step": sum(k["l2_bytes"] for k in kernels) / agents,
        "warp_instructions_per_agent_step": sum(k["warp_instructions"] for k in kernels) / agents,
    }
    if copy_bandwidth:
        result["dram_fraction_of_copy"] = dram / time_s / copy_bandwidth
    return result


def format_table(kernels: list[dict], totals: dict, agents: int) -> str:
    lines = [
        f"{'kernel':34s} {'time us':>8s} {'DRAM rd B/ag':>12s} {'DRAM wr B/ag':>12s} {'L2 B/ag':>8s} "
        f"{'instr/ag':>8s} {'issue %':>7s} {'occ %':>6s} {'thr/ins':>7s} {'regs':>4s}"
    ]
    for k in kernels:
        lines.append(
            f"{k['kernel'][:34]:34s} {k['time_ns'] / 1e3:8.1f} {k['dram_read_bytes'] / agents:12.1f} "
            f"{k['dram_write_bytes'] / agents:12.1f} {k['l2_bytes'] / agents:8.1f} "
            f"{k['warp_instructions'] * 32 / agents:8.0f} {k['issue_active_pct']:7.1f} "
            f"{k['occupancy_pct']:6.1f} {k['threads_per_instruction']:7.1f} {k['registers']:4.0f}"
        )
    lines.append(
        f"kernels {totals['kernel_time_ms']:.3f} ms (launched one by one); DRAM "
        f"{totals['dram_bytes_per_agent_step']:.0f} B per agent-step measured vs "
        f"{totals['model_bytes_per_agent_step']:.0f} B in step_byte_model "
        f"({totals['dram_over_model']:.2f}x); {totals['dram_bandwidth_tb_s']:.2f} TB/s over the kernels"
        + (
            f" ({100 * totals['dram_fraction_of_copy']:.1f}% of copy bandwidth)"
            if "dram_fraction_of_copy" in totals
            else ""
        )
    )
    lines.append("instr/ag: thread-instruction slots per agent (warp instructions x 32 / agents)")
    return "\n".join(lines)


def find_ncu(given: str | None) -> str:
    for candidate in (given, shutil.which("ncu"), "/usr/local/cuda/bin/ncu"):
        if candidate and Path(candidate).exists():
            return candidate
    raise SystemExit("ncu (Nsight Compute) not found: pass --ncu PATH")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--worlds", type=int, default=1)
    parser.add_argument("--agents", type=int, default=1_000_000, help="agents per world at the default density")
    parser.add_argument("--ncu", default=None, help="path of the ncu executable (default: PATH, then /usr/local/cuda)")
    parser.add_argument("--out-dir", default=str(REPO / "benchmarks" / "results"))
    parser.add_argument("--git-commit", default=None)
    parser.add_argument(
        "--step-kernel",
        default="auto",
        choices=("auto", "fused", "stages"),
        help="the env's step_kernel option (default auto: fused on worlds of one cell)",
    )
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worlds < 1 or args.agents < 2:
        parser.error(f"--worlds must be >= 1 and --agents >= 2, got {args.worlds} and {args.agents}")
    if not args.device.startswith("cuda"):
        parser.error(f"--device must be a CUDA device (Nsight Compute profiles GPU kernels), got {args.device!r}")
    if args.child:
        return child(args)

    from aquarium_warp.bench import copy_bandwidth, density_config, step_byte_model
    from aquarium_warp.records import command_line, git_info, machine_info

    ncu = find_ncu(args.ncu)
    command = [
        ncu,
        "--profile-from-start",
        "off",
        "--cache-control",
        "none",
        "--clock-control",
        "none",
        "--metrics",
        ",".join(METRICS),
        "--csv",
        "--page",
        "raw",
        sys.executable,
        str(Path(__file__).resolve()),
        "--child",
        "--device",
        args.device,
        "--worlds",
        str(args.worlds),
        "--agents",
        str(args.agents),
        "--step-kernel",
        args.step_kernel,
    ]
    run = subprocess.run(command, capture_output=True, text=True, env=dict(os.environ, GIT_PYTHON_REFRESH="quiet"))
    if run.returncode != 0:
        sys.stderr.write(run.stdout[-3000:] + run.stderr[-3000:])
        return run.returncode
    kernels = parse_ncu_csv(run.stdout)
    cfg = density_config(args.agents)
    agents = args.worlds * cfg.capacity
    copy = copy_bandwidth(args.device)
    totals = summarize(kernels, agents, step_byte_model(cfg)["total"], copy.get("bytes_per_s"))
    print(f"{args.worlds} worlds x {cfg.capacity} agents on {args.device}: one step, kernel by kernel (Nsight Compute)")
    print(format_table(kernels, totals, agents))
    result = {
        "benchmark": "aquarium-warp: Nsight Compute profile of one step",
        "created_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command_line(),
        "ncu_command": " ".join(command[:12]),
        "machine": machine_info(args.device),
        "git": git_info(args.git_commit),
        "copy_bandwidth": copy,
        "worlds": args.worlds,
        "agents_per_world": cfg.capacity,
        "step_kernel": args.step_kernel,
        "kernels": kernels,
        "totals": totals,
    }
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    suffix = "" if args.step_kernel == "auto" else f"_{args.step_kernel}"
    path = out / f"profile_{args.device.replace(':', '')}_{args.worlds}x{cfg.capacity}{suffix}.json"
    path.write_text(json.dumps(result, indent=1))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
