"""The package's layering, read from the source (nothing imported, imports inside functions included):
every module sits in one room of `LAYERS` and imports only its own room and the layers below (the
core nothing built on it; the core and training none of the app layers: studies, viewer, bench, the
command line), the core imports without a circle, and no module imports a private name (`_name`) of
another package."""

from __future__ import annotations

import ast
import os

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
# Source folders and the package each installs as (pyproject.toml's package-dir).
FOLDERS = {"aquarium_warp": "aquarium_warp", "kernels": "aquarium_warp.kernels", "training": "aquarium_warp.training"}
# The layers, lowest first, each of rooms side by side: a module imports its own room, the rooms of
# lower layers and nothing else (not a room beside its own, nor anything above). Every module of the
# package is in exactly one room (a name covers its submodules).
LAYERS: tuple[dict[str, tuple[str, ...]], ...] = (
    {"kernels": ("aquarium_warp.kernels",)},
    {
        "core": (
            "aquarium_warp.config",
            "aquarium_warp.env",
            "aquarium_warp.state",
            "aquarium_warp.shard",
            "aquarium_warp.params",
            "aquarium_warp.per_world",
            "aquarium_warp.checks",
            "aquarium_warp.device",
            "aquarium_warp.seeding",
            "aquarium_warp.agent_types",
        )
    },
    {
        # What every consumer shares, on the core: argument types, files, statistics, shipped policies.
        "tools": (
            "aquarium_warp.arguments",
            "aquarium_warp.atomic",
            "aquarium_warp.records",
            "aquarium_warp.statistics",
            "aquarium_warp.pretrained",
            "aquarium_warp.world_state",
            "aquarium_warp.nulls",
            "aquarium_warp.heuristics",
            "aquarium_warp.render",
        )
    },
    {
        # What drives and measures worlds: drivers, the episode loop, metrics, videos, the job runner.
        "consumers": (
            "aquarium_warp.drivers",
            "aquarium_warp.rollout",
            "aquarium_warp.metrics",
            "aquarium_warp.video",
            "aquarium_warp.jobs",
        )
    },
    {
        "interop": ("aquarium_warp.interop", "aquarium_warp.aquarium_v1", "aquarium_warp.policies"),
        "training": ("aquarium_warp.training",),
    },
    {"studies": ("aquarium_warp.studies",), "viewer": ("aquarium_warp.viewer",), "bench": ("aquarium_warp.bench",)},
    # The command line, and the package's front (its re-exports and the PettingZoo/Gymnasium registration).
    {"cli": ("aquarium_warp.cli", "aquarium_warp.__main__", "aquarium_warp")},
)
# The one door up, by design: a trained policy's driver and world come from training, imported only
# when a policy file is asked for (`drivers.make_driver`, `drivers.policy_world`).
DOORS = {("aquarium_warp.drivers", "training")}
APP_ROOMS = ("studies", "viewer", "bench", "cli")


def modules() -> dict[str, str]:
    """`{module name: source path}` of every module of the package."""
    out = {}
    for folder, package in FOLDERS.items():
        for dirpath, _, files in os.walk(os.path.join(ROOT, folder)):
            for name in files:
                if not name.endswith(".py"):
                    continue
                rel = os.path.relpath(os.path.join(dirpath, name), os.path.join(ROOT, folder))
                parts = rel[:-3].split(os.sep)
                if parts[-1] == "__init__":
                    parts = parts[:-1]
                out[".".join([package] + parts)] = os.path.join(dirpath, name)
    return out


def imports(module: str, path: str) -> list[tuple[str, list[str], int]]:
    """`(imported module, imported names, line)` of every import statement, relative ones resolved."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    package = module if path.endswith("__init__.py") else module.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, [], node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            out.append((base, [alias.name for alias in node.names], node.lineno))
    return out


def package_of(module: str, known: dict[str, str]) -> str:
    """The package a module belongs to (a package is its own)."""
    return module if known.get(module, "").endswith("__init__.py") else module.rpartition(".")[0]


def room_of(module: str) -> tuple[int, str]:
    """The layer (its index in `LAYERS`) and room of `module`: the room naming it or its nearest package."""
    best: tuple[int, int, str] | None = None
    for rank, rooms in enumerate(LAYERS):
        for room, names in rooms.items():
            for name in names:
                if (module == name or module.startswith(name + ".")) and (best is None or len(name) > best[0]):
                    best = (len(name), rank, room)
    assert best is not None, f"{module} is in no room of LAYERS"
    return best[1], best[2]


def imported_modules(module: str, path: str, known: dict[str, str]) -> list[tuple[str, int]]:
    """`(module of the package, line)` of each import of `module`: `from a import b` counts as `a.b` when
    that is a module, else as `a`."""
    out = []
    for target, names, line in imports(module, path):
        if not target.startswith("aquarium_warp"):
            continue
        submodules = [f"{target}.{n}" for n in names if f"{target}.{n}" in known]
        out += [(m, line) for m in submodules] if submodules and len(submodules) == len(names) else [(target, line)]
    return out


def layer_breaches() -> list[str]:
    known = modules()
    bad = []
    for module, path in known.items():
        rank, room = room_of(module)
        for target, line in imported_modules(module, path, known):
            target_rank, target_room = room_of(target)
            if target_room == room or target_rank < rank:
                continue
            if any(module == door or module.startswith(door + ".") for door, to in DOORS if to == target_room):
                continue
            bad.append(f"{os.path.relpath(path, ROOT)}:{line} ({room}) imports {target} ({target_room})")
    return bad


def test_every_module_is_in_one_room():
    rooms = [room_of(module) for module in modules()]
    assert {room for _, room in rooms} == {room for layer in LAYERS for room in layer}


def test_no_module_imports_a_room_above_or_beside_its_own():
    """The core imports nothing built on it, and neither the core nor training imports the app layers
    (studies, viewer, bench, the command line); the lazy imports inside functions count too."""
    bad = layer_breaches()
    assert not bad, "\n".join(bad)


def test_the_core_and_training_import_no_app_layer():
    known = modules()
    for module, path in known.items():
        rank, room = room_of(module)
        if room not in ("kernels", "core", "training"):
            continue
        for target, line in imported_modules(module, path, known):
            assert room_of(target)[1] not in APP_ROOMS, f"{os.path.relpath(path, ROOT)}:{line} imports {target}"


def test_no_module_imports_a_private_name_of_another_package():
    known = modules()
    bad = []
    for module, path in known.items():
        own = package_of(module, known)
        for target, names, line in imports(module, path):
            if not target.startswith("aquarium_warp"):
                continue
            for name in names:
                full = f"{target}.{name}"
                if full in known:  # a module: its package is the target
                    continue
                if name.startswith("_") and package_of(target, known) != own:
                    bad.append(f"{os.path.relpath(path, ROOT)}:{line} imports {name} from {target}")
    assert not bad, "\n".join(bad)


def test_the_core_imports_without_a_circle():
    """No module of the core imports, even for types only (`if TYPE_CHECKING:`), a module that imports it
    back, directly or through others."""
    known = modules()
    core = {m: path for m, path in known.items() if room_of(m)[1] == "core"}
    graph = {
        m: {target for target, _ in imported_modules(m, path, known) if target in core and target != m}
        for m, path in core.items()
    }

    def reached(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for target in graph[todo.pop()] - seen:
                seen.add(target)
                todo.append(target)
        return seen

    assert [m for m in sorted(core) if m in reached(m)] == []
