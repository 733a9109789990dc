"""The PPO update with torch's MLP against the fused MLP (`training/fused_mlp.py`, Triton kernels), on
one device.

For each `--worlds`: the trainer of `--preset` (default: the default preset, 32 steps per
iteration, 5 epochs x 4 mini-batches, actor and critic 2 x 64 tanh) is built, its rollout storage
filled with random samples, and `AquariumPPO.update_on_device` timed on three paths (`MLPSwitch`, the same
parameters): "torch" (torch's modules), "fused-mlp" (the actor's and critic's `mlp` as `FusedMLP`,
the loss through autograd) and "fused" (the fused MLPs and the fused loss of `fused_ppo.py`): eagerly,
and on CUDA also replayed from a CUDA graph. One update from the same state with each then gives, for
each fused path, the largest relative difference per parameter tensor (max |fused - torch| / max
|torch|) under `max_relative_difference`. With `--tf32` torch's products and the kernels' are TF32;
with `--profile` (CUDA) each path's kernels in one eager update are listed (torch.profiler). The fused
kernels run on CUDA, and on the CPU only under Triton's interpreter (`TRITON_INTERPRET=1`, slow: the
tests use it); elsewhere the script refuses the device.

Beside each time: the update's floor on the device (`aquarium_warp.bench.floors`: the MLPs'
matrix products forward and backward at the card's float32 peak, the least bytes at its bandwidth;
the fused backward also recomputes the forward, which the floor does not count), and "of floor"
the fraction of it reached.

First, before any timing, the trainer of the first `--worlds` is built (the simulation's kernels
compiled or loaded) and the fused kernels are built and loaded by one forward and backward of the
actor's and critic's MLP, each step's seconds printed as it ends and recorded under `build_seconds`
(`--compile-only` stops there).

    python benchmarks/bench_fused_update.py --device cuda:0 --worlds 1024,65536
    python benchmarks/bench_fused_update.py --device cuda:0 --compile-only
    TRITON_INTERPRET=1 python benchmarks/bench_fused_update.py --device cpu --worlds 4 --preset tiny --repeats 1

Prints each time as it is measured (flushed) and writes JSON (atomically) to `--out` (default
`fused_update_<device>.json`) after the build step and after every point, so a time limit keeps what
was measured.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.atomic import atomic_open
from aquarium_warp.bench import parse_counts
from aquarium_warp.bench.floors import Floor, card_peaks, update_work
from aquarium_warp.bench.timing import torch_timer
from aquarium_warp.device import synchronize
from aquarium_warp.records import command_line, provenance
from aquarium_warp.training import Trainer, make_config
from aquarium_warp.training.fused_mlp import DEVICES, FusedMLP
from aquarium_warp.training.fused_ppo import FusedPPOLoss
from aquarium_warp.training.loop import collection_paused


def build(preset: str, worlds: int, device: str):
    """The rsl-rl PPO of `preset` at `worlds` worlds (through the trainer, as training builds it)."""
    changes = {"train": {"num_worlds": worlds, "device": device, "quiet": True, "export": [], "fused_mlp": False}}
    return Trainer(make_config(preset, changes)).runner.alg


def fill_storage(alg, seed: int = 0) -> None:
    """Samples in every storage field the update reads, as a rollout would leave them: random
    observations, actions (in range), returns and advantages; the actor's log-probabilities of those
    actions and its distribution parameters, and the critic's values, on those observations (so that
    the ratios start at 1, and the clipping acts as it does in training)."""
    gen = torch.Generator(device=alg.device).manual_seed(seed)
    storage = alg.storage

    def normal(t: torch.Tensor) -> None:
        t.copy_(torch.randn(t.shape, generator=gen, device=t.device, dtype=t.dtype))

    for key in storage.observations.keys():
        normal(storage.observations[key])
    categories = alg.actor.distribution.input_dim
    storage.actions.copy_(torch.randint(0, categories, storage.actions.shape, generator=gen, device=alg.device))
    for t in (storage.returns, storage.advantages):
        normal(t)
    obs = storage.observations.flatten(0, 1)
    with torch.no_grad():
        alg.actor(obs, stochastic_output=True)
        log_prob = alg.actor.get_output_log_prob(storage.actions.flatten(0, 1))
        params = alg.actor.output_distribution_params
        values = alg.critic(obs)
    storage.actions_log_prob.copy_(log_prob.view_as(storage.actions_log_prob))
    storage.values.copy_(values.view_as(storage.values))
    storage.distribution_params = tuple(p.view(*storage.actions.shape[:2], *p.shape[1:]).clone() for p in params)


PATHS = ("torch", "fused-mlp", "fused")  # see MLPSwitch


class MLPSwitch:
    """Switches the learner's update between three paths, on the same parameter objects: "torch"
    (torch's modules), "fused-mlp" (the actor's and critic's `mlp` as `FusedMLP`, the loss through
    autograd) and "fused" (the fused MLPs and the fused loss, `fused_ppo.FusedPPOLoss`); and restores
    the learner's state for updates from the same start."""

    def __init__(self, alg) -> None:
        self.alg = alg
        self.models = (alg.actor, alg.critic)
        torch_mlps = [m.mlp for m in self.models]
        fused_mlps = [FusedMLP(m.mlp) for m in self.models]
        self.mlps = {"torch": torch_mlps, "fused-mlp": fused_mlps, "fused": fused_mlps}
        for model, mlp in zip(self.models, fused_mlps):
            model.mlp = mlp
        self.fused_loss = FusedPPOLoss(alg)  # (its one-line error where the learner is not covered)
        self.use("torch")
        self.start = self.state()

    def use(self, path: str) -> None:
        for model, mlp in zip(self.models, self.mlps[path]):
            model.mlp = mlp
        self.alg.fused_loss = self.fused_loss if path == "fused" else None

    def state(self) -> dict:
        alg = self.alg
        return copy.deepcopy(
            {
                "actor": alg.actor.state_dict(),
                "critic": alg.critic.state_dict(),
                "optimizer": alg.optimizer.state_dict(),
            }
        )

    def restore(self) -> None:
        self.alg.actor.load_state_dict(self.start["actor"])
        self.alg.critic.load_state_dict(self.start["critic"])
        self.alg.optimizer.load_state_dict(self.start["optimizer"])


def parameters_after_update(switch: MLPSwitch, path: str, indices: torch.Tensor, size: int) -> dict[str, torch.Tensor]:
    """Every parameter after one update with `path`'s MLPs from the switch's start state."""
    switch.restore()
    switch.use(path)
    switch.alg.update_on_device(indices, size)
    return {
        f"{name}.{k}": v.detach().clone()
        for name, model in (("actor", switch.alg.actor), ("critic", switch.alg.critic))
        for k, v in model.state_dict().items()
    }


def update_difference(switch: MLPSwitch, seed: int = 0) -> dict[str, dict[str, float]]:
    """Per fused path and parameter tensor, max |fused - torch| / max |torch| after one update from the
    same state with that path and with torch's."""
    torch.manual_seed(seed)
    indices, size = switch.alg.mini_batch_indices()
    after = {path: parameters_after_update(switch, path, indices, size) for path in PATHS}
    return {
        path: {
            name: float((after[path][name] - ref).abs().max() / ref.abs().max().clamp_min(1e-30))
            for name, ref in after["torch"].items()
        }
        for path in PATHS[1:]
    }


def time_update(switch: MLPSwitch, path: str, repeats: int, graph: bool) -> float:
    """Median seconds of `repeats` updates with `path`'s MLPs (after a warm-up update), eagerly or
    replayed from a CUDA graph of one update."""
    alg = switch.alg
    switch.restore()
    switch.use(path)
    indices, size = alg.mini_batch_indices()
    timer = torch_timer(str(alg.device))
    if not graph:
        alg.update_on_device(indices, size)  # warm-up: kernels compiled and loaded, optimizer state made
        return statistics.median(timer(lambda: alg.update_on_device(indices, size)) for _ in range(repeats))
    alg.update_on_device(indices, size)  # warm-up on the capturing stream (the current one), as torch asks
    cuda_graph = torch.cuda.CUDAGraph()
    with collection_paused(), torch.cuda.graph(cuda_graph, stream=torch.cuda.current_stream(alg.device)):
        alg.update_on_device(indices, size)
    cuda_graph.replay()
    return statistics.median(timer(cuda_graph.replay) for _ in range(repeats))


def update_floor(alg, device: torch.device) -> Floor:
    """The update's floor on `device`'s card (`bench.floors`; None peaks: no floor)."""
    return Floor(
        update_work(alg),
        card_peaks(torch.cuda.get_device_name(device)) if device.type == "cuda" else None,
        tf32=torch.backends.cuda.matmul.allow_tf32,
    )


def kernel_profile(switch: MLPSwitch, path: str, top: int = 20) -> list[dict]:
    """The kernels of one eager update with `path`'s MLPs (after a warm-up update), under
    torch.profiler: the `top` kernels by device time, each with its launches and milliseconds, and a
    last row "all kernels" with the totals."""
    alg = switch.alg
    switch.restore()
    switch.use(path)
    indices, size = alg.mini_batch_indices()
    alg.update_on_device(indices, size)
    synchronize(torch.device(alg.device))
    activities = [torch.profiler.ProfilerActivity.CUDA]
    with torch.profiler.profile(activities=activities) as prof:
        alg.update_on_device(indices, size)
        synchronize(torch.device(alg.device))
    events = [e for e in prof.key_averages() if e.device_type == torch.autograd.DeviceType.CUDA]
    rows = sorted(
        ({"kernel": e.key[:100], "launches": e.count, "ms": e.device_time_total / 1e3} for e in events),
        key=lambda r: -r["ms"],
    )
    total = {"kernel": "all kernels", "launches": sum(r["launches"] for r in rows), "ms": sum(r["ms"] for r in rows)}
    return rows[:top] + [total]


def build_seconds(preset: str, worlds: int, device: str) -> dict[str, float]:
    """Seconds to build the trainer of `preset` at `worlds` worlds (the simulation's kernels compiled
    or loaded from Warp's cache), then of the first fused forward and backward of the actor's and
    critic's MLP on one row (each kernel is compiled or loaded at its first launch, and does not
    specialise on the row count); each printed as it ends."""
    seconds = {}
    started = time.perf_counter()
    switch = MLPSwitch(build(preset, worlds, device))
    seconds["trainer"] = time.perf_counter() - started
    print(f"trainer built in {seconds['trainer']:.1f} s", flush=True)
    torch_device = torch.device(switch.alg.device)
    for name, mlp in zip(("actor", "critic"), switch.mlps["fused"]):
        params = list(mlp.parameters())
        key = f"fused {name}"
        started = time.perf_counter()
        out = mlp(torch.zeros(1, mlp.spec.dims[0], device=torch_device))
        synchronize(torch_device)
        seconds[f"{key} forward"] = time.perf_counter() - started
        print(f"{key} forward kernel built and loaded in {seconds[f'{key} forward']:.1f} s", flush=True)
        started = time.perf_counter()
        torch.autograd.grad(out.sum(), params)  # not into .grad: the update's state stays untouched
        synchronize(torch_device)
        seconds[f"{key} backward"] = time.perf_counter() - started
        print(f"{key} backward kernel built and loaded in {seconds[f'{key} backward']:.1f} s", flush=True)
    return seconds


def measure(preset: str, worlds: int, device: str, repeats: int, profile: bool = False) -> dict:
    """One point: the update's time with torch's MLPs and the fused ones at `worlds` worlds (printed
    as each is measured), the largest relative difference after one update, and the floor; with
    `profile`, each path's kernels (`kernel_profile`) under "profile"."""
    alg = build(preset, worlds, device)
    fill_storage(alg)
    switch = MLPSwitch(alg)
    torch_device = torch.device(alg.device)
    floor = update_floor(alg, torch_device)
    print(f"{worlds} worlds: {floor.describe()}", flush=True)
    point: dict = {"worlds": worlds, "seconds": {}}
    graphs = (False, True) if torch_device.type == "cuda" else (False,)
    # Every update of the point runs on one side stream, where the graphs are captured too: the actor
    # keeps its last forward's autograd graph (its distribution), whose gradient accumulators belong to
    # the stream that made them, and a capture on another stream fails when it meets them (H200, 8d0272d).
    side = torch.cuda.Stream(torch_device) if torch_device.type == "cuda" else None
    if side is not None:
        side.wait_stream(torch.cuda.current_stream(torch_device))
    with torch.cuda.stream(side) if side is not None else contextlib.nullcontext():
        for graph in graphs:
            for path in PATHS:
                key = f"{path} {'graph' if graph else 'eager'}"
                seconds = point["seconds"][key] = time_update(switch, path, repeats, graph)
                reached = floor.fraction(seconds)
                print(
                    f"  {key:12s} {seconds * 1e3:10.2f} ms{'' if reached is None else f'  {reached:6.1%} of floor'}",
                    flush=True,
                )
        if profile and torch_device.type == "cuda":
            point["profile"] = {path: kernel_profile(switch, path) for path in PATHS}
            for path, rows in point["profile"].items():
                print(f"  kernels of one eager update, {path}:", flush=True)
                for r in rows:
                    print(f"    {r['ms']:9.2f} ms {r['launches']:6d}x  {r['kernel']}", flush=True)
    if side is not None:
        torch.cuda.current_stream(torch_device).wait_stream(side)
    differences = point["max_relative_difference"] = update_difference(switch)
    for path, by_name in differences.items():
        worst = max(by_name.items(), key=lambda kv: kv[1])
        print(f"  one update, {path} vs torch: max relative difference {worst[1]:.2e} ({worst[0]})", flush=True)
    point["floor"] = floor.record(point["seconds"])
    point["floor_text"] = floor.describe()
    return point


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--worlds", default="1024,65536", help="comma-separated world counts")
    parser.add_argument("--preset", default="default")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None, help="JSON path (default fused_update_<device>.json)")
    parser.add_argument("--commit", default=None, help="the commit measured, for a copy without git history")
    parser.add_argument(
        "--compile-only", action="store_true", help="stop after building the trainer and the fused kernels"
    )
    parser.add_argument(
        "--tf32", action="store_true", help="TF32 matrix products (train.tf32), in torch and the kernels"
    )
    parser.add_argument("--profile", action="store_true", help="also each path's kernels in one eager update (CUDA)")
    args = parser.parse_args(argv)
    torch.backends.cuda.matmul.allow_tf32 = args.tf32
    if args.repeats < 1:
        parser.error(f"--repeats={args.repeats} must be an integer >= 1")
    worlds = parse_counts(args.worlds, "--worlds")
    if torch.device(args.device).type not in DEVICES:
        parser.error(
            f"--device={args.device!r}: the fused kernels take {list(DEVICES)} here "
            "(the CPU only under Triton's interpreter, TRITON_INTERPRET=1)"
        )
    out = args.out or Path(f"fused_update_{args.device.replace(':', '')}.json")
    record = {
        **provenance(args.device, command_line(argv, "benchmarks/bench_fused_update.py"), args.commit),
        "preset": args.preset,
        "repeats": args.repeats,
        "tf32": args.tf32,
        "points": [],
    }

    def write() -> None:
        with atomic_open(out) as f:
            json.dump(record, f, indent=1)

    record["build_seconds"] = build_seconds(args.preset, worlds[0], args.device)
    write()
    if not args.compile_only:
        for w in worlds:
            record["points"].append(measure(args.preset, w, args.device, args.repeats, args.profile))
            write()  # after every point: a time limit keeps what was measured
    print(f"wrote {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
