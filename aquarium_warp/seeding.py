"""Every random stream derived from a seed, and the rule that derives it: one home, so that no two
streams coincide by accident and a reader finds where a number came from.

| function | rule | the stream of |
|---|---|---|
| `seed_key(seed)` | a 32-bit key of device streams (1) | the kernels: spawns, respawns, headings, heuristics |
| `config_stream(seed)` | numpy `default_rng(seed)` | `AquariumConfig.draw`: the config's per-world samplers |
| `set_params_stream(seed)` | numpy `default_rng((seed, 1))` | `BatchedAquarium.set_params`' samplers |
| `randomiser_stream(seed)` | numpy `default_rng((seed, 2))` | training's per-world randomiser (`ParamRandomizer`) |
| `team_seed(seed, team)` | prey `seed`, predators `seed + 1` | a trained team's sampled actions (`make_drivers`) |
| `rank_seed(seed, rank)` | `seed + rank` | a torchrun training process (`Trainer`) |
| `seed_process(seed)` | (2) | torch's, numpy's and Python's global generators (`Trainer`) |
| `evaluation_seed(seed)` | `1_000_003 * (seed + 1)` | the evaluation worlds of group hunting, many eyes, co-evolution |
| `baseline_seed(seed, prey)` | `1_000_003 * seed + prey` | the swarm-size study's uniform baselines |
| `reset_seeds(seed)`, `next_reset_seed` | (3) | the seeds of resets without a seed (PettingZoo, vector envs) |
| `space_seed(seed, agent, kind)` | (4) | a PettingZoo agent's action and observation spaces |

(1) Counter-based streams of `(key, world, episode, step, slot, purpose)`, on the device: docs/model.md
"Randomness" (the `demo` command's random actions: a torch generator seeded with the key).
(2) `torch.manual_seed(seed)`, `np.random.seed(seed % 2**32)`, `random.seed(seed)`. (3) A Python
`random.Random(seed)` (for None, seeded from Python's global `random`, so that `random.seed(s)` makes
such code reproducible), each reset taking its next 63 bits. (4) numpy
`SeedSequence([seed, crc32(agent), kind])`, kind 0 for the action space, 1 for the observation space.

The numpy streams of one seed differ by their entropy (`seed`, `(seed, 1)`, `(seed, 2)`), so the
config's draws, `set_params`' and the randomiser's are independent. The evaluation and baseline seeds
put a large prime between the seeds of a study, away from the training seeds (0, 1, 2, ...) that the
same study uses. Where a caller passes the seed itself on (the env of a training run, its opponent's
sampling, a training video's world), no rule is needed and none is listed.
"""

from __future__ import annotations

import random
import zlib

import numpy as np

from .agent_types import TYPES

EVALUATION_STRIDE = 1_000_003  # a prime far above the seeds a study numbers its runs with


def seed_key(seed) -> int:
    """The 32-bit key of the random streams for a non-negative integer `seed`."""
    if isinstance(seed, (bool, float)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r} must be a non-negative integer")
    seed = int(seed)
    key = 0
    while True:  # fold every 32-bit word of the seed into the key
        key = (key * 0x9E3779B1 + (seed & 0xFFFFFFFF)) & 0xFFFFFFFF
        seed >>= 32
        if seed == 0:
            return key


def seeds_value(seeds: tuple[int, ...]) -> int | tuple[int, ...]:
    """`env.seed`: the one seed, or the tuple of the groups' seeds."""
    return seeds[0] if len(seeds) == 1 else seeds


def seed_groups(seed, num_worlds: int) -> tuple[int, ...]:
    """The seeds of a batch's equal groups of consecutive worlds. An integer seeds every world (one
    group). A sequence of K seeds splits the `num_worlds` worlds into K groups of `num_worlds / K`;
    group k's random streams are keyed by seed k and count its worlds from 0, so it draws exactly what
    a batch of `num_worlds / K` worlds seeded with seed k draws (a population's runs, each trained as
    if alone: `training/population.py`)."""
    if isinstance(seed, (list, tuple)):
        if not seed:
            raise ValueError("seed=[] must hold at least one seed")
        for s in seed:
            seed_key(s)
        if num_worlds % len(seed):
            raise ValueError(
                f"seed gives {len(seed)} seeds for {num_worlds} worlds: the number of worlds must be a "
                "multiple of the number of seeds (equal groups of worlds)"
            )
        return tuple(int(s) for s in seed)
    seed_key(seed)
    return (int(seed),)


def seed_keys(seeds: tuple[int, ...], num_worlds: int) -> np.ndarray:
    """`[num_worlds]` uint32: each world's stream key, that of its group's seed (`seed_groups`)."""
    return np.repeat(np.array([seed_key(s) for s in seeds], dtype=np.uint32), num_worlds // len(seeds))


def config_stream(seed: int) -> np.random.Generator:
    """The generator `AquariumConfig.draw` draws per-world sampler values from."""
    return np.random.default_rng(seed)


def set_params_stream(seed: int | tuple[int, ...]) -> np.random.Generator:
    """The generator `BatchedAquarium.set_params` draws sampler values from by default (an env seeded
    with several seeds: from all of them)."""
    return np.random.default_rng((*seed, 1) if isinstance(seed, tuple) else (int(seed), 1))


def randomiser_stream(seed: int) -> np.random.Generator:
    """The generator of training's per-world randomisation (`ParamRandomizer`)."""
    return np.random.default_rng((int(seed), 2))


def team_seed(seed: int, team: str) -> int:
    """The sampling seed of `team`'s trained policy in a run of seed `seed`: the prey's is `seed`, the
    predators' `seed + 1`, so the two teams' draws are independent."""
    if team not in TYPES:
        raise ValueError(f"team={team!r} must be one of {TYPES}")
    return int(seed) + TYPES.index(team)


def rank_seed(seed: int, rank: int) -> int:
    """The seed of process `rank` of a several-process (torchrun) training run of seed `seed`."""
    return int(seed) + int(rank)


def seed_process(seed: int) -> None:
    """Seed torch's, numpy's and Python's global generators from `seed` (numpy's takes 32 bits)."""
    import torch  # (here: the config's draws need only numpy)

    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)


def evaluation_seed(seed: int) -> int:
    """The seed of the worlds in which an open-question study evaluates its run of seed `seed`."""
    return EVALUATION_STRIDE * (int(seed) + 1)


def baseline_seed(seed: int, prey: int) -> int:
    """The seed of the swarm-size study's uniform-random baseline for `prey` prey (study seed `seed`)."""
    return int(seed) * EVALUATION_STRIDE + int(prey)


def reset_seeds(seed: int | None) -> random.Random:
    """The generator of the seeds of later resets without a seed (`next_reset_seed`): seeded by `seed`,
    or, for None, from Python's global `random` (so `random.seed(s)` makes such code reproducible)."""
    return random.Random(seed if seed is not None else random.getrandbits(64))


def next_reset_seed(seeds: random.Random) -> int:
    """The next seed of `reset_seeds`' generator (63 bits: a valid seed everywhere)."""
    return seeds.getrandbits(63)


def space_seed(seed: int, agent: str, kind: int) -> int:
    """The seed of agent `agent`'s action (`kind` 0) or observation (`kind` 1) space after a reset with
    `seed` (63 bits)."""
    key = [int(seed), zlib.crc32(agent.encode()), int(kind)]
    return int(np.random.SeedSequence(key).generate_state(1, np.uint64)[0] >> 1)
