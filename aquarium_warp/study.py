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
configuration, the machine, timings, per-setting means/std/sem over seeds, nearest-neighbour
distributions, population traces when populations change) and PNG figures (`aquarium_warp.study_plots`):
`captures_vs_size.png` (dilution), `polarization_groups_vs_size.png`, `spacing_vs_size.png`,
`nn_distribution.png` and, with population dynamics, `population.png`.

```python
from aquarium_warp.study import SwarmSizeStudy, run_swarm_size_study
results = run_swarm_size_study(SwarmSizeStudy(prey=[4, 8, 16], seeds=2, episode_steps=200, out="out"))
```

With `ray=RayOptions(...)` (`aquarium_warp.ray_tasks`; `--ray` on the command line) every setting is a
Ray task calling the same `run_setting`, and the files are the same.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import platform
import shutil
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch

from .atomic import atomic_open
from .bench.machine import git_info, machine_info
from .config import AquariumConfig
from .device import resolve_device
from .drivers import check_spec, is_heuristic, make_driver
from .env import BatchedAquarium
from .json_records import json_safe
from .metrics import EPISODE_METRICS, EpisodeMetrics, SwarmMetrics
from .number_lists import check_distinct
from .number_lists import parse_list as parse_list  # re-exported: the study's list options use it
from .pretrained import is_policy_file
from .ray_tasks import RayOptions, placement, run_tasks
from .rollout import Observer, Progress, rollout
from .seeding import baseline_seed
from .study_plots import plot_study

# Per-seed columns of the CSV, in order.
RESULT_METRICS = ("captures", "captures_per_prey") + EPISODE_METRICS + ("episode_length",)
POPULATION_TRACES = ("prey_alive", "predator_alive")
# The "definitions" entry of swarm_size.json for the baselines (written by the study and by replot).
UNIFORM_BASELINE_DEFINITION = ("the same metrics for uniformly random prey and predator positions and headings "
                               "(same arena and N; mean over snapshots of about 65k prey in all)")


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
    """Settings of a swarm-size study (the CLI's options)."""

    prey: list[int] = field(default_factory=lambda: [4 * 2 ** k for k in range(11)])  # 4 .. 4096
    seeds: int = 5
    episodes_per_seed: int = 1
    episode_steps: int = 3000
    prey_policy: str = "turnaway"
    predator_policy: str = "naivchase"
    confusion: bool = True  # NaivChase: a random visible prey each step (False: the nearest)
    predators: int = 1
    fov_angles: list[float] | None = None  # prey field of view, degrees (None: the config's, 120)
    view_distances: list[float] | None = None  # prey view distance, px (None: the config's, 100)
    world_size: tuple[float, float] = (800.0, 800.0)
    constant_density: bool = False  # scale the arena with N so that N / area stays that of reference_prey
    reference_prey: int = 16
    linking_distance: float | None = None  # px (None: 2.5 prey radii)
    metrics_every: int = 10
    respawn: bool = True
    reproduction: bool = False
    max_prey_factor: float = 2.0  # with reproduction: max_prey = factor x N
    starvation_steps: int | None = None  # None: the config's (3000)
    device: str | None = None
    seed: int = 0
    jobs: int | None = None  # settings run at once on the CPU (threads); None: the CPU's cores; GPU: 1
    out: str = "swarm_size"
    figures: bool = True
    one_batch: bool = False  # every setting in one batch (worlds of setting i: its prey count, FOV and view)
    kind: str = "swarm-size"  # "swarm-size" or "fov-view": names the output files and figures

    @property
    def basename(self) -> str:
        """The output files' name: swarm_size.csv/json or fov_view.csv/json."""
        return self.kind.replace("-", "_")

    def validate(self) -> None:
        def positive_int(name, value):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}={value!r} must be an integer >= 1")

        if not self.prey:
            raise ValueError("prey must list at least one prey count")
        for n in self.prey:
            positive_int("prey count", n)
        for name in ("seeds", "episodes_per_seed", "episode_steps", "predators", "metrics_every", "reference_prey"):
            positive_int(name.replace("_", "-"), getattr(self, name))
        if self.jobs is not None:
            positive_int("jobs", self.jobs)
        for name in ("fov_angles", "view_distances"):
            values = getattr(self, name)
            if values is not None and not values:
                raise ValueError(f"{name} must list at least one value")
        # One rule for every study: a repeated setting would run twice and pool its seeds with its twin's.
        options = ("--fov", "--view") if self.kind == "fov-view" else ("--fov-angle", "--view-distance")
        for option, values in zip(("--prey", *options), (self.prey, self.fov_angles, self.view_distances)):
            check_distinct(option, values or [])
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
            raise ValueError(f"--jobs {self.jobs} runs settings at once, a batch each; one batch holds every setting "
                             "(--one-batch, fov-view's default): drop --jobs, or use one batch per setting "
                             "(fov-view --per-setting)")

    def settings(self) -> list[dict]:
        """One dict per (fov angle, view distance, prey count), with its `AquariumConfig` (where a team is a
        trained policy, its agents observe and act as in the policy's world)."""
        base = AquariumConfig()
        for agent_type, name in (("prey", self.prey_policy), ("predator", self.predator_policy)):
            if not is_heuristic(name, agent_type) and is_policy_file(name):
                base = base.with_interface_of(trained_policy_world(name))
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
                    changes = dict(width=float(width), height=float(height), prey_count=int(n),
                                   predator_count=self.predators, max_steps=self.episode_steps,
                                   respawn_captured_prey=self.respawn,
                                   prey=dataclasses.replace(base.prey, fov_angle=float(fov), view_distance=float(view)))
                    if self.reproduction:
                        changes.update(prey_reproduction=True,
                                       max_prey=max(int(n), int(round(self.max_prey_factor * n))))
                    if self.starvation_steps is not None:
                        changes["predator_starvation_steps"] = self.starvation_steps
                    out.append({"prey": int(n), "fov_angle": float(fov), "view_distance": float(view),
                                "width": float(width), "height": float(height), "config": base.replace(**changes)})
        return out

    @property
    def population_changes(self) -> bool:
        """Whether populations can change within an episode (then population traces are recorded)."""
        starve = (self.starvation_steps if self.starvation_steps is not None
                  else AquariumConfig().predator_starvation_steps)
        return (not self.respawn) or self.reproduction or starve < self.episode_steps


# --------------------------------------------------------------------------------------------------
# Policies
# --------------------------------------------------------------------------------------------------
def trained_policy_world(path: str) -> AquariumConfig:
    """The world the policy file at `path` was trained in (from its metadata)."""
    try:  # the training extra is optional
        from .training.config import env_config
        from .training.export import policy_world
    except ImportError as error:
        raise ValueError(f"trained policies need aquarium_warp.training (importing it failed: {error})") from error
    return env_config({"env": policy_world(path)})


def check_policies(study: SwarmSizeStudy) -> None:
    """Fail early (before any simulation) on policy names that are neither heuristics nor files."""
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
    start = time.perf_counter()
    env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=study.seed)
    prey = make_driver(study.prey_policy, env, "prey", confusion=study.confusion)
    predator = make_driver(study.predator_policy, env, "predator", confusion=study.confusion)
    metrics = SwarmMetrics(env, linking_distance=study.linking_distance)
    trace = POPULATION_TRACES if study.population_changes else ()
    episodes = EpisodeMetrics(env, metrics=metrics, every=study.metrics_every, trace=trace)
    observers: list[Observer] = [episodes] if progress is None else [episodes, Progress(progress, every=25)]
    rollout(env, {"prey": prey, "predator": predator}, study.episode_steps, observers)
    out = {"worlds": {k: v.detach().cpu().double().numpy() for k, v in episodes.result().items()},
           "nn_bin_edges": metrics.bin_edges.numpy(), "linking_distance": metrics.linking_distance}
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
    per_seed = {name: result[name].reshape(study.seeds, E).mean(axis=1) for name in RESULT_METRICS}
    out = {"per_seed": per_seed, "nn_distribution": result["nn_distribution"].mean(axis=0),
           "nn_bin_edges": batch["nn_bin_edges"], "linking_distance": batch["linking_distance"],
           "wall_s": batch["wall_s"], "agent_steps": batch["agent_steps"]}
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
    batch = _run_batch(study, one_batch_config(study, settings), block * len(settings), device,
                       progress=lambda n: advance(n * len(settings), "one batch"))
    return {i: _setting_result(study, batch, i * block, f"N={s['prey']} fov={s['fov_angle']:g} "
                                                         f"view={s['view_distance']:g}")
            for i, s in enumerate(settings)}


BASELINE_METRICS = ("polarization", "cohesion", "nn_mean", "groups", "largest_group", "predator_distance")


def uniform_baseline(cfg: AquariumConfig, worlds: int, linking_distance: float | None, device: str,
                     seed: int) -> dict[str, float]:
    """The metrics of `worlds` snapshots of uniformly random prey and predators with uniformly random
    headings (prey that ignore each other and the predator), in `cfg`'s arena, by the same kernels:
    the reference each measured curve is read against. Means over the snapshots."""
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
            cache[key] = uniform_baseline(s["config"], snapshots, study.linking_distance, device,
                                          seed=baseline_seed(study.seed, s["prey"]))
        entry["uniform_baseline"] = cache[key]


def _warm_up(study: SwarmSizeStudy, device: str) -> None:
    """Load every kernel module once before settings run on parallel threads."""
    cfg = study.settings()[0]["config"].replace(prey_count=2, max_steps=2)
    if cfg.prey_reproduction:
        cfg = cfg.replace(max_prey=4)
    env = BatchedAquarium(cfg, num_worlds=1, device=device, seed=0)
    prey = make_driver(study.prey_policy, env, "prey", confusion=study.confusion)
    predator = make_driver(study.predator_policy, env, "predator", confusion=study.confusion)
    metrics = SwarmMetrics(env, linking_distance=study.linking_distance)
    metrics.compute()
    env.step({"prey": prey(), "predator": predator()}, validate=False)
    env.close()


def seed_stats(values) -> dict:
    """Mean, std, s.e.m. and n over seeds (NaN seeds left out) and the per-seed values."""
    v = np.asarray(values, dtype=np.float64)
    ok = v[~np.isnan(v)]
    n = len(ok)
    mean = float(ok.mean()) if n else math.nan
    std = float(ok.std(ddof=1)) if n > 1 else (0.0 if n == 1 else math.nan)
    return {"mean": mean, "std": std, "sem": std / math.sqrt(n) if n > 1 else math.nan, "n": n,
            "seeds": [None if math.isnan(x) else float(x) for x in v]}


def _run_here(study: SwarmSizeStudy, settings: list[dict], device: str, advance) -> tuple[dict[int, dict], int]:
    """`run_setting` of every setting on this machine: on the CPU several at once on threads (`study.jobs`),
    on a GPU one after another. Returns the results by setting index and the number of threads."""
    import warp as wp

    on_gpu = wp.get_device(device).is_cuda
    # On a GPU settings run one after another: the batch already fills the device, and a CUDA graph
    # being captured in one thread must not see another thread's launches.
    jobs = 1 if on_gpu else (study.jobs if study.jobs is not None else (os.cpu_count() or 1))
    jobs = max(1, min(jobs, len(settings)))
    _warm_up(study, device)

    def job(index: int) -> dict:
        s = settings[index]
        label = f"N={s['prey']} fov={s['fov_angle']:g} view={s['view_distance']:g}"
        return run_setting(study, s, device, progress=lambda n: advance(n, label))

    order = _largest_first(settings)
    results: dict[int, dict] = {}
    if jobs == 1:
        for i in order:
            results[i] = job(i)
    else:
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            for i, r in zip(order, pool.map(job, order)):
                results[i] = r
    return results, jobs


def _largest_first(settings: list[dict]) -> list[int]:
    """Setting indices, largest worlds first, so that settings run side by side (threads, Ray tasks) finish
    together."""
    return sorted(range(len(settings)), key=lambda i: -settings[i]["config"].capacity)


# --------------------------------------------------------------------------------------------------
# Ray: one task per setting
# --------------------------------------------------------------------------------------------------
# Settings finished on Ray, one JSON file each, kept in the study's `out` until swarm_size.json is
# written: a rerun of the same study skips them (after the driver died, say).
KEPT_DIR = "ray_settings"


def _setting_on_worker(study: SwarmSizeStudy, setting: dict, device: str) -> dict:
    """A Ray task: `run_setting` on the worker's `device`, with the worker's machine and host name."""
    result = run_setting(study, setting, device)
    result["machine"] = machine_info(device)
    result["node"] = platform.node()
    return result


def _baselines_on_worker(summary: dict, study: SwarmSizeStudy, device: str) -> dict:
    """A Ray task: `add_uniform_baselines` on a worker's `device` (this machine may have no GPU)."""
    add_uniform_baselines(summary, study, device)
    return summary


def _kept_path(study: SwarmSizeStudy, setting: dict) -> str:
    name = f"prey{setting['prey']}_fov{setting['fov_angle']:g}_view{setting['view_distance']:g}.json"
    return os.path.join(study.out, KEPT_DIR, name)


def _kept_key(study: SwarmSizeStudy, device: str) -> dict:
    """What a kept result must have been run with: the study's settings (not where it writes) and device."""
    config = {k: v for k, v in dataclasses.asdict(study).items() if k not in ("out", "jobs", "figures", "device")}
    return json.loads(json.dumps({"study": config, "device": device}))  # as read back from a file


def _arrays_as_lists(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _arrays_as_lists(v) for k, v in value.items()}
    return value


def _run_on_ray(study: SwarmSizeStudy, settings: list[dict], ray: RayOptions, device: str,
                advance) -> tuple[dict[int, dict], dict]:
    """`run_setting` of every setting as a Ray task (`ray` placed, on `device`), kept settings
    skipped. Returns the results by setting index and the record of the run for swarm_size.json."""
    key = _kept_key(study, device)
    results: dict[int, dict] = {}
    for i, s in enumerate(settings):
        path = _kept_path(study, s)
        if os.path.isfile(path):
            with open(path, encoding="utf-8") as f:
                kept = json.load(f)
            if kept["key"] == key:
                results[i] = kept["result"]
                advance(study.episode_steps, f"N={s['prey']} kept")
    kept_count = len(results)
    todo = [i for i in _largest_first(settings) if i not in results]
    os.makedirs(os.path.join(study.out, KEPT_DIR), exist_ok=True)

    def finished(k: int, result: dict) -> None:
        i = todo[k]
        # JSON writes a float's shortest repr, which reads back as the same float: kept equals fresh.
        with atomic_open(_kept_path(study, settings[i])) as f:
            json.dump({"key": key, "result": _arrays_as_lists(result)}, f)
        results[i] = result
        advance(study.episode_steps, f"N={settings[i]['prey']} done")

    run_tasks(_setting_on_worker, [(study, settings[i], device) for i in todo], ray, on_result=finished)
    record = {"address": ray.address, "gpus_per_task": ray.gpus_per_task, "cpus_per_task": ray.cpus_per_task,
              "max_retries": ray.max_retries, "device": device, "settings_kept": kept_count,
              "nodes": sorted({results[i]["node"] for i in results})}
    return results, record


def run_swarm_size_study(study: SwarmSizeStudy, progress: bool = True, ray: RayOptions | None = None,
                         command: str | None = None) -> dict:
    """Run every setting of `study`, write the CSV, JSON and figures into `study.out`, and return the
    JSON's content. `ray`: run each setting as a Ray task (`_run_on_ray`) instead of on this machine.
    `command`: the command recorded in the JSON (default: this process's, as `aquarium-warp ...`)."""
    from .studies.common import command_line  # here: aquarium_warp.studies imports this module

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

        bar = tqdm(total=len(settings) * study.episode_steps, unit="step", desc=f"{study.kind} study",
                   dynamic_ncols=True)

    def advance(steps: int, label: str) -> None:
        if bar is not None:
            with lock:
                bar.set_postfix_str(label, refresh=False)
                bar.update(steps)

    try:
        if ray is None:
            device = resolve_device(study.device)
            if study.one_batch:
                results, jobs = _run_one_batch(study, settings, device, advance), 1
            else:
                results, jobs = _run_here(study, settings, device, advance)
            machine = machine_info(device)
        else:
            ray, device = placement(ray, study.device)
            results, ray_record = _run_on_ray(study, settings, ray, device, advance)
            jobs, machine = None, results[0]["machine"]
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - start

    rows, entries = [], []
    for i, s in enumerate(settings):
        r = results[i]
        for seed in range(study.seeds):
            row = {"prey": s["prey"], "fov_angle": s["fov_angle"], "view_distance": s["view_distance"],
                   "world_width": s["width"], "world_height": s["height"], "seed": seed,
                   "episodes": study.episodes_per_seed}
            row.update({name: float(r["per_seed"][name][seed]) for name in RESULT_METRICS})
            rows.append(row)
        entry = {"prey": s["prey"], "fov_angle": s["fov_angle"], "view_distance": s["view_distance"],
                 "world_width": s["width"], "world_height": s["height"],
                 "worlds": study.seeds * study.episodes_per_seed, "wall_s": round(r["wall_s"], 3),
                 "agent_steps_per_s": r["agent_steps"] / r["wall_s"],
                 "metrics": {name: seed_stats(r["per_seed"][name]) for name in RESULT_METRICS},
                 "nn_distribution": [round(float(x), 6) for x in r["nn_distribution"]]}
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
        "path": ("one batch: every setting's worlds in one BatchedAquarium (capacity: the largest prey count)"
                 if study.one_batch else "one batch per setting"),
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
            "spread": "std and sem over seeds",
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
        summary = run_tasks(_baselines_on_worker, [(summary, study, device)], ray)[0]
    write_csv(os.path.join(study.out, f"{study.basename}.csv"), rows)
    with atomic_open(os.path.join(study.out, f"{study.basename}.json")) as f:
        json.dump(json_safe(summary), f, indent=1)
    if ray is not None:  # swarm_size.json now holds every setting
        shutil.rmtree(os.path.join(study.out, KEPT_DIR), ignore_errors=True)
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


def write_csv(path: str, rows: list[dict]) -> None:
    with atomic_open(path, newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
