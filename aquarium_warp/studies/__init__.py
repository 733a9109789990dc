"""The studies, `aquarium-warp study <name>`: each module of `STUDIES` owns its command line,
`add_arguments(parser)` and `run(args) -> int`, with its `HELP` line and `DESCRIPTION`.

- `swarm_size`: captures, polarization and groups vs the number of prey (figures in `swarm_size_plots`);
- `fov_view`: the swarm-size study over prey FOV angle x view distance;
- `group_hunting`: learning predator teams of 1-4, with and without the shared catch reward, against
  TurnAway or co-trained prey: captures per predator and how the predators stand at captures;
- `many_eyes`: learned prey groups of 1-64 over FOV angles: captures against pure dilution, flight
  initiation distance and flights started with the predator unseen;
- `flow`: currents of growing strength: captures, swarm metrics and escape direction against the current;
- `swarm`: can collective behaviour pay, and does it emerge in learned prey: a heuristic screen over
  density, view distance and predator speed, then learned prey with their controls (aggregation index);
- `phase`: the pre-registered phase diagram of learned prey over capture rule, density, view and
  predator, with controls in every cell and regimes named by declared thresholds;
- `learned_prey`: learned prey under named training conditions in worlds A, B and C against the
  random, constant-heading and TurnAway baselines (the recipe behind the `learned-prey-*` presets);
- `coevolution`: both teams learning with an opponent pool, cross-play of their generations over
  training seeds, and the two-learner path's speed.

What they share: `jobs` (the job runner: finished-task cache, threads, worker processes, Ray tasks),
`statistics` (over seeds: means with 95% intervals, Welch differences, TOST equivalence) and `common`
(training runs, rollouts, geometry, output files, error-band plots).
"""

from __future__ import annotations

from types import ModuleType

from . import coevolution, flow, fov_view, group_hunting, learned_prey, many_eyes, phase, swarm, swarm_size

STUDIES: dict[str, ModuleType] = {
    "swarm-size": swarm_size,
    "fov-view": fov_view,
    "group-hunting": group_hunting,
    "many-eyes": many_eyes,
    "flow": flow,
    "swarm": swarm,
    "phase": phase,
    "learned-prey": learned_prey,
    "coevolution": coevolution,
}

__all__ = ["STUDIES"]
