"""Swarm metrics of every world of a `BatchedAquarium`, computed on the device without host sync.

```python
from aquarium_warp.metrics import SwarmMetrics, EpisodeMetrics, rollout_metrics

metrics = SwarmMetrics(env, linking_distance=50.0)
values = metrics.compute()          # {"polarization": [W], "groups": [W], ..., "nn_histogram": [W, bins]}
values["group_rotation"]            # per-group measures; identities carry over to the next compute()

episodes = EpisodeMetrics(env, every=10)    # per-episode means, for training logs and evaluation
env.reset(); episodes.begin()
for _ in range(steps):
    obs, rewards, terminated, truncated, info = env.step(actions)
    episodes.update(info)
# or, as an observer of the episode loop: rollout(env, drivers, steps, observers=[episodes])
episodes.result()                   # per world: mean over its completed episodes ([W] tensors)
episodes.log_values()               # {"swarm/polarization": float, ...}: means since the last call
```

Definitions (all over the live prey of a world; distances are torus-shortest, in px):
- `polarization`: length of the mean unit heading, in [0, 1] (1: all aligned; about
  `0.886 / sqrt(n)` for n independent random headings).
- `centroid_x`, `centroid_y`: the swarm's centroid on the torus, each axis by its circular mean
  (`x = atan2(mean sin(2 pi x / W), mean cos(2 pi x / W)) * W / (2 pi)`, in [0, W)).
- `cohesion`: mean torus distance of the prey to that centroid, px (small: a compact swarm).
- `nn_mean`: mean over prey of the distance to the nearest other live prey, px (NaN with < 2 prey);
  `nn_histogram` `[W, bins]` int32 counts those distances per bin of `nn_range / bins` px (the last bin
  also holds everything beyond `nn_range`).
- `groups`: connected components of the graph linking prey closer than `linking_distance`;
  `largest_group`: the largest component's share of the live prey.
- `predator_distance`: mean over prey of the distance to the nearest live predator, px.
- `local_alignment`: mean over the prey with a linked neighbour (closer than `linking_distance`) of
  |own heading + the neighbours' headings| / (1 + neighbours), in [0, 1] (NaN where no prey has one):
  alignment among neighbours, which a swarm of several differently heading groups keeps.
- `milling`: |mean over prey of (r / |r|) x heading|, r the prey's offset from the centroid, in [0, 1]:
  1 when every prey circles the centroid the same way (a mill); about `0.886 / sqrt(n)` for random
  headings. About the swarm's one centroid: meaningful where the prey form one group.
- `prey_alive`, `predator_alive`: populations; `captures`: captures in the last step.

The groups' measures (`GROUP_METRICS`; a "measured group" has at least `min_group_size` prey, default 3):
- `group_sizes` `[W, prey_capacity]` int32: the number of groups of each size (column s - 1 for s
  members: the full distribution, no bins); `mean_group_size`: live prey / groups;
  `grouped_share`: the share of the live prey in groups of >= 2 (those with a linked neighbour);
  `measured_share`: in measured groups.
- Per measured group (Tunstrøm et al. 2013; Li et al. 2023), about the group's own torus centroid
  (the circular mean per axis over its members, as the swarm's): polarization |mean unit heading|,
  rotation |mean over members of (r / |r|) x heading| (r the member's offset from that centroid; a
  member at the centroid adds 0: a mill is 1, a line heading along itself 0) and speed |mean
  velocity| (px/step). `group_polarization`, `group_rotation`, `group_speed`: their means over the
  measured groups weighted by members (what the average prey in a measured group sees; NaN without one).
- Identity across calls: a measured group continues the measured group of the predecessor state that
  holds a strict majority of its members, counting only prey that are the same individuals (live
  there, and their age grew by the steps between: a respawned or newborn prey restarts at age 0, and
  so does a parent that reproduced). When several groups take a majority from one group (a split),
  the one with most of its members continues it (the lower label on ties); any other group is new.
  The predecessor state is the previous call's, in the same episode (a new episode, an earlier step or
  `restart_tracking()` starts over; calling twice on one state gives the same values). `group_age`:
  the member-weighted mean over measured groups of the steps since each was first seen (NaN without
  one). A group that nobody continues ended: `groups_ended` counts those since the predecessor state
  and `ended_lifetime_total` sums their lifetimes (steps from the first to the last state that saw
  them, so with every k-th step computed a lifetime is a multiple of k). Groups alive at an episode's
  end are not counted (censored): short episodes undercount long lifetimes.
  `EpisodeMetrics` reports `group_lifetime`, their ratio: the mean completed lifetime.
- `nn_ratio_point`, `nn_ratio_hard_disk`: `nn_mean` over its expectation for the same number of live
  prey placed at random on the torus: uniform points (the aggregation index R against the point
  null), or disks of the prey hit-box diameter 2 r that may touch but not overlap (random sequential
  addition, a seeded Monte Carlo, see `aquarium_warp.nulls`): contact pushes keep prey about 2 r apart, so
  R cannot fall far below 2 r / E[point NN] (about 0.56 at 32 prey of radius 20 in 800 x 800), while
  the hard-disk null is 1 for prey as spread as non-overlapping random disks. NaN with fewer than 2
  prey and, for the hard-disk null, in arenas too crowded for the disks (the tables are made for
  the config at construction).
- `confusion_neighbour_share`: the share of live prey with another live prey strictly within the
  world's `confusion_radius` (k >= 1 in capture confusion's 1 / (1 + c k), docs/model.md step 5).

Undefined values (no live prey) are NaN.

`compute()` launches the kernels of `kernels/metrics.py` on every shard (threads on the CPU, Warp's
stream ordered with torch's on GPU) and returns views of buffers that the next `compute()`
overwrites; the per-prey arrays behind them are `nearest_neighbour`, `nearest_predator` and
`group_label` (`[W, prey_capacity]`, -1 for dead slots). Results are deterministic: float sums run
in a fixed order, group labels are the smallest prey slot of each group. The groups' passes add
about a fifth to the time of `compute()` (0.19 ms to 1.0 ms for 64 worlds of 32 prey on one CPU thread).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping

import numpy as np
import torch
import warp as wp

from .device import TorchStreamLaunches
from .env import BatchedAquarium, StepResult
from .kernels import metrics as kernels
from .nulls import hard_disk_nn_means, point_nn_means
from .per_world import per_world
from .rollout import Drivers, Observer, Progress, rollout
from .state import struct_type

# compute()'s [W] values: the swarm's measures, then the groups' (both columns of `SwarmMetrics.values`).
SCALAR_METRICS = kernels.VALUE_NAMES[: kernels.NUM_SWARM_VALUES]
GROUP_METRICS = kernels.VALUE_NAMES[kernels.NUM_SWARM_VALUES :]
# Metrics averaged over the sampled states of an episode by `EpisodeMetrics` (the centroid is not:
# its average over time means nothing on a torus; captures come from the env's episode counters).
EPISODE_METRICS = (
    "polarization",
    "cohesion",
    "nn_mean",
    "groups",
    "largest_group",
    "predator_distance",
    "prey_alive",
    "predator_alive",
    "local_alignment",
    "milling",
) + tuple(GROUP_METRICS)


def default_linking_distance(env: BatchedAquarium) -> float | tuple[float, ...]:
    """2.5 prey hit-box radii (50 px by default): prey whose hit boxes are less than half a radius apart;
    one per world (a tuple) where the prey radius differs between worlds."""
    radius = env.config.prey.radius
    return tuple(2.5 * r for r in radius) if isinstance(radius, tuple) else 2.5 * radius


# The group-tracking buffers of `kernels.metrics.GroupArrays` that a resumed run restores.
TRACKING = ("last_time", "before_time", "last_label", "before_label", "last_birth", "before_birth")


class SwarmMetrics:
    """Per-world swarm metrics of `env`'s current state (the one its last observations show).

    Args:
        env: the batched simulator.
        linking_distance: px; prey closer than this are linked into one group (default
            `default_linking_distance(env)`, 2.5 prey radii, each world's own); one number or one per world.
        nn_bins: bins of the nearest-neighbour histogram.
        nn_range: px covered by the histogram's bins, shared by the worlds (default: 2 x the prey view
            distance, the largest over the worlds, or the largest torus distance if smaller or the view
            is unlimited).
        min_group_size: the fewest members of a measured group, whose order, age and lifetime are
            measured (default 3: two prey's polarization and rotation say little, about 0.64 on average for
            two random headings).
        group_metrics: compute `GROUP_METRICS` (and `group_sizes`). False computes only
            `SCALAR_METRICS` (the group columns stay NaN, `group_sizes` zero): the group passes run one
            thread per world, which on a GPU takes tens of milliseconds in a world of 100,000 prey (the
            viewer shows only the swarm's measures).
    """

    def __init__(
        self,
        env: BatchedAquarium,
        linking_distance: float | tuple[float, ...] | None = None,
        nn_bins: int = 50,
        nn_range: float | None = None,
        min_group_size: int = 3,
        group_metrics: bool = True,
    ):
        if not isinstance(env, BatchedAquarium):
            raise ValueError(f"env must be a BatchedAquarium, got {type(env).__name__}")
        cfg = env.config
        if linking_distance is None:
            linking_distance = default_linking_distance(env)
        W = env.num_worlds
        links = list(linking_distance) if isinstance(linking_distance, (tuple, list)) else [linking_distance] * W
        if len(links) != W or any(
            isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d) or d <= 0 for d in links
        ):
            raise ValueError(
                f"linking_distance={linking_distance!r} must be a finite number > 0 (px), or {W} "
                "of them (one per world)"
            )
        if isinstance(nn_bins, bool) or not isinstance(nn_bins, int) or nn_bins < 1:
            raise ValueError(f"nn_bins={nn_bins!r} must be an integer >= 1")
        if nn_range is None:
            nn_range = min(2.0 * max(per_world(cfg.prey.view_distance, W)), cfg.max_torus_distance)
        assert nn_range is not None  # for the type checker: set just above
        if (
            isinstance(nn_range, bool)
            or not isinstance(nn_range, (int, float))
            or not math.isfinite(nn_range)
            or nn_range <= 0
        ):
            raise ValueError(f"nn_range={nn_range!r} must be a finite number > 0 (px)")
        if isinstance(min_group_size, bool) or not isinstance(min_group_size, int) or min_group_size < 2:
            raise ValueError(f"min_group_size={min_group_size!r} must be an integer >= 2")
        if not isinstance(group_metrics, bool):
            raise ValueError(f"group_metrics={group_metrics!r} must be True or False")
        self._env = env
        self.group_metrics = group_metrics
        # One float where every world links at the same distance, else one per world.
        self.linking_distance: float | tuple[float, ...] = (
            float(links[0]) if len(set(links)) == 1 else tuple(float(d) for d in links)
        )
        self._linking_distances: wp.array = wp.array(links, dtype=float, device=env.device)
        self.nn_bins = nn_bins
        self.nn_range = float(nn_range)
        self.bin_width = self.nn_range / nn_bins
        self.min_group_size = min_group_size
        Pc, P = env.prey_capacity, env.predator_capacity
        dev = env.device
        # A lone predator (or a few) is found faster by looping over the predator slots than by a ring
        # search, which walks every prey entry on the way to it.
        self.predators_by_grid = int(P > 32 and P * P > 4 * Pc)
        self._chunks = (Pc + kernels.CHUNK - 1) // kernels.CHUNK
        a = self._arrays = kernels.SwarmArrays()
        a.nearest_prey = wp.zeros((W, Pc), dtype=float, device=dev)
        a.nearest_predator = wp.zeros((W, Pc), dtype=float, device=dev)
        a.nn_histogram = wp.zeros((W, nn_bins), dtype=wp.int32, device=dev)
        a.confusion_neighbour = wp.zeros((W, Pc), dtype=wp.bool, device=dev)
        a.parent = wp.zeros(W * Pc, dtype=wp.int32, device=dev)
        a.group_label = wp.zeros((W, Pc), dtype=wp.int32, device=dev)
        a.group_size = wp.zeros((W, Pc), dtype=wp.int32, device=dev)
        a.local_alignment = wp.zeros((W, Pc), dtype=float, device=dev)
        a.partial = wp.zeros((W, self._chunks, kernels.NUM_PARTIALS), dtype=float, device=dev)
        a.values = wp.zeros((W, kernels.NUM_VALUES), dtype=float, device=dev)
        g = self._groups = kernels.GroupArrays()
        for name in struct_type(kernels.GroupArrays).vars:
            shape = {"order": (W, Pc, 3), "last_time": (W, 3), "before_time": (W, 3)}.get(name, (W, Pc))
            if name in ("point_null", "hard_disk_null"):  # read by the group passes only
                nulls = self._nn_nulls(name) if group_metrics else np.full((W, Pc + 1), np.nan, np.float32)
                setattr(g, name, wp.array(nulls, dtype=float, device=dev))
            else:
                setattr(g, name, wp.zeros(shape, dtype=wp.int32 if name != "order" else float, device=dev))
        self._tracked_times = (wp.to_torch(g.last_time), wp.to_torch(g.before_time))
        # What the group identities carry from one `compute()` to the next (the last state's and its
        # predecessor's times, labels and births): a resumed run needs them to continue its groups.
        self._tracking = {name: wp.to_torch(getattr(g, name)) for name in TRACKING}
        values = wp.to_torch(a.values)
        if not group_metrics:  # no pass writes them
            values[:, kernels.NUM_SWARM_VALUES :] = float("nan")
        self.values = values  # [W, len(SCALAR_METRICS + GROUP_METRICS)] float32, columns in that order
        self.nn_histogram = wp.to_torch(a.nn_histogram)
        self.group_sizes = wp.to_torch(g.size_counts)
        self.nearest_neighbour = wp.to_torch(a.nearest_prey)
        self.nearest_predator = wp.to_torch(a.nearest_predator)
        self.group_label = wp.to_torch(a.group_label)
        self._result = {name: values[:, k] for k, name in enumerate(kernels.VALUE_NAMES)}
        self._result["nn_histogram"] = self.nn_histogram
        self._result["group_sizes"] = self.group_sizes
        self._program = env.record_program(self._shard_commands)

    @property
    def env(self) -> BatchedAquarium:
        return self._env

    @property
    def bin_edges(self) -> torch.Tensor:
        """`[bins + 1]` px: edges of the histogram's bins (the last bin also counts distances beyond)."""
        return torch.linspace(0.0, self.nn_range, self.nn_bins + 1)

    def _nn_nulls(self, name: str) -> np.ndarray:
        """`[W, prey_capacity + 1]` float32: each world's expected mean nearest-neighbour distance of n
        uniform points ("point_null") or of n prey hit boxes that do not overlap ("hard_disk_null"),
        at index n (`nulls.py`; NaN where undefined)."""
        cfg, env = self._env.config, self._env
        Pc = env.prey_capacity
        if name == "point_null":
            rows = [point_nn_means(Pc, cfg.width, cfg.height)] * env.num_worlds
        else:
            radii = per_world(cfg.prey.radius, env.num_worlds)
            rows = [hard_disk_nn_means(Pc, cfg.width, cfg.height, 2.0 * float(r))[0] for r in radii]
        return np.stack(rows).astype(np.float32)

    def tracking_state(self) -> dict[str, torch.Tensor]:
        """The group identities' state (CPU copies), for `load_tracking_state`."""
        return {name: t.cpu().clone() for name, t in self._tracking.items()}

    def load_tracking_state(self, state: dict[str, torch.Tensor]) -> None:
        for name, t in self._tracking.items():
            t.copy_(state[name].to(t.device))

    def restart_tracking(self) -> None:
        """Forget the groups of earlier calls: the next `compute()` sees every group as new (device work,
        no sync; `EpisodeMetrics.begin()` calls it)."""
        for times in self._tracked_times:
            times.zero_()

    def _shard_commands(self, shard) -> list:
        s, g, world, Pc = shard.state, shard.grid, shard.world, self._env.prey_capacity
        W, w0, w1 = shard.num_worlds, shard.w0, shard.w1
        arrays = kernels.SwarmArrays()  # the shard's worlds of every buffer
        for name in struct_type(kernels.SwarmArrays).vars:
            rows = slice(w0 * Pc, w1 * Pc) if name == "parent" else slice(w0, w1)  # parent: [W * Pc]
            setattr(arrays, name, getattr(self._arrays, name)[rows])
        groups = kernels.GroupArrays()
        for name in struct_type(kernels.GroupArrays).vars:
            setattr(groups, name, getattr(self._groups, name)[w0:w1])
        smallest = self.min_group_size
        commands = [
            arrays.nn_histogram.zero_,
            arrays.group_size.zero_,
            shard.record(
                kernels.prey_distances, (W, Pc), [world, g, s.agents, self.predators_by_grid, self.bin_width], [arrays]
            ),
            shard.record(kernels.link_groups, (W, Pc), [world, g, s.agents, self._linking_distances[w0:w1]], [arrays]),
            shard.record(
                kernels.local_alignment, (W, Pc), [world, g, s.agents, self._linking_distances[w0:w1]], [arrays]
            ),
            shard.record(kernels.resolve_groups, (W, Pc), [world, s.agents], [arrays]),
            shard.record(kernels.prey_partial_sums, (W, self._chunks), [world, s.agents], [arrays]),
            shard.record(kernels.finish_prey_sums, W, [world, s.worlds, s.outputs], [arrays]),
            shard.record(kernels.centroid_partial_sums, (W, self._chunks), [world, s.agents], [arrays]),
            shard.record(kernels.finish_cohesion, W, [], [arrays]),
        ]
        if not self.group_metrics:
            return commands
        return commands + [
            shard.record(kernels.track_groups, W, [world, s.agents, s.worlds, smallest], [arrays, groups]),
            shard.record(kernels.group_order, (W, Pc), [world, s.agents, smallest], [arrays, groups]),
            shard.record(kernels.finish_groups, W, [world, s.agents, smallest], [arrays, groups]),
        ]

    def compute(self) -> dict[str, torch.Tensor]:
        """Metrics of the current state of every world: `{name: [W] float32}` for the names in
        `SCALAR_METRICS` and `GROUP_METRICS`, plus `"nn_histogram"` `[W, bins]` int32 and
        `"group_sizes"` `[W, prey_capacity]` int32; on the env's device, no host sync. The tensors are
        views overwritten by the next `compute()`: clone what you keep. Group identities carry over to
        the next call (see the module's definitions)."""
        self._program.run()
        return self._result


class EpisodeMetrics(Observer):
    """Per-episode averages of `SwarmMetrics` for every world, accumulated on the device.

    Call `begin()` after `env.reset()` and `update(info)` after every `env.step()`, or let the episode
    loop do it (an observer of `rollout.rollout`). The state is
    sampled every `every` steps (the first state of an episode, then every `every`-th): an episode's
    value of a metric is its mean over the episode's sampled states, skipping NaN samples. When a
    world's episode ends (`info["episode_ended"]`, the env resets it), its episode values, its
    captures (`info["episode_captures"]`), `captures_per_prey` (captures / `prey_count`, the initial
    prey) and `episode_length` are added to the completed totals. Nothing synchronises with the host
    but `log_values()`/`summary()`.

    `trace` names metrics of `SCALAR_METRICS` or `GROUP_METRICS` to record at every sample (e.g.
    `("prey_alive", "predator_alive")` for population dynamics with reproduction and starvation,
    `("group_rotation", "group_age")` for the groups' course within episodes): `traces()` returns them
    as `[samples, worlds]` tensors, with `trace_steps` the step count of each sample; `trace_worlds`
    picks the worlds (default: all).
    """

    def __init__(
        self,
        env: BatchedAquarium,
        metrics: SwarmMetrics | None = None,
        every: int = 1,
        trace: Iterable[str] = (),
        trace_worlds: Iterable[int] | None = None,
        **metric_kwargs,
    ):
        if metrics is None:
            metrics = SwarmMetrics(env, **metric_kwargs)
        elif metric_kwargs:
            raise ValueError(f"pass either metrics= or SwarmMetrics arguments, not both: {sorted(metric_kwargs)}")
        if metrics.env is not env:
            raise ValueError("metrics was made for another env")
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"every={every!r} must be an integer >= 1")
        trace = tuple(trace)
        names = kernels.VALUE_NAMES
        unknown = [name for name in trace if name not in names]
        if unknown:
            raise ValueError(f"unknown trace metrics {unknown}; choose from {names}")
        W, dev = env.num_worlds, env.torch_device
        worlds = list(range(W)) if trace_worlds is None else list(trace_worlds)
        if not worlds or any(isinstance(w, bool) or not isinstance(w, int) or not 0 <= w < W for w in worlds):
            raise ValueError(f"trace_worlds={trace_worlds!r} must be world indices in [0, {W - 1}]")
        self.env, self.metrics, self.every, self.trace_names = env, metrics, every, trace
        self.trace_worlds = worlds
        self._columns = torch.tensor([names.index(n) for n in EPISODE_METRICS], device=dev)
        self._trace_columns = torch.tensor([names.index(n) for n in trace], device=dev)
        self._trace_rows = torch.tensor(worlds, device=dev)
        K, B, Pc = len(EPISODE_METRICS), metrics.nn_bins, env.prey_capacity
        zeros = functools.partial(torch.zeros, device=dev, dtype=torch.float64)
        self._group_members = torch.arange(1, Pc + 1, device=dev, dtype=torch.float64)  # the size of each column
        # Current episode: sums over samples, and how many samples were not NaN; the histograms.
        self._sum, self._count = zeros(W, K), zeros(W, K)
        self._hist, self._group_hist = zeros(W, B), zeros(W, Pc)
        # Completed episodes: sums of episode values and how many episodes gave a value.
        self._done_sum, self._done_count = zeros(W, K), zeros(W, K)
        self._done_hist, self._done_group_hist = zeros(W, B), zeros(W, Pc)
        self._done_captures, self._done_length, self._episodes = zeros(W), zeros(W), zeros(W)
        self.ended_values = torch.full((W, K), math.nan, device=dev, dtype=torch.float64)  # see close_episodes
        self._launches = TorchStreamLaunches(env.device)  # close_episodes' launch
        self.steps = 0  # steps counted since `begin()` (`advance`, `count_replayed`)
        self._trace: list[torch.Tensor] = []
        self.trace_steps: list[int] = []

    def _totals(self) -> tuple[torch.Tensor, ...]:
        """The running totals, in `kernels.metrics.close_episodes`' order: the current episode's sums,
        counts and histograms, then the completed episodes' sums, counts, histograms, captures, lengths
        and number."""
        return (
            self._sum,
            self._count,
            self._hist,
            self._group_hist,
            self._done_sum,
            self._done_count,
            self._done_hist,
            self._done_group_hist,
            self._done_captures,
            self._done_length,
            self._episodes,
        )

    def begin(self) -> None:
        """Forget everything (the groups tracked too) and sample the current state as step 0 (call right
        after `env.reset()`)."""
        for t in self._totals():
            t.zero_()
        self._trace.clear()
        self.trace_steps.clear()
        self.steps = 0
        self.metrics.restart_tracking()
        self._sample()

    def _sample(self) -> None:
        values = self.metrics.compute()
        x = self.metrics.values.index_select(1, self._columns).double()
        valid = ~torch.isnan(x)
        self._sum += torch.where(valid, x, 0.0)
        self._count += valid
        self._hist += values["nn_histogram"]
        self._group_hist += values["group_sizes"] * self._group_members  # prey in groups of each size
        if self.trace_names:
            self._trace.append(self.metrics.values[self._trace_rows][:, self._trace_columns])
            self.trace_steps.append(self.steps)

    def on_start(self, env: BatchedAquarium) -> None:
        self.begin()

    def on_step(self, env: BatchedAquarium, step: int, result: StepResult) -> None:
        self.update(result.info)

    def update(self, info: Mapping) -> None:
        """Account for one `env.step()`: close the episodes that ended in it, then sample the new state
        if the step count is a multiple of `every` (for worlds that were reset, the state is the next
        episode's first, and belongs to it)."""
        self.close_episodes(info)
        self.advance()

    def close_episodes(self, info: Mapping) -> None:
        """The first half of `update()`: device work only (one launch on torch's current stream: no host
        sync, no allocation), so it can be captured in a CUDA graph; `advance()` must follow it. Sets
        `ended_values` `[W, len(EPISODE_METRICS)]`: the episode values of the worlds whose episode just
        ended (NaN elsewhere), for callers that record every episode."""
        inputs = (info["episode_ended"], info["episode_captures"], info["episode_length"])
        self._launches.run(
            tuple(t.data_ptr() for t in inputs),  # recorded once per set of info buffers
            kernels.close_episodes,
            self.env.num_worlds,
            lambda: [*inputs, *self._totals(), self.ended_values],
        )

    def advance(self) -> None:
        """The second half of `update()`: count the step and sample the state every `every` steps."""
        self.steps += 1
        if self.steps % self.every == 0:
            self._sample()

    @property
    def phase(self) -> int:
        """Steps since the last sample (`steps % every`): which of the next steps sample the state."""
        return self.steps % self.every

    def count_replayed(self, steps: int) -> None:
        """Count `steps` steps whose `close_episodes` and `advance` ran in a replayed CUDA graph (captured
        when the counter stood at the same `phase`): their samples were taken there. Refused with a
        trace, whose samples are host lists that a graph cannot append to."""
        if self.trace_names:
            raise ValueError("EpisodeMetrics with a trace records its samples on the host: it cannot run in a graph")
        self.steps += steps

    def result(self) -> dict[str, torch.Tensor]:
        """Per world, the mean over its completed episodes (NaN where none): `[W]` float64 tensors for
        `EPISODE_METRICS`, `captures`, `captures_per_prey`, `episode_length`, plus `episodes` (count),
        `group_lifetime` (the mean lifetime of the groups that ended in those episodes, steps),
        `nn_distribution` `[W, bins]` (the histogram normalised per episode, then averaged) and
        `group_size_distribution` `[W, prey_capacity]` (the share of the sampled prey in groups of each
        size, column s - 1 for size s, per episode, then averaged)."""
        episodes = self._episodes
        out = {name: self._done_sum[:, k] / self._done_count[:, k] for k, name in enumerate(EPISODE_METRICS)}
        out["group_lifetime"] = out["ended_lifetime_total"] / out["groups_ended"]
        out["captures"] = self._done_captures / episodes
        out["captures_per_prey"] = out["captures"] / self._prey_counts()
        out["episode_length"] = self._done_length / episodes
        out["episodes"] = episodes.clone()
        out["nn_distribution"] = self._done_hist / episodes.unsqueeze(1)
        out["group_size_distribution"] = self._done_group_hist / episodes.unsqueeze(1)
        return out

    def _prey_counts(self) -> torch.Tensor:
        """`[W]` float64: each world's initial prey count (as the env's config holds it now)."""
        return torch.tensor(
            per_world(self.env.config.prey_count, self.env.num_worlds),
            dtype=torch.float64,
            device=self._done_captures.device,
        )

    def summary(self) -> dict[str, float]:
        """Means over every completed episode of every world (host sync); `episodes`: their number."""
        episodes = float(self._episodes.sum())
        out = {}
        for k, name in enumerate(EPISODE_METRICS):
            n = float(self._done_count[:, k].sum())
            out[name] = float(self._done_sum[:, k].sum()) / n if n else math.nan
        out["group_lifetime"] = out["ended_lifetime_total"] / out["groups_ended"] if out["groups_ended"] else math.nan
        out["captures"] = float(self._done_captures.sum()) / episodes if episodes else math.nan
        prey = self.env.config.prey_count
        if isinstance(prey, tuple):  # each world's captures over its own prey count
            out["captures_per_prey"] = (
                float((self._done_captures / self._prey_counts()).sum()) / episodes if episodes else math.nan
            )
        else:
            out["captures_per_prey"] = out["captures"] / prey
        out["episode_length"] = float(self._done_length.sum()) / episodes if episodes else math.nan
        out["episodes"] = episodes
        return out

    def log_values(self, prefix: str = "swarm/") -> dict[str, float]:
        """`summary()` of the episodes completed since the last call, keys prefixed for a logger
        (empty when none completed); then forgets those episodes (the running ones carry on)."""
        summary = self.summary()
        for t in (
            self._done_sum,
            self._done_count,
            self._done_hist,
            self._done_group_hist,
            self._done_captures,
            self._done_length,
            self._episodes,
        ):
            t.zero_()
        if not summary["episodes"]:
            return {}
        return {prefix + k: v for k, v in summary.items()}

    _STATE = (
        "_sum",
        "_count",
        "_hist",
        "_group_hist",
        "_done_sum",
        "_done_count",
        "_done_hist",
        "_done_group_hist",
        "_done_captures",
        "_done_length",
        "_episodes",
    )

    def state_dict(self) -> dict:
        """The accumulators (CPU copies), so that a resumed run reports the same episode values."""
        state = {name: getattr(self, name).cpu().clone() for name in self._STATE}
        state["steps"] = self.steps
        state["tracking"] = self.metrics.tracking_state()
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restore `state_dict()`. A state saved before the group measures existed (fewer metric columns,
        no group-size histograms) restores the metrics it holds; the newer ones count from here on."""
        for name in self._STATE:
            target = getattr(self, name)
            saved = state.get(name)
            target.zero_()
            if saved is None:
                continue
            if saved.shape == target.shape:
                target.copy_(saved)
            elif (
                saved.dim() == target.dim() == 2
                and saved.shape[0] == target.shape[0]
                and (saved.shape[1] < target.shape[1])
            ):  # fewer metric columns: a state from before the group measures
                target[:, : saved.shape[1]].copy_(saved)
            else:
                raise ValueError(
                    f"episode metrics state {name!r} has shape {tuple(saved.shape)}: expected {tuple(target.shape)} "
                    "(a checkpoint of another world count or metric set)"
                )
        self.steps = int(state["steps"])
        if "tracking" in state:
            self.metrics.load_tracking_state(state["tracking"])
        else:  # a state from before group tracking: groups count as new from here on
            self.metrics.restart_tracking()

    def traces(self) -> dict[str, torch.Tensor]:
        """`{name: [samples, worlds]}` of the metrics named in `trace` (float32) in `trace_worlds`, at steps
        `trace_steps`."""
        if not self._trace:
            return {name: torch.zeros(0, len(self.trace_worlds)) for name in self.trace_names}
        stacked = torch.stack(self._trace)
        return {name: stacked[:, :, k] for k, name in enumerate(self.trace_names)}


def rollout_metrics(
    env: BatchedAquarium,
    act: Drivers,
    steps: int,
    every: int = 1,
    reset: bool = True,
    trace: Iterable[str] = (),
    trace_worlds: Iterable[int] | None = None,
    progress: bool = False,
    **metric_kwargs,
) -> dict[str, torch.Tensor]:
    """Run `steps` steps of `env` (`rollout.rollout`) with the actions of `act` (`{team: driver}`, or a
    function of the observations returning every team's actions) and return `EpisodeMetrics.result()`
    (per world, means over the episodes completed in the run), plus the traces when `trace` names some
    (`trace_<name>` `[samples, worlds]` of the worlds `trace_worlds`, default all, and `trace_steps`).

    For evaluation: `rollout_metrics(env, lambda obs: heuristic_actions(env), steps=env.config.max_steps)`
    gives one episode per world. `metric_kwargs` go to `SwarmMetrics` (e.g. `linking_distance`)."""
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps={steps!r} must be an integer >= 1")
    episodes = EpisodeMetrics(env, every=every, trace=trace, trace_worlds=trace_worlds, **metric_kwargs)
    observers: list[Observer] = [episodes]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc="rollout", unit="step")
        observers.append(Progress(bar.update))
    try:
        rollout(env, act, steps, observers, reset=reset)
    finally:
        if bar is not None:
            bar.close()
    out = episodes.result()
    if trace:
        out.update({f"trace_{k}": v for k, v in episodes.traces().items()})
        out["trace_steps"] = torch.tensor(episodes.trace_steps)
    return out
