"""The training loop of `aquarium-warp train`: rsl-rl's PPO (its actor, critic, rollout storage and
optimizer, unmodified) driven from our own loop so that nothing in an iteration waits for the host.

rsl-rl's `OnPolicyRunner.learn` spends most of an iteration in Python and host synchronisation around
small networks: its logger reads the done flags back every step, and its update reads three losses
back after every mini-batch. This loop makes the same calls in the same order, and on CUDA replays
them as CUDA graphs (the adapter's own host reads, where its settings need them, are listed in
`vec_env.py`: episodes that can end otherwise than by truncation, domain randomisation):

- the whole rollout is one graph: for each of its steps `PPO.act` (actor, sampling, critic,
  log-probabilities, and the actions into the adapter's int32 buffer), the other team's policy and the
  simulation step (Warp launches recorded into torch's capture: `shard.ShardSet.run`), then the rows'
  rewards, dones and time-outs, `PPO.process_env_step` into the storage, per-world episode statistics
  on the device, the next observations, and the swarm metrics' sample where one falls. Which steps
  sample depends on the step count the rollout starts at, so there is one such graph per starting
  phase (`every / gcd(every, num_steps)` of them: 5 for the paper's 32 steps and a sample every 10;
  at most `MAX_ROLLOUT_GRAPHS`), all captured together. One replay per rollout leaves the host nothing to do
  per step and the GPU no gap between graphs: on one H100 the paper preset's rollout (1,024 worlds,
  fused MLP and TF32) took 4.41 ms as one graph against 8.85 ms as `act[t]` and `after[t]` per step
  with the simulation launched between them (`benchmarks/results/rollout_fusion_h100_e968e81/`);
- where an adapter's simulation step needs the host (a domain randomiser, a loaded or recurrent
  opponent: `AquariumVecEnv.step_capturable`), or the sampling phases would need more than
  `MAX_ROLLOUT_GRAPHS` graphs, step `t` is graph `act[t]`, then the simulation step outside any
  torch graph (itself one CUDA graph of Warp's), then graph `after[t]`;
- after the rollout, graph `learn`: `PPO.compute_returns` (GAE) and `AquariumPPO.update_on_device`
  (every mini-batch of every epoch: forward, losses, backward, gradient clipping, Adam), reading the
  mini-batch indices drawn just before it by the same `randperm` as rsl-rl's generator;
- once per iteration the losses and episode statistics are copied to pinned host memory without
  blocking; the trainer logs iteration `i` while the GPU runs iteration `i + 1`.

One observation buffer serves the whole loop: `after[t]` stores the observations the actor saw before
it overwrites them with the next ones, so the storage receives exactly what rsl-rl's loop stores.

On the CPU (or where a graph cannot serve: recurrent models, RND, symmetry) the same functions run
eagerly; recurrent models are updated by rsl-rl's own `PPO.update`. With the adaptive learning-rate
schedule (which reads the KL on the host) or `graph_update=False` (`train.graph_update`), the rollout
replays its graphs and the update runs eagerly between rollouts.

Several processes (torchrun): a rank's update all-reduces its gradients after every mini-batch. By
default ("auto") the update is captured as a `SplitGraph`: CUDA graphs cut at each all-reduce, which
runs eagerly between two replays, so the collectives never enter a graph and any backend serves (NCCL,
or gloo's host-side wait). `graph_update=True` instead captures the whole update, NCCL's all-reduce
inside its graph: every rank captures and replays the same collectives in the same order (the graphs
are captured at the same iteration on every rank, after the parameters' broadcast has set up the
communicator). Both run at the same speed on 2 and 4 H200s (benchmarks/results/multi_gpu_h200x4_c6239ee/).
A graph that holds NCCL's kernels must be freed before the process group is destroyed
(`release_graphs`, called by the trainer's `close`): otherwise `destroy_process_group` waits forever,
which is why such runs once seemed to hang (2 x H100 at 8535669; found on 4 x H200 at b717c38). Captures on
several ranks use CUDA's thread-local capture mode: NCCL's proxy threads and torch's watchdog make CUDA
calls of their own while this thread captures, which the global mode would count against the capture.
A capture that fails raises, naming the learner and the way out (`train.graph_update=false`); there is
no silent fallback (a failed capture of a collective may leave the communicator unusable). On the CPU
this loop and `OnPolicyRunner.learn` produce the same parameters bit for bit
(`tests/training/test_training_loop.py`), so `train.loop = "rsl-rl"` (rsl-rl's
own runner) remains as the reference and for the benchmark's before/after.

Several learners (`train.team = "both"`: one PPO learner per team, acting in the same worlds): `act[t]`
runs every learner's `PPO.act` (and the opponent pool's snapshots, `pool.py`), one simulation step
follows, and `after[t]` runs every learner's `process_env_step` and statistics; each learner has its
own update graph. A learner may be frozen for an iteration (the alternating schedule): it acts as
usual, but its rollout is dropped instead of learned from. With one learner the calls and their order
are exactly those above.

CUDA graphs are captured after one eager warm-up iteration (the rollout's), and a learner's update
graph after its first, eager, update (its optimizer state must exist first), from one memory pool;
they replay the same memory addresses, which is why every buffer they touch is allocated once.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import itertools
import math
import time
from collections.abc import Callable

import torch
import torch.distributed as dist

from . import distributed
from .vec_env import AquariumVecEnv


@contextlib.contextmanager
def collection_paused():
    """Pause Python's garbage collector for the block: a torch graph capture must not free Warp arrays
    (of an env or trainer dropped earlier in the process, e.g. a study's previous run), because Warp
    frees them at once, which a capturing stream refuses (CUDA error 900, and the capture is lost).
    Their cycles are collected after the capture instead. (No collection first: it would free nothing
    the pause does not already keep out of the capture, and its two full collections took 0.37 s of the
    4.5 s of a paper-preset training on one H100 at 724d195, under cProfile.)"""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class SplitGraph:
    """Work that calls `torch.distributed.all_reduce`, captured as CUDA graphs cut at each call.

    `capture(fn)` runs `fn` with every stream-ordered GPU operation captured (nothing executes): the
    work up to its first all-reduce becomes one graph, the all-reduce a call to repeat on the same
    tensor (which stays allocated in the graphs' memory pool), the work up to the next all-reduce the
    next graph, and so on. `replay()` replays the graphs and runs the all-reduces between them, in the
    captured order, with the same arguments. The collectives thus run eagerly from the host, as in an
    eager update, while everything between them replays: no collective is captured, so any backend
    serves, gloo's host-side wait included.

    rsl-rl's gradient average (`reduce_gradients_in_buckets`) calls `torch.distributed.all_reduce`
    directly; the cut replaces that function for the capture only (the capturing thread is the only
    one that calls it) and puts it back afterwards. An asynchronous all-reduce cannot be cut (its
    handle would be waited on inside a graph) and raises. Every graph shares `pool`, in capture order,
    which is also replay order, as torch asks of graphs that share a pool."""

    def __init__(self, pool, stream: torch.cuda.Stream | None, capture_error_mode: str = "global"):
        self.pool = pool
        self.stream = stream
        self.capture_error_mode = capture_error_mode
        self.steps: list[Callable[[], object]] = []  # graph replays and all-reduces, in order
        self._open: torch.cuda.CUDAGraph | None = None  # the graph being captured

    @property
    def collectives(self) -> int:
        """How many all-reduces run between the graphs."""
        return sum(isinstance(step, functools.partial) for step in self.steps)

    def _begin(self) -> None:
        self._open = torch.cuda.CUDAGraph()
        self._open.capture_begin(pool=self.pool, capture_error_mode=self.capture_error_mode)

    def _end(self) -> None:
        graph, self._open = self._open, None
        if graph is not None:
            graph.capture_end()
            self.steps.append(graph.replay)

    def capture(self, fn: Callable[[], object]):
        """Capture `fn()` (see the class doc); its result (tensors written by the graphs)."""
        if self.steps:
            raise RuntimeError("a SplitGraph is captured once")
        all_reduce = dist.all_reduce

        def cut(tensor, op=dist.ReduceOp.SUM, group=None, async_op=False):
            if async_op:
                raise RuntimeError("an asynchronous all-reduce cannot be cut out of a captured update")
            self._end()
            self.steps.append(functools.partial(all_reduce, tensor, op=op, group=group))
            self._begin()

        with torch.cuda.stream(self.stream):
            self._begin()
            dist.all_reduce = cut
            try:
                return fn()
            finally:
                dist.all_reduce = all_reduce
                self._end()

    def replay(self) -> None:
        for step in self.steps:
            step()


class IterationRecord:
    """What an iteration reports: mean losses, episode statistics and phase times, copied to the host
    without blocking. `read()` waits for this iteration's work only, so the trainer can log iteration
    `i` while the GPU already runs iteration `i + 1`."""

    def __init__(self, device: torch.device):
        self.cuda = device.type == "cuda"
        self._host = torch.empty(0)  # the values of the last `finish` (pinned on CUDA)
        if self.cuda:
            self._events = [torch.cuda.Event(enable_timing=True) for _ in range(3)]
        self._times = [0.0, 0.0, 0.0]

    def mark(self, i: int) -> None:
        """Phase boundaries: 0 before the rollout, 1 after it, 2 after the update."""
        if self.cuda:
            self._events[i].record()
        else:
            self._times[i] = time.perf_counter()

    def finish(self, values: torch.Tensor) -> None:
        """Copy `values` (losses and statistics, on the device) to the host after the iteration."""
        if self.cuda:
            if self._host.shape != values.shape:
                self._host = torch.empty(values.shape, dtype=values.dtype, pin_memory=True)
            self._host.copy_(values, non_blocking=True)
        else:
            self._host = values.clone()
        self.mark(2)

    def read(self) -> tuple[list[float], tuple[float, float]]:
        """`(values, (collect seconds, learn seconds))`, waiting for the iteration to finish."""
        if self.cuda:
            e = self._events
            e[2].synchronize()
            times = e[0].elapsed_time(e[1]) / 1e3, e[1].elapsed_time(e[2]) / 1e3
        else:
            t = self._times
            times = t[1] - t[0], t[2] - t[1]
        return self._host.tolist(), times


def graph_plan(algs, cuda: bool, graph_update: bool | str = "auto") -> tuple[bool, list[bool | str]]:
    """Which CUDA graphs a loop over `algs` captures (`cuda`: graphs asked for on a CUDA device): the
    rollout's, where every algorithm allows it (`rollout_graphable`), and per learner how its update is
    captured, where the rollout is and its algorithm allows it (`graphable`): False (eager), True (one
    graph) or "split" (a `SplitGraph`, cut at its all-reduces). `graph_update` "auto": one graph in one
    process, split on several ranks; True: one graph, on several ranks with the all-reduce inside (NCCL
    only; see the module doc); False: eager."""
    rollout = cuda and all(alg.rollout_graphable for alg in algs)
    updates: list[bool | str] = []
    for alg in algs:
        if not (rollout and alg.graphable) or graph_update is False:
            updates.append(False)
        elif not alg.is_multi_gpu:
            updates.append(True)
        elif graph_update is True:
            if not distributed.collectives_capturable():
                raise ValueError(
                    "train.graph_update=true captures the gradient all-reduce inside the update's graph, which "
                    "only NCCL's collectives allow; 'auto' replays the update in graphs cut at each all-reduce"
                )
            updates.append(True)
        else:
            updates.append("split")
    if not all(getattr(alg, "capturable_optimizer", False) for alg, u in zip(algs, updates) if u):
        raise ValueError("CUDA graphs need the algorithms built with capturable_optimizer=True")
    return rollout, updates


MAX_ROLLOUT_GRAPHS = 10  # whole-rollout graphs at most (one per sampling phase); more: a graph per stage


def rollout_phases(num_steps: int, every: list[int]) -> int:
    """How many whole-rollout graphs a loop of `num_steps` steps per rollout needs with swarm metrics
    sampled every `every[i]` steps: the phases the rollouts start at repeat after `every / gcd(every,
    num_steps)` rollouts for each, after their least common multiple for all."""
    return math.lcm(*(e // math.gcd(e, num_steps) for e in every)) if every else 1


class TrainingLoop:
    """Runs iterations of rollout + PPO update for one or more learners over the same worlds; see the
    module doc.

    `learners`: `(alg, env)` pairs (an `AquariumPPO` and its `AquariumVecEnv`), one per learning team.
    The first adapter steps the worlds; the other learners' actions reach it through its opponent
    (`LearnerActions`). `pool`: an `OpponentPool` whose snapshots play some worlds. `graphs=True`
    captures the rollout's CUDA graphs where the device is CUDA and every algorithm allows it
    (`alg.rollout_graphable`), and as `graph_update` asks ("auto": one graph in one process, graphs cut at
    the all-reduces on several ranks; True: one graph, on NCCL ranks with the all-reduce inside; False:
    never) a learner's update graphs where its algorithm allows that too (`alg.graphable`; else the update
    runs eagerly between the replayed rollouts: the adaptive schedule); `self.graphs` says whether graphs
    are in use, `self.update_graphs` per learner how its update is captured (see `graph_plan`).
    `reduce`: applied in place to each iteration's values (losses and statistics, on the device) before
    they are copied to the host; a torchrun run sums them over the ranks there, in stream order (the
    record's learn time then includes waiting for the slowest rank's sum).
    """

    def __init__(
        self,
        learners,
        num_steps: int,
        graphs: bool = True,
        pool=None,
        reduce: Callable[[torch.Tensor], None] | None = None,
        graph_update: bool | str = "auto",
    ):
        self.learners = [(alg, env) for alg, env in learners]
        if not self.learners:
            raise ValueError("a training loop needs at least one learner")
        self.algs = [alg for alg, _ in self.learners]
        self.envs: list[AquariumVecEnv] = [env for _, env in self.learners]
        self.env = self.envs[0]
        self.num_steps = int(num_steps)
        if self.num_steps < 1:
            raise ValueError(f"num_steps={num_steps!r} must be >= 1 (steps of a rollout)")
        self.pool = pool
        self.reduce = reduce
        self.device = torch.device(self.algs[0].device)
        self.graphs, self.update_graphs = graph_plan(
            self.algs, bool(graphs) and self.device.type == "cuda", graph_update
        )
        # Several ranks: other threads (NCCL's proxies, torch's watchdog) call CUDA during a capture.
        self._capture_mode = "thread_local" if any(alg.is_multi_gpu for alg in self.algs) else "global"
        for env in self.envs:
            env.device_stats = True
        self.obs = [env.get_observations() for env in self.envs]
        # Two records alternate: the trainer reads one while the next iteration fills the other.
        self._records = [IterationRecord(self.device), IterationRecord(self.device)]
        self._record_index = 0
        self._warm = False
        self.capture_seconds = 0.0  # host time spent capturing CUDA graphs (`train --verbose`'s start-up)
        self._capture_stream = torch.cuda.Stream(self.device) if self.graphs else None
        self._pool_handle = torch.cuda.graph_pool_handle() if self.graphs else None  # the graphs' memory pool
        # The rollout as one graph per sampling phase of the swarm metrics (`_rollout_key`), where every
        # adapter's simulation step is device work only and the phases are few; otherwise graphs
        # `act[t]` and `after[t]`.
        phases = rollout_phases(self.num_steps, [swarm.every for swarm in self._swarms()])
        self.whole_rollout = (
            self.graphs and phases <= MAX_ROLLOUT_GRAPHS and all(env.step_capturable for env in self.envs)
        )
        self._rollout_graphs: dict[tuple[int, ...], torch.cuda.CUDAGraph] = {}
        self._act_graphs: list = []
        self._after_graphs: list = []
        n = len(self.learners)
        # Per learner: its update graph, the indices it reads, the losses it writes, and whether the
        # learner has updated once eagerly (its optimizer state exists: only then can a graph hold it).
        self._learn_graphs: list = [None] * n
        self._indices: list = [None] * n
        self._losses: list = [None] * n
        self._updated = [False] * n
        self._frozen_losses = torch.full((3,), float("nan"), dtype=torch.float64, device=self.device)

    # ------------------------------------------------------------------ the stages (captured or eager)
    def _act(self) -> None:
        for alg, env, obs in zip(self.algs, self.envs, self.obs):
            alg.act_into(obs, env.actions_buffer)
        if self.pool is not None:
            self.pool.act()

    def _after_step(self) -> None:
        if self.pool is not None:
            self.pool.resample()
        for alg, env, obs in zip(self.algs, self.envs, self.obs):
            env.row_outcomes()
            rewards, dones, extras = env.outputs
            # The storage copies `obs` (still the observations the actor saw) before they are replaced.
            alg.process_env_step(obs, rewards, dones, extras)
            if env.swarm is not None:
                env.swarm.close_episodes(env.info)
            env.accumulate_episode_stats()
            env.copy_observations()

    def _advance_metrics(self) -> None:
        for env in self.envs:
            if env.swarm is not None:
                env.swarm.advance()

    def _rollout_step(self, t: int | None = None, mark=lambda phase: None) -> None:
        """One step of a rollout: act, the other team and the simulation step, then after (outcomes,
        storage, statistics) and the swarm metrics' sample; `act[t]` and `after[t]` replayed where `t`
        is given. `mark` as in `_run`."""
        self._act_graphs[t].replay() if t is not None else self._act()
        mark("policy")
        self.env.step_simulation()
        mark("env")
        self._after_graphs[t].replay() if t is not None else self._after_step()
        self._advance_metrics()
        mark("storage")

    def _swarms(self) -> list:
        return [env.swarm for env in self.envs if env.swarm is not None]

    def _rollout_key(self) -> tuple[int, ...]:
        """Which whole-rollout graph serves the next rollout: the swarm metrics' sampling phases (the
        steps of a rollout that sample the state differ with the phase it starts at)."""
        return tuple(swarm.phase for swarm in self._swarms())

    def _learn(self, i: int, indices: torch.Tensor | None, mini_batch_size: int) -> torch.Tensor:
        alg = self.algs[i]
        with torch.inference_mode():
            alg.compute_returns(self.obs[i])
        if indices is not None:
            return alg.update_on_device(indices, mini_batch_size)
        # Recurrent models: rsl-rl's own update (its trajectory mini-batches), which also does what
        # `finish_update` does.
        losses = alg.update()
        return torch.tensor(
            [losses["value"], losses["surrogate"], losses["entropy"]], dtype=torch.float64, device=self.device
        )

    # ------------------------------------------------------------------ one iteration
    def iteration(self, learning=None) -> IterationRecord:
        """One rollout of `num_steps` steps and the PPO updates of the learners flagged in `learning`
        (default: all; a frozen learner acts but does not learn, its rollout is dropped), enqueued (on
        CUDA nothing waits). The record's `read()` gives, per learner in order, `[value loss, surrogate
        loss, entropy (NaN when frozen), *episode statistics]` (`split` cuts it; see
        `AquariumVecEnv.decode_episode_stats` for the statistics) and the (collect, learn) seconds."""
        learning = [True] * len(self.learners) if learning is None else [bool(x) for x in learning]
        if len(learning) != len(self.learners):
            raise ValueError(f"learning has {len(learning)} flags for {len(self.learners)} learners")
        if self.graphs and self._warm:
            self._capture_rollout()
        if self.graphs and not self._warm:
            # Warm-up on the side stream that will capture, as torch asks: lazy initialisations (cuBLAS
            # workspaces are per stream) must not happen during a capture.
            with self._on_capture_stream():
                result = self._run(self._record(), learning)
            self._warm = True
            return result
        return self._run(self._record(), learning)

    def split(self, values: list[float]) -> list[tuple[list[float], list[float]]]:
        """A record's values cut per learner: `[(losses [3], episode statistics), ...]`."""
        out, start = [], 0
        for env in self.envs:
            end = start + 3 + env.episode_stats_size
            out.append((values[start : start + 3], values[start + 3 : end]))
            start = end
        return out

    @contextlib.contextmanager
    def _on_capture_stream(self):
        """Run eager work on the capturing stream, ordered with the current stream on both sides."""
        stream = self._capture_stream
        assert stream is not None, "only a loop that captures graphs runs on a capture stream"
        stream.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(stream):
            yield
        torch.cuda.current_stream(self.device).wait_stream(stream)

    def _record(self) -> IterationRecord:
        self._record_index ^= 1
        return self._records[self._record_index]

    def _run(self, record: IterationRecord, learning: list[bool], mark=lambda phase: None) -> IterationRecord:
        """One rollout and update, eagerly or by replaying the captured graphs; `mark(phase)` is called
        after each stage for `phase_times`: "policy", "env", "storage" per step, or "rollout" for a
        whole-rollout graph, then "update"."""
        graphs = bool(self._act_graphs)
        record.mark(0)
        with torch.inference_mode():
            if self._rollout_graphs:
                self._rollout_graphs[self._rollout_key()].replay()
                for swarm in self._swarms():
                    swarm.count_replayed(self.num_steps)
                mark("rollout")
            else:
                for t in range(self.num_steps):
                    self._rollout_step(t if graphs else None, mark)
        record.mark(1)
        parts = []
        for i, alg in enumerate(self.algs):
            if learning[i]:
                parts.append(self._update(i))
            else:
                alg.storage.clear()  # a frozen learner: its parameters, optimizer and normaliser stay
                parts.append(self._frozen_losses)
            parts.append(self.envs[i].episode_stats_snapshot())
        mark("update")
        values = torch.cat(parts)
        if self.reduce is not None:
            self.reduce(values)
        record.finish(values)
        return record

    def _update(self, i: int) -> torch.Tensor:
        """Learner `i`'s update: its captured graph, captured now if it has updated eagerly before, or
        eagerly (the first time, on the capturing stream when graphs are in use)."""
        alg = self.algs[i]
        indices, size = alg.mini_batch_indices() if alg.feed_forward else (None, 0)
        if self.update_graphs[i] and self._updated[i] and self._learn_graphs[i] is None:
            self._capture_learn(i, size)
        if self._learn_graphs[i] is not None:
            self._indices[i].copy_(indices)
            self._learn_graphs[i].replay()
            losses = self._losses[i]
        elif self.graphs and self._warm:
            with self._on_capture_stream():
                losses = self._learn(i, indices, size)
        else:
            losses = self._learn(i, indices, size)
        self._updated[i] = True
        if alg.feed_forward:
            alg.finish_update()
        return losses

    def phase_times(self) -> dict[str, float]:
        """One more iteration (it trains like any other, every learner learning), timed stage by stage:
        seconds spent in the policy (`act`), the env (other team + simulation), the storage (`after`:
        outcomes, storage writes, statistics), or in the rollout where one graph replays it whole, and
        the update (returns + mini-batches). For the benchmark: on CUDA the stages are bracketed by
        events, which adds no synchronisation."""
        while self.graphs and not (
            (self._act_graphs or self._rollout_key() in self._rollout_graphs)
            and all(g is not None for g, graphed in zip(self._learn_graphs, self.update_graphs) if graphed)
        ):
            self.iteration()  # warm-up, then capture
        cuda = self.device.type == "cuda"
        marks: list = []

        def mark(phase: str) -> None:
            if cuda:
                event = torch.cuda.Event(enable_timing=True)
                event.record()
                marks.append((phase, event))
            else:
                marks.append((phase, time.perf_counter()))

        mark("start")
        self._run(self._record(), [True] * len(self.learners), mark)
        if cuda:
            marks[-1][1].synchronize()
        times: dict[str, float] = {}
        for (_, a), (phase, b) in zip(marks[:-1], marks[1:]):
            times[phase] = times.get(phase, 0.0) + (a.elapsed_time(b) / 1e3 if cuda else b - a)
        return times

    def release_graphs(self) -> None:
        """Free every captured graph, once the GPU has finished with them (a later iteration captures
        anew). Before its process group is destroyed: a graph that holds NCCL's kernels keeps the
        communicator busy, and destroying the group then waited forever (4 x H200, commit b717c38)."""
        if self.graphs:
            torch.cuda.synchronize(self.device)
        self._act_graphs, self._after_graphs = [], []
        self._rollout_graphs = {}
        self._learn_graphs = [None] * len(self.learners)

    def _graph_capture(self, graph: torch.cuda.CUDAGraph):
        return torch.cuda.graph(
            graph, pool=self._pool_handle, stream=self._capture_stream, capture_error_mode=self._capture_mode
        )

    def _capture_rollout(self) -> None:
        """Record the rollout's graphs not yet recorded, from the loop's memory pool: the whole rollout
        (every step's act, simulation step, after and sampling) for each sampling phase the coming
        rollouts start at, or else `act[t]` and `after[t]` in replay order (once). Capturing runs
        nothing: the storages' step counters and the swarm metrics' step counts advance as if it had
        and are put back after each capture."""
        if self._rollout_key() in self._rollout_graphs if self.whole_rollout else bool(self._act_graphs):
            return
        start = time.perf_counter()
        torch.cuda.synchronize(self.device)
        swarms = self._swarms()
        steps = [swarm.steps for swarm in swarms]
        with torch.inference_mode(), collection_paused():
            if self.whole_rollout:
                # Every phase the coming rollouts start at, so that none is captured mid-run.
                for k in itertools.count():
                    for swarm, count in zip(swarms, steps):
                        swarm.steps = count + k * self.num_steps
                    key = self._rollout_key()
                    if key in self._rollout_graphs:
                        break
                    graph = self._rollout_graphs[key] = torch.cuda.CUDAGraph()
                    with self._graph_capture(graph):
                        for _ in range(self.num_steps):
                            self._rollout_step()
                    self._clear_storages()
            else:
                for _ in range(self.num_steps):
                    for stage, graphs in ((self._act, self._act_graphs), (self._after_step, self._after_graphs)):
                        graph = torch.cuda.CUDAGraph()
                        with self._graph_capture(graph):
                            stage()
                        graphs.append(graph)
                self._clear_storages()
        for swarm, count in zip(swarms, steps):
            swarm.steps = count
        self.capture_seconds += time.perf_counter() - start

    def _clear_storages(self) -> None:
        for alg in self.algs:
            alg.storage.clear()

    def _capture_learn(self, i: int, size: int) -> None:
        """Record learner `i`'s update (GAE, every mini-batch of every epoch; with several ranks, the
        gradients' all-reduce of each: inside the graph, or between the graphs of a `SplitGraph`)
        without running it; the indices are drawn before each replay (capturing must not draw: it would
        shift the stream). A failed capture raises, saying so."""
        alg = self.algs[i]
        start = time.perf_counter()
        torch.cuda.synchronize(self.device)
        self._indices[i] = torch.arange(size * alg.num_mini_batches, device=self.device)
        split = self.update_graphs[i] == "split"
        try:
            with collection_paused():
                graph: SplitGraph | torch.cuda.CUDAGraph
                if split:
                    split_graph = SplitGraph(self._pool_handle, self._capture_stream, self._capture_mode)
                    self._losses[i] = split_graph.capture(lambda: self._learn(i, self._indices[i], size))
                    graph = split_graph
                else:
                    graph = cuda_graph = torch.cuda.CUDAGraph()
                    with self._graph_capture(cuda_graph):
                        self._losses[i] = self._learn(i, self._indices[i], size)
        except Exception as error:  # name what failed and the way out; no silent fallback
            if not alg.is_multi_gpu:
                where = "one process"
            elif split:
                where = f"rank {alg.gpu_global_rank}, cut at its all-reduces"
            else:
                where = f"rank {alg.gpu_global_rank}, with its NCCL all-reduce"
            raise RuntimeError(
                f"capturing the PPO update of learner {i} ({self.envs[i].team}; {where}) as a CUDA graph "
                f"failed: {error}. train.graph_update=false runs the update eagerly"
            ) from error
        self._learn_graphs[i] = graph
        self.capture_seconds += time.perf_counter() - start
