"""The fused PPO update's time per kernel shape: rows per tile of the backward and loss kernels, warps
per program, persistent programs per multiprocessor, and (with TF32 products) tanh as the
multiprocessor's approximation or as the float32 formula. What `training/fused_mlp.py`'s choices
(`block_rows`, `NUM_WARPS`, `PROGRAMS_PER_SM`, `FAST_TANH_WITH_TF32`) rest on; rerun it on a new card.

The learner of `--preset` at `--worlds` worlds is built, its storage filled as a rollout leaves it
(`bench_fused_update.fill_storage`), and for each shape the whole update with the fused loss
(`bench_fused_update.MLPSwitch`, path "fused") is timed: on CUDA the median of `--repeats` replays of
a CUDA graph of one update, on the CPU (Triton's interpreter, a smoke test) eagerly. Each shape sets
the module settings above for the run; the compiled kernels' registers and spills (CUDA) come with
the table. `--act-rows` also times the fused rollout step (`fused_ppo.FusedAct.act`: actor, sampler,
critic and storage writes for every row of one step) per rows per tile of `_act_kernel` and warps
(`--act-warps`), the median of `--repeats` runs of 20 steps.

    python benchmarks/tune_fused_kernels.py --device cuda:0 --worlds 65536 --tf32
    python benchmarks/tune_fused_kernels.py --device cuda:0 --worlds 65536 --tf32 --rows 32 --warps 4 \
        --programs 2 --act-rows 32,64,128,256 --act-warps 4,8
    TRITON_INTERPRET=1 python benchmarks/tune_fused_kernels.py --device cpu --preset tiny --worlds 2 \
        --rows 32 --warps 4 --programs 2 --repeats 1

Prints each shape's time as it is measured and writes JSON (atomically, after every shape) with the
command, the commit (`--commit` where git is not available), the machine and the library versions.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import bench_fused_update as bench

from aquarium_warp.arguments import parse_list
from aquarium_warp.atomic import atomic_open
from aquarium_warp.device import synchronize
from aquarium_warp.records import command_line, provenance
from aquarium_warp.training import fused_mlp, fused_ppo


@contextlib.contextmanager
def kernel_shape(rows: int, warps: int, programs: int, fast_tanh: bool):
    """The fused kernels' shape settings for the duration (restored after)."""
    saved = (fused_mlp.block_rows, fused_mlp.NUM_WARPS, fused_ppo.NUM_WARPS, fused_mlp.PROGRAMS_PER_SM,
             fused_mlp.FAST_TANH_WITH_TF32)  # fmt: skip
    forward_rows = fused_mlp.block_rows
    fused_mlp.block_rows = lambda spec, backward=False: rows if backward else forward_rows(spec)
    fused_mlp.NUM_WARPS = fused_ppo.NUM_WARPS = warps
    fused_mlp.PROGRAMS_PER_SM = programs
    fused_mlp.FAST_TANH_WITH_TF32 = fast_tanh
    try:
        yield
    finally:
        (fused_mlp.block_rows, fused_mlp.NUM_WARPS, fused_ppo.NUM_WARPS, fused_mlp.PROGRAMS_PER_SM,
         fused_mlp.FAST_TANH_WITH_TF32) = saved  # fmt: skip


@contextlib.contextmanager
def act_shape(rows: int, warps: int):
    """The fused rollout step's rows per tile and warps for the duration (restored after)."""
    saved = fused_ppo.block_rows, fused_ppo.NUM_WARPS
    fused_ppo.block_rows = lambda spec, backward=False: rows
    fused_ppo.NUM_WARPS = warps
    try:
        yield
    finally:
        fused_ppo.block_rows, fused_ppo.NUM_WARPS = saved


def time_act(alg, repeats: int, steps: int = 20) -> float:
    """Median seconds of one fused rollout step over the learner's storage rows (each run: `steps`
    steps into the storage's first step, on the observations stored there)."""
    act = fused_ppo.FusedAct(alg)
    obs = {act.group: alg.storage.observations[act.group][0].clone()}
    times = []
    for _ in range(repeats + 1):  # the first run compiles the kernel: untimed
        synchronize(torch.device(alg.device))
        started = time.perf_counter()
        for _ in range(steps):
            alg.storage.step = 0
            act.act(obs)
        synchronize(torch.device(alg.device))
        times.append((time.perf_counter() - started) / steps)
    alg.storage.step = 0
    return statistics.median(times[1:])


def compiled_kernels() -> list[dict]:
    """Registers and spills of every compiled loss kernel (CUDA; none under the interpreter)."""
    out = []
    for kernel in (fused_ppo._actor_loss_kernel, fused_ppo._critic_loss_kernel):
        for cache in getattr(kernel, "device_caches", {}).values():
            for compiled in cache[0].values():
                out.append(
                    {
                        "kernel": kernel.fn.__name__,
                        "num_warps": compiled.metadata.num_warps,
                        "registers": compiled.n_regs,
                        "spills": compiled.n_spills,
                    }
                )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--worlds", type=int, default=65536)
    parser.add_argument("--rows", default="32,64,128", help="rows per tile of the backward and loss kernels")
    parser.add_argument("--warps", default="4,8", help="warps per program")
    parser.add_argument("--programs", default="1,2,4", help="persistent programs per multiprocessor")
    parser.add_argument("--act-rows", default="", help="rows per tile of the fused rollout step (none: not timed)")
    parser.add_argument("--act-warps", default="4", help="warps per program of the fused rollout step")
    parser.add_argument("--tf32", action="store_true", help="TF32 products; then each shape also without fast tanh")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None, help="JSON path (default tune_fused_<device>.json)")
    parser.add_argument("--commit", default=None, help="the commit measured, for a copy without git history")
    args = parser.parse_args(argv)
    try:
        rows = parse_list(args.rows, int, name="--rows", minimum=16)
        warps = parse_list(args.warps, int, name="--warps", minimum=1)
        programs = parse_list(args.programs, int, name="--programs", minimum=1)
        act_rows = parse_list(args.act_rows, int, name="--act-rows", minimum=16) if args.act_rows else []
        act_warps = parse_list(args.act_warps, int, name="--act-warps", minimum=1)
    except ValueError as error:
        parser.error(str(error))
    for name, values in (("--rows", rows), ("--act-rows", act_rows)):
        if bad := [r for r in values if r & (r - 1)]:
            parser.error(f"{name}: {bad} are not powers of two (tl.dot's tiles)")
    if args.worlds < 1 or args.repeats < 1:
        parser.error("--worlds and --repeats must be integers >= 1")
    device = torch.device(args.device)
    if device.type not in fused_mlp.DEVICES:
        parser.error(f"--device={args.device!r}: the fused kernels take {list(fused_mlp.DEVICES)} here")
    torch.backends.cuda.matmul.allow_tf32 = args.tf32
    out = args.out or Path(f"tune_fused_{args.device.replace(':', '')}.json")
    record = {
        **provenance(args.device, command_line(argv, "benchmarks/tune_fused_kernels.py"), args.commit),
        "preset": args.preset,
        "worlds": args.worlds,
        "tf32": args.tf32,
        "shapes": [],
        "act_shapes": [],
    }
    alg = bench.build(args.preset, args.worlds, args.device)
    bench.fill_storage(alg)
    switch = bench.MLPSwitch(alg)
    cuda = device.type == "cuda"
    side = torch.cuda.Stream(device) if cuda else None  # one stream for every capture (see bench_fused_update)

    def measure(table: str, shape: dict, contexts: list, seconds, label: str) -> None:
        """Time one shape (`seconds()` within `contexts`) into `record[table]`, print it, rewrite the JSON."""
        with contextlib.ExitStack() as stack:
            for context in contexts:
                stack.enter_context(context)
            try:
                shape["ms"] = 1e3 * seconds()
            except Exception as error:  # noqa: BLE001 (a shape the compiler refuses, e.g. out of shared memory: recorded)
                shape["error"] = f"{type(error).__name__}: {str(error)[:300]}"
        record[table].append(shape)
        print(f"{label}: {shape['ms']:9.3f} ms" if "ms" in shape else f"{label}: {shape['error']}", flush=True)
        with atomic_open(out) as f:
            json.dump(record, f, indent=1)

    update = functools.partial(bench.time_update, switch, "fused", args.repeats, graph=cuda)
    for r, w, p, fast in itertools.product(rows, warps, programs, (True, False) if args.tf32 else (True,)):
        shape = {"rows": r, "warps": w, "programs_per_sm": p, "fast_tanh": fast if args.tf32 else None}
        on_side = torch.cuda.stream(side) if cuda else contextlib.nullcontext()
        label = f"rows {r:4d} warps {w} programs/SM {p} fast tanh {shape['fast_tanh']}"
        measure("shapes", shape, [kernel_shape(r, w, p, fast), on_side], update, label)
    switch.use("fused")
    act = functools.partial(time_act, switch.alg, args.repeats)
    for r, w in itertools.product(act_rows, act_warps):
        measure("act_shapes", {"rows": r, "warps": w}, [act_shape(r, w)], act, f"rollout step: rows {r:4d} warps {w}")
    record["kernels"] = compiled_kernels()
    with atomic_open(out) as f:
        json.dump(record, f, indent=1)
    timed = [s for s in record["shapes"] if "ms" in s]
    if timed:
        best = min(timed, key=lambda s: s["ms"])
        print(f"fastest: {best}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
