"""A per-row reference of the native vector envs' rows (`aquarium_warp.interop.gymnasium`), written as
a plain Python loop over slots from `BatchedAquarium`s stepped directly: `ref` with the simulation's
own auto-reset (the trajectory) and `last` without it (the ended worlds' last state, resynchronised to
`ref` after each step), so neither the rows' torch code nor their restart program is used.

Rows (team "all"): per world the predator slots, then the prey slots. A row acts in a step when it
was active before it; it ends with its agent's death (terminated) or its world's end (truncated).
"""

from __future__ import annotations

import numpy as np
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium


class RowsReference:
    """`mode` "same_step" (any number of worlds) or "next_step" (one world: the env then discards one
    step of a world that ended, which `ref`, stepping every world together, cannot follow for several)."""

    def __init__(self, config: AquariumConfig, num_worlds: int, seed: int, mode: str):
        assert mode == "same_step" or num_worlds == 1
        self.mode = mode
        self.ref = BatchedAquarium(config, num_worlds=num_worlds, seed=seed)
        self.last = BatchedAquarium(config, num_worlds=num_worlds, seed=seed, auto_reset=False)
        self.W, self.P, self.C = num_worlds, config.predator_capacity, config.prey_capacity
        self.S = self.P + self.C
        self.L = config.observation_size("prey")
        self.reset_step = False  # next-step: the world ended in the last step
        self.active = self._alive(self.ref)

    def close(self) -> None:
        self.ref.close()
        self.last.close()

    def _slots(self):
        """(row, world, type, slot) of every row."""
        for w in range(self.W):
            for k in range(self.S):
                t, s = ("predator", k) if k < self.P else ("prey", k - self.P)
                yield w * self.S + k, w, t, s

    def _alive(self, env) -> np.ndarray:
        return np.array([bool(env.alive[t][w, s]) for _, w, t, s in self._slots()])

    def _obs(self, env) -> np.ndarray:
        return np.stack([env.observations[t][w, s].numpy() for _, w, t, s in self._slots()])

    def observations(self) -> np.ndarray:
        return self._obs(self.ref)

    def step(self, actions: np.ndarray) -> dict:
        """The rows' step: obs, reward, terminated, truncated, active (after), final_obs (same-step:
        rows that ended, else None)."""
        N = self.W * self.S
        out = dict(
            reward=np.zeros(N, np.float32),
            terminated=np.zeros(N, bool),
            truncated=np.zeros(N, bool),
            final_obs=[None] * N,
        )
        if self.reset_step:  # the world's reset step: its next episode's first state, already in `ref`
            self.reset_step = False
            self.last.load_state_dict(self.ref.state_dict())
            self.active = self._alive(self.ref)
            return dict(out, obs=self.observations(), active=self.active.copy())
        a = actions.reshape(self.W, self.S)
        step_actions = {
            "predator": torch.from_numpy(a[:, : self.P].copy()),
            "prey": torch.from_numpy(a[:, self.P :].copy()),
        }
        for env in (self.ref, self.last):
            env.step(step_actions)
        _, rew, term, trunc, info = self.last.outputs
        captured = self.last.state.torch.captured
        last_obs = self._obs(self.last)
        for row, w, t, s in self._slots():
            if not self.active[row]:
                continue
            died = bool(term[t][w, s]) or (t == "prey" and bool(captured[w, s]))
            out["reward"][row] = float(rew[t][w, s])
            out["terminated"][row] = died
            out["truncated"][row] = bool(trunc[t][w, s]) and not died
            if died or out["truncated"][row]:
                out["final_obs"][row] = np.zeros(self.L, np.float32) if died else last_obs[row]
        ended = out["terminated"] | out["truncated"]
        if self.mode == "same_step":
            self.active = self._alive(self.ref)
            obs = self.observations()
        else:
            world_ended = bool(info["episode_ended"][0])
            obs = last_obs.copy()
            obs[out["terminated"]] = 0.0
            self.active = self._alive(self.last) & ~ended & (not world_ended)
            self.reset_step = world_ended
            out["final_obs"] = [None] * N  # next-step: the last observations are the returned ones
        if not (self.mode == "next_step" and self.reset_step):
            self.last.load_state_dict(self.ref.state_dict())
        return dict(out, obs=obs, active=self.active.copy())


def life_returns(config: AquariumConfig, num_worlds: int, seed: int, actions: np.ndarray, dtype=np.float32) -> list:
    """Per step, the lives that ended in it as `(row, return)`, in row order, by hand: a slot's life
    is its agent's, from the step after it appeared (a reset, a respawn, a birth) to its death or its
    world's end; its return is the sum (in `dtype`, step by step) of its slot's rewards over those steps."""
    env = BatchedAquarium(config, num_worlds=num_worlds, seed=seed)
    P, S = config.predator_capacity, config.capacity
    running = np.zeros(num_worlds * S, dtype)
    live = np.concatenate([np.concatenate([env.alive["predator"][w], env.alive["prey"][w]]) for w in range(num_worlds)])
    ended_per_step = []
    for a in actions:
        a = a.reshape(num_worlds, S)
        env.step({"predator": torch.from_numpy(a[:, :P].copy()), "prey": torch.from_numpy(a[:, P:].copy())})
        _, rew, term, trunc, _ = env.outputs
        captured = env.state.torch.captured
        ended = []
        for w in range(num_worlds):
            for k in range(S):
                row = w * S + k
                t, s = ("predator", k) if k < P else ("prey", k - P)
                if live[row]:
                    running[row] += dtype(float(rew[t][w, s]))
                    if bool(term[t][w, s]) or (t == "prey" and bool(captured[w, s])) or bool(trunc[t][w, s]):
                        ended.append((row, float(running[row])))
                        running[row] = 0.0
                live[row] = bool(env.alive[t][w, s])
        ended_per_step.append(ended)
    env.close()
    return ended_per_step
