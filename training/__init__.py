"""Training on top of `BatchedAquarium` (rsl-rl adapter and trainer)."""
