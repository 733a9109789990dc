"""Swarm metrics (`aquarium_warp.metrics`) against numpy references: hand-made formations set with
`env.set_state` (aligned, opposite pairs, clusters across the seam, rings) and random states compared
with an all-pairs float64 reference (nearest neighbours, nearest predators, connected components),
plus determinism across CPU shards and the per-episode accumulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.heuristics import heuristic_actions
from aquarium_warp.metrics import EPISODE_METRICS, SCALAR_METRICS, EpisodeMetrics, SwarmMetrics, rollout_metrics


def make_env(device, prey_count, predator_count=1, num_worlds=1, **kw) -> BatchedAquarium:
    cfg = AquariumConfig(prey_count=prey_count, predator_count=predator_count, **kw)
    return BatchedAquarium(cfg, num_worlds=num_worlds, device=device, seed=0)


def set_prey(env, prey_pos, prey_heading, predator_pos=None, world=0, prey_alive=None):
    """One world: prey at `prey_pos` with unit `prey_heading`; predators at `predator_pos` (default: far
    corner), all live unless `prey_alive` says otherwise."""
    C, Pc = env.capacity, env.prey_capacity
    pos = np.zeros((C, 2), np.float32)
    head = np.tile(np.array([1.0, 0.0], np.float32), (C, 1))
    alive = np.zeros(C, bool)
    n = len(prey_pos)
    pos[:n] = np.asarray(prey_pos, np.float32) % np.array([env.config.width, env.config.height], np.float32)
    head[:n] = np.asarray(prey_heading, np.float32)
    alive[:n] = True if prey_alive is None else np.asarray(prey_alive, bool)
    if predator_pos is None:
        predator_pos = [[1.0, 1.0]] * env.predator_capacity
    pos[Pc:] = np.asarray(predator_pos, np.float32)
    alive[Pc:] = True
    env.set_state(world=world, position=pos, velocity=head * 2.0, heading=head, alive=alive)


def unit(angles):
    a = np.asarray(angles, np.float64)
    return np.stack([np.cos(a), np.sin(a)], axis=-1).astype(np.float32)


# --------------------------------------------------------------------------------------------------
# numpy reference (float64, all pairs)
# --------------------------------------------------------------------------------------------------
def torus(d, size):
    return d - size * np.round(d / size)


def reference(pos, head, alive, Pc, size, link, bins, bin_width):
    """Metrics of one world from its state arrays ([C, 2], [C, 2], [C])."""
    pos, head = pos.astype(np.float64), head.astype(np.float64)
    prey = np.flatnonzero(alive[:Pc])
    preds = Pc + np.flatnonzero(alive[Pc:])
    n = len(prey)
    out = {"prey_alive": n, "predator_alive": len(preds), "nan": float("nan")}
    hist = np.zeros(bins, np.int64)
    if n == 0:
        out.update(
            polarization=math.nan,
            cohesion=math.nan,
            centroid_x=math.nan,
            centroid_y=math.nan,
            nn_mean=math.nan,
            groups=0,
            largest_group=math.nan,
            predator_distance=math.nan,
            local_alignment=math.nan,
            milling=math.nan,
            labels=np.full(Pc, -1),
            hist=hist,
            nn=np.full(Pc, -1.0),
        )
        return out
    p = pos[prey]
    out["polarization"] = np.linalg.norm(head[prey].mean(axis=0))
    centroid = []
    for axis in range(2):
        ang = 2 * np.pi * p[:, axis] / size[axis]
        c = math.atan2(np.sin(ang).sum(), np.cos(ang).sum()) * size[axis] / (2 * np.pi)
        centroid.append(c % size[axis])
    out["centroid_x"], out["centroid_y"] = centroid
    r = torus(p - np.array(centroid), size)
    out["cohesion"] = np.linalg.norm(r, axis=1).mean()
    radius = np.linalg.norm(r, axis=1)
    h = head[prey]
    moving = radius > 0
    out["milling"] = abs(((r[:, 0] * h[:, 1] - r[:, 1] * h[:, 0])[moving] / radius[moving]).sum()) / n
    d = np.linalg.norm(torus(p[:, None, :] - p[None, :, :], size), axis=-1)  # [n, n]
    np.fill_diagonal(d, np.inf)
    linked = d < link
    alignments = [
        np.linalg.norm(h[a] + h[linked[a]].sum(axis=0)) / (1 + linked[a].sum()) for a in range(n) if linked[a].any()
    ]
    out["local_alignment"] = float(np.mean(alignments)) if alignments else math.nan
    nn = np.full(Pc, -1.0)
    if n > 1:
        nn[prey] = d.min(axis=1)
        out["nn_mean"] = nn[prey].mean()
        for x in nn[prey]:
            hist[min(int(x / bin_width), bins - 1) if x < bins * bin_width else bins - 1] += 1
    else:
        out["nn_mean"] = math.nan
    out["nn"], out["hist"] = nn, hist
    if len(preds):
        dp = np.linalg.norm(torus(p[:, None, :] - pos[preds][None, :, :], size), axis=-1)
        out["predator_distance"] = dp.min(axis=1).mean()
    else:
        out["predator_distance"] = math.nan
    # Connected components by breadth-first search over the all-pairs adjacency.
    adjacency = d < link
    labels = np.full(Pc, -1)
    for start in range(n):
        if labels[prey[start]] >= 0:
            continue
        frontier, members = [start], [start]
        labels[prey[start]] = prey[start]
        while frontier:
            nxt = []
            for a in frontier:
                for b in np.flatnonzero(adjacency[a]):
                    if labels[prey[b]] < 0:
                        labels[prey[b]] = prey[start]
                        nxt.append(b)
                        members.append(b)
            frontier = nxt
    out["labels"] = labels
    roots, sizes = np.unique(labels[prey], return_counts=True)
    out["groups"] = len(roots)
    out["largest_group"] = sizes.max() / n
    return out


def check_world(metrics: SwarmMetrics, w: int, rtol=2e-5, atol=2e-3):
    env = metrics.env
    t = env.state.torch
    values = metrics.compute()
    size = np.array([env.config.width, env.config.height])
    ref = reference(
        t.position[w].cpu().numpy(),
        t.heading[w].cpu().numpy(),
        t.alive[w].cpu().numpy(),
        env.prey_capacity,
        size,
        metrics.linking_distance,
        metrics.nn_bins,
        metrics.bin_width,
    )
    for name in SCALAR_METRICS:
        if name == "captures":
            continue
        got = float(values[name][w])
        want = float(ref[name])
        if name.startswith("centroid") and ref["prey_alive"]:
            # compare on the circle
            length = size[0] if name.endswith("x") else size[1]
            got = want + torus(got - want, length)
        if math.isnan(want):
            assert math.isnan(got), (name, w, got)
        else:
            assert got == pytest.approx(want, rel=rtol, abs=atol), (name, w, got, want)
    np.testing.assert_array_equal(metrics.group_label[w].cpu().numpy(), ref["labels"])
    np.testing.assert_allclose(metrics.nearest_neighbour[w].cpu().numpy(), ref["nn"], rtol=1e-5, atol=1e-3)
    np.testing.assert_array_equal(values["nn_histogram"][w].cpu().numpy(), ref["hist"])
    return values


# --------------------------------------------------------------------------------------------------
# Hand-made formations
# --------------------------------------------------------------------------------------------------
def test_aligned_and_opposite_headings(device):
    env = make_env(device, prey_count=8, num_worlds=2)
    rng = np.random.default_rng(0)
    pos = rng.uniform(100, 700, (8, 2))
    set_prey(env, pos, unit([0.3] * 8), world=0)  # all aligned
    set_prey(env, pos, unit([0.3, 0.3 + np.pi, 1.0, 1.0 + np.pi, 2.0, 2.0 + np.pi, -1.2, -1.2 + np.pi]), world=1)
    values = SwarmMetrics(env).compute()
    assert float(values["polarization"][0]) == pytest.approx(1.0, abs=1e-6)
    assert float(values["polarization"][1]) == pytest.approx(0.0, abs=1e-6)
    # Two groups far apart, each aligned, heading opposite ways: no global order, full local order.
    left = [[100.0 + 10 * k, 200.0] for k in range(4)]
    set_prey(env, left + [[400.0 + 10 * k, 500.0] for k in range(4)], unit([0.3] * 4 + [0.3 + np.pi] * 4))
    values = check_world(SwarmMetrics(env, linking_distance=50.0), 0)
    assert float(values["polarization"][0]) == pytest.approx(0.0, abs=1e-6)
    assert float(values["local_alignment"][0]) == pytest.approx(1.0, abs=1e-6)


def test_two_clusters_across_the_seam(device):
    env = make_env(device, prey_count=8, num_worlds=1)
    xs = [790.0, 795.0, 5.0, 10.0, 90.0, 95.0, 105.0, 110.0]  # one cluster straddles x = 0
    pos = [[x, 300.0] for x in xs]
    metrics = SwarmMetrics(env, linking_distance=50.0)
    set_prey(env, pos, unit([0.0] * 8), predator_pos=[[50.0, 700.0]])
    values = check_world(metrics, 0)
    assert float(values["groups"][0]) == 2
    assert float(values["largest_group"][0]) == pytest.approx(0.5)
    # The circular mean puts the centroid between the clusters at x = 50 (the plain mean says 250).
    assert float(values["centroid_x"][0]) == pytest.approx(50.0, abs=1e-3)
    assert float(values["centroid_y"][0]) == pytest.approx(300.0, abs=1e-3)
    assert float(values["cohesion"][0]) == pytest.approx(50.0, abs=1e-3)
    assert float(values["nn_mean"][0]) == pytest.approx(5.0, abs=1e-4)
    assert float(values["predator_distance"][0]) == pytest.approx(
        np.mean([math.hypot(torus(x - 50.0, 800.0), 400.0) for x in xs]), rel=1e-5
    )
    assert metrics.group_label[0].tolist() == [0, 0, 0, 0, 4, 4, 4, 4]
    # The same two clusters straddling the horizontal seam (y = 0) and the corner.
    set_prey(env, [[y, x] for x, y in pos], unit([0.0] * 8))
    values = check_world(metrics, 0)
    assert float(values["groups"][0]) == 2 and float(values["centroid_y"][0]) == pytest.approx(50.0, abs=1e-3)
    set_prey(env, [[x, (x + 400.0) % 800.0] for x in xs], unit([0.0] * 8))
    values = check_world(metrics, 0)
    assert float(values["groups"][0]) == 2


@pytest.mark.parametrize("center", [(400.0, 400.0), (790.0, 10.0)])
def test_ring(device, center):
    n, radius = 12, 150.0
    env = make_env(device, prey_count=n, num_worlds=1)
    phi = 2 * np.pi * np.arange(n) / n
    pos = np.stack([center[0] + radius * np.cos(phi), center[1] + radius * np.sin(phi)], axis=1)
    tangent = unit(phi + np.pi / 2)  # a mill: headings cancel
    set_prey(env, pos, tangent, predator_pos=[[center[0], (center[1] + 400.0) % 800.0]])
    metrics = SwarmMetrics(env, linking_distance=80.0)
    values = check_world(metrics, 0)
    spacing = 2 * radius * math.sin(math.pi / n)  # 77.6 px
    assert float(values["nn_mean"][0]) == pytest.approx(spacing, rel=1e-5)
    assert float(values["polarization"][0]) == pytest.approx(0.0, abs=1e-5)
    assert float(values["cohesion"][0]) == pytest.approx(radius, rel=1e-5)
    assert float(values["centroid_x"][0]) == pytest.approx(center[0], abs=1e-3)
    assert float(values["groups"][0]) == 1  # neighbours 77.6 px apart, linked at 80
    hist = values["nn_histogram"][0].cpu().numpy()
    assert hist.sum() == n and hist[int(spacing / metrics.bin_width)] == n
    # A mill: every prey turns the same way round the centre (milling 1), and each one's two linked
    # neighbours head 30 degrees either side of it: |h + 2 cos(30) h| / 3.
    assert float(values["milling"][0]) == pytest.approx(1.0, abs=1e-5)
    assert float(values["local_alignment"][0]) == pytest.approx((1 + 2 * math.cos(math.pi / 6)) / 3, rel=1e-5)
    set_prey(env, pos, -tangent, predator_pos=[[center[0], (center[1] + 400.0) % 800.0]])  # the other way round
    assert float(check_world(metrics, 0)["milling"][0]) == pytest.approx(1.0, abs=1e-5)
    set_prey(env, pos, unit(phi), predator_pos=[[center[0], (center[1] + 400.0) % 800.0]])  # all facing out
    assert float(check_world(metrics, 0)["milling"][0]) == pytest.approx(0.0, abs=1e-5)
    values = SwarmMetrics(env, linking_distance=75.0).compute()
    assert float(values["groups"][0]) == n  # not linked at 75


def test_empty_and_single_prey_worlds(device):
    env = make_env(device, prey_count=4, num_worlds=3)
    pos = [[100.0, 100.0], [200.0, 100.0], [300.0, 100.0], [400.0, 100.0]]
    set_prey(env, pos, unit([0.0] * 4), world=0, prey_alive=[False] * 4)
    set_prey(env, pos, unit([0.0] * 4), world=1, prey_alive=[False, True, False, False])
    values = SwarmMetrics(env).compute()
    assert math.isnan(float(values["polarization"][0])) and float(values["groups"][0]) == 0
    assert math.isnan(float(values["cohesion"][0])) and math.isnan(float(values["nn_mean"][0]))
    assert float(values["polarization"][1]) == 1.0 and float(values["groups"][1]) == 1
    assert float(values["cohesion"][1]) == 0.0 and math.isnan(float(values["nn_mean"][1]))
    assert float(values["largest_group"][1]) == 1.0 and float(values["prey_alive"][2]) == 4


# --------------------------------------------------------------------------------------------------
# Random states against the all-pairs reference
# --------------------------------------------------------------------------------------------------
def random_state(env, rng, clustered: bool):
    W, C = env.num_worlds, env.capacity
    cfg = env.config
    size = np.array([cfg.width, cfg.height], np.float32)
    if clustered:  # a few blobs, some across the seam, so groups and seams matter
        centers = rng.uniform(0, 1, (W, 5, 2)) * size
        which = rng.integers(0, 5, (W, C))
        pos = centers[np.arange(W)[:, None], which] + rng.normal(0, 40, (W, C, 2))
    else:
        pos = rng.uniform(0, 1, (W, C, 2)) * size
    pos = np.mod(pos, size).astype(np.float32)
    pos = np.minimum(pos, np.nextafter(size, 0)).astype(np.float32)
    head = unit(rng.uniform(0, 2 * np.pi, (W, C)))
    alive = rng.uniform(size=(W, C)) < rng.uniform(0.3, 1.0, (W, 1))
    alive[0, :] = True
    env.set_state(position=pos, velocity=head, heading=head, alive=alive)


@pytest.mark.parametrize(
    "prey_count,predator_count,link,worlds",
    [(60, 1, 50.0, 12), (150, 3, 35.0, 12), (100, 40, 60.0, 12), (700, 2, 30.0, 3)],
)
def test_random_states_match_all_pairs_reference(device, prey_count, predator_count, link, worlds):
    """Every metric of every world; 700 prey span three chunks of the two-stage sums."""
    env = make_env(device, prey_count=prey_count, predator_count=predator_count, num_worlds=worlds)
    rng = np.random.default_rng(prey_count)
    metrics = SwarmMetrics(env, linking_distance=link, nn_bins=20, nn_range=100.0)
    if predator_count == 40:
        assert metrics.predators_by_grid == 1  # many predators: ring search
    for clustered in (False, True):
        random_state(env, rng, clustered)
        for w in range(env.num_worlds):
            check_world(metrics, w)


@pytest.mark.slow
def test_deterministic_across_cpu_shards_and_calls():
    cfg = AquariumConfig(prey_count=200, predator_count=2, max_steps=50)
    results = []
    for threads in (1, 2):
        env = BatchedAquarium(cfg, num_worlds=64, device="cpu", seed=3, cpu_threads=threads)
        assert len(env.shards) == threads
        metrics = SwarmMetrics(env, linking_distance=45.0)
        for _ in range(30):
            env.step(heuristic_actions(env), validate=False)
        first = {k: v.clone() for k, v in metrics.compute().items()}
        second = metrics.compute()
        for k in first:
            assert torch.equal(first[k].nan_to_num(-1), second[k].nan_to_num(-1)), k
        results.append((first, metrics.group_label.clone()))
    for k in results[0][0]:
        assert torch.equal(results[0][0][k].nan_to_num(-1), results[1][0][k].nan_to_num(-1)), k
    assert torch.equal(results[0][1], results[1][1])


# --------------------------------------------------------------------------------------------------
# Per-episode accumulation
# --------------------------------------------------------------------------------------------------
def test_episode_metrics_average_each_episode(device):
    env = make_env(device, prey_count=24, num_worlds=3, max_steps=7)
    metrics = SwarmMetrics(env)
    episodes = EpisodeMetrics(env, metrics=metrics, every=2, trace=("prey_alive", "polarization"))
    env.reset()
    episodes.begin()
    # By hand: samples at steps 0, 2, 4, ...; an episode's samples are those taken before it ended.
    samples = [{k: v.double().clone() for k, v in metrics.compute().items()}]
    sample_steps, ends, captures = [0], [], []
    for step in range(1, 22):
        _, _, _, _, info = env.step(heuristic_actions(env), validate=False)
        if bool(info["episode_ended"].all()):
            ends.append(len(samples))
            captures.append(info["episode_captures"].double().clone())
        episodes.update(info)
        if step % 2 == 0:
            samples.append({k: v.double().clone() for k, v in metrics.compute().items()})
            sample_steps.append(step)
    assert len(ends) == 3  # episodes end at steps 7, 14, 21 in every world
    result = episodes.result()
    bounds = [0] + ends
    for name in EPISODE_METRICS:
        per_episode = [
            torch.stack([samples[i][name] for i in range(a, b)]).nanmean(dim=0) for a, b in zip(bounds[:-1], bounds[1:])
        ]
        want = torch.stack(per_episode).nanmean(dim=0)  # an episode without a value (no measured group) is skipped
        torch.testing.assert_close(result[name], want, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(result["captures"], torch.stack(captures).mean(dim=0))
    torch.testing.assert_close(result["captures_per_prey"], result["captures"] / 24)
    assert result["episodes"].tolist() == [3.0] * 3 and result["episode_length"].tolist() == [7.0] * 3
    dist = result["nn_distribution"]
    torch.testing.assert_close(dist.sum(dim=1), torch.ones(3, dtype=dist.dtype, device=dist.device))
    traces = episodes.traces()
    assert episodes.trace_steps == sample_steps and traces["prey_alive"].shape == (len(sample_steps), 3)
    assert (traces["prey_alive"] == 24).all()
    summary = episodes.summary()
    assert summary["episodes"] == 9 and summary["polarization"] == pytest.approx(float(result["polarization"].mean()))
    logged = episodes.log_values()
    assert logged["swarm/episodes"] == 9 and episodes.log_values() == {}


def test_episode_metrics_phase_and_replayed_steps(device):
    """The sampling phase (steps since the last sample) that selects a training loop's whole-rollout
    graph, and `count_replayed`, which counts the steps such a graph ran without sampling again;
    refused with a trace (host lists a graph cannot append to)."""
    env = make_env(device, prey_count=4, num_worlds=2, max_steps=50)
    episodes = EpisodeMetrics(env, every=10)
    env.reset()
    episodes.begin()
    hist = episodes._hist.clone()
    assert episodes.phase == 0
    for step in range(1, 14):
        episodes.update(env.step(heuristic_actions(env), validate=False).info)
        assert (episodes.steps, episodes.phase) == (step, step % 10)
    sampled = episodes._hist.clone()
    assert sampled.sum() == 2 * hist.sum()  # step 0 and step 10 sampled
    episodes.count_replayed(32)
    assert (episodes.steps, episodes.phase) == (45, 5)
    assert torch.equal(episodes._hist, sampled)  # counting samples nothing
    traced = EpisodeMetrics(env, every=10, trace=("prey_alive",))
    with pytest.raises(ValueError, match="trace"):
        traced.count_replayed(32)


def test_rollout_metrics_population_traces(device):
    # Respawn off: captured prey are gone, so the prey population never grows within the episode.
    env = make_env(device, prey_count=16, num_worlds=4, max_steps=40, respawn_captured_prey=False)
    out = rollout_metrics(
        env, lambda obs: heuristic_actions(env), steps=40, every=1, trace=("prey_alive", "predator_alive")
    )
    prey = out["trace_prey_alive"]
    assert prey.shape == (41, 4) and out["trace_steps"].tolist() == list(range(41))
    assert (prey[1:-1] <= prey[:-2]).all() and (prey[0] == 16).all() and (prey[-1] == 16).all()  # last: reset
    assert (out["trace_predator_alive"] == 1).all() and out["episodes"].tolist() == [1.0] * 4
    assert torch.equal(out["prey_alive"], prey[:-1].double().mean(dim=0))
    # Reproduction: the prey population grows to the cap.
    env = make_env(
        device, prey_count=8, num_worlds=2, max_steps=100, prey_reproduction=True, prey_replication_age=12, max_prey=20
    )
    out = rollout_metrics(env, lambda obs: heuristic_actions(env), steps=60, every=5, trace=("prey_alive",))
    prey = out["trace_prey_alive"]
    assert (prey[0] == 8).all() and (prey[-1] == 20).all() and (prey[1:] >= prey[:-1]).all()


def test_bad_arguments(device):
    env = make_env(device, prey_count=4)
    with pytest.raises(ValueError, match="linking_distance"):
        SwarmMetrics(env, linking_distance=0.0)
    with pytest.raises(ValueError, match="nn_bins"):
        SwarmMetrics(env, nn_bins=0)
    with pytest.raises(ValueError, match="every"):
        EpisodeMetrics(env, every=0)
    with pytest.raises(ValueError, match="trace"):
        EpisodeMetrics(env, trace=("nope",))
