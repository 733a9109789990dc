"""A/B step time: the package on PYTHONPATH (old or new), graph step, two configurations."""

import json
import statistics
import time

import torch

import aquarium_warp
from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.bench import density_config
from aquarium_warp.rollout import random_actions

out = {"package": aquarium_warp.__file__}
for name, cfg, worlds in (("65536x17", AquariumConfig(), 65536), ("1x1M", density_config(1_000_000), 1)):
    env = BatchedAquarium(cfg, num_worlds=worlds, device="cuda:0", seed=0)
    gen = torch.Generator(device="cuda:0").manual_seed(0)
    pool = [random_actions(cfg, worlds, gen, env.torch_device) for _ in range(8)]
    for i in range(20):
        env.step(pool[i % 8], validate=False)
    torch.cuda.synchronize()
    runs = []
    n = 400 if worlds > 1 else 300
    for _ in range(7):
        t = time.perf_counter()
        for i in range(n):
            env.step(pool[i % 8], validate=False)
        torch.cuda.synchronize()
        runs.append((time.perf_counter() - t) / n)
    out[name] = {"median_ms": 1e3 * statistics.median(runs), "agents": worlds * (cfg.prey_count + cfg.predator_count)}
    del env
    torch.cuda.empty_cache()
print(json.dumps(out))
