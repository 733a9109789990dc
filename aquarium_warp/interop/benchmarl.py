"""BenchMARL task `aquarium/predator_prey` over `AquariumTorchRLEnv` (optional: the `[torchrl]` extra).

```python
from benchmarl.algorithms import MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models.mlp import MlpConfig
from aquarium_warp.interop.benchmarl import AquariumTask

task = AquariumTask.PREDATOR_PREY.get_task(config={"max_steps": 100})  # AquariumConfig fields; others default
config = ExperimentConfig.get_from_yaml()
config.sampling_device = config.train_device = config.buffer_device = "cpu"
config.on_policy_n_envs_per_worker = 20               # worlds of one BatchedAquarium
config.on_policy_collected_frames_per_batch = 2000    # 20 worlds x 100 steps per iteration
config.on_policy_n_minibatch_iters = 5
config.max_n_iters = 3
config.loggers = ["csv"]                              # the default also has wandb
Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(), model_config=MlpConfig.get_from_yaml(),
           critic_model_config=MlpConfig.get_from_yaml(), seed=0, config=config).run()
```

The groups are the teams ("prey", "predator"): BenchMARL's algorithms for discrete actions (MAPPO is
tested) learn both teams at once, each with its own networks. The worlds of a batch are BenchMARL's
`num_envs` (one `BatchedAquarium`, stepped by Warp kernels). Actions are discrete only.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable

from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import EnvBase

from ..config import AquariumConfig
from .torchrl import AquariumTorchRLEnv


@dataclasses.dataclass
class TaskConfig:
    """The task's settings: the world (`AquariumConfig` fields) and the simulation's CPU threads.
    Defaults are docs/model.md's world, as `AquariumConfig()`; a config given to `get_task` may name any
    `AquariumConfig` field, and the fields it leaves out keep `AquariumConfig`'s defaults."""

    width: float = 800.0
    height: float = 800.0
    prey_count: int = 16
    predator_count: int = 1
    max_steps: int = 3000
    respawn_captured_prey: bool = True
    prey_reproduction: bool = False
    cpu_threads: int | None = None


class AquariumClass(TaskClass):
    """How BenchMARL builds, describes and steps the Aquarium task."""

    def _world(self) -> tuple[AquariumConfig, int | None]:
        config = copy.deepcopy(self.config)
        threads = config.pop("cpu_threads", None)
        return AquariumConfig(**config), threads

    def get_env_fun(self, num_envs: int, continuous_actions: bool, seed: int | None, device) -> Callable[[], EnvBase]:
        if continuous_actions:
            raise ValueError("aquarium/predator_prey has discrete actions only: use an algorithm's discrete form")
        world, threads = self._world()
        return lambda: AquariumTorchRLEnv(
            world, num_worlds=num_envs, device=device, seed=0 if seed is None else seed, cpu_threads=threads
        )

    def supports_continuous_actions(self) -> bool:
        return False

    def supports_discrete_actions(self) -> bool:
        return True

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return env.aquarium.config.max_steps

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def state_spec(self, env: EnvBase) -> Composite | None:
        return None

    def _group_keys(self, env: EnvBase, keep: str) -> Composite | None:
        spec = env.full_observation_spec_unbatched.clone()
        for group in self.group_map(env):
            for key in list(spec[group].keys()):
                if key != keep:
                    del spec[(group, key)]
        return spec

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return self._group_keys(env, "action_mask")

    def observation_spec(self, env: EnvBase) -> Composite:
        return self._group_keys(env, "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        return None

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return "aquarium"


class AquariumTask(Task):
    """BenchMARL's enum of the Aquarium tasks: `AquariumTask.PREDATOR_PREY`."""

    PREDATOR_PREY = None

    @staticmethod
    def associated_class():
        return AquariumClass

    def get_from_yaml(self, path: str | None = None) -> TaskClass:
        """The task with `TaskConfig`'s defaults, or with the settings of the YAML file at `path`."""
        if path is None:
            return self.get_task(config=dataclasses.asdict(TaskConfig()))
        return super().get_from_yaml(path)
