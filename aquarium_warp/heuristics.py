"""The paper's baseline policies (docs/model.md "Heuristic policies") for every world of a `BatchedAquarium`.

```python
from aquarium_warp.heuristics import heuristic_actions, make_policy

prey = make_policy("turnaway", env, "prey")            # or "random", "constant"
predator = make_policy("naivchase", env, "predator")   # or "random"; confusion=False: the nearest prey
obs, rewards, terminated, truncated, info = env.step({"prey": prey(), "predator": predator()})
# or, in one call:
env.step(heuristic_actions(env, prey="turnaway", predator="naivchase"))
```

A policy decides from the env's current state (the one whose observations `reset()` / `step()` /
`set_state()` returned last) with one kernel launch per shard, no host synchronisation. It returns an
int32 tensor `[num_worlds, slots of its type]` on the env's device that is overwritten by its next
call (clone what you keep); dead slots get action 0. Random draws come from the counter-based stream
(seed, world, episode, step, slot, PURPOSE_POLICY): reproducible, the same on CPU and GPU.
"""

from __future__ import annotations

import weakref

import numpy as np
import torch
import warp as wp

from .agent_types import TYPES
from .env import BatchedAquarium, action_directions
from .kernels import heuristics as kernels
from .seeding import seed_groups, seed_keys

# Policies allowed for each agent type.
POLICIES = {"prey": ("random", "constant", "turnaway", "boids"), "predator": ("random", "constant", "naivchase")}


def normalise_name(name) -> str:
    """A policy name as the registries hold it: lower case, without "_" and "-" (the one rule)."""
    if not isinstance(name, str):
        raise ValueError(f"policy name {name!r} must be a string: one of {sorted(set(sum(POLICIES.values(), ())))}")
    return name.lower().replace("_", "").replace("-", "")


class HeuristicPolicy:
    """One heuristic policy for the agents of one type in every world of `env`.

    Calling it returns `actions`: an int32 tensor `[num_worlds, prey_capacity]` (prey) or
    `[num_worlds, predator_capacity]` (predators) on the env's device, written by a kernel into a buffer
    allocated once (so the next call overwrites it).
    """

    capturable = True  # a call is device work only (one Warp launch, no host state): a CUDA graph may hold it

    def __init__(
        self, name: str, env: BatchedAquarium, agent_type: str, seed: int | None = None, confusion: bool | None = None
    ):
        if not isinstance(env, BatchedAquarium):
            raise ValueError(f"env must be a BatchedAquarium, got {type(env).__name__}")
        if agent_type not in TYPES:
            raise ValueError(f"agent_type={agent_type!r} must be one of {TYPES}")
        key = normalise_name(name)
        if key not in POLICIES[agent_type]:
            raise ValueError(f"policy {name!r} is not available for {agent_type}: allowed {POLICIES[agent_type]}")
        if confusion is not None and key != "naivchase":
            raise ValueError(f"confusion={confusion!r} applies only to 'naivchase', not {key!r}")
        if confusion is not None and not isinstance(confusion, bool):
            raise ValueError(f"confusion={confusion!r} must be True or False")
        own_seeds = None if seed is None else seed_groups(seed, env.num_worlds)  # validates
        # A weak reference: the policies cached by `heuristic_actions` must not keep their env alive.
        self._env = weakref.ref(env)
        self.name, self.agent_type, self.seed = key, agent_type, seed
        self.confusion = (confusion is not False) if key == "naivchase" else None
        if key == "random":
            self._code = kernels.POLICY_RANDOM
        elif key == "constant":
            self._code = kernels.POLICY_CONSTANT
        elif key == "boids":
            self._code = kernels.POLICY_BOIDS
        elif key == "turnaway":
            self._code = kernels.POLICY_TURN_AWAY
        else:
            self._code = kernels.POLICY_CHASE_CONFUSED if self.confusion else kernels.POLICY_CHASE_NEAREST
        self._first_slot = 0 if agent_type == "prey" else env.prey_capacity
        slots = env.prey_capacity if agent_type == "prey" else env.predator_capacity
        self._buffer = wp.zeros((env.num_worlds, slots), dtype=wp.int32, device=env.device)
        self.actions = wp.to_torch(self._buffer)
        # The streams' keys: the env's seed (device data, so a reseed reaches the recorded launches),
        # or the policy's own (several: one per equal group of worlds, as the env's own seeds).
        seeds = env.state.worlds.seed
        if own_seeds is not None:
            seeds = wp.array(seed_keys(own_seeds, env.num_worlds), dtype=wp.uint32, device=env.device)
        self._program = env.record_program(
            lambda shard: [
                shard.record(
                    kernels.heuristic_policy,
                    (shard.num_worlds, slots),
                    [
                        shard.world,
                        shard.types,
                        shard.grid,
                        env.action_directions,
                        shard.state.agents,
                        shard.state.worlds,
                        seeds[shard.w0 : shard.w1],
                        self._code,
                        self._first_slot,
                    ],
                    [self._buffer[shard.w0 : shard.w1]],
                )
            ]
        )

    @property
    def env(self) -> BatchedAquarium:
        env = self._env()
        if env is None:
            raise ValueError("the env of this policy no longer exists")
        return env

    def __repr__(self) -> str:
        extra = f", confusion={self.confusion}" if self.confusion is not None else ""
        return f"HeuristicPolicy({self.name!r}, {self.agent_type!r}, seed={self.seed}{extra})"

    def __call__(self) -> torch.Tensor:
        _ = self.env  # raises once the env is gone
        self._program.run()
        return self.actions


def make_policy(
    name: str, env: BatchedAquarium, agent_type: str, seed: int | None = None, confusion: bool | None = None
) -> HeuristicPolicy:
    """A heuristic policy for the `agent_type` agents ("prey" or "predator") of every world of `env`.

    `name`: "random" (either type), "constant" (either type: always the world direction "up", the
    baseline of an agent that ignores everything), "turnaway" (prey), "boids" (prey: Reynolds flocking
    over the visible prey, fleeing a visible predator; the positive control of the swarm measures) or
    "naivchase" (predators); case, "_" and "-" are ignored. `seed`: keys the policy's random stream
    (None: the env's current seed).
    `confusion` (naivchase only, default True): with several prey visible, chase a uniformly random
    one each step; False chases the nearest (ties: lower slot).
    """
    return HeuristicPolicy(name, env, agent_type, seed=seed, confusion=confusion)


# Policies made by `heuristic_actions`, kept per env so that repeated calls reuse their buffers.
_cached: weakref.WeakKeyDictionary[BatchedAquarium, dict] = weakref.WeakKeyDictionary()


def heuristic_actions(
    env: BatchedAquarium,
    prey: str = "turnaway",
    predator: str = "naivchase",
    seed: int | None = None,
    confusion: bool = True,
) -> dict[str, torch.Tensor]:
    """Actions of both types for `env.step`: `{"prey": [W, prey_capacity], "predator": [W, predator_capacity]}`
    int32 tensors (overwritten by the next call with the same arguments). `confusion` applies to a
    "naivchase" predator policy only."""
    policies = _cached.setdefault(env, {})
    actions = {}
    for agent_type, name in (("prey", prey), ("predator", predator)):
        normal = normalise_name(name)
        chase = normal == "naivchase"
        key = (agent_type, normal, seed, confusion if chase else None)
        if key not in policies:
            policies[key] = make_policy(name, env, agent_type, seed=seed, confusion=confusion if chase else None)
        actions[agent_type] = policies[key]()
    return actions


def nearest_action(direction, heading, action_count: int) -> np.ndarray | int:
    """The action whose desired direction makes the smallest angle with `direction` (ties: the lower
    action); where `direction` is zero, with `heading` instead. Shapes `[..., 2]` -> `[...]` int64
    (a plain int for a single vector). Brute force over all actions in float64 (a reference for the
    kernel, which may differ only at near-ties within float32 rounding)."""
    d = np.asarray(direction, dtype=np.float64)
    h = np.broadcast_to(np.asarray(heading, dtype=np.float64), d.shape)
    zero = np.all(d == 0.0, axis=-1, keepdims=True)
    d = np.where(zero, h, d)
    # The dot product with unit directions ranks the actions by angle (|d| is common to all of them).
    dots = d @ action_directions(action_count).astype(np.float64).T  # [..., n]
    best = np.argmax(dots, axis=-1)  # first maximum: ties to the lower action
    return int(best) if best.ndim == 0 else best
