"""The hardware floors of PPO training: the least time a card could spend on the update and on the
rollout, from their arithmetic at the card's float32 peak (its TF32 tensor-core peak for a run with
TF32 products, `train.tf32`) and from their bytes at the card's memory bandwidth, so that a benchmark
prints the floor beside what it measured and the fraction of the floor reached.

```python
from aquarium_warp.bench.floors import Floor, card_peaks, rollout_work, update_work

peaks = card_peaks(torch.cuda.get_device_name())
floor = Floor(update_work(trainer.runner.alg), peaks)
print(floor.describe(seconds))     # "floor 80.1 ms on H200 SXM (arithmetic: ...), 21% reached" or "floor n/a (...)"
record["floor"] = floor.record({"update": seconds})   # the floor, and the fraction reached per time
rollout = Floor(rollout_work(trainer.runner.alg, trainer.env.state), peaks)
```

Several GPUs: `linear_scaling` gives the ideal (linear) speed-up and the fraction of it reached.

**The update** (`update_work`). The arithmetic counts the matrix products of the actor's and critic's
MLPs, forward and backward, for every sample in every epoch: a layer of `in x out` weights costs a
sample `2 in out` FLOPs forward, as much again for its weights' gradient, and as much again for its
input's gradient (except the first layer: the observations need none). Biases, activations, losses
and the optimizer are left out (a few FLOPs per parameter or activation). The bytes are those no
implementation can avoid: every epoch reads each sample's stored fields once (observations, action,
old value, return, old log-probability, advantage, old distribution parameters; activations kept on
chip for backward), and every mini-batch reads the parameters for the forward, writes their gradients
and has Adam read parameter, gradient and both moments and write parameter and moments. The floor is
the larger of the two times; an update that keeps each layer's activations in memory for backward
moves far more.

**The rollout** (`rollout_work`): every step of the rollout, the actor's and critic's forward for
every learning row (their matrix products); and the bytes every step must move: the simulation reads
and writes each slot's agent state and each world's counters once, reads the actions and writes the
observations and the step's outputs (rewards, dones) once; the policy reads each row's observation
once and the parameters once; the storage is written once per row (observation, action, value,
log-probability, distribution parameters, reward, done). Neighbour search, the other team's policy
and the statistics are left out (reads of data already counted, or a few bytes per world).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch.nn as nn


@dataclass(frozen=True)
class CardPeaks:
    """A card's datasheet peaks: `fp32_flops` (FLOP/s, float32 on the CUDA cores, no tensor cores),
    `tf32_flops` (FLOP/s, TF32 on the tensor cores, dense: the datasheets' figure is with sparsity, twice
    this) and `bandwidth` (bytes/s of device memory)."""

    name: str
    fp32_flops: float
    tf32_flops: float
    bandwidth: float


# torch.cuda.get_device_name (and Warp's device name) -> the card's peaks. Exact names: the PCIe and
# NVL versions of these cards report other names and have other peaks.
CARD_PEAKS = {
    # NVIDIA H100 Tensor Core GPU datasheet, H100 SXM: FP32 67 TFLOPS, TF32 Tensor Core 989 TFLOPS with
    # sparsity, GPU memory bandwidth 3.35 TB/s
    "NVIDIA H100 80GB HBM3": CardPeaks("H100 SXM", 67e12, 494.5e12, 3.35e12),
    # NVIDIA H200 Tensor Core GPU datasheet, H200 SXM: FP32 67 TFLOPS, TF32 Tensor Core 989 TFLOPS with
    # sparsity, GPU memory bandwidth 4.8 TB/s
    "NVIDIA H200": CardPeaks("H200 SXM", 67e12, 494.5e12, 4.8e12),
}


def card_peaks(device_name: str) -> CardPeaks | None:
    """The peaks of the card named `device_name` (as torch names it), None for a card not in
    `CARD_PEAKS` (a CPU included): its floor is "n/a"."""
    return CARD_PEAKS.get(device_name.strip())


def matmul_shapes(model: nn.Module) -> list[tuple[int, int]]:
    """`(in, out)` of each matrix product one sample passes through in `model`, in order: its
    `nn.Linear` layers, and the per-slot layers of Individual Learning (`BatchedLinear`: a sample
    uses its own slot's weights), and a population's stacked layers (`StackedMLP`: a sample uses its
    own run's)."""
    from ..training.models import BatchedLinear, StackedMLP

    shapes = []
    for module in model.modules():
        if isinstance(module, (nn.Linear, BatchedLinear)):
            shapes.append((int(module.in_features), int(module.out_features)))
        elif isinstance(module, StackedMLP):
            shapes.extend((int(w.shape[2]), int(w.shape[1])) for w in module.weights)
    return shapes


def mlp_flops(shapes: Sequence[tuple[int, int]], backward: bool = True) -> int:
    """Matrix-product FLOPs of one sample through the layers `shapes` (`(in, out)` each, first layer
    first): forward, and with `backward` the weights' and the inputs' gradients (none for the first
    layer's input)."""
    forward = sum(2 * i * o for i, o in shapes)
    if not backward:
        return forward
    return 2 * forward + sum(2 * i * o for i, o in shapes[1:])


@dataclass(frozen=True)
class UpdateWork:
    """What one PPO update must do: `flops` (matrix products, forward and backward, every epoch) and
    `bytes` (the samples read once per epoch, the parameters' and Adam's traffic per mini-batch)."""

    flops: float
    bytes: float
    samples: int
    epochs: int
    mini_batches: int

    def fields(self) -> dict:
        """The work as JSON values (`Floor.record`)."""
        return {
            "update_flops": self.flops,
            "update_bytes": self.bytes,
            "samples": self.samples,
            "epochs": self.epochs,
            "mini_batches": self.mini_batches,
        }


@dataclass(frozen=True)
class RolloutWork:
    """What one rollout must do: `flops` (the actor's and critic's forward matrix products for every
    sample) and `bytes` (the simulation's state, the policy's reads and the storage's writes, every
    step) over `samples` learning rows x `steps` steps."""

    flops: float
    bytes: float
    samples: int
    steps: int

    def fields(self) -> dict:
        """The work as JSON values (`Floor.record`)."""
        return {"rollout_flops": self.flops, "rollout_bytes": self.bytes, "samples": self.samples, "steps": self.steps}


def ppo_update_work(
    mlps: Sequence[Sequence[tuple[int, int]]],
    samples: int,
    epochs: int,
    mini_batches: int,
    sample_bytes: int,
    parameter_bytes: int,
) -> UpdateWork:
    """The work of an update over `samples` samples (`sample_bytes` stored per sample), `epochs` times
    in `mini_batches` mini-batches, of the MLPs whose layers are `mlps` (`matmul_shapes` of each) and
    whose parameters take `parameter_bytes`."""
    for name, value in (("samples", samples), ("epochs", epochs), ("mini_batches", mini_batches)):
        if value < 1:
            raise ValueError(f"{name}={value!r} must be >= 1")
    flops = epochs * samples * sum(mlp_flops(shapes) for shapes in mlps)
    # Per mini-batch: parameters read (forward), gradients written (backward), Adam reads parameter,
    # gradient and two moments and writes parameter and two moments: 9 passes over the parameters.
    data = epochs * samples * sample_bytes + epochs * mini_batches * 9 * parameter_bytes
    return UpdateWork(float(flops), float(data), samples, epochs, mini_batches)


def update_work(alg) -> UpdateWork:
    """The work of an update of `alg` (an `AquariumPPO` that has collected a rollout: its storage
    allocates some fields at the first step), from its actor's and critic's layers and parameters and
    its rollout storage's fields."""
    from ..training.ppo import flat_samples, mini_batch_size

    storage = alg.storage
    if storage.distribution_params is None:
        raise ValueError("update_work needs an algorithm that has collected a rollout (its storage is not filled yet)")
    rows = storage.num_envs * storage.num_transitions_per_env
    group = getattr(alg, "minibatch_group_size", 1)
    used = mini_batch_size(storage, alg.num_mini_batches, group) * alg.num_mini_batches
    sample_bytes = 0
    for field in flat_samples(storage):
        for tensor in _tensors(field):
            sample_bytes += tensor.element_size() * tensor.numel() // rows
    models = (alg.actor, alg.critic)
    parameter_bytes = sum(p.element_size() * p.numel() for model in models for p in model.parameters())
    return ppo_update_work(
        [matmul_shapes(model) for model in models],
        used,
        alg.num_learning_epochs,
        alg.num_mini_batches,
        sample_bytes,
        parameter_bytes,
    )


def ppo_rollout_work(
    mlps: Sequence[Sequence[tuple[int, int]]],
    rows: int,
    steps: int,
    simulation_bytes: int,
    observation_bytes: int,
    stored_bytes: int,
    parameter_bytes: int,
) -> RolloutWork:
    """The work of a rollout of `steps` steps of `rows` learning rows through the MLPs whose layers are
    `mlps` (`matmul_shapes` of each; their parameters take `parameter_bytes`): per step the simulation
    moves `simulation_bytes`, each row's observation (`observation_bytes`) is read by the policy and
    `stored_bytes` per row are written to the storage."""
    for name, value in (("rows", rows), ("steps", steps)):
        if value < 1:
            raise ValueError(f"{name}={value!r} must be >= 1")
    samples = rows * steps
    flops = samples * sum(mlp_flops(shapes, backward=False) for shapes in mlps)
    data = steps * (simulation_bytes + parameter_bytes) + samples * (observation_bytes + stored_bytes)
    return RolloutWork(float(flops), float(data), samples, steps)


def simulation_bytes(state) -> int:
    """Bytes one simulation step of `state` (a `SimulationState`) cannot avoid moving: every agent field
    and world counter read and written, the actions read, the observations and outputs written."""

    import warp as wp

    from ..state import GROUPS, struct_type

    def group_bytes(name: str) -> int:
        group = getattr(state, name)
        arrays = (getattr(group, field) for field in struct_type(GROUPS[name]).vars)
        return sum(a.size * wp.types.type_size_in_bytes(a.dtype) for a in arrays)

    read_write = group_bytes("agents") + group_bytes("worlds")
    return 2 * read_write + group_bytes("actions") + group_bytes("observations") + group_bytes("outputs")


def rollout_work(alg, state) -> RolloutWork:
    """The work of a rollout of `alg` (an `AquariumPPO` that has collected a rollout) in the worlds of
    `state` (the trainer's `SimulationState`; the learning team's rows are the storage's envs)."""
    storage = alg.storage
    if storage.distribution_params is None:
        raise ValueError("rollout_work needs an algorithm that has collected a rollout (its storage is not filled yet)")
    rows, steps = storage.num_envs, storage.num_transitions_per_env
    fields = (
        storage.observations,
        storage.actions,
        storage.values,
        storage.actions_log_prob,
        storage.distribution_params,
        storage.rewards,
        storage.dones,
    )
    stored = sum(t.element_size() * t.numel() for field in fields for t in _tensors(field)) // (rows * steps)
    observation = sum(t.element_size() * t.numel() for t in _tensors(storage.observations)) // (rows * steps)
    models = (alg.actor, alg.critic)
    parameter_bytes = sum(p.element_size() * p.numel() for model in models for p in model.parameters())
    return ppo_rollout_work(
        [matmul_shapes(model) for model in models],
        rows,
        steps,
        simulation_bytes(state),
        observation,
        stored,
        parameter_bytes,
    )


def _tensors(field) -> list:
    """The tensors of one stored field: a tensor, a tuple of them, or a TensorDict of observation groups."""
    if isinstance(field, tuple):
        return [t for item in field for t in _tensors(item)]
    if hasattr(field, "values") and not hasattr(field, "element_size"):  # a TensorDict
        return list(field.values(include_nested=True, leaves_only=True))
    return [field]


@dataclass(frozen=True)
class Floor:
    """The floor of a work (`UpdateWork` or `RolloutWork`) on a card (`peaks` None: unknown card, no
    floor). `seconds` is the larger of `flop_seconds` (arithmetic at the float32 peak, or with `tf32`
    at the TF32 tensor-core peak) and `byte_seconds` (bytes at the bandwidth)."""

    work: UpdateWork | RolloutWork
    peaks: CardPeaks | None
    tf32: bool = False

    @property
    def flops_peak(self) -> float | None:
        """The arithmetic peak the floor assumes (FLOP/s)."""
        if self.peaks is None:
            return None
        return self.peaks.tf32_flops if self.tf32 else self.peaks.fp32_flops

    @property
    def flop_seconds(self) -> float | None:
        peak = self.flops_peak
        return None if peak is None else self.work.flops / peak

    @property
    def byte_seconds(self) -> float | None:
        return None if self.peaks is None else self.work.bytes / self.peaks.bandwidth

    @property
    def seconds(self) -> float | None:
        if self.flop_seconds is None or self.byte_seconds is None:
            return None
        return max(self.flop_seconds, self.byte_seconds)

    @property
    def bound(self) -> str | None:
        """Which of the two sets the floor: "arithmetic" or "memory"."""
        if self.flop_seconds is None or self.byte_seconds is None:
            return None
        return "arithmetic" if self.flop_seconds >= self.byte_seconds else "memory"

    def fraction(self, measured_seconds: float) -> float | None:
        """The fraction of the floor reached by a measured time (1: at the floor)."""
        if measured_seconds <= 0:
            raise ValueError(f"measured_seconds={measured_seconds!r} must be > 0")
        return None if self.seconds is None else self.seconds / measured_seconds

    def describe(self, measured_seconds: float | None = None) -> str:
        """One line: the floor, what sets it, and the fraction reached by `measured_seconds`."""
        reached = None if measured_seconds is None else self.fraction(measured_seconds)
        work = f"{self.work.flops / 1e12:.3g} TFLOP, {self.work.bytes / 1e9:.3g} GB"
        peaks, flop_seconds, byte_seconds, seconds = self.peaks, self.flop_seconds, self.byte_seconds, self.seconds
        peak = self.flops_peak
        if peaks is None or peak is None or flop_seconds is None or byte_seconds is None or seconds is None:
            return f"floor n/a (no peaks for this card; {work})"
        text = (
            f"floor {1e3 * seconds:.3g} ms on {peaks.name} ({self.bound}: {work}; "
            f"{1e3 * flop_seconds:.3g} ms at {peak / 1e12:.4g} TFLOP/s {'tf32' if self.tf32 else 'fp32'}, "
            f"{1e3 * byte_seconds:.3g} ms at {peaks.bandwidth / 1e12:.3g} TB/s)"
        )
        if reached is not None:
            text += f", {100 * reached:.3g}% reached"
        return text

    def record(self, measured_seconds: dict[str, float] | None = None) -> dict:
        """The floor as JSON values (None where the card is unknown), and per measured time in
        `measured_seconds` (`{what: seconds}`) the fraction of the floor reached."""
        out = {
            "card": None if self.peaks is None else self.peaks.name,
            "fp32_flops_peak": None if self.peaks is None else self.peaks.fp32_flops,
            "tf32": self.tf32,
            "flops_peak": self.flops_peak,
            "bandwidth_peak": None if self.peaks is None else self.peaks.bandwidth,
            **self.work.fields(),
            "flop_seconds": self.flop_seconds,
            "byte_seconds": self.byte_seconds,
            "seconds": self.seconds,
            "bound": self.bound,
        }
        for what, seconds in (measured_seconds or {}).items():
            out[f"fraction_of_{what}"] = self.fraction(seconds)
        return out


def linear_scaling(gpus: int, one_gpu_rate: float, rate: float) -> dict:
    """Several GPUs against one: the ideal (linear) speed-up `gpus`, the measured one (`rate` over
    `one_gpu_rate`, any unit of work per second) and the fraction of the ideal reached."""
    if gpus < 1 or one_gpu_rate <= 0 or rate <= 0:
        raise ValueError(f"gpus={gpus!r} must be >= 1 and the rates ({one_gpu_rate!r}, {rate!r}) > 0")
    speedup = rate / one_gpu_rate
    return {"ideal_speedup": gpus, "speedup": speedup, "fraction_of_ideal": speedup / gpus}
