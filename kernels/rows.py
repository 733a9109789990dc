"""Rows: one agent slot of one world is one row of a learner or a vector env, world-major (`[W, S]`). The
per-step work of the two row adapters, a few launches per step instead of a few dozen small torch kernels
(they run in every rollout step's CUDA graph, where each kernel costs its launch): rsl-rl's
(`aquarium_warp.training.vec_env.AquariumVecEnv`, a team's slots: row `w * slots + s`) and the native
vector envs' (`aquarium_warp.interop.gymnasium.AquariumRows`, whose row `k` of world `w` is the world's slot
`row_slot[k]`; team "all": the predator slots, then the prey slots).

Both read a slot's outcome of the last step by one rule (`slot_outcome`): its agent died (terminated:
caught, respawned or not, or starved) or timed out (truncated by its world's episode end, not dead).

rsl-rl's rows:
- `learner_row_outcomes` (one thread per row): a row's done (active rows: their life ended; inactive
  rows: their slot is filled again); its time-out (active and timed out); its reward (zero for inactive
  rows, times the reward scale); and the row's activity for the next step.
- `episode_statistics` (one thread per world): the world's terms of the running sums: the logged
  values of a world episode that ended and started at step 0 (captures, returns, length and the
  swarm metrics' episode values where not NaN) with their counts, and of its rows the reward sums of
  the lives that ended (each row's running return, then cleared) with their count. The terms go to one
  row per world of a float64 buffer that torch sums over the worlds in a fixed order (deterministic;
  no float atomics).

The vector envs' rows:
- `vector_row_outcomes` (one thread per row): a row's reward and flags of the last step. A row whose
  agent acted in it (`active`) takes its slot's reward and ends with its agent's death (terminated) or
  time-out (truncated); other rows take 0 and no flag. Each world's first row also notes whether the
  world ended in the step, unless it was `restarting` (next-step: a world that ended in the step before,
  moved once more in its ended state and then restarted; that step is discarded).
- `row_observations` (one thread per row): the rows' observations from the two types' arrays, all
  zeros for the rows flagged in `zero` (a dead agent's last observation).
- `row_activity` (one thread per row): the rows whose next action moves a live agent: the slot holds
  one and, next-step only, the row did not end and its world did not end (their next step is their
  reset step).
"""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def slot_outcome(
    terminated: wp.array2d(dtype=wp.bool),
    captured: wp.array2d(dtype=wp.bool),
    truncated: wp.array2d(dtype=wp.bool),
    w: int,
    s: int,
):
    """Slot `s` of world `w` in the last step: (its agent died, its agent timed out alive)."""
    died = terminated[w, s] or captured[w, s]
    return died, truncated[w, s] and not died


# ---------------------------------------------------------------------------------------------- rsl-rl's rows
@wp.kernel
def learner_row_outcomes(
    terminated: wp.array2d(dtype=wp.bool),
    captured: wp.array2d(dtype=wp.bool),
    truncated: wp.array2d(dtype=wp.bool),
    live: wp.array2d(dtype=wp.bool),
    rewards_in: wp.array2d(dtype=wp.float32),
    reward_scale: wp.float32,
    active: wp.array2d(dtype=wp.bool),
    dones: wp.array2d(dtype=wp.int64),
    time_outs: wp.array2d(dtype=wp.bool),
    rewards: wp.array2d(dtype=wp.float32),
):
    w, s = wp.tid()
    died, timed_out = slot_outcome(terminated, captured, truncated, w, s)
    was_active = active[w, s]
    row_done = died or timed_out
    if not was_active:
        row_done = live[w, s]
    dones[w, s] = wp.int64(row_done)
    time_outs[w, s] = timed_out and was_active
    rewards[w, s] = rewards_in[w, s] * wp.float32(was_active) * reward_scale
    active[w, s] = live[w, s]


@wp.kernel
def episode_statistics(
    ended: wp.array(dtype=wp.bool),
    full: wp.array(dtype=wp.bool),
    ended_captures: wp.array(dtype=wp.int32),
    ended_return: wp.array(dtype=wp.float32),
    ended_return_other: wp.array(dtype=wp.float32),
    ended_length: wp.array(dtype=wp.int32),
    swarm_values: wp.array2d(dtype=wp.float64),
    rewards: wp.array2d(dtype=wp.float32),
    dones: wp.array2d(dtype=wp.int64),
    row_return: wp.array2d(dtype=wp.float32),
    terms: wp.array2d(dtype=wp.float64),
):
    """`terms[w]`: `[values (C), counts (C), ended lives' return sum, ended lives]`, C = 4 + the swarm
    metrics (`swarm_values` has zero columns without them)."""
    w = wp.tid()
    report = ended[w] and full[w]
    full[w] = full[w] or ended[w]
    one = wp.float64(0.0)
    if report:
        one = wp.float64(1.0)
    m = swarm_values.shape[1]
    c = 4 + m
    terms[w, 0] = one * wp.float64(wp.float32(ended_captures[w]))
    terms[w, 1] = one * wp.float64(ended_return[w])
    terms[w, 2] = one * wp.float64(ended_return_other[w])
    terms[w, 3] = one * wp.float64(wp.float32(ended_length[w]))
    for k in range(4):
        terms[w, c + k] = one
    for k in range(m):
        value = swarm_values[w, k]
        counted = report and not wp.isnan(value)
        if counted:
            terms[w, 4 + k] = value
            terms[w, c + 4 + k] = wp.float64(1.0)
        else:
            terms[w, 4 + k] = wp.float64(0.0)
            terms[w, c + 4 + k] = wp.float64(0.0)
    lives_return = wp.float64(0.0)
    lives = wp.float64(0.0)
    for s in range(rewards.shape[1]):
        total = row_return[w, s] + rewards[w, s]
        d = wp.float32(dones[w, s])
        lives_return = lives_return + wp.float64(total * d)
        lives = lives + wp.float64(d)
        row_return[w, s] = total * (wp.float32(1.0) - d)
    terms[w, 2 * c] = lives_return
    terms[w, 2 * c + 1] = lives


# ---------------------------------------------------------------------------------------------- the vector envs' rows
@wp.kernel
def vector_row_outcomes(
    row_slot: wp.array(dtype=wp.int32),
    terminated: wp.array2d(dtype=wp.bool),
    captured: wp.array2d(dtype=wp.bool),
    truncated: wp.array2d(dtype=wp.bool),
    reward: wp.array2d(dtype=wp.float32),
    episode_ended: wp.array(dtype=wp.bool),
    restarting: wp.array(dtype=wp.bool),
    active: wp.array2d(dtype=wp.bool),
    rewards: wp.array2d(dtype=wp.float32),
    row_terminated: wp.array2d(dtype=wp.bool),
    row_truncated: wp.array2d(dtype=wp.bool),
    row_ended: wp.array2d(dtype=wp.bool),
    ended_worlds: wp.array(dtype=wp.bool),
):
    w, k = wp.tid()
    s = row_slot[k]
    acted = active[w, k]
    died, timed_out = slot_outcome(terminated, captured, truncated, w, s)
    row_terminated[w, k] = acted and died
    row_truncated[w, k] = acted and timed_out
    row_ended[w, k] = acted and (died or timed_out)
    rewards[w, k] = wp.where(acted, reward[w, s], 0.0)
    if k == 0:
        ended_worlds[w] = episode_ended[w] and not restarting[w]


@wp.kernel
def row_observations(
    prey_capacity: int,
    row_slot: wp.array(dtype=wp.int32),
    prey_obs: wp.array3d(dtype=wp.float32),
    predator_obs: wp.array3d(dtype=wp.float32),
    zero: wp.array2d(dtype=wp.bool),
    obs: wp.array3d(dtype=wp.float32),
):
    w, k = wp.tid()
    s = row_slot[k]
    for j in range(obs.shape[2]):
        value = float(0.0)
        if not zero[w, k]:
            if s < prey_capacity:
                value = prey_obs[w, s, j]
            else:
                value = predator_obs[w, s - prey_capacity, j]
        obs[w, k, j] = value


@wp.kernel
def row_activity(
    next_step: int,
    row_slot: wp.array(dtype=wp.int32),
    alive: wp.array2d(dtype=wp.bool),
    row_ended: wp.array2d(dtype=wp.bool),
    ended_worlds: wp.array(dtype=wp.bool),
    active: wp.array2d(dtype=wp.bool),
):
    w, k = wp.tid()
    live = alive[w, row_slot[k]]
    if next_step != 0:
        live = live and not row_ended[w, k] and not ended_worlds[w]
    active[w, k] = live
