"""Swarm-size study: how captures, polarization and grouping change with the number of prey.

`aquarium-warp study swarm-size` (see `aquarium_warp.cli`) runs, for every prey count N (and every
prey field-of-view angle and view distance of the sweeps), one `BatchedAquarium` whose worlds are
all seeds x episodes of that setting, stepped together for exactly one episode of `episode_steps`
steps. Seed `s` is the block of worlds `[s * E, (s + 1) * E)` (E episodes per seed): the env's
counter-based random streams are keyed by the world index, so the blocks are independent runs.
Metrics (`aquarium_warp.metrics`) are sampled every `metrics_every` steps on the device and averaged
per episode, then per seed; the spread in the figures is the standard deviation over seeds.

With `one_batch=True` (`--one-batch`) every setting runs in one `BatchedAquarium` instead: setting i is
the block of worlds `[i * S * E, (i + 1) * S * E)` with its own prey count, FOV angle and view distance
(per-world parameters, `one_batch_config`); every world has the slots of the largest prey count. The
per-setting statistics come from the same code (`_setting_result`) on both paths. Other worlds draw
other random streams, so the two paths agree statistically, not bit for bit (a single setting is bit
for bit). `aquarium-warp study fov-view` is this study with one prey count over prey FOV angle x view
distance (`kind="fov-view"`: `fov_view.csv/json` and a heatmap), in one batch by default.

Outputs in `out`: `swarm_size.csv` (one row per setting and seed), `swarm_size.json` (the
configuration, the machine, timings, per-setting means/std/sem/95% intervals over seeds,
nearest-neighbour distributions, population traces when populations change) and PNG figures
(`aquarium_warp.studies.swarm_size_plots`): `captures_vs_size.png` (dilution),
`polarization_groups_vs_size.png`, `spacing_vs_size.png`, `nn_distribution.png` and, with population
dynamics, `population.png`.

```python
from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_swarm_size_study
results = run_swarm_size_study(SwarmSizeStudy(prey=[4, 8, 16], seeds=2, episode_steps=200, out="out"))
```

Each setting is a task of the job runner (`aquarium_warp.jobs`): here on threads
(`jobs`), or with `ray=RayOptions(...)` (`--ray` on the command line) as Ray tasks calling the same
`run_setting`; the files are the same. Finished settings are kept in `out/finished/` until the JSON is
written: a rerun after an interruption runs only the others.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shutil
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..arguments import (
    DEVICE_HELP,
    POLICY_SPECS,
    add_options,
    check_distinct,
    check_int,
    from_options,
    non_negative_int,
    option,
    parse_list,
    plural,
    policy_spec,
    positive_int,
)
from ..atomic import atomic_open, check_output_dir
from ..config import AquariumConfig
from ..jobs import (
    FINISHED_DIR,
    RayOptions,
    add_ray_arguments,
    placement,
    ray_options,
    resolve_jobs,
    run_jobs,
    run_ray_tasks,
    warm_up,
)
from ..pretrained import is_policy_file
from ..records import command_line, git_info, json_safe, machine_info
from ..seeding import baseline_seed
from ..statistics import seed_stats
from .common import write_csv
from .swarm_size_plots import plot_study

if TYPE_CHECKING:
    from ..rollout import Observer


def result_metrics() -> tuple[str, ...]:
    """Per-seed columns of the CSV, in order (the metrics module loads the simulator: read when a study runs)."""
    from ..metrics import EPISODE_METRICS

    return ("captures", "captures_per_prey") + EPISODE_METRICS + ("episode_length",)


POPULATION_TRACES = ("prey_alive", "predator_alive")
# The "definitions" entry of swarm_size.json for the baselines (written by the study and by replot).
UNIFORM_BASELINE_DEFINITION = (
    "the same metrics for uniformly random prey and predator positions and headings "
    "(same arena and N; mean over snapshots of about 65k prey in all)"
)


def parse_world_size(text) -> tuple[float, float]:
    """`"800"` or `"800x600"` -> (width, height) px."""
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"world size {text!r} must be WIDTH or WIDTHxHEIGHT in px") from None
    if len(values) == 1:
        values = values * 2
    if len(values) != 2:
        raise ValueError(f"world size {text!r} must be WIDTH or WIDTHxHEIGHT in px")
    return values[0], values[1]


@dataclass
class SwarmSizeStudy:
    """Settings of a swarm-size study (the CLI's options: every option of `study swarm-size`, those
    named in `RUN_OPTIONS` also `study fov-view`'s)."""

    prey: list[int] = field(  # 4 .. 4096
        default_factory=lambda: [4 * 2**k for k in range(11)],
        metadata=option(
            "prey counts: a comma list; '...' continues the progression",
            parse=lambda text, flag: parse_list(text, int, flag),
            shown="4,8,...,4096",
        ),
    )
    seeds: int = field(default=5, metadata=option("independent runs per setting", type=int))
    episodes_per_seed: int = field(default=1, metadata=option("episodes per seed, run as more worlds", type=int))
    episode_steps: int = field(default=3000, metadata=option("steps per episode (the paper's)", type=int))
    prey_policy: str = field(default="turnaway", metadata=option(POLICY_SPECS["prey"], type=policy_spec("prey")))
    predator_policy: str = field(
        default="naivchase", metadata=option(POLICY_SPECS["predator"], type=policy_spec("predator"))
    )
    confusion: bool = field(  # NaivChase: a random visible prey each step (False: the nearest)
        default=True,
        metadata=option("NaivChase chases the nearest visible prey instead of a random one each step", negated=True),
    )
    predators: int = field(default=1, metadata=option("predators per world", type=int))
    fov_angles: list[float] | None = field(  # None: the config's, 120
        default=None,
        metadata=option(
            "prey field-of-view angles to sweep, degrees (list; default 120)",
            parse=lambda text, flag: parse_list(text, float, flag),
            flag="--fov-angle",
        ),
    )
    view_distances: list[float] | None = field(  # None: the config's, 100
        default=None,
        metadata=option(
            "prey view distances to sweep, px (list; default 100)",
            parse=lambda text, flag: parse_list(text, float, flag),
            flag="--view-distance",
        ),
    )
    world_size: tuple[float, float] = field(
        default=(800.0, 800.0),
        metadata=option("arena WIDTHxHEIGHT px", parse=lambda text, flag: parse_world_size(text), shown="800x800"),
    )
    constant_density: bool = field(  # scale the arena with N so that N / area stays that of reference_prey
        default=False,
        metadata=option(
            "scale the arena with N instead of a fixed --world-size, keeping the density of --reference-prey "
            "prey in --world-size"
        ),
    )
    reference_prey: int = field(
        default=16,
        metadata=option("with --constant-density: the prey count that --world-size is sized for", type=int),
    )
    linking_distance: float | None = field(  # None: 2.5 prey radii
        default=None,
        metadata=option("px; prey closer than this form one group (default 2.5 prey radii = 50)", type=float),
    )
    metrics_every: int = field(default=10, metadata=option("sample the swarm metrics every K steps", type=int))
    respawn: bool = field(default=True, metadata=option("captured prey are removed (populations shrink)", negated=True))
    reproduction: bool = field(default=False, metadata=option("prey reproduce (up to 2 N)"))
    max_prey_factor: float = 2.0  # with reproduction: max_prey = factor x N
    starvation_steps: int | None = field(  # None: the config's (3000)
        default=None, metadata=option("predator starvation limit (default 3000)", type=int)
    )
    device: str | None = field(default=None, metadata=option(DEVICE_HELP))
    seed: int = field(
        default=0,
        metadata=option("seed of the batched worlds (the --seeds runs are worlds of one env)", type=non_negative_int),
    )
    jobs: int | None = field(  # settings run at once on the CPU (threads); None: the CPU's cores; GPU: 1
        default=None,
        metadata=option(
            "settings run at once in threads, one batch per setting (default: CPU cores on the CPU, 1 on a GPU)",
            type=positive_int,
        ),
    )
    out: str = "swarm_size"
    figures: bool = field(default=True, metadata=option("write CSV/JSON only, no figures", negated=True))
    one_batch: bool = field(  # every setting in one batch (worlds of setting i: its prey count, FOV and view)
        default=False,
        metadata=option(
            "every setting in one batch (per-world prey counts; every world has the slots of the largest count) "
            "instead of one batch per setting"
        ),
    )
    kind: str = "swarm-size"  # "swarm-size" or "fov-view": names the output files and figures

    @property
    def basename(self) -> str:
        """The output files' name: swarm_size.csv/json or fov_view.csv/json."""
        return self.kind.replace("-", "_")

    def validate(self) -> None:
        if not self.prey:
            raise ValueError("prey must list at least one prey count")
        for n in self.prey:
            check_int("prey count", n)
        for name in ("seeds", "episodes_per_seed", "episode_steps", "predators", "metrics_every", "reference_prey"):
            check_int(name.replace("_", "-"), getattr(self, name))
        if self.jobs is not None:
            check_int("jobs", self.jobs)
        for name in ("fov_angles", "view_distances"):
            values = getattr(self, name)
            if values is not None and not values:
                raise ValueError(f"{name} must list at least one value")
        # One rule for every study: a repeated setting would run twice and pool its seeds with its twin's.
        flags = ("--fov", "--view") if self.kind == "fov-view" else ("--fov-angle", "--view-distance")
        for flag, values in zip(("--prey", *flags), (self.prey, self.fov_angles, self.view_distances)):
            check_distinct(flag, values or [])
        if self.max_prey_factor < 1:
            raise ValueError(f"max_prey_factor={self.max_prey_factor!r} must be >= 1")
        if self.kind not in ("swarm-size", "fov-view"):
            raise ValueError(f"kind={self.kind!r} must be 'swarm-size' or 'fov-view'")
        # The arena and max_prey size the arrays, so they cannot differ between the worlds of one batch.
        if self.one_batch and self.constant_density:
            raise ValueError("one batch: every world has one arena, so not with constant density")
        if self.one_batch and self.reproduction:
            raise ValueError("one batch: max_prey (2 N with reproduction) sizes the arrays, so not with reproduction")
        if self.one_batch and self.jobs is not None and self.jobs > 1:
            raise ValueError(
                f"--jobs {self.jobs} runs settings at once, a batch each; one batch holds every setting "
                "(--one-batch, fov-view's default): drop --jobs, or use one batch per setting "
                "(fov-view --per-setting)"
            )

    def settings(self) -> list[dict]:
        """One dict per (fov angle, view distance, prey count), with its `AquariumConfig` (where a team is a
        trained policy, its agents observe and act as in the policy's world)."""
        from ..drivers import is_heuristic, trained_world

        base = AquariumConfig()
        for agent_type, name in (("prey", self.prey_policy), ("predator", self.predator_policy)):
            if not is_heuristic(name, agent_type) and is_policy_file(name):
                base = base.with_interface_of(trained_world(name))
        fovs = self.fov_angles or [base.prey.fov_angle]
        views = self.view_distances or [base.prey.view_distance]
        out = []
        for fov in fovs:
            for view in views:
                for n in self.prey:
                    width, height = self.world_size
                    if self.constant_density:
                        scale = math.sqrt(n / self.reference_prey)
                        width, height = width * scale, height * scale
                    changes = dict(
                        width=float(width),
                        height=float(height),
                        prey_count=int(n),
                        predator_count=self.predators,
                        max_steps=self.episode_steps,
                        respawn_captured_prey=self.respawn,
                        prey=dataclasses.replace(base.prey, fov_angle=float(fov), view_distance=float(view)),
                    )
                    if self.reproduction:
                        changes.update(
                            prey_reproduction=True, max_prey=max(int(n), int(round(self.max_prey_factor * n)))
                        )
                    if self.starvation_steps is not None:
                        changes["predator_starvation_steps"] = self.starvation_steps
                    out.append(
                        {
                            "prey": int(n),
                            "fov_angle": float(fov),
                            "view_distance": float(view),
                            "width": float(width),
                            "height": float(height),
                            "config": base.replace(**changes),
                        }
                    )
        return out

    @property
    def population_changes(self) -> bool:
        """Whether populations can change within an episode (then population traces are recorded)."""
        starve = (
            self.starvation_steps if self.starvation_steps is not None else AquariumConfig().predator_starvation_steps
        )
        return (not self.respawn) or self.reproduction or starve < self.episode_steps


# --------------------------------------------------------------------------------------------------
# Policies
# --------------------------------------------------------------------------------------------------
def check_policies(study: SwarmSizeStudy) -> None:
    """Fail early (before any simulation) on policy names that are neither heuristics nor files."""
    from ..drivers import check_spec

    for agent_type, name in (("prey", study.prey_policy), ("predator", study.predator_policy)):
        check_spec(name, agent_type)


# --------------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------------
def _run_batch(study: SwarmSizeStudy, cfg: AquariumConfig, worlds: int, device: str, progress=None) -> dict:
    """Step `worlds` worlds of `cfg` (its per-world tuples: one value per world) for one episode. Returns the
    per-world episode statistics (numpy `[W]`, `nn_distribution` `[W, bins]`), the population traces
    (`[samples, W]` tensors, the last sample dropped: it is the next episode's first state) and the batch's
    wall time and agent-steps."""
    from ..drivers import make_driver
    from ..env import BatchedAquarium
    from ..metrics import EpisodeMetrics, SwarmMetrics
    from ..rollout import Progress, rollout

    start = time.perf_counter()
    env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=study.seed)
    prey = make_driver(study.prey_policy, env, "prey", confusion=study.confusion)
    predator = make_driver(study.predator_policy, env, "predator", confusion=study.confusion)
    metrics = SwarmMetrics(env, linking_distance=study.linking_distance)
    trace = POPULATION_TRACES if study.population_changes else ()
    episodes = EpisodeMetrics(env, metrics=metrics, every=study.metrics_every, trace=trace)
    observers: list[Observer] = [episodes] if progress is None else [episodes, Progress(progress, every=25)]
    rollout(env, {"prey": prey, "predator": predator}, study.episode_steps, observers)
    out = {
        "worlds": {k: v.detach().cpu().double().numpy() for k, v in episodes.result().items()},
        "nn_bin_edges": metrics.bin_edges.numpy(),
        "linking_distance": metrics.linking_distance,
    }
    if trace:
        traces = episodes.traces()
        population: dict = {"step": list(episodes.trace_steps)[:-1]}
        population.update({name: traces[name][:-1].double() for name in trace})
        out["population"] = population
    out["wall_s"] = time.perf_counter() - start
    out["agent_steps"] = worlds * cfg.capacity * study.episode_steps
    env.close()
    return out


def _setting_result(study: SwarmSizeStudy, batch: dict, first_world: int, label: str) -> dict:
    """The statistics of one setting from its worlds `[first_world, first_world + seeds x episodes_per_seed)`
    of `batch` (`_run_batch`): per-seed metrics (numpy arrays `[seeds]`), the mean nearest-neighbour
    distribution and, with population dynamics, the mean population traces. Both paths (one batch per
    setting, every setting in one batch) go through here."""
    E = study.episodes_per_seed
    worlds = slice(first_world, first_world + study.seeds * E)
    result = {k: v[worlds] for k, v in batch["worlds"].items()}
    # Every world finishes its episode at the last step, or earlier if it ran out of prey or predators
    # (then it restarts, and the restarted episode, unfinished, is not counted).
    if (result["episodes"] < 1).any():
        raise RuntimeError(f"{label}: a world finished no episode ({result['episodes']})")
    per_seed = {name: result[name].reshape(study.seeds, E).mean(axis=1) for name in result_metrics()}
    out = {
        "per_seed": per_seed,
        "nn_distribution": result["nn_distribution"].mean(axis=0),
        "nn_bin_edges": batch["nn_bin_edges"],
        "linking_distance": batch["linking_distance"],
        "wall_s": batch["wall_s"],
        "agent_steps": batch["agent_steps"],
    }
    if "population" in batch:
        out["population"] = {"step": batch["population"]["step"]}
        for name in POPULATION_TRACES:
            out["population"][name] = batch["population"][name][:, worlds].mean(dim=1).cpu().numpy()
    return out


def run_setting(study: SwarmSizeStudy, setting: dict, device: str, progress=None) -> dict:
    """Run one setting: `seeds x episodes_per_seed` worlds for one episode (`_setting_result`)."""
    batch = _run_batch(study, setting["config"], study.seeds * study.episodes_per_seed, device, progress)
    return _setting_result(study, batch, 0, f"N={setting['prey']}")


def one_batch_config(study: SwarmSizeStudy, settings: list[dict]) -> AquariumConfig:
    """Every setting in one config: setting i's prey count, prey FOV angle and view distance for its block of
    `seeds x episodes_per_seed` worlds `[i * block, (i + 1) * block)`. Every world has the slots of the
    largest prey count."""
    block = study.seeds * study.episodes_per_seed

    def per_world(key):
        return tuple(s[key] for s in settings for _ in range(block))

    first = settings[0]["config"]
    prey = dataclasses.replace(first.prey, fov_angle=per_world("fov_angle"), view_distance=per_world("view_distance"))
    return first.replace(prey_count=per_world("prey"), prey=prey)


def _run_one_batch(study: SwarmSizeStudy, settings: list[dict], device: str, advance) -> dict[int, dict]:
    """Every setting in one batch (`one_batch_config`), then each setting's statistics from its worlds."""
    block = study.seeds * study.episodes_per_seed
    batch = _run_batch(
        study,
        one_batch_config(study, settings),
        block * len(settings),
        device,
        progress=lambda n: advance(n * len(settings), "one batch"),
    )
    return {i: _setting_result(study, batch, i * block, _label(s)) for i, s in enumerate(settings)}


BASELINE_METRICS = (
    "polarization",
    "cohesion",
    "nn_mean",
    "groups",
    "largest_group",
    "predator_distance",
    "local_alignment",
    "milling",
)


def uniform_baseline(
    cfg: AquariumConfig, worlds: int, linking_distance: float | None, device: str, seed: int
) -> dict[str, float]:
    """The metrics of `worlds` snapshots of uniformly random prey and predators with uniformly random
    headings (prey that ignore each other and the predator), in `cfg`'s arena, by the same kernels:
    the reference each measured curve is read against. Means over the snapshots."""
    import torch

    from ..env import BatchedAquarium
    from ..metrics import SwarmMetrics

    cfg = cfg.replace(prey_reproduction=False) if cfg.prey_reproduction else cfg
    env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=0)
    W, C = env.num_worlds, env.capacity
    gen = torch.Generator().manual_seed(int(seed))
    size = torch.tensor([cfg.width, cfg.height], dtype=torch.float32)
    position = torch.minimum(torch.rand(W, C, 2, generator=gen) * size, torch.nextafter(size, torch.zeros(2)))
    angle = torch.rand(W, C, generator=gen, dtype=torch.float64) * (2 * math.pi)
    heading = torch.stack([torch.cos(angle), torch.sin(angle)], dim=-1).float()
    env.set_state(position=position, velocity=heading, heading=heading, alive=torch.ones(W, C, dtype=torch.bool))
    values = SwarmMetrics(env, linking_distance=linking_distance).compute()
    out = {name: float(torch.nanmean(values[name].double()).cpu()) for name in BASELINE_METRICS}
    env.close()
    return out


def add_uniform_baselines(summary: dict, study: SwarmSizeStudy, device: str) -> None:
    """Store `uniform_baseline` in every entry of `summary["results"]` (snapshots of about 65k prey in
    all, at least one per seed, at most 256)."""
    settings = {(s["prey"], s["fov_angle"], s["view_distance"]): s for s in study.settings()}
    cache: dict[tuple, dict] = {}
    for entry in summary["results"]:
        s = settings[(entry["prey"], entry["fov_angle"], entry["view_distance"])]
        key = (s["prey"], s["width"], s["height"])  # the baseline depends on the arena and N only
        if key not in cache:
            snapshots = min(256, max(study.seeds, -(-65536 // s["prey"])))  # about 64k prey in all
            cache[key] = uniform_baseline(
                s["config"], snapshots, study.linking_distance, device, seed=baseline_seed(study.seed, s["prey"])
            )
        entry["uniform_baseline"] = cache[key]


def _largest_first(settings: list[dict]) -> list[int]:
    """Setting indices, largest worlds first, so that settings run side by side (threads, Ray tasks) finish
    together."""
    return sorted(range(len(settings)), key=lambda i: -settings[i]["config"].capacity)


# --------------------------------------------------------------------------------------------------
# One task per setting (`jobs.run_jobs`: on threads here, or as Ray tasks)
# --------------------------------------------------------------------------------------------------
def setting_tasks(study: SwarmSizeStudy, settings: list[dict], device: str) -> list[dict]:
    """One task per setting, largest worlds first: its prey count, FOV angle and view distance (the
    setting of `study.settings()` it runs), its seed count and device."""
    return [
        {
            "name": f"prey{s['prey']}_fov{s['fov_angle']:g}_view{s['view_distance']:g}",
            "prey": s["prey"],
            "fov_angle": s["fov_angle"],
            "view_distance": s["view_distance"],
            "seeds": study.seeds,
            "device": device,
            "study": study,
        }
        for s in (settings[i] for i in _largest_first(settings))
    ]


def run_setting_task(task: dict, progress=None) -> dict:
    """`run_setting` of a task of `setting_tasks`."""
    study: SwarmSizeStudy = task["study"]
    setting = next(
        s
        for s in study.settings()
        if (s["prey"], s["fov_angle"], s["view_distance"]) == (task["prey"], task["fov_angle"], task["view_distance"])
    )
    return run_setting(study, setting, task["device"], progress)


def _setting_on_worker(task: dict) -> dict:
    """A Ray task: `run_setting_task` on the worker's device, with the worker's machine."""
    result = run_setting_task(task)
    result["machine"] = machine_info(task["device"])
    return result


def _baselines_on_worker(summary: dict, study: SwarmSizeStudy, device: str) -> dict:
    """A Ray task: `add_uniform_baselines` on a worker's `device` (this machine may have no GPU)."""
    add_uniform_baselines(summary, study, device)
    return summary


def _run_settings(
    study: SwarmSizeStudy, settings: list[dict], device: str, ray: RayOptions | None, advance
) -> tuple[dict[int, dict], int | None, dict | None]:
    """Every setting a task of `jobs.run_jobs`: here on threads (`study.jobs`: on the CPU several at once,
    on a GPU one after another), or with `ray` as Ray tasks. Returns the results by setting index, the
    threads (None on Ray) and, on Ray, the run's record."""
    tasks = setting_tasks(study, settings, device)

    def finished(k: int, result: dict, kept: bool) -> None:
        if ray is not None or kept:  # here, run_setting's progress advances the bar as the steps run
            advance(study.episode_steps, f"N={tasks[k]['prey']} {'kept' if kept else 'done'}")

    if ray is None:
        threads = min(resolve_jobs(study.jobs, device, threads=True), len(settings))
        run = run_jobs(
            lambda task: run_setting_task(task, progress=lambda n: advance(n, _label(task))),
            tasks,
            study.out,
            jobs=threads,
            threads=True,
            device=device,
            label=study.kind,
            on_result=finished,
            report=None,
            prepare=lambda: warm_up(
                device,
                settings[0]["config"],
                study.prey_policy,
                study.predator_policy,
                study.confusion,
                study.linking_distance,
            ),
        )
        return _by_setting(settings, tasks, run.results), threads, None
    run = run_jobs(
        _setting_on_worker, tasks, study.out, device=device, ray=ray, label=study.kind, on_result=finished, report=None
    )
    return (
        _by_setting(settings, tasks, run.results),
        None,
        dict(ray.record(device), settings_kept=run.kept, nodes=run.nodes),
    )


def _by_setting(settings: list[dict], tasks: list[dict], results: list) -> dict[int, dict]:
    """The results of `setting_tasks`' tasks by the index of their setting in `settings`."""
    index = {(s["prey"], s["fov_angle"], s["view_distance"]): i for i, s in enumerate(settings)}
    return {index[(t["prey"], t["fov_angle"], t["view_distance"])]: r for t, r in zip(tasks, results)}


def _label(setting: dict) -> str:
    return f"N={setting['prey']} fov={setting['fov_angle']:g} view={setting['view_distance']:g}"


def run_swarm_size_study(
    study: SwarmSizeStudy, progress: bool = True, ray: RayOptions | None = None, command: str | None = None
) -> dict:
    """Run every setting of `study`, write the CSV, JSON and figures into `study.out`, and return the
    JSON's content. `ray`: run each setting as a Ray task (`_run_settings`) instead of on this machine.
    `command`: the command recorded in the JSON (default: this process's, as `aquarium-warp ...`)."""
    from ..device import resolve_device

    study.validate()
    if study.one_batch and ray is not None:
        raise ValueError("one batch runs on this machine: not with Ray (whose tasks are settings)")
    check_policies(study)
    settings = study.settings()
    os.makedirs(study.out, exist_ok=True)
    start = time.perf_counter()

    bar = None
    lock = threading.Lock()
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=len(settings) * study.episode_steps, unit="step", desc=f"{study.kind} study", dynamic_ncols=True
        )

    def advance(steps: int, label: str) -> None:
        if bar is not None:
            with lock:
                bar.set_postfix_str(label, refresh=False)
                bar.update(steps)

    try:
        if ray is None:
            device = resolve_device(study.device)
        else:
            ray, device = placement(ray, study.device)
        jobs: int | None
        if study.one_batch:
            results, jobs, ray_record = _run_one_batch(study, settings, device, advance), 1, None
        else:
            results, jobs, ray_record = _run_settings(study, settings, device, ray, advance)
        # On Ray, a worker's machine (every setting kept from a run here: this one, which ran them)
        machine = next((r["machine"] for r in results.values() if "machine" in r), None) or machine_info(device)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - start

    rows, entries = [], []
    for i, s in enumerate(settings):
        r = results[i]
        for seed in range(study.seeds):
            row = {
                "prey": s["prey"],
                "fov_angle": s["fov_angle"],
                "view_distance": s["view_distance"],
                "world_width": s["width"],
                "world_height": s["height"],
                "seed": seed,
                "episodes": study.episodes_per_seed,
            }
            row.update({name: float(r["per_seed"][name][seed]) for name in result_metrics()})
            rows.append(row)
        entry = {
            "prey": s["prey"],
            "fov_angle": s["fov_angle"],
            "view_distance": s["view_distance"],
            "world_width": s["width"],
            "world_height": s["height"],
            "worlds": study.seeds * study.episodes_per_seed,
            "wall_s": round(r["wall_s"], 3),
            "agent_steps_per_s": r["agent_steps"] / r["wall_s"],
            "metrics": {name: seed_stats(r["per_seed"][name]) for name in result_metrics()},
            "nn_distribution": [round(float(x), 6) for x in r["nn_distribution"]],
        }
        if "population" in r:
            entry["population"] = {k: [round(float(x), 4) for x in v] for k, v in r["population"].items()}
        entries.append(entry)

    config = dataclasses.asdict(study)
    config["world_size"] = list(study.world_size)
    config["linking_distance"] = results[0]["linking_distance"]
    config["jobs"] = jobs
    config["prey_radius"] = settings[0]["config"].prey.radius
    summary: dict = {
        "study": study.kind,
        "path": (
            "one batch: every setting's worlds in one BatchedAquarium (capacity: the largest prey count)"
            if study.one_batch
            else "one batch per setting"
        ),
        "config": config,
        "definitions": {
            "seed": "seed s = worlds [s*E, (s+1)*E) of one batch per setting (independent random streams); "
            "E = episodes_per_seed; env seed = config.seed",
            "captures": "captures per episode (all predators), per seed the mean over its episodes",
            "captures_per_prey": "captures per episode / initial prey count",
            "sampled metrics": f"mean over an episode's states sampled every {study.metrics_every} steps "
            "(aquarium_warp.metrics), then over the seed's episodes",
            "predator_distance": "mean over live prey of the torus distance to the nearest live predator, px",
            "groups": "connected components of prey closer than linking_distance px",
            "spread": "std and sem over seeds; ci95: half-width of the 95% Student-t interval of the mean",
            "wall_s": "per setting, the wall time of the batch it ran in (with one batch, shared by every setting)",
            "uniform_baseline": UNIFORM_BASELINE_DEFINITION,
        },
        "nn_bin_edges": [float(x) for x in results[0]["nn_bin_edges"]],
        "command": command if command is not None else command_line(),
        "git": git_info(),
        "machine": machine,
        "wall_time_s": round(wall, 2),
        "results": entries,
    }
    if ray is None:
        add_uniform_baselines(summary, study, device)
    else:
        summary["ray"] = ray_record
        summary = run_ray_tasks(_baselines_on_worker, [(summary, study, device)], ray)[0]
    write_csv(os.path.join(study.out, f"{study.basename}.csv"), rows)
    with atomic_open(os.path.join(study.out, f"{study.basename}.json")) as f:
        json.dump(json_safe(summary), f, indent=1)
    # swarm_size.json now holds every setting
    shutil.rmtree(os.path.join(study.out, FINISHED_DIR), ignore_errors=True)
    if study.figures:
        summary["figures"] = plot_study(summary, study.out)
    return summary


def study_from_config(config: dict) -> SwarmSizeStudy:
    """The `SwarmSizeStudy` recorded in a `swarm_size.json`'s "config"."""
    names = {f.name for f in dataclasses.fields(SwarmSizeStudy)}
    kwargs = {k: v for k, v in config.items() if k in names}
    kwargs["world_size"] = tuple(kwargs.get("world_size", (800.0, 800.0)))
    return SwarmSizeStudy(**kwargs)


def replot_study(out: str, device=None) -> dict:
    """Redraw the figures of the study in `out` from its `swarm_size.json` (no simulation), first adding
    the uniform-random baselines if the file lacks them. Returns the summary."""
    from ..device import resolve_device

    path = os.path.join(out, "swarm_size.json")
    if not os.path.isfile(path):
        raise ValueError(f"{path} does not exist: run the study first")
    with open(path, encoding="utf-8") as f:
        summary = json.load(f)
    if not all("uniform_baseline" in e for e in summary["results"]):
        study = study_from_config(summary["config"])
        add_uniform_baselines(summary, study, resolve_device(device))
        summary["definitions"]["uniform_baseline"] = UNIFORM_BASELINE_DEFINITION
        with atomic_open(path) as f:
            json.dump(json_safe(summary), f, indent=1)
    summary["figures"] = plot_study(summary, out)
    return summary


# --------------------------------------------------------------------------------------------------
# Command line: `aquarium-warp study swarm-size` (and the options `study fov-view` shares)
# --------------------------------------------------------------------------------------------------
HELP = "captures per prey (dilution), polarization and groups vs prey count"
DESCRIPTION = (
    "Run every prey count and seed as batched worlds, one episode each, and write swarm_size.csv/json "
    "and figures into --out."
)


# The options of `study swarm-size` that `study fov-view` takes too (its own sweep in `fov_view.FovView`).
RUN_OPTIONS = (
    "seeds",
    "episodes_per_seed",
    "episode_steps",
    "prey_policy",
    "predator_policy",
    "confusion",
    "predators",
    "world_size",
    "linking_distance",
    "metrics_every",
    "device",
    "seed",
    "jobs",
    "figures",
)


def add_output_arguments(p: argparse.ArgumentParser, out: str) -> None:
    """The output options of both swarm-size subcommands (not settings of the study's results)."""
    p.add_argument("--out", default=out, help=f"output directory (default {out})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, SwarmSizeStudy)
    add_output_arguments(p, "swarm_size")
    p.add_argument("--replot", action="store_true", help="only redraw the figures from --out's swarm_size.json")
    add_ray_arguments(p, "setting (prey count, FOV angle and view distance)")


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study swarm-size`: captures, polarization and groups vs the number of prey."""
    if args.replot:
        summary = replot_study(args.out, device=args.device)
        print(f"redrew {len(summary['figures'])} figures in {args.out} from swarm_size.json")
        return 0
    ray = ray_options(args)
    if ray is not None and args.jobs is not None:
        raise ValueError(
            "--jobs sets the threads of a run on this machine; with --ray each setting is a task "
            "(--cpus-per-task, --gpus-per-task)"
        )
    if ray is not None and args.one_batch:
        raise ValueError("--one-batch runs every setting in one batch on this machine: not with --ray")
    study = from_options(SwarmSizeStudy, args, out=args.out)
    print(
        f"aquarium-warp study swarm-size: prey {study.prey}, {plural(study.seeds, 'seed')} x "
        f"{plural(study.episodes_per_seed, 'episode')} of {plural(study.episode_steps, 'step')}, "
        f"{study.prey_policy} vs {study.predator_policy} -> {study.out}"
    )
    check_output_dir(study.out, "--out")
    summary = run_swarm_size_study(study, progress=not args.no_progress, ray=ray, command=command_line(args.argv))
    where = summary["machine"]["device_name"]
    if ray is not None:
        where = f"Ray ({len(summary['ray']['nodes'])} machine(s), {summary['ray']['settings_kept']} setting(s) kept)"
    print(
        f"wrote {os.path.join(study.out, 'swarm_size.csv')}, swarm_size.json and {len(summary.get('figures', []))} "
        f"figures in {summary['wall_time_s']:.1f} s on {where} ({summary['path']})"
    )
    return 0
