"""The training adapter's per-step work (`aquarium_warp.training.vec_env.AquariumVecEnv`): each learning
row's outcome of the last step, and the device-side sums of the episode statistics, one launch each
instead of a few dozen small torch kernels (they run in every rollout step's CUDA graph, where each
kernel costs its launch).

- `row_outcomes` (one thread per row, world-major: row `w * slots + s`): a row's life ended (captured,
  terminated, truncated); its done (active rows: their life ended; inactive rows: their slot is filled
  again); its time-out (active, truncated by the world's episode end, not terminated or captured); its
  reward (zero for inactive rows, times the reward scale); and the row's activity for the next step.
- `episode_statistics` (one thread per world): the world's terms of the running sums: the logged
  values of a world episode that ended and started at step 0 (captures, returns, length and the
  swarm metrics' episode values where not NaN) with their counts, and of its rows the reward sums of
  the lives that ended (each row's running return, then cleared) with their count. The terms go to one
  row per world of a float64 buffer that torch sums over the worlds in a fixed order (deterministic;
  no float atomics).
"""

import warp as wp


@wp.kernel
def row_outcomes(
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
    stopped = terminated[w, s] or captured[w, s]
    life_ended = stopped or truncated[w, s]
    was_active = active[w, s]
    row_done = life_ended
    if not was_active:
        row_done = live[w, s]
    dones[w, s] = wp.int64(row_done)
    time_outs[w, s] = (not stopped) and truncated[w, s] and was_active
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
