"""Warp kernels of aquarium-warp, one module per stage of docs/model.md.

- `state`: the typed groups of the simulation state (Warp structs of arrays)
- `common`: parameter structs, torus geometry, counter-based random streams
- `grid`: cell lists over (world, cell) and the neighbour walks (fixed radius, widening)
- `spawn`: reset, initial state, respawn and newborn agents
- `motion`: steps 1-4 (steering, acceleration with memory, contact, clamp, wrap)
- `capture`: steps 5-6 (captures, reward sharing, starvation, respawn/removal)
- `population`: steps 7-9 (reproduction, rewards, episode end; `restart_worlds` for worlds without auto-reset)
- `observation`: step 10 (field-of-view observations)
- `world_step`: steps 1-10 of a small world in one launch (the fused step)
- `heuristics`: the paper's baseline policies (Random, TurnAway, NaivChase)
- `metrics`: swarm metrics (polarization, cohesion, nearest neighbours, groups) and their per-episode totals
- `rows`: a slot as a row: the rsl-rl adapter's and the native vector envs' per-step rows (outcomes,
  observations, activity, episode statistics)
- `render`: the rasteriser behind `aquarium_warp.render`
"""
