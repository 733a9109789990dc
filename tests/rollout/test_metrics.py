"""Swarm metrics (`aquarium_warp.metrics`) against numpy references: hand-made formations set with
`env.set_state` (aligned, opposite pairs, clusters across the seam, rings) and random states compared
with an all-pairs float64 reference (nearest neighbours, nearest predators, connected components),
plus determinism across CPU shards and the per-episode accumulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium, nulls
from aquarium_warp.heuristics import heuristic_actions
from aquarium_warp.metrics import (
    EPISODE_METRICS,
    GROUP_METRICS,
    SCALAR_METRICS,
    EpisodeMetrics,
    SwarmMetrics,
    rollout_metrics,
)
from aquarium_warp.nulls import hard_disk_nn_means, point_nn_means
from aquarium_warp.per_world import per_world


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


def test_swarm_measures_only(device):
    """`group_metrics=False` (the viewer's): the swarm's measures as the float64 reference and the full
    computation give them, bit for bit with the latter; the group measures NaN and no group sizes."""
    env = make_env(device, prey_count=24, num_worlds=3)
    env.reset(seed=5)
    for _ in range(6):
        env.step(heuristic_actions(env, "turnaway", "naivchase"))
    light = SwarmMetrics(env, linking_distance=50.0, group_metrics=False)
    full = SwarmMetrics(env, linking_distance=50.0).compute()
    for w in range(3):
        values = check_world(light, w)
    for name in SCALAR_METRICS:
        torch.testing.assert_close(values[name], full[name], rtol=0, atol=0, equal_nan=True)
    for name in GROUP_METRICS:
        assert torch.isnan(values[name]).all(), name
    assert not torch.isnan(full["mean_group_size"]).any()  # defined wherever prey live
    assert int(values["group_sizes"].sum()) == 0 and int(full["group_sizes"].sum()) > 0
    with pytest.raises(ValueError, match="group_metrics=1 must be True or False"):
        SwarmMetrics(env, group_metrics=1)


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


# --------------------------------------------------------------------------------------------------
# The groups' measures against a numpy reference (float64, all pairs)
# --------------------------------------------------------------------------------------------------
def group_reference(pos, head, velocity, alive, labels, Pc, size, min_size, confusion_radius):
    """The per-state group measures of one world (no tracking) from its state arrays and the group
    labels (`reference`'s breadth-first search)."""
    pos, head, velocity = pos.astype(np.float64), head.astype(np.float64), velocity.astype(np.float64)
    prey = np.flatnonzero(alive[:Pc])
    n = len(prey)
    counts = np.zeros(Pc, np.int64)
    out = {"group_sizes": counts}
    roots, sizes = np.unique(labels[prey], return_counts=True)
    for s in sizes:
        counts[s - 1] += 1
    nan = math.nan
    out["mean_group_size"] = n / len(roots) if n else nan
    out["grouped_share"] = sizes[sizes >= 2].sum() / n if n else nan
    out["measured_share"] = sizes[sizes >= min_size].sum() / n if n else nan
    order, weights = [], []
    for root, s in zip(roots, sizes):
        if s < min_size:
            continue
        members = prey[labels[prey] == root]
        p = pos[members]
        centroid = []
        for axis in range(2):
            ang = 2 * np.pi * p[:, axis] / size[axis]
            c = math.atan2(np.sin(ang).sum(), np.cos(ang).sum()) * size[axis] / (2 * np.pi)
            centroid.append(c % size[axis])
        r = torus(p - np.array(centroid), size)
        radius = np.linalg.norm(r, axis=1)
        h = head[members]
        cross = np.where(radius > 0, (r[:, 0] * h[:, 1] - r[:, 1] * h[:, 0]) / np.where(radius > 0, radius, 1), 0.0)
        order.append(
            [
                np.linalg.norm(h.mean(axis=0)),
                abs(cross.sum()) / s,
                np.linalg.norm(velocity[members].mean(axis=0)),
            ]
        )
        weights.append(s)
    for k, name in enumerate(("group_polarization", "group_rotation", "group_speed")):
        out[name] = float(np.average([o[k] for o in order], weights=weights)) if weights else nan
    if n:
        d = np.linalg.norm(torus(pos[prey][:, None, :] - pos[prey][None, :, :], size), axis=-1)
        np.fill_diagonal(d, np.inf)
        out["confusion_neighbour_share"] = (d < confusion_radius).any(axis=1).mean()
    else:
        out["confusion_neighbour_share"] = nan
    return out


class TrackedGroups:
    """The measured groups' identities across calls, as `aquarium_warp.metrics` defines them, with
    dicts: per call the group ages, and the groups that ended since the predecessor state."""

    def __init__(self, min_size):
        self.min_size = min_size
        self.last = None  # (episode, step, {slot: measured group}, {measured group: birth step})
        self.before = None

    def update(self, labels, alive, age, episode, step):
        if self.last is None or self.last[:2] != (episode, step):
            self.before = self.last
        before = self.before
        linked = before is not None and before[0] == episode and before[1] <= step
        prey = np.flatnonzero(alive)
        groups = {int(g): prey[labels[prey] == g] for g in np.unique(labels[prey])}
        groups = {g: m for g, m in groups.items() if len(m) >= self.min_size}
        predecessor, claims = {}, {}  # claims: previous root -> (votes, current root)
        for g in sorted(groups):
            votes = {}
            if linked:
                for j in groups[g]:
                    p = before[2].get(int(j))
                    if p is not None and age[j] >= step - before[1]:
                        votes[p] = votes.get(p, 0) + 1
            if votes:
                p, v = max(votes.items(), key=lambda item: (item[1], -item[0]))
                if 2 * v > len(groups[g]):
                    predecessor[g] = p
                    if p not in claims or v > claims[p][0]:
                        claims[p] = (v, g)
        birth = {}
        for g in groups:
            p = predecessor.get(g)
            birth[g] = before[3][p] if p is not None and claims[p][1] == g else step
        ended = [before[1] - b for p, b in before[3].items() if p not in claims] if linked else []
        measured = [(len(m), step - birth[g]) for g, m in groups.items()]
        self.last = (episode, step, {int(j): g for g, m in groups.items() for j in m}, birth)
        age_mean = np.average([a for _, a in measured], weights=[s for s, _ in measured]) if measured else math.nan
        return {"group_age": age_mean, "groups_ended": len(ended), "ended_lifetime_total": float(sum(ended))}


def check_groups(metrics: SwarmMetrics, w: int, tracked: TrackedGroups | None = None, values=None):
    """compute() (or `values` from it) of world w against `group_reference` and, with `tracked`, the
    tracking reference (updated here with the same state)."""
    env = metrics.env
    t = env.state.torch
    values = metrics.compute() if values is None else values
    size = np.array([env.config.width, env.config.height])
    Pc = env.prey_capacity
    alive = t.alive[w].cpu().numpy()
    labels = metrics.group_label[w].cpu().numpy()
    base = reference(
        t.position[w].cpu().numpy(),
        t.heading[w].cpu().numpy(),
        alive,
        Pc,
        size,
        metrics.linking_distance,
        metrics.nn_bins,
        metrics.bin_width,
    )
    np.testing.assert_array_equal(labels, base["labels"])  # the components the measures are over
    confusion_radius = per_world(env.config.confusion_radius, env.num_worlds)[w]
    want = group_reference(
        t.position[w].cpu().numpy(),
        t.heading[w].cpu().numpy(),
        t.velocity[w].cpu().numpy(),
        alive,
        labels,
        Pc,
        size,
        metrics.min_group_size,
        confusion_radius,
    )
    n = base["prey_alive"]
    radius = per_world(env.config.prey.radius, env.num_worlds)[w]
    want["nn_ratio_point"] = base["nn_mean"] / point_nn_means(Pc, *size)[n]
    want["nn_ratio_hard_disk"] = base["nn_mean"] / hard_disk_nn_means(Pc, *size, 2.0 * radius)[0][n]
    if tracked is not None:
        want.update(
            tracked.update(labels, alive[:Pc], t.age[w, :Pc].cpu().numpy(), int(t.episode[w]), int(t.world_step[w]))
        )
    np.testing.assert_array_equal(values["group_sizes"][w].cpu().numpy(), want.pop("group_sizes"))
    for name, expected in want.items():
        got = float(values[name][w])
        if math.isnan(expected):
            assert math.isnan(got), (name, w, got)
        else:
            assert got == pytest.approx(expected, rel=2e-5, abs=2e-5), (name, w, got, expected)
    return values


def set_world(env, pos, head, alive=None, world=0, age=None, step=None, episode=None, speed=2.0):
    """`set_prey`, then the prey's ages (default 1000: no respawn between the states a test sets), the
    world's step and episode."""
    set_prey(env, pos, head, world=world, prey_alive=alive)
    fields = {}
    ages = np.full(env.capacity, 1000, np.int32)
    if age is not None:
        ages[: len(age)] = age
    fields["age"] = ages
    fields["velocity"] = env.state.torch.heading[world].cpu().numpy() * speed
    if step is not None:
        fields["world_step"] = step
    if episode is not None:
        fields["episode"] = episode
    env.set_state(world=world, **fields)


def test_mill_across_the_seam_and_a_line(device):
    """4 prey on a circle round (795, 5) (across both seams) heading tangentially: a mill (rotation 1,
    polarization 0, speed 0); 3 prey in a row heading along it: polarization 1, rotation 0, speed 2.
    Member-weighted over the two groups; a pair and a lone prey are not measured."""
    env = make_env(device, prey_count=10)
    metrics = SwarmMetrics(env, linking_distance=50.0)
    phi = np.pi / 4 + np.pi / 2 * np.arange(4)
    ring = np.stack([795.0 + 15.0 * np.cos(phi), 5.0 + 15.0 * np.sin(phi)], axis=1)
    line = [[300.0, 300.0], [330.0, 300.0], [360.0, 300.0]]
    pair = [[500.0, 600.0], [520.0, 600.0]]
    lone = [[100.0, 500.0]]
    heads = np.concatenate([unit(phi + np.pi / 2), unit([0.0] * 3), unit([1.0, 2.0, 3.0])])
    set_world(env, np.concatenate([ring, line, pair, lone]), heads)
    values = check_groups(metrics, 0)
    assert values["group_sizes"][0].tolist()[:5] == [1, 1, 1, 1, 0]
    assert float(values["group_polarization"][0]) == pytest.approx(3 / 7, abs=1e-6)
    assert float(values["group_rotation"][0]) == pytest.approx(4 / 7, abs=1e-6)
    assert float(values["group_speed"][0]) == pytest.approx(2.0 * 3 / 7, abs=1e-6)
    assert float(values["mean_group_size"][0]) == pytest.approx(10 / 4)
    assert float(values["grouped_share"][0]) == pytest.approx(0.9)
    assert float(values["measured_share"][0]) == pytest.approx(0.7)
    # The lone prey is 180 px from the pair: within the default 100 px of nobody.
    assert float(values["confusion_neighbour_share"][0]) == pytest.approx(0.9)
    set_world(env, ring, unit(phi + np.pi / 2), alive=[True] * 4)
    values = check_groups(metrics, 0)
    assert float(values["group_rotation"][0]) == pytest.approx(1.0, abs=1e-6)
    assert float(values["group_polarization"][0]) == pytest.approx(0.0, abs=1e-6)
    assert float(values["group_speed"][0]) == pytest.approx(0.0, abs=1e-5)
    # Heading out of the circle: no rotation; measured from 5 members on, no group qualifies.
    set_world(env, ring, unit(phi), alive=[True] * 4)
    assert float(check_groups(metrics, 0)["group_rotation"][0]) == pytest.approx(0.0, abs=1e-6)
    values = check_groups(SwarmMetrics(env, linking_distance=50.0, min_group_size=5), 0)
    assert math.isnan(float(values["group_rotation"][0])) and float(values["measured_share"][0]) == 0.0


def test_group_measures_of_empty_and_single_prey_worlds(device):
    env = make_env(device, prey_count=4, num_worlds=3)
    pos = [[100.0, 100.0], [200.0, 100.0], [300.0, 100.0], [400.0, 100.0]]
    set_world(env, pos, unit([0.0] * 4), world=0, alive=[False] * 4)
    set_world(env, pos, unit([0.0] * 4), world=1, alive=[False, True, False, False])
    metrics = SwarmMetrics(env)
    values = metrics.compute()
    for w in range(3):
        check_groups(metrics, w, values=values)
    for name in ("mean_group_size", "group_polarization", "nn_ratio_point", "confusion_neighbour_share"):
        assert math.isnan(float(values[name][0])), name
    assert float(values["mean_group_size"][1]) == 1.0 and float(values["grouped_share"][1]) == 0.0
    assert math.isnan(float(values["group_age"][1])) and math.isnan(float(values["nn_ratio_hard_disk"][1]))
    assert values["group_sizes"][0].sum() == 0 and values["group_sizes"][1].tolist() == [1, 0, 0, 0]
    assert float(values["groups_ended"][0]) == 0.0


@pytest.mark.parametrize("prey_count,link,worlds,min_size", [(60, 50.0, 8, 3), (150, 35.0, 6, 2), (700, 30.0, 2, 4)])
def test_group_measures_of_random_states(device, prey_count, link, worlds, min_size):
    """Random and clustered states (groups across the seam, dead slots): every group measure of every
    world; 700 prey span three chunks."""
    env = make_env(device, prey_count=prey_count, num_worlds=worlds)
    rng = np.random.default_rng(prey_count + 1)
    metrics = SwarmMetrics(env, linking_distance=link, min_group_size=min_size)
    for clustered in (False, True):
        random_state(env, rng, clustered)
        values = metrics.compute()
        assert float(values["measured_share"].nan_to_num(0).max()) > 0  # some groups are measured
        for w in range(env.num_worlds):
            check_groups(metrics, w, values=values)


def test_group_identity_by_hand(device):
    """Ages and lifetimes over set states: a measured group (>= 3 prey) continues the previous one
    holding a strict majority of its members (the largest such fragment of it; ties to the lower
    label), a respawned prey (its age restarted) is a new individual, a group ends when nobody
    continues it, and a new episode starts over without ending anything."""
    env = make_env(device, prey_count=9, max_steps=1000)
    metrics = SwarmMetrics(env, linking_distance=50.0)
    tracked = TrackedGroups(3)
    head = unit([0.0] * 9)
    # Uneven spacings: no member sits at its group's centroid, where r / |r| is undefined.
    a = [[x, 100.0] for x in (100.0, 120.0, 150.0, 170.0, 190.0)]  # slots 0-4
    b = [[x, 400.0] for x in (400.0, 430.0, 450.0)]  # slots 5-7
    lone = [[700.0, 700.0]]  # slot 8

    def state(pos, step, age=None, episode=0):
        set_world(env, pos, head, step=step, age=age, episode=episode)
        return check_groups(metrics, 0, tracked)

    values = state(a + b + lone, step=10)
    assert float(values["group_age"][0]) == 0.0 and float(values["groups_ended"][0]) == 0.0
    values = state(a + b + lone, step=10)  # the same state again: the same values
    assert float(values["group_age"][0]) == 0.0
    values = state(a + b + lone, step=30)
    assert float(values["group_age"][0]) == 20.0
    # A splits 3 + 2: the 3 (slots 0-2) continue it; the pair (3-4) is new. B drifts off intact.
    split = a[:3] + [[100.0, 300.0], [120.0, 300.0]] + b + lone
    values = state(split, step=40)
    assert float(values["group_age"][0]) == pytest.approx(30.0)  # (3 x 30 + 3 x 30) / 6
    assert float(values["groups_ended"][0]) == 0.0
    # The lone prey joins B (4 members, 3 from B: it continues); A's 3 scatter: it ended, lived 30 steps.
    scattered = [[100.0, 100.0], [100.0, 200.0], [100.0, 600.0]] + split[3:5] + b + [[490.0, 400.0]]
    values = state(scattered, step=45)
    assert float(values["group_age"][0]) == pytest.approx(35.0)
    assert float(values["groups_ended"][0]) == 1.0 and float(values["ended_lifetime_total"][0]) == 30.0
    # Two of B's members respawned in place (ages below the 5 steps elapsed): 2 of 4 is no majority,
    # so B (first seen at step 10, last at 45) ended.
    values = state(scattered, step=50, age=[1000] * 5 + [1000, 3, 4, 1000])
    assert float(values["group_age"][0]) == 0.0
    assert float(values["groups_ended"][0]) == 1.0 and float(values["ended_lifetime_total"][0]) == 35.0
    # A new episode: every group is new, nothing ended.
    values = state(scattered, step=5, episode=1)
    assert float(values["group_age"][0]) == 0.0 and float(values["groups_ended"][0]) == 0.0
    # A group of 6 splits into two triples, each all its: the lower label continues it (a tie), the
    # other is new; then one triple falls apart into a pair and a lone prey: too small, it ended.
    six = [[x, 500.0] for x in (100.0, 130.0, 150.0, 180.0, 200.0, 230.0)]
    rest = [[600.0, 100.0], [600.0, 200.0], [600.0, 300.0]]
    values = state(six + rest, step=7, episode=1)  # (B, seen at step 5 only, ended: 1 of 6 is no majority)
    assert float(values["group_age"][0]) == 0.0
    assert float(values["groups_ended"][0]) == 1.0 and float(values["ended_lifetime_total"][0]) == 0.0
    triples = six[:3] + [[x, 700.0] for x in (180.0, 200.0, 230.0)] + rest
    values = state(triples, step=9, episode=1)
    assert float(values["group_age"][0]) == pytest.approx((3 * 2 + 3 * 0) / 6)
    assert float(values["groups_ended"][0]) == 0.0
    values = state(triples[:5] + [[400.0, 700.0]] + rest, step=12, episode=1)
    assert float(values["group_age"][0]) == pytest.approx(5.0)  # the triple of slots 0-2, since step 7
    assert float(values["groups_ended"][0]) == 1.0 and float(values["ended_lifetime_total"][0]) == 0.0


def test_group_identity_in_rollouts_match_the_reference(device):
    """Heuristic rollouts with respawns and episode ends, sampled every 3 steps (twice per state, which
    changes nothing): ages and lifetimes against the tracking reference, in every world."""
    env = make_env(device, prey_count=24, num_worlds=3, max_steps=40, width=400.0, height=400.0)
    metrics = SwarmMetrics(env, linking_distance=80.0)
    tracked = [TrackedGroups(3) for _ in range(env.num_worlds)]
    env.reset()
    metrics.restart_tracking()
    ended = respawned = 0
    for step in range(100):
        if step % 3 == 0:
            for repeat in range(2):
                values = metrics.compute()
                for w in range(env.num_worlds):
                    check_groups(metrics, w, tracked[w] if repeat == 0 else None, values=values)
            ended += int(values["groups_ended"].sum())
        env.step(heuristic_actions(env), validate=False)
        respawned += int(env.state.torch.captured[:, : env.prey_capacity].sum())
    assert ended > 0 and respawned > 0  # the cases the test is about happened


# --------------------------------------------------------------------------------------------------
# The nearest-neighbour nulls
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("width,height", [(800.0, 800.0), (600.0, 300.0)])
def test_point_null_matches_uniform_points(width, height):
    rng = np.random.default_rng(7)
    table = point_nn_means(32, width, height)
    assert np.isnan(table[:2]).all()
    for n in (2, 5, 32):
        samples = 40000 // n
        p = rng.uniform(0, 1, (samples, n, 2)) * [width, height]
        d = np.linalg.norm(torus(p[:, :, None] - p[:, None], np.array([width, height])), axis=-1)
        d[:, np.arange(n), np.arange(n)] = np.inf
        per = d.min(axis=2).mean(axis=1)
        assert abs(table[n] - per.mean()) < 4 * per.std(ddof=1) / math.sqrt(samples), n


def test_hard_disk_null_matches_brute_force():
    """Random sequential addition written plainly (one arrangement at a time), other seeds; tiny disks
    give the point null; a crowded arena is NaN past what the disks can fill."""
    width, height, diameter = 400.0, 300.0, 60.0
    means, errors = hard_disk_nn_means(8, width, height, diameter)
    rng = np.random.default_rng(11)
    size = np.array([width, height])
    samples = 1500
    per = np.zeros((samples, 9))
    for s in range(samples):
        placed = []
        while len(placed) < 8:
            c = rng.uniform(0, 1, 2) * size
            if all(np.linalg.norm(torus(c - q, size)) >= diameter for q in placed):
                placed.append(c)
        p = np.array(placed)
        for n in range(2, 9):
            d = np.linalg.norm(torus(p[:n, None] - p[None, :n], size), axis=-1)
            np.fill_diagonal(d, np.inf)
            per[s, n] = d.min(axis=1).mean()
    for n in range(2, 9):
        se = math.hypot(errors[n], per[:, n].std(ddof=1) / math.sqrt(samples))
        assert abs(means[n] - per[:, n].mean()) < 4 * se, n
        assert means[n] > point_nn_means(8, width, height)[n]  # hard cores spread the prey
    assert errors[8] < 0.01 * means[8]
    tiny = hard_disk_nn_means(32, 800.0, 800.0, 1e-3)
    point = point_nn_means(32, 800.0, 800.0)
    assert (np.abs(tiny[0][2:] - point[2:]) < 4 * tiny[1][2:]).all()
    crowded = hard_disk_nn_means(12, 200.0, 200.0, 100.0)[0]
    assert np.isfinite(crowded[2]) and np.isnan(crowded[-1]) and np.isnan(crowded[:2]).all()


@pytest.mark.parametrize("width,height", [(61357.0, 61357.0), (6000.0, 1500.0)])
def test_large_point_nulls_take_the_closed_form_where_clipping_cannot_matter(width, height):
    """Above POINT_QUADRATURE_MAX the unclipped disk's integral, sqrt(W H) / 2 * Gamma(n) / Gamma(n + 1/2):
    the same numbers as the quadrature it replaces (computed here as the small counts are)."""
    n = nulls.POINT_QUADRATURE_MAX + 5
    table = point_nn_means(n, width, height)
    r = np.linspace(0.0, math.hypot(width, height) / 2.0, nulls.POINT_GRID)
    free = 1.0 - nulls.torus_disk_area(r, width, height) / (width * height)
    quadrature = np.trapezoid(np.maximum(free, 0.0) ** (n - 1), r)
    assert table[n] == pytest.approx(quadrature, rel=1e-10)
    assert table[n] == 0.5 * math.sqrt(width * height) * math.exp(math.lgamma(n) - math.lgamma(n + 0.5))
    below = point_nn_means(nulls.POINT_QUADRATURE_MAX, width, height)
    assert np.array_equal(table[: nulls.POINT_QUADRATURE_MAX + 1], below, equal_nan=True)


def test_hard_disk_null_is_not_drawn_above_its_largest_count():
    largest = nulls.HARD_DISK_MAX_PREY
    means, errors = hard_disk_nn_means(largest + 3, 20000.0, 20000.0, 10.0)
    small = hard_disk_nn_means(largest, 20000.0, 20000.0, 10.0)
    assert np.array_equal(means[: largest + 1], small[0], equal_nan=True)
    assert np.array_equal(errors[: largest + 1], small[1], equal_nan=True)
    assert np.isnan(means[largest + 1 :]).all() and np.isnan(errors[largest + 1 :]).all()


def test_episode_metrics_group_lifetimes_sizes_and_traces(device):
    """Per episode: the mean completed group lifetime (the ended groups' lifetimes over their number,
    from the sampled values), the share of the sampled prey in groups of each size, and traces of
    chosen worlds (group measures included)."""
    env = make_env(device, prey_count=24, num_worlds=3, max_steps=30, width=400.0, height=400.0)
    metrics = SwarmMetrics(env, linking_distance=80.0)
    episodes = EpisodeMetrics(env, metrics=metrics, every=3, trace=("group_age", "groups_ended"), trace_worlds=[2, 0])
    env.reset()
    episodes.begin()
    sizes = torch.arange(1, env.prey_capacity + 1, dtype=torch.float64)
    samples = [{k: v.double().clone() for k, v in metrics.compute().items()}]
    ends = []
    for step in range(1, 61):
        _, _, _, _, info = env.step(heuristic_actions(env), validate=False)
        if bool(info["episode_ended"].all()):
            ends.append(len(samples))
        episodes.update(info)
        if step % 3 == 0:
            samples.append({k: v.double().clone() for k, v in metrics.compute().items()})
    assert len(ends) == 2
    result = episodes.result()
    bounds = [0] + ends
    lifetimes, ended, shares = [], [], []
    for a, b in zip(bounds[:-1], bounds[1:]):
        lifetimes.append(sum(samples[i]["ended_lifetime_total"] for i in range(a, b)))
        ended.append(sum(samples[i]["groups_ended"] for i in range(a, b)))
        prey = sum(samples[i]["group_sizes"] * sizes for i in range(a, b))
        shares.append(prey / prey.sum(dim=1, keepdim=True))
    assert float(torch.stack(ended).sum()) > 0
    torch.testing.assert_close(result["group_lifetime"], torch.stack(lifetimes).sum(0) / torch.stack(ended).sum(0))
    torch.testing.assert_close(result["group_size_distribution"], torch.stack(shares).mean(0))
    traces = episodes.traces()
    want = torch.stack([s["group_age"][[2, 0]] for s in samples]).float()
    assert traces["group_age"].shape == (len(samples), 2)
    torch.testing.assert_close(traces["group_age"], want, equal_nan=True)
    summary = episodes.summary()
    assert summary["group_lifetime"] == pytest.approx(
        float(torch.stack(lifetimes).sum()) / float(torch.stack(ended).sum())
    )
    assert episodes.log_values()["swarm/group_lifetime"] == summary["group_lifetime"]


def test_bad_group_arguments(device):
    env = make_env(device, prey_count=4, num_worlds=2)
    with pytest.raises(ValueError, match="min_group_size"):
        SwarmMetrics(env, min_group_size=1)
    with pytest.raises(ValueError, match="trace_worlds"):
        EpisodeMetrics(env, trace=("group_age",), trace_worlds=[2])


def test_episode_metrics_resume_a_state_saved_before_the_group_measures(device):
    """A checkpoint's episode-metric state from before the group measures (the first 10 metric columns,
    no group-size histograms) restores those metrics exactly; the group measures count from the resume.
    A state of another world count is refused with one line."""
    env = make_env(device, prey_count=24, num_worlds=3, max_steps=7)
    episodes = EpisodeMetrics(env, every=2)
    env.reset()
    episodes.begin()
    for _ in range(10):
        _, _, _, _, info = env.step(heuristic_actions(env), validate=False)
        episodes.update(info)
    state = episodes.state_dict()
    old = {
        name: v[:, :10].clone() for name, v in state.items() if name in ("_sum", "_count", "_done_sum", "_done_count")
    }
    old |= {"_hist": state["_hist"], "_done_hist": state["_done_hist"], "steps": state["steps"]}
    resumed = EpisodeMetrics(env, every=2)
    resumed.load_state_dict(old)
    after = resumed.state_dict()
    for name in ("_sum", "_count", "_done_sum", "_done_count"):
        torch.testing.assert_close(after[name][:, :10], state[name][:, :10], rtol=0, atol=0)
        assert not after[name][:, 10:].any()
    assert not after["_group_hist"].any() and after["steps"] == state["steps"]
    with pytest.raises(ValueError, match="episode metrics state '_sum' has shape"):
        resumed.load_state_dict({**old, "_sum": old["_sum"][:2]})
