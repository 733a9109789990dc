"""PettingZoo's registry (`aquarium_warp.interop.pettingzoo_registry`): `pettingzoo.make("parallel" | "aec",
"aquarium/Aquarium-v1", **kwargs)` after `import aquarium_warp`, with PettingZoo's own api, parallel
and seed tests run on the envs it makes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test

import aquarium_warp  # noqa: F401 - registers the env
from aquarium_warp import aquarium_v1
from aquarium_warp.interop.pettingzoo_registry import ENV_ID, register

pettingzoo = pytest.importorskip("pettingzoo")
if not hasattr(pettingzoo, "make"):  # pragma: no cover - PettingZoo < 1.27
    pytest.skip("the installed PettingZoo has no registry (pettingzoo.make arrived in 1.27)", allow_module_level=True)

# Agents leave (permanent capture, starvation) and join (reproduction): the harder case for the tests.
DYNAMIC = dict(
    prey_count=6,
    predator_count=2,
    width=300,
    height=300,
    keep_prey_count_constant=False,
    predator_max_age=30,
    procreate=True,
    prey_replication_age=20,
    max_prey_count=12,
)


def test_ids_are_registered_once_with_the_aquarium_v1_entry_points():
    assert pettingzoo.spec("parallel", ENV_ID).entry_point == "aquarium_warp.aquarium_v1:parallel_env"
    assert pettingzoo.spec("aec", ENV_ID).entry_point == "aquarium_warp.aquarium_v1:env"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second registration would warn "Overriding environment"
        assert register() is True


def test_make_parallel_passes_keywords_and_max_cycles():
    env = pettingzoo.make("parallel", ENV_ID, prey_count=5, predator_count=2, max_cycles=17, seed=3)
    try:
        assert isinstance(env, ParallelEnv) and env.config.max_steps == 17
        assert env.possible_agents == ["predator_0", "predator_1"] + [f"prey_{j}" for j in range(5)]
        # The same episode as aquarium_v1.parallel_env with the same keywords and seed.
        direct = aquarium_v1.parallel_env(prey_count=5, predator_count=2, max_cycles=17)
        a, _ = env.reset(seed=9)
        b, _ = direct.reset(seed=9)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
        direct.close()
    finally:
        env.close()
    # Unversioned ids resolve to the latest version; a bad keyword is the constructor's TypeError.
    assert pettingzoo.make("parallel", "aquarium/Aquarium").config.prey_count == 16
    with pytest.raises(TypeError, match="unknown keyword"):
        pettingzoo.make("parallel", ENV_ID, prey_cuont=3)
    with pytest.raises(pettingzoo.env_registry.exceptions.VersionNotFound):
        pettingzoo.make("parallel", "aquarium/Aquarium-v0")


def test_make_aec_is_the_wrapped_aec_env():
    env = pettingzoo.make("aec", ENV_ID, prey_count=3)
    assert isinstance(env, AECEnv) and type(env) is type(aquarium_v1.env())
    env.reset(seed=1)
    assert env.agent_selection == "predator_0"


def test_parallel_api_and_seed_tests_on_the_registered_env():
    parallel_api_test(pettingzoo.make("parallel", ENV_ID, max_cycles=80, **DYNAMIC), num_cycles=100)
    parallel_seed_test(lambda: pettingzoo.make("parallel", ENV_ID, **DYNAMIC), num_cycles=40)


def test_aec_api_and_seed_tests_on_the_registered_env():
    api_test(pettingzoo.make("aec", ENV_ID, max_cycles=80, **DYNAMIC), num_cycles=100)
    seed_test(lambda: pettingzoo.make("aec", ENV_ID, **DYNAMIC), num_cycles=20)
