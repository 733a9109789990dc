"""Adapters of `BatchedAquarium` to other libraries' interfaces, one module per library:
`pettingzoo` (the `ParallelEnv` behind `aquarium_v1`) and `pettingzoo_registry` (`pettingzoo.make`),
`gymnasium` (a Gymnasium `VectorEnv`), `sb3` (a Stable-Baselines3 `VecEnv`), `torchrl` (a TorchRL
`EnvBase`) and `benchmarl` (a BenchMARL task). Each imports its library, so this package imports none of
them: import the module you use."""
