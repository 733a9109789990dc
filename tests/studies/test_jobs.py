"""The studies' job runner (`aquarium_warp.jobs.run_jobs`): finished tasks are kept under
`out/finished/` keyed on the task and the study's settings, so that a rerun with more seeds runs only
the new (setting, seed) tasks and keeps the old rows, while a changed setting runs afresh; threads return
the results in task order; tasks spread over several devices get one each, which their keys do not
hold, so a rerun on other devices keeps them."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import re
import threading

import pytest

from aquarium_warp.cli import main
from aquarium_warp.jobs import FINISHED_DIR, read_finished, run_jobs, task_key


@dataclasses.dataclass
class Study:
    seeds: int = 2
    scale: float = 1.0
    out: str = "out"
    jobs: int | None = None
    figures: bool = True
    device: str | None = None

    def tasks(self) -> list[dict]:
        return [
            {"name": f"x{x}_seed{seed}", "x": x, "seed": seed, "study": self}
            for x in (1, 2)
            for seed in range(self.seeds)
        ]


class Counted:
    """`x * scale + seed` of a task, counting the calls (thread-safe)."""

    def __init__(self):
        self.names: list[str] = []
        self.lock = threading.Lock()

    def __call__(self, task: dict) -> dict:
        with self.lock:
            self.names.append(task["name"])
        return {"value": task["x"] * task["study"].scale + task["seed"]}


def test_more_seeds_run_only_the_new_tasks_and_keep_the_old_results(tmp_path):
    out = str(tmp_path)
    first = Counted()
    run = run_jobs(first, Study(seeds=2).tasks(), out, report=None)
    assert run.kept == 0 and sorted(first.names) == ["x1_seed0", "x1_seed1", "x2_seed0", "x2_seed1"]
    assert len(list((tmp_path / FINISHED_DIR).iterdir())) == 4
    more = Counted()
    lines: list[str] = []
    run = run_jobs(more, Study(seeds=3).tasks(), out, report=lines.append)
    assert sorted(more.names) == ["x1_seed2", "x2_seed2"] and run.kept == 4
    assert [r["value"] for r in run.results] == [1.0, 2.0, 3.0, 2.0, 3.0, 4.0]  # task order, kept ones included
    assert lines[0] == f"  run: 4 of 6 tasks kept from {tmp_path / FINISHED_DIR}"
    # Another setting of the study is another computation: every task runs again.
    other = Counted()
    assert run_jobs(other, Study(seeds=3, scale=2.0).tasks(), out, report=None).kept == 0 and len(other.names) == 6
    # Where it writes, its workers, figures and device option are not: the tasks are kept.
    same = Counted()
    moved = Study(seeds=3, scale=2.0, out="elsewhere", jobs=4, figures=False, device="cpu")
    assert run_jobs(same, moved.tasks(), out, report=None).kept == 6 and same.names == []


@dataclasses.dataclass
class StudyWithAxes(Study):
    """`xs` only lists which tasks exist (each task carries its `x`): a `TASK_AXES` entry."""

    TASK_AXES = ("xs",)
    xs: tuple = (1, 2)

    def tasks(self) -> list[dict]:
        return [{"name": f"x{x}_seed{s}", "x": x, "seed": s, "study": self} for x in self.xs for s in range(self.seeds)]


def test_a_run_over_fewer_or_more_task_axes_keeps_the_tasks_they_share(tmp_path):
    out = str(tmp_path)
    run_jobs(Counted(), StudyWithAxes(xs=(1, 2)).tasks(), out, report=None)
    fewer = Counted()
    assert run_jobs(fewer, StudyWithAxes(xs=(2,)).tasks(), out, report=None).kept == 2 and fewer.names == []
    more = Counted()
    assert run_jobs(more, StudyWithAxes(xs=(2, 3)).tasks(), out, report=None).kept == 2
    assert sorted(more.names) == ["x3_seed0", "x3_seed1"]
    # A setting that is not an axis still changes every task's key.
    other = Counted()
    assert run_jobs(other, StudyWithAxes(xs=(2,), scale=3.0).tasks(), out, report=None).kept == 0


def test_the_studies_task_axes_are_their_settings():
    from aquarium_warp.studies.group_hunting import GroupHuntingStudy
    from aquarium_warp.studies.many_eyes import ManyEyesStudy

    for study in (GroupHuntingStudy, ManyEyesStudy):
        fields = {f.name for f in dataclasses.fields(study)}
        assert study.TASK_AXES and set(study.TASK_AXES) <= fields


def test_the_key_leaves_out_the_seed_count_and_the_task_s_output_folder():
    task = dict(Study(seeds=2).tasks()[0], policy_dir="out/policies/x1_seed0")
    key = task_key(task)
    assert key == task_key(dict(Study(seeds=7).tasks()[0], policy_dir="elsewhere"))
    assert key["task"] == {"name": "x1_seed0", "x": 1, "seed": 0} and "seeds" not in key["study"]


def test_threads_return_results_in_task_order_and_call_back_each(tmp_path):
    seen: list[tuple[int, bool]] = []
    prepared: list[bool] = []
    run = run_jobs(
        Counted(),
        Study(seeds=3).tasks(),
        str(tmp_path),
        jobs=3,
        threads=True,
        report=None,
        prepare=lambda: prepared.append(True),
        on_result=lambda i, result, kept: seen.append((i, kept)),
    )
    assert [r["value"] for r in run.results] == [1.0, 2.0, 3.0, 2.0, 3.0, 4.0]
    assert prepared == [True] and sorted(seen) == [(i, False) for i in range(6)]
    seen.clear()
    run_jobs(
        Counted(),
        Study(seeds=3).tasks(),
        str(tmp_path),
        jobs=3,
        threads=True,
        report=None,
        prepare=lambda: prepared.append(True),
        on_result=lambda i, result, kept: seen.append((i, kept)),
    )
    assert seen == [(i, True) for i in range(6)] and prepared == [True]  # nothing left to run: no warm-up


class Located(Counted):
    """`Counted` that is given a device, and records it."""

    def __init__(self):
        super().__init__()
        self.devices: list[str] = []

    def __call__(self, task: dict, device: str) -> dict:
        self.devices.append(device)
        return super().__call__(task)


def on_device(task: dict, device: str) -> dict:
    """A worker process's task: its value, the device it was given and the process it ran in."""
    return {"value": task["x"] * task["study"].scale + task["seed"], "device": device, "process": os.getpid()}


def test_one_device_runs_here_and_gives_each_task_the_device(tmp_path):
    here = Located()
    run = run_jobs(here, Study(seeds=2).tasks(), str(tmp_path), devices=["cpu"], report=None)
    assert [r["value"] for r in run.results] == [1.0, 2.0, 2.0, 3.0] and here.devices == ["cpu"] * 4
    # The device is not part of a task's key: a run on other devices keeps every task.
    for task in Study(seeds=2).tasks():
        assert "device" not in task_key(task)["task"] and read_finished(str(tmp_path), task) == (
            True,
            {"value": task["x"] + task["seed"]},
        )
    again = Located()
    assert (
        run_jobs(again, Study(seeds=2).tasks(), str(tmp_path), devices=["cpu", "cpu"], jobs=2, report=None).kept == 4
        and again.devices == []
    )


@pytest.mark.slow
def test_two_devices_run_in_a_worker_process_each_and_a_rerun_keeps_all(tmp_path):
    tasks = Study(seeds=2).tasks()
    run = run_jobs(on_device, tasks, str(tmp_path), devices=["cpu", "cpu"], report=None, prepare=lambda: None)
    assert [r["value"] for r in run.results] == [1.0, 2.0, 2.0, 3.0] and {r["device"] for r in run.results} == {"cpu"}
    processes = {r["process"] for r in run.results}
    assert len(processes) == 2 and os.getpid() not in processes  # one worker per device (jobs=1 on each)
    for task in tasks:
        with open(tmp_path / FINISHED_DIR / f"{task['name']}.json", encoding="utf-8") as f:
            assert json.load(f)["key"] == task_key(task)
    here = Located()
    rerun = run_jobs(here, tasks, str(tmp_path), devices=["cpu"], report=None)
    assert rerun.kept == 4 and here.devices == [] and rerun.results == run.results


@pytest.mark.parametrize(
    "options, message",
    [
        ({"devices": []}, "devices=[] must name at least one device"),
        ({"devices": ["cpu"], "threads": True}, "devices spread tasks over worker processes of this machine"),
        ({"devices": ["cpu", "cpu"], "jobs": 0}, "jobs=0 must be an integer >= 1"),
    ],
)
def test_bad_devices_are_refused(tmp_path, options, message):
    with pytest.raises(ValueError, match="^" + re.escape(message)):
        run_jobs(Located(), Study().tasks(), str(tmp_path), report=None, **options)
    assert not (tmp_path / FINISHED_DIR).exists()


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_a_rerun_with_more_seeds_trains_only_the_new_seeds(tmp_path, capsys, one_thread):
    argv = [
        "study",
        "many-eyes",
        "--group-sizes",
        "1",
        "--fov",
        "120",
        "--rows",
        "4",
        "--iterations",
        "1",
        "--train-steps",
        "20",
        "--eval-rows",
        "4",
        "--eval-steps",
        "30",
        "--no-turnaway",
        "--device",
        "cpu",
        "--no-figures",
        "--out",
        str(tmp_path),
    ]
    assert main(argv + ["--seeds", "1"]) == 0
    first = read_csv(tmp_path / "many_eyes.csv")
    capsys.readouterr()
    assert main(argv + ["--seeds", "2"]) == 0
    out = capsys.readouterr().out
    assert "1 of 2 tasks kept" in out and "many-eyes 2/2 (learned_N1_fov120_seed1)" in out
    rows = read_csv(tmp_path / "many_eyes.csv")
    assert [r for r in rows if r["seed"] == "0"] == first  # the old rows, timings included: nothing rerun
    assert sorted({r["seed"] for r in rows}) == ["0", "1"] and len(rows) == 2 * len(first)
    assert (tmp_path / "policies" / "learned_N1_fov120_seed1").is_dir()


@pytest.mark.slow
def test_training_tasks_train_together_as_populations_each_as_alone(tmp_path):
    """Training tasks of a study (`run_training_task`) that may share a process become populations:
    with 2 runs per process, 3 tasks train as a population of 2 and one alone, each into its own folder
    with the parameters the same config trains alone (bit for bit on the CPU), its policy exported;
    a rerun keeps all three."""
    import torch

    from aquarium_warp.studies.common import policy_path, run_training_task
    from aquarium_warp.training import Trainer, make_config

    def config(seed: int, view: float) -> dict:
        train = {"num_worlds": 4, "iterations": 2, "quiet": True, "export": [], "metrics_every": 0, "seed": seed}
        cfg = make_config("tiny", {"train": train, "runner": {"num_steps_per_env": 8}})
        cfg["env"]["prey"] = {"view_distance": view}
        return cfg

    tasks = [{"name": f"s{s}-v{v}", "seed": s, "config": config(s, v), "run_dir": str(tmp_path / f"run-{s}-{v}")}
             for s, v in ((0, 100.0), (1, 100.0), (0, 150.0))]  # fmt: skip
    lines: list[str] = []
    run = run_jobs(run_training_task, tasks, str(tmp_path / "out"), devices=["cpu"], runs_per_process=2,
                   report=lines.append)  # fmt: skip
    assert sorted(r.get("population", 1) for r in run.results) == [1, 2, 2]  # a population of 2, one alone
    assert any("populations of up to 2 (given)" in line for line in lines)
    for task in tasks:
        assert os.path.isfile(policy_path(task["run_dir"]))
        saved = torch.load(os.path.join(task["run_dir"], "model_1.pt"), weights_only=False)
        alone = Trainer(task["config"])
        alone.train()
        for name, value in alone.runner.alg.actor.state_dict().items():
            assert torch.equal(saved["actor_state_dict"][name], value), f"{task['name']}: {name}"
        alone.close()
    again = run_jobs(run_training_task, tasks, str(tmp_path / "out"), devices=["cpu"], runs_per_process=2)
    assert again.kept == 3
