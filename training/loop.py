"""The training loop of `aquarium-warp train`: rsl-rl's PPO (its actor, critic, rollout storage and
optimizer, unmodified) driven from our own loop so that nothing in an iteration waits for the host.

rsl-rl's `OnPolicyRunner.learn` spends most of an iteration in Python and host synchronisation around
small networks: its logger reads the done flags back every step, and its update reads three losses
back after every mini-batch. This loop makes the same calls in the same order, and on CUDA replays
them as CUDA graphs:

- step `t` of a rollout is graph `act[t]` (`PPO.act`: actor, sampling, critic, log-probabilities,
  and the actions into the adapter's int32 buffer), then the Warp work outside any torch graph (the
  other team's policy and the simulation step, itself one CUDA graph), then graph `after[t]` (rows'
  rewards, dones and time-outs, `PPO.process_env_step` into the storage, per-world episode statistics
  on the device, the next observations);
- after the rollout, graph `learn`: `PPO.compute_returns` (GAE) and `AquariumPPO.update_on_device`
  (every mini-batch of every epoch: forward, losses, backward, gradient clipping, Adam), reading the
  mini-batch indices drawn just before it by the same `randperm` as rsl-rl's generator;
- once per iteration the losses and episode statistics are copied to pinned host memory without
  blocking; the trainer logs iteration `i` while the GPU runs iteration `i + 1`.

One observation buffer serves the whole loop: `after[t]` stores the observations the actor saw before
it overwrites them with the next ones, so the storage receives exactly what rsl-rl's loop stores.

On the CPU (or where a graph cannot serve: recurrent models, the adaptive learning-rate schedule, RND)
the same functions run eagerly; recurrent models are updated by rsl-rl's own `PPO.update`. On the CPU this loop and `OnPolicyRunner.learn` produce the same
parameters bit for bit (`tests/test_training_loop.py`), so `train.loop = "rsl-rl"` (rsl-rl's own
runner) remains as the reference and for the benchmark's before/after.

CUDA graphs are captured after one eager warm-up iteration, in the order they replay, from one memory
pool; they replay the same memory addresses, which is why every buffer they touch is allocated once.
"""

from __future__ import annotations

import time

import torch

from .ppo import mini_batch_size
from .vec_env import AquariumVecEnv


class IterationRecord:
    """What an iteration reports: mean losses, episode statistics and phase times, copied to the host
    without blocking. `read()` waits for this iteration's work only, so the trainer can log iteration
    `i` while the GPU already runs iteration `i + 1`."""

    def __init__(self, device: torch.device):
        self.cuda = device.type == "cuda"
        self._host = None
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
            if self._host is None or self._host.shape != values.shape:
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


class TrainingLoop:
    """Runs iterations of rollout + PPO update for `alg` (an `AquariumPPO`) over `env`; see the module doc.

    `graphs=True` captures CUDA graphs where the device is CUDA and the algorithm allows it
    (`alg.graphable`); `self.graphs` says whether they are in use.
    """

    def __init__(self, alg, env: AquariumVecEnv, num_steps: int, graphs: bool = True):
        self.alg, self.env, self.num_steps = alg, env, int(num_steps)
        self.device = torch.device(alg.device)
        self.graphs = bool(graphs) and self.device.type == "cuda" and alg.graphable
        if self.graphs and not getattr(alg, "capturable_optimizer", False):
            raise ValueError("CUDA graphs need the algorithm built with capturable_optimizer=True")
        env.device_stats = True
        self.obs = env.get_observations()
        # Two records alternate: the trainer reads one while the next iteration fills the other.
        self._records = [IterationRecord(self.device), IterationRecord(self.device)]
        self._record_index = 0
        self._warm = False
        self._capture_stream = torch.cuda.Stream(self.device) if self.graphs else None
        self._act_graphs: list = []
        self._after_graphs: list = []
        self._learn_graph = None
        self._indices = None
        self._losses = None

    # ------------------------------------------------------------------ the stages (captured or eager)
    def _act(self) -> None:
        actions = self.alg.act(self.obs)
        self.env.actions_buffer.copy_(actions.view(self.env.actions_buffer.shape))

    def _after_step(self) -> None:
        env = self.env
        env.row_outcomes()
        rewards, dones, extras = env.outputs
        # The storage copies `self.obs` (still the observations the actor saw) before they are replaced.
        self.alg.process_env_step(self.obs, rewards, dones, extras)
        if env.swarm is not None:
            env.swarm.close_episodes(env.info)
        env.accumulate_episode_stats()
        env.copy_observations()

    def _advance_metrics(self) -> None:
        if self.env.swarm is not None:
            self.env.swarm.advance()

    def _learn(self, indices: torch.Tensor | None, mini_batch_size: int) -> torch.Tensor:
        with torch.inference_mode():
            self.alg.compute_returns(self.obs)
        if indices is not None:
            return self.alg.update_on_device(indices, mini_batch_size)
        # Recurrent models: rsl-rl's own update (its trajectory mini-batches), which also does what
        # `finish_update` does.
        losses = self.alg.update()
        return torch.tensor([losses["value"], losses["surrogate"], losses["entropy"]], dtype=torch.float64,
                            device=self.device)

    def _draw_indices(self) -> tuple[torch.Tensor | None, int]:
        return self.alg.mini_batch_indices() if self.alg.feed_forward else (None, 0)

    def _finish_update(self) -> None:
        if self.alg.feed_forward:
            self.alg.finish_update()

    # ------------------------------------------------------------------ one iteration
    def iteration(self) -> IterationRecord:
        """One rollout of `num_steps` steps and one PPO update, enqueued (on CUDA nothing waits). The
        record's `read()` gives `[value loss, surrogate loss, entropy, *episode statistics]` (see
        `AquariumVecEnv.decode_episode_stats` for the tail) and the (collect, learn) seconds."""
        if self.graphs and self._warm and self._learn_graph is None:
            self._capture()
        if self.graphs and not self._warm:
            # Warm-up on the side stream that will capture, as torch asks: lazy initialisations (cuBLAS
            # workspaces are per stream) must not happen during a capture.
            stream = self._capture_stream
            stream.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(stream):
                result = self._run(self._record())
            torch.cuda.current_stream(self.device).wait_stream(stream)
            self._warm = True
            return result
        return self._run(self._record())

    def _record(self) -> IterationRecord:
        self._record_index ^= 1
        return self._records[self._record_index]

    def _finish(self, record: IterationRecord, losses: torch.Tensor) -> IterationRecord:
        record.finish(torch.cat([losses, self.env.episode_stats_snapshot()]))
        return record

    def _run(self, record: IterationRecord, mark=lambda phase: None) -> IterationRecord:
        """One rollout and update, eagerly or by replaying the captured graphs; `mark(phase)` is called
        after each stage ("policy", "env", "storage", "update") for `phase_times`."""
        graphs = self._learn_graph is not None
        record.mark(0)
        with torch.inference_mode():
            for t in range(self.num_steps):
                self._act_graphs[t].replay() if graphs else self._act()
                mark("policy")
                self.env.step_simulation()
                mark("env")
                self._after_graphs[t].replay() if graphs else self._after_step()
                self._advance_metrics()
                mark("storage")
        record.mark(1)
        indices, size = self._draw_indices()
        if graphs:
            self._indices.copy_(indices)
            self._learn_graph.replay()
            losses = self._losses
        else:
            losses = self._learn(indices, size)
        self._finish_update()
        mark("update")
        return self._finish(record, losses)

    def phase_times(self) -> dict[str, float]:
        """One more iteration (it trains like any other), timed stage by stage: seconds spent in the
        policy (`act`), the env (other team + simulation), the storage (`after`: outcomes, storage
        writes, statistics) and the update (returns + mini-batches). For the benchmark: on CUDA the
        stages are bracketed by events, which adds no synchronisation."""
        while self.graphs and self._learn_graph is None:
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
        self._run(self._record(), mark)
        if cuda:
            marks[-1][1].synchronize()
        times = dict.fromkeys(("policy", "env", "storage", "update"), 0.0)
        for (_, a), (phase, b) in zip(marks[:-1], marks[1:]):
            times[phase] += a.elapsed_time(b) / 1e3 if cuda else b - a
        self.env.episode_stats_snapshot()  # this iteration's statistics are not logged
        return times

    def _capture(self) -> None:
        """Record `act[t]`, `after[t]` and `learn` in replay order, from one memory pool. Capturing
        runs nothing: the storage's step counter advances as if it had and is reset afterwards."""
        pool = torch.cuda.graph_pool_handle()
        storage = self.alg.storage
        torch.cuda.synchronize(self.device)
        with torch.inference_mode():
            for _ in range(self.num_steps):
                for stage, graphs in ((self._act, self._act_graphs), (self._after_step, self._after_graphs)):
                    graph = torch.cuda.CUDAGraph()
                    with torch.cuda.graph(graph, pool=pool, stream=self._capture_stream):
                        stage()
                    graphs.append(graph)
        # The indices are drawn before each replay; capturing must not draw (it would shift the stream).
        size = mini_batch_size(storage, self.alg.num_mini_batches, self.alg.minibatch_group_size)
        self._indices = torch.arange(size * self.alg.num_mini_batches, device=self.device)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=pool, stream=self._capture_stream):
            self._losses = self._learn(self._indices, size)
        self._learn_graph = graph
        storage.clear()
