"""Warp kernels of aquarium-warp, one module per stage of MODEL.md.

- `common`: parameter structs, torus geometry, counter-based random streams
- `grid`: cell lists over (world, cell) and ring-by-ring neighbour search
- `spawn`: initial state, respawn and newborn agents
- `motion`: steps 1-4 (steering, acceleration with memory, contact, clamp, wrap)
- `capture`: step 5 (captures, reward sharing, respawn/removal)
- `population`: steps 6-9 (starvation, reproduction, rewards, episode end)
- `observation`: step 10 (field-of-view observations)
- `heuristics`: the paper's baseline policies (Random, TurnAway, NaivChase)
- `render`: the rasteriser behind `aquarium_warp.render`
"""
