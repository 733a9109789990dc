"""The native vector envs' per-step work on their rows (`aquarium_warp.interop.gymnasium.AquariumRows`):
a few launches per step instead of a few dozen small torch kernels.

Rows are world-major, `[W, S]`: row `k` of world `w` is the world's slot `row_slot[k]` (team "all": the
predator slots, then the prey slots; a team: its slots).

- `row_outcomes` (one thread per row): a row's reward and flags of the last step. A row whose agent
  acted in it (`active`) takes its slot's reward and ends with its agent's death (terminated: caught,
  respawned or not, or starved) or its world's end (truncated, when not dead); other rows take 0 and no
  flag. Each world's first row also notes whether the world ended in the step, unless it was
  `restarting` (next-step: a world that ended in the step before, moved once more in its ended state
  and then restarted; that step is discarded).
- `row_observations` (one thread per row): the rows' observations from the two types' arrays, all
  zeros for the rows flagged in `zero` (a dead agent's last observation).
- `row_activity` (one thread per row): the rows whose next action moves a live agent: the slot holds
  one and, next-step only, the row did not end and its world did not end (their next step is their
  reset step).
"""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def row_outcomes(
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
    died = terminated[w, s] or captured[w, s]
    timed_out = truncated[w, s] and not died
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
