"""The evaluation grid's cells (`grid.py` evaluates them): the prey count, the prey's view distance and
field of view, and the predator's top speed of each world, and the heuristics beside them. Light (no
torch, no simulator), so that the command line declares `eval --grid`'s options from it."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..config import AquariumConfig

UNLIMITED = 10000.0  # px: past the half diagonal of the default 800 x 800 torus (566 px), the whole world
PREY_COUNTS: tuple[int, ...] = (6, 16, 32, 64)
VIEWS: tuple[float, ...] = (100.0, 200.0, UNLIMITED)
FOVS: tuple[float, ...] = (120.0, 240.0, 360.0)
SPEEDS: tuple[float, ...] = (4.5, 5.0, 6.0)
BASELINES = ("turnaway", "boids", "constant", "random")
NAIVCHASE = ("naivchase", "naivchase-noconfusion")


@dataclasses.dataclass(frozen=True)
class Cell:
    """One world of the grid."""

    prey_count: int
    prey_view_distance: float
    prey_fov_angle: float
    predator_max_speed: float

    @property
    def label(self) -> str:
        view = "unlimited" if self.prey_view_distance >= UNLIMITED else f"{self.prey_view_distance:g} px"
        return f"{self.prey_count} prey, {view}, {self.prey_fov_angle:g} deg, speed {self.predator_max_speed:g}"


def grid_cells(
    prey_counts: Sequence[int] = PREY_COUNTS,
    views: Sequence[float] = VIEWS,
    fovs: Sequence[float] = FOVS,
    speeds: Sequence[float] = SPEEDS,
) -> list[Cell]:
    """Every combination, prey count slowest, predator speed fastest."""
    return [
        Cell(int(n), float(v), float(f), float(s)) for n, v, f, s in itertools.product(prey_counts, views, fovs, speeds)
    ]


def cell_of(world: AquariumConfig) -> Cell:
    """The cell of a world (a shipped specialist's own world, for its target)."""
    return Cell(world.prey_count, world.prey.view_distance, world.prey.fov_angle, world.predator.max_speed)
