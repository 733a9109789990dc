"""The fast training loop (`training/loop.py`) against rsl-rl's own runner loop, the reference.

On the CPU both loops must produce the same parameters bit for bit (same calls to rsl-rl's PPO, same
random draws, `update_on_device` = `PPO.update`), and the episode statistics the loop accumulates on
the device must equal those rsl-rl's logger averages from the adapter's `extras["log"]`. With CUDA
(`AQUARIUM_TEST_DEVICE=cuda:0`), the graph-replayed loop is compared with the eager one.
"""

import csv
import os

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest
import torch

from aquarium_warp.training import Trainer, make_config


def _train(loop: str, log_dir=None, device="cpu", plan: list | None = None, **changes):
    train = {"loop": loop, "iterations": 3, "quiet": True, "num_worlds": 16, "device": device, "export": []}
    train.update(changes.pop("train", {}))
    cfg = make_config("tiny", {"train": train, **changes})
    trainer = Trainer(cfg, log_dir=log_dir)
    trainer.train()
    alg = trainer.runner.alg
    if plan is not None:  # the graphs the fast loop used: (rollout, [update per learner], whole rollout)
        loop = trainer.runner.loop
        plan.append((loop.graphs, loop.update_graphs, loop.whole_rollout))
        swarm = trainer.runner.env.swarm  # the swarm metrics' totals: their samples ran in the graphs too
        plan.append(swarm.state_dict() if swarm is not None else {})
    params = {f"actor.{k}": v.clone() for k, v in alg.actor.state_dict().items()}
    params.update({f"critic.{k}": v.clone() for k, v in alg.critic.state_dict().items()})
    params.update(
        {
            f"adam.{i}.{k}": v.clone()
            for i, s in alg.optimizer.state_dict()["state"].items()
            for k, v in s.items()
            if isinstance(v, torch.Tensor) and k != "step"
        }
    )
    trainer.close()
    return params, alg.learning_rate


NORMALISED = {"runner": {"actor": {"obs_normalization": True}, "critic": {"obs_normalization": True}}}


CASES = [
    ("parameter sharing", {}),
    ("individual learning", {"train": {"sharing": "individual"}}),
    ("adaptive schedule", {"runner": {"algorithm": {"schedule": "adaptive", "desired_kl": 0.002}}}),
    (
        "per-mini-batch advantages, clipped value loss",
        {"runner": {"algorithm": {"normalize_advantage_per_mini_batch": True, "use_clipped_value_loss": True}}},
    ),
    ("observation normalisation", NORMALISED),
    (
        "recurrent models (rsl-rl's own update)",
        {"runner": {"actor": {"class_name": "RNNModel"}, "critic": {"class_name": "RNNModel"}}},
    ),
    (
        "permanent capture (inactive rows), predators learn",
        {"env": {"respawn_captured_prey": False}, "train": {"team": "predator", "opponent": "turnaway"}},
    ),
]


@pytest.mark.parametrize("name,changes", CASES, ids=[c[0] for c in CASES])
@pytest.mark.slow
def test_fast_loop_equals_rsl_rl_runner_bit_for_bit(name, changes):
    import copy

    reference, lr_ref = _train("rsl-rl", **copy.deepcopy(changes))
    fast, lr_fast = _train("fast", **copy.deepcopy(changes))
    assert reference.keys() == fast.keys()
    differing = [k for k in reference if not torch.equal(reference[k], fast[k])]
    assert not differing, f"{name}: parameters differ in {differing}"
    assert lr_ref == lr_fast
    # A changed update would be caught: one extra iteration moves the parameters.
    longer, _ = _train("fast", **{**copy.deepcopy(changes), "train": {**changes.get("train", {}), "iterations": 4}})
    assert any(not torch.equal(reference[k], longer[k]) for k in reference)


def _rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("metrics_every", [10, 0], ids=["swarm metrics", "no swarm metrics"])
@pytest.mark.slow
def test_device_episode_statistics_equal_rsl_rl_logger(tmp_path, metrics_every):
    """captures, rewards and lengths of the ended world episodes, logged per iteration: the fast loop's
    device sums against rsl-rl's logger averaging the adapter's per-step `extras["log"]`. Short episodes
    (max_steps 40) so that several iterations log episodes, some with partial first episodes."""
    changes = {"env": {"max_steps": 40}, "train": {"iterations": 6, "metrics_every": metrics_every}}
    _train("rsl-rl", log_dir=str(tmp_path / "ref"), **changes)
    _train("fast", log_dir=str(tmp_path / "fast"), **changes)
    ref, fast = _rows(tmp_path / "ref" / "progress.csv"), _rows(tmp_path / "fast" / "progress.csv")
    assert len(ref) == len(fast) == 6
    logged = 0
    for a, b in zip(ref, fast):
        assert a["episodes_logged"] == b["episodes_logged"]
        for field in (
            "captures",
            "captures_per_prey",
            "reward_per_agent",
            "opponent_reward_per_agent",
            "episode_length",
        ):
            assert (a[field] == "") == (b[field] == ""), field
            if a[field] != "":
                assert float(b[field]) == pytest.approx(float(a[field]), rel=1e-6, abs=1e-9), field
                logged += 1
        for field in ("value_loss", "surrogate_loss", "entropy"):  # float32 sums vs rsl-rl's float64 .item()
            assert float(b[field]) == pytest.approx(float(a[field]), rel=1e-5, abs=1e-7), field
    assert logged >= 10  # the comparison saw real episodes
    with open(tmp_path / "fast" / "progress.csv", encoding="utf-8") as f:
        header = f.readline()
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tags = EventAccumulator(str(tmp_path / "fast")).Reload().Tags()["scalars"]
    assert any(t.startswith("Swarm/") for t in tags) == (metrics_every > 0), tags
    assert "captures_per_prey" in header
    # The swarm metrics' series over training, in swarm.csv: the TensorBoard values of the iterations
    # where episodes ended, each measure a column.
    swarm_csv = tmp_path / "fast" / "swarm.csv"
    assert swarm_csv.exists() == (metrics_every > 0)
    if metrics_every:
        events = EventAccumulator(str(tmp_path / "fast")).Reload()
        rows = _rows(swarm_csv)
        assert [int(r["iteration"]) for r in rows] == [e.step for e in events.Scalars("Swarm/nn_ratio_hard_disk")]
        for tag in ("Swarm/nn_mean", "Swarm/nn_ratio_hard_disk", "Swarm/group_polarization"):
            logged = {e.step: e.value for e in events.Scalars(tag)}
            for row in rows:  # a measure without a value in an iteration's episodes is logged in neither
                if row[tag] == "":
                    assert int(row["iteration"]) not in logged, tag
                else:
                    assert float(row[tag]) == pytest.approx(logged[int(row["iteration"])], rel=1e-6), tag


class _Alg:
    """What `graph_plan` reads of an algorithm."""

    def __init__(self, rollout: bool, update: bool, capturable: bool = True, ranks: bool = False):
        self.rollout_graphable, self.graphable, self.capturable_optimizer = rollout, update, capturable
        self.is_multi_gpu = ranks


@pytest.mark.parametrize(
    "algs,cuda,plan",
    [
        ([_Alg(True, True)], False, (False, [False])),  # the CPU captures nothing
        ([_Alg(True, True), _Alg(True, True)], True, (True, [True, True])),
        # several ranks or the adaptive schedule: the rollout replays graphs, that learner's update is eager
        ([_Alg(True, False), _Alg(True, True)], True, (True, [False, True])),
        ([_Alg(True, False, capturable=False)], True, (True, [False])),
        # a recurrent model (or RND, symmetry) in either learner: everything eager
        ([_Alg(False, False), _Alg(True, True)], True, (False, [False, False])),
    ],
    ids=["cpu", "all", "eager-update", "eager-update-any-optimizer", "eager"],
)
def test_graph_plan(algs, cuda, plan):
    from aquarium_warp.training.loop import graph_plan

    assert graph_plan(algs, cuda) == plan


@pytest.mark.parametrize(
    "algs,plan",
    [
        ([_Alg(True, True)], (True, [False])),
        ([_Alg(True, True), _Alg(True, False)], (True, [False, False])),
        ([_Alg(False, False)], (False, [False])),
    ],
    ids=["one", "two", "recurrent"],
)
def test_graph_plan_without_graph_update_keeps_the_rollout_graphs(algs, plan):
    """`train.graph_update=false`: the update runs eagerly between the replayed rollouts."""
    from aquarium_warp.training.loop import graph_plan

    assert graph_plan(algs, True, graph_update=False) == plan


@pytest.mark.parametrize(
    "graph_update,backend,plan",
    [
        ("auto", "nccl", (True, [True, "split"])),
        ("auto", "gloo", (True, [True, "split"])),
        (True, "nccl", (True, [True, True])),
        (False, "nccl", (True, [False, False])),
    ],
)
def test_graph_plan_splits_the_update_of_several_ranks_at_its_all_reduces(monkeypatch, graph_update, backend, plan):
    """One process captures its update as one graph; a rank of several (its update all-reduces) as
    graphs cut at each all-reduce by default, with any backend, and as one graph with NCCL's all-reduce
    inside only when `train.graph_update=true`."""
    from aquarium_warp.training import distributed
    from aquarium_warp.training.loop import graph_plan

    monkeypatch.setattr(distributed, "collectives_capturable", lambda: backend == "nccl")
    assert graph_plan([_Alg(True, True), _Alg(True, True, ranks=True)], True, graph_update) == plan


def test_graph_plan_refuses_to_capture_a_gloo_all_reduce(monkeypatch):
    from aquarium_warp.training import distributed
    from aquarium_warp.training.loop import graph_plan

    monkeypatch.setattr(distributed, "collectives_capturable", lambda: False)
    with pytest.raises(ValueError, match=r"^train.graph_update=true captures the gradient all-reduce .* only NCCL"):
        graph_plan([_Alg(True, True, ranks=True)], True, True)


def _learners(monkeypatch, ranks: int, backend: str | None, *changes: dict, team: str = "prey"):
    """The algorithms of a CPU trainer built as for CUDA graphs (capturable optimizer), made to believe
    they are one of `ranks` ranks whose process group runs `backend` (NCCL's capture cannot be
    exercised on the CPU; what `graph_plan` reads of it can)."""
    from aquarium_warp.training import distributed

    monkeypatch.setattr(distributed, "collectives_capturable", lambda: backend == "nccl")
    train = {"team": team, "num_worlds": 4, "quiet": True, "export": [], "pool_every": int(team == "both")}
    cfg = make_config("tiny", {"train": train, "runner": {"algorithm": {"capturable_optimizer": True}}}, *changes)
    trainer = Trainer(cfg)
    algs = [learner.alg for learner in trainer.runner.learners]
    for alg in algs:
        alg.is_multi_gpu = ranks > 1
    trainer.close()
    return algs


@pytest.mark.parametrize(
    "ranks,backend,team,changes,graph_update,plan",
    [
        (1, None, "prey", {}, True, (True, [True])),
        (1, None, "prey", {}, "auto", (True, [True])),
        (1, None, "prey", {}, False, (True, [False])),
        # torchrun on GPUs: the update replays graphs cut at its all-reduces by default, any backend
        (2, "nccl", "prey", {}, "auto", (True, ["split"])),
        (2, "nccl", "both", {}, "auto", (True, ["split", "split"])),
        (2, "gloo", "both", {}, "auto", (True, ["split", "split"])),
        # train.graph_update=true: the update with its all-reduce is captured, for one team and for both
        (2, "nccl", "prey", {}, True, (True, [True])),
        (2, "nccl", "both", {}, True, (True, [True, True])),
        (2, "nccl", "both", {}, False, (True, [False, False])),
        # the adaptive schedule reads the KL on the host: eager update
        (2, "nccl", "prey", CASES[2][1], True, (True, [False])),
        # a recurrent model: nothing captured
        (2, "nccl", "prey", CASES[5][1], True, (False, [False])),
    ],
    ids=[
        "one",
        "one-auto",
        "one-eager-update",
        "nccl-auto",
        "nccl-both-auto",
        "gloo-both-auto",
        "nccl-opted-in",
        "nccl-both-opted-in",
        "nccl-both-eager-update",
        "nccl-adaptive",
        "rnn",
    ],
)
def test_graph_plan_of_real_algorithms(monkeypatch, ranks, backend, team, changes, graph_update, plan):
    """What the loop would capture on CUDA, from the algorithms a run builds (both teams: with the
    opponent pool)."""
    from aquarium_warp.training.loop import graph_plan

    algs = _learners(monkeypatch, ranks, backend, changes, team=team)
    assert graph_plan(algs, True, graph_update) == plan
    assert graph_plan(algs, False, graph_update) == (False, [False] * len(algs))  # the CPU: none


def test_graph_update_is_a_switch():
    with pytest.raises(ValueError, match=r"train.graph_update='no' must be true or false"):
        make_config("tiny", {"train": {"graph_update": "no"}})
    with pytest.raises(ValueError, match=r"train.graph_update=1 must be true or false, or 'auto'"):
        make_config("tiny", {"train": {"graph_update": 1}})
    assert make_config("tiny")["train"]["graph_update"] == "auto"


@pytest.mark.slow
def test_graph_update_leaves_cpu_training_unchanged(tmp_path):
    """The CPU captures nothing: `train.graph_update` changes no bit there; `config.json` says so."""
    import json

    default, _ = _train("fast", log_dir=str(tmp_path / "default"), train={"iterations": 2})
    eager, _ = _train("fast", train={"iterations": 2, "graph_update": False})
    assert default.keys() == eager.keys()
    assert all(torch.equal(default[k], eager[k]) for k in default)
    with open(tmp_path / "default" / "config.json", encoding="utf-8") as f:
        assert json.load(f)["cuda_graphs"] == {"rollout": False, "update": {"prey": False}}


def test_a_loop_needs_at_least_one_rollout_step():
    from aquarium_warp.training.loop import TrainingLoop

    with pytest.raises(ValueError, match=r"num_steps=0 must be >= 1"):
        TrainingLoop([(object(), object())], 0)


def test_graph_plan_needs_capturable_optimizers():
    from aquarium_warp.training.loop import graph_plan

    with pytest.raises(ValueError, match="capturable_optimizer=True"):
        graph_plan([_Alg(True, True, capturable=False)], True)


def test_algorithms_say_which_graphs_they_allow():
    """The adaptive schedule keeps the rollout graphable but not the update; a recurrent model neither."""
    for changes, want in [({}, (True, True)), (CASES[2][1], (True, False)), (CASES[5][1], (False, False))]:
        trainer = Trainer(make_config("tiny", {"train": {"num_worlds": 4, "quiet": True, "export": []}, **changes}))
        alg = trainer.runner.alg
        assert (alg.rollout_graphable, alg.graphable) == want, changes
        trainer.close()


ADAPTIVE = CASES[2][1]


@pytest.mark.parametrize(
    "num_steps,every,phases",
    [(32, [], 1), (32, [10], 5), (30, [10], 1), (32, [8], 1), (24, [10], 5), (32, [10, 4], 5), (7, [3, 5], 15)],
)
def test_rollout_phases(num_steps, every, phases):
    """Whole-rollout graphs needed: by hand, 32 steps and a sample every 10 start rollouts at steps 0, 2,
    4, 6, 8 (mod 10), then repeat; 30 steps always at 0; 7 steps with samples every 3 and every 5 start
    at (0, 0), (1, 2), (2, 4), ... and repeat after lcm(3, 5) rollouts."""
    from aquarium_warp.training.loop import rollout_phases

    assert rollout_phases(num_steps, every) == phases


def test_adapters_say_whether_their_step_can_be_captured(tmp_path):
    """A heuristic opponent and the other learner's buffer are device work only; a domain randomiser
    (host reads of the ended worlds), swarm metrics with a trace and a loaded policy (its own random
    stream) are not: the loop then replays a graph per stage instead of the whole rollout."""
    common = {"num_worlds": 4, "quiet": True, "export": []}
    for changes, want in [
        ({}, [True]),
        ({"train": {"team": "both"}}, [True, True]),
        ({"train": {"randomize": {"prey_max_speed": "3:5"}}}, [False]),
    ]:
        trainer = Trainer(make_config("tiny", {"train": {**common, **changes.get("train", {})}}))
        assert [learner.vec_env.step_capturable for learner in trainer.runner.learners] == want, changes
        assert trainer.runner.loop is None or not trainer.runner.loop.whole_rollout  # (no graphs on the CPU)
        trainer.close()
    # swarm metrics with a trace append each sample to host lists: not in a graph
    from aquarium_warp.metrics import EpisodeMetrics

    trainer = Trainer(make_config("tiny", {"train": common}))
    vec_env = trainer.runner.env
    assert vec_env.swarm is not None and vec_env.step_capturable
    vec_env.swarm = EpisodeMetrics(vec_env.env, every=vec_env.swarm.every, trace=("prey_alive",))
    assert not vec_env.step_capturable
    trainer.close()
    trainer = Trainer(make_config("tiny", {"train": common}), log_dir=str(tmp_path / "run"))
    trainer.train(1)
    policy = trainer.export(formats=["jit"])["jit"]
    trainer.close()
    loaded = Trainer(make_config("tiny", {"train": {**common, "opponent": policy, "team": "predator"}}))
    assert not loaded.runner.env.step_capturable
    loaded.close()


RANDOMISED = {"train": {"randomize": {"prey_max_speed": "3:5"}}}


@pytest.mark.parametrize(
    "changes",
    [{}, NORMALISED, ADAPTIVE, RANDOMISED],
    ids=[
        "plain",
        "observation normalisation",
        "adaptive schedule (eager update)",
        "domain randomisation (a graph per step)",
    ],
)
def test_cuda_graph_loop_matches_eager_loop(changes, cuda_device):
    """Replayed graphs run the eager loop's kernels, and torch's generator gives a replayed kernel the
    offset the eager call would have had: the same parameters and swarm-metric totals after iterations
    2-7 (graphs). The whole-rollout graphs of the 5 sampling phases of 32 steps with a sample every 10
    come at iterations 2-6 (and the first again at 7). With observation normalisation the graphs must
    see the statistics updated after every iteration. With the adaptive schedule only the rollout is
    replayed (as in a torchrun run), and the eager update between the replays must see what the eager
    loop's saw. A domain randomiser reads the ended worlds on the host every step, so its rollout
    replays a graph per stage and launches the simulation step between them."""
    import copy

    iterations = 7
    changes = copy.deepcopy(changes)
    train = changes.pop("train", {})
    eager_plan: list = []
    eager, _ = _train(
        "fast", device=cuda_device, plan=eager_plan, train={**train, "cuda_graphs": False, "iterations": iterations},
        **copy.deepcopy(changes),
    )  # fmt: skip
    plan: list = []
    graphed, _ = _train(
        "fast", device=cuda_device, plan=plan, train={**train, "cuda_graphs": True, "iterations": iterations},
        **copy.deepcopy(changes),
    )  # fmt: skip
    assert plan[0] == (True, [changes != ADAPTIVE], not train)
    differing = {k: float((eager[k] - graphed[k]).abs().max()) for k in eager if not torch.equal(eager[k], graphed[k])}
    assert not differing, differing
    swarm_eager, swarm_graphed = eager_plan[1], plan[1]
    assert swarm_graphed["steps"] == iterations * 32
    assert swarm_eager.keys() == swarm_graphed.keys()
    for key, value in swarm_eager.items():
        same = value == swarm_graphed[key] if key == "steps" else torch.equal(value, swarm_graphed[key])
        assert same, key


def test_a_failed_update_capture_says_so(cuda_device, monkeypatch):
    """An update that cannot be captured (here: a host read) raises at its capture, naming the learner
    and the way out; no silent fallback to the eager update."""
    config = make_config("tiny", {"train": {"device": cuda_device, "num_worlds": 4, "quiet": True, "export": []}})
    trainer = Trainer(config)
    alg = trainer.runner.alg
    update = alg.update_on_device

    def reading_update(indices, size):
        losses = update(indices, size)
        losses.sum().item()  # allowed eagerly, refused while capturing
        return losses

    monkeypatch.setattr(alg, "update_on_device", reading_update)
    with pytest.raises(RuntimeError, match=r"learner 0 \(prey; one process\).*train.graph_update=false"):
        trainer.train(3)
    trainer.close()


def test_graph_captures_pause_the_garbage_collector():
    """A torch capture must not run Python's collector (it would free Warp arrays of dropped envs, which
    a capturing stream refuses): paused inside, restored after, also when the block raises."""
    import gc

    from aquarium_warp.training.loop import collection_paused

    assert gc.isenabled()
    with collection_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError), collection_paused():
        raise RuntimeError("capture failed")
    assert gc.isenabled()


class _FakeGraph:
    """A stand-in for `torch.cuda.CUDAGraph` on the CPU: it records when its capture opens and closes
    (in `log`) and when it is replayed."""

    def __init__(self, log: list):
        self.log, self.number = log, sum(entry[0] == "begin" for entry in log)

    def capture_begin(self, pool=None, capture_error_mode="global"):
        self.log.append(("begin", self.number, pool, capture_error_mode))

    def capture_end(self):
        self.log.append(("end", self.number))

    def replay(self):
        self.log.append(("replay", self.number))


def test_split_graph_cuts_at_each_all_reduce_and_replays_them_in_order(monkeypatch):
    """`SplitGraph` captures the work between all-reduces as graphs and repeats the all-reduces (same
    tensors, same arguments) between their replays; `torch.distributed.all_reduce` is itself again
    after the capture, also after a capture that raised. (CUDA graphs need a GPU: a recording stand-in
    takes their place; the GPU tests of tests/training/test_distributed.py run real ones.)"""
    import torch.distributed as dist

    from aquarium_warp.training import loop

    log: list = []
    reduced: list = []

    def all_reduce(tensor, op=dist.ReduceOp.SUM, group=None, async_op=False):
        reduced.append((tensor, op, group))
        log.append(("all_reduce", len(reduced) - 1))

    monkeypatch.setattr(dist, "all_reduce", all_reduce)
    monkeypatch.setattr(loop.torch.cuda, "CUDAGraph", lambda: _FakeGraph(log))
    a, b = torch.zeros(3), torch.ones(2)

    def update():
        dist.all_reduce(a)
        dist.all_reduce(b, op=dist.ReduceOp.MAX)
        return "losses"

    graph = loop.SplitGraph("pool", None, "thread_local")
    assert graph.capture(update) == "losses"
    assert dist.all_reduce is all_reduce and reduced == []  # capturing runs no collective
    assert log == [
        ("begin", 0, "pool", "thread_local"),
        ("end", 0),
        ("begin", 1, "pool", "thread_local"),
        ("end", 1),
        ("begin", 2, "pool", "thread_local"),
        ("end", 2),
    ]
    assert graph.collectives == 2
    log.clear()
    graph.replay()
    assert log == [("replay", 0), ("all_reduce", 0), ("replay", 1), ("all_reduce", 1), ("replay", 2)]
    assert reduced[0][0] is a and reduced[0][1] == dist.ReduceOp.SUM and reduced[1][0] is b
    assert reduced[1][1] == dist.ReduceOp.MAX
    with pytest.raises(RuntimeError, match="captured once"):
        graph.capture(update)

    def asynchronous():
        dist.all_reduce(a, async_op=True)

    log.clear()
    with pytest.raises(RuntimeError, match="asynchronous all-reduce cannot be cut"):
        loop.SplitGraph("pool", None).capture(asynchronous)
    assert dist.all_reduce is all_reduce
    assert log == [("begin", 0, "pool", "global"), ("end", 0)]  # the open capture was closed


def test_close_frees_the_graphs_before_the_process_group(monkeypatch):
    """A CUDA graph holding NCCL's kernels keeps the communicator busy: destroying the process group
    first waited forever (4 x H200, b717c38). The trainer frees the loop's graphs, then leaves the group."""
    from aquarium_warp.training import distributed

    trainer = Trainer(make_config("tiny", {"train": {"num_worlds": 4, "quiet": True, "export": []}}))
    trainer.train(1)
    order: list[str] = []
    monkeypatch.setattr(trainer.runner.loop, "release_graphs", lambda: order.append("graphs"))
    monkeypatch.setattr(distributed, "close", lambda: order.append("process group"))
    trainer.world_size = 2  # as a torchrun rank's trainer
    trainer.close()
    assert order == ["graphs", "process group"]
