"""The two agent types in their one order, `TYPES`: the order of the slots in a world (prey slots first),
of the per-type arrays and observation tables, of the teams that learn ("both": prey, then predators)
and of their seeds (`seeding.team_seed`). `OTHER` names each type's opponent."""

from __future__ import annotations

TYPES = ("prey", "predator")
OTHER = {"prey": "predator", "predator": "prey"}
