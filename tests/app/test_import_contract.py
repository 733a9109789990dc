"""The package's layering, read from the source (nothing imported): the core (the config, per-world
fields, checks, device, seeding, env, state, shards, parameters and kernels) imports nothing from training,
the command line, the studies, the viewer, the adapters or the episode loop, and no module imports a private
name (`_name`) of another package."""

from __future__ import annotations

import ast
import os

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
# Source folders and the package each installs as (pyproject.toml's package-dir).
FOLDERS = {"aquarium_warp": "aquarium_warp", "kernels": "aquarium_warp.kernels", "training": "aquarium_warp.training"}
CORE = (
    "aquarium_warp.config",
    "aquarium_warp.env",
    "aquarium_warp.state",
    "aquarium_warp.shard",
    "aquarium_warp.params",
    "aquarium_warp.per_world",
    "aquarium_warp.checks",
    "aquarium_warp.device",
    "aquarium_warp.seeding",
)
# What the core must not reach: everything built on top of it.
ABOVE_CORE = (
    "aquarium_warp.training",
    "aquarium_warp.cli",
    "aquarium_warp.studies",
    "aquarium_warp.viewer",
    "aquarium_warp.drivers",
    "aquarium_warp.interop",
    "aquarium_warp.aquarium_v1",
    "aquarium_warp.video",
    "aquarium_warp.bench",
    "aquarium_warp.rollout",
)


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


def test_the_core_imports_nothing_built_on_it():
    known = modules()
    bad = []
    for module, path in known.items():
        if not (module in CORE or module.startswith("aquarium_warp.kernels")):
            continue
        for target, names, line in imports(module, path):
            for name in [target] + [f"{target}.{n}" for n in names]:
                if any(name == up or name.startswith(up + ".") for up in ABOVE_CORE):
                    bad.append(f"{os.path.relpath(path, ROOT)}:{line} imports {name}")
    assert not bad, "\n".join(bad)


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
