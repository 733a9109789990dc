"""TorchRL `EnvBase` over `BatchedAquarium` (optional: `pip install -c .ci/constraints-torchrl.txt -e ".[torchrl]"`).

```python
from torchrl.envs.utils import check_env_specs
from aquarium_warp.interop.torchrl import AquariumTorchRLEnv

env = AquariumTorchRLEnv(num_worlds=64, device="cpu", seed=0)   # batch_size [64]
check_env_specs(env)
rollout = env.rollout(100)                     # random actions of live agents
rollout["next", "prey", "reward"].shape       # [64, 100, 16, 1]
```

Batch: one entry per world (`batch_size=[num_worlds]`), on the simulation's device; no data goes
through the host. Groups: one per team, `group_map = {"prey": ["prey_0", ...], "predator": [...]}`
(one agent per slot: prey slots, including those that reproduction can fill, then predators). Per
group: `observation` [W, slots, L] float32, `action_mask` [W, slots, action_count] bool, `action`
[W, slots] categorical (what BenchMARL's discrete algorithms sample), `reward`, `done`, `terminated`,
`truncated` [W, slots, 1]. At the root: `done` / `terminated` / `truncated` [W, 1] per world.

Deaths and respawns: an agent is `terminated` (and `done`) in the step it leaves the episode (caught
with respawn off, starved); a captured prey that respawns carries on. `truncated` marks the agents
still alive when the episode ends (a prey born in that very step has not acted and is not). A slot
that holds no live agent (before a birth, after a removal)
is never done, so TorchRL does not reset or cut anything for it: its reward is 0 and its action mask
allows only action 0 (which the simulation ignores), so its transitions give the policy no gradient
and masked policies always have an action to sample. A newborn prey starts acting in its slot in the
step after its birth.

Resets: the simulation resets an ended world inside `step()` (`BatchedAquarium`'s auto-reset), so
the next observation of the step that ends an episode is already the new episode's first one, and
the partial `reset()` TorchRL then asks for returns the current observations. A reset without a
`_reset` mask (the first one, or a user's) restarts every world. Outputs are written to new tensors on
the device each step: the simulation's own buffers are overwritten by the next step, while TorchRL
keeps every step of a rollout.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from ..agent_types import TYPES
from ..config import AquariumConfig
from ..env import BatchedAquarium


class AquariumTorchRLEnv(EnvBase):
    """`num_worlds` Aquarium worlds as one batched TorchRL env with a "prey" and a "predator" group.

    Args: `config` (an `AquariumConfig`, default docs/model.md's), `num_worlds`, `device` (None: CUDA when
    present), `seed`, `cpu_threads`, or `aquarium=` an existing `BatchedAquarium` (with auto-reset).
    `validate_actions=False` skips `BatchedAquarium.step`'s check of the live agents' actions (and
    its host synchronisation); out-of-range actions are then undefined behaviour."""

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device=None,
        seed: int = 0,
        cpu_threads: int | None = None,
        aquarium: BatchedAquarium | None = None,
        validate_actions: bool = True,
    ):
        if not isinstance(validate_actions, bool):
            raise ValueError(f"validate_actions={validate_actions!r} must be True or False")
        self.validate_actions = validate_actions
        if aquarium is None:
            aquarium = BatchedAquarium(config, num_worlds=num_worlds, device=device, seed=seed, cpu_threads=cpu_threads)
        elif not isinstance(aquarium, BatchedAquarium) or not aquarium.auto_reset:
            raise ValueError("aquarium must be a BatchedAquarium with auto_reset=True")
        self.aquarium = aquarium
        super().__init__(device=aquarium.torch_device, batch_size=torch.Size([aquarium.num_worlds]))
        self.slots = {"prey": aquarium.prey_capacity, "predator": aquarium.predator_capacity}
        self.group_map = {t: [f"{t}_{i}" for i in range(n)] for t, n in self.slots.items()}
        self._make_specs()

    def _make_specs(self) -> None:
        W, dev, n = self.aquarium.num_worlds, self.device, self.aquarium.config.action_count
        obs, act, rew, done = {}, {}, {}, {}
        for t, slots in self.slots.items():
            shape = (W, slots)
            size = self.aquarium.observation_size[t]
            obs[t] = Composite(
                observation=Unbounded(shape=(*shape, size), dtype=torch.float32, device=dev),
                action_mask=Categorical(n=2, shape=(*shape, n), dtype=torch.bool, device=dev),
                shape=shape,
                device=dev,
            )
            act[t] = Composite(
                action=Categorical(n=n, shape=shape, dtype=torch.int64, device=dev), shape=shape, device=dev
            )
            rew[t] = Composite(
                reward=Unbounded(shape=(*shape, 1), dtype=torch.float32, device=dev), shape=shape, device=dev
            )
            done[t] = Composite(
                {
                    k: Categorical(n=2, shape=(*shape, 1), dtype=torch.bool, device=dev)
                    for k in ("done", "terminated", "truncated")
                },
                shape=shape,
                device=dev,
            )
        self.observation_spec = Composite(obs, shape=(W,), device=dev)
        self.action_spec = Composite(act, shape=(W,), device=dev)
        self.reward_spec = Composite(rew, shape=(W,), device=dev)
        root_done = {
            k: Categorical(n=2, shape=(W, 1), dtype=torch.bool, device=dev) for k in ("done", "terminated", "truncated")
        }
        self.done_spec = Composite({**done, **root_done}, shape=(W,), device=dev)

    # ------------------------------------------------------------------ TorchRL hooks
    def _observations(self) -> dict:
        aq, n = self.aquarium, self.aquarium.config.action_count
        out = {}
        for t in TYPES:
            alive = aq.alive[t]
            # Empty slots may take only action 0 (ignored by the simulation): a row without any allowed
            # action would make a masked categorical policy undefined.
            mask = alive.unsqueeze(-1).expand(*alive.shape, n).clone()
            mask[..., 0] = True
            out[t] = {"observation": aq.observations[t].clone(), "action_mask": mask}
        return out

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        partial = tensordict is not None and any(
            (key if isinstance(key, str) else key[-1]) == "_reset" for key in tensordict.keys(True, True)
        )
        if not partial:  # partial resets already happened inside step(): the worlds auto-reset
            self.aquarium.reset()
        W, dev = self.aquarium.num_worlds, self.device
        out = self._observations()
        for t, slots in self.slots.items():
            for k in ("done", "terminated", "truncated"):
                out[t][k] = torch.zeros((W, slots, 1), dtype=torch.bool, device=dev)
        for k in ("done", "terminated", "truncated"):
            out[k] = torch.zeros((W, 1), dtype=torch.bool, device=dev)
        return self._tensordict(out)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        aq = self.aquarium
        acted = {t: aq.alive[t].clone() for t in TYPES}  # the agents whose actions this step takes
        actions = {t: tensordict.get((t, "action")) for t in TYPES}
        _, rewards, terminated, truncated, info = aq.step(actions, validate=self.validate_actions)
        out = self._observations()
        for t in TYPES:
            # A prey born in the step that ends the episode is truncated by the simulation, but it never
            # acted: only agents that acted end a trajectory.
            term, trunc = (terminated[t] & acted[t]).unsqueeze(-1), (truncated[t] & acted[t]).unsqueeze(-1)
            out[t].update(reward=rewards[t].unsqueeze(-1).clone(), terminated=term, truncated=trunc, done=term | trunc)
        ended = info["episode_ended"].unsqueeze(-1).clone()
        truncated_world = ended & (aq.state.torch.ended_length == aq.config.max_steps).unsqueeze(-1)
        out.update(done=ended, truncated=truncated_world, terminated=ended & ~truncated_world)
        return self._tensordict(out)

    def _tensordict(self, out: dict) -> TensorDict:
        """Root entries [W, ...], each group's a TensorDict of batch [W, slots] (as the specs say)."""
        for t, slots in self.slots.items():
            out[t] = TensorDict(out[t], batch_size=(self.aquarium.num_worlds, slots), device=self.device)
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        self.aquarium.reset(seed=0 if seed is None else seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        self.aquarium.close()
        super().close(raise_if_closed=raise_if_closed)
