"""The paper's open questions as studies (`aquarium-warp study group-hunting | many-eyes | flow`):

- `group_hunting`: learning predator teams of 1-4, with and without the shared catch reward, against
  TurnAway or co-trained prey: captures per predator and how the predators stand at captures;
- `many_eyes`: learned prey groups of 1-64 over FOV angles: captures against pure dilution, flight
  initiation distance and flights started with the predator unseen;
- `flow`: currents of growing strength: captures, swarm metrics and escape direction against the current;
- `common`: what they share (training runs, worker processes, rollouts, geometry, statistics, outputs).
"""
