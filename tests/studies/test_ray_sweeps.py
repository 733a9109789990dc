"""Sweeps on Ray (aquarium_warp/jobs.py) on a local two-CPU cluster: a tiny study equals the run on this
machine; a setting whose worker dies is rerun (Ray's max_retries) and, once the retries are spent, a rerun
of the study keeps the settings that finished; a training sweep equals the runs here and a rerun keeps
them; a started training run resumes from its newest checkpoint; without Ray, --ray names the extra."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time

import pytest
import torch

from aquarium_warp.cli import main
from aquarium_warp.jobs import FINISHED_DIR, RayOptions
from aquarium_warp.records import json_safe
from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_swarm_size_study

TINY_TRAIN = [
    "--preset",
    "tiny",
    "--iterations",
    "2",
    "--save-interval",
    "1",
    "--num-worlds",
    "4",
    "--num-steps-per-env",
    "8",
    "--export",
    "none",
    "--quiet",
    "--device",
    "cpu",
]


def dying_setting_hook(plan: str, died: str):
    """A Ray worker setup hook: where the file `plan` exists, the first setting of `plan`'s prey count to
    start kills its worker (as a crash or an OOM kill would), after waiting for the file that `plan` names
    if any; `died` marks that it happened (the retry then runs normally)."""

    def setup() -> None:
        import aquarium_warp.studies.swarm_size as study

        run_setting = study.run_setting

        def run_or_die(s, setting, device, progress=None):
            if os.path.exists(plan) and not os.path.exists(died):
                with open(plan, encoding="utf-8") as f:
                    target = json.load(f)
                if setting["prey"] == target["prey"]:
                    deadline = time.monotonic() + 60
                    while target["wait_for"] and not os.path.exists(target["wait_for"]) and time.monotonic() < deadline:
                        time.sleep(0.05)
                    open(died, "w").close()
                    os._exit(1)
            return run_setting(s, setting, device, progress)

        study.run_setting = run_or_die

    return setup


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """One local Ray session of two CPUs for the module (starting one takes seconds)."""
    ray = pytest.importorskip("ray")
    marks = tmp_path_factory.mktemp("ray_marks")
    plan, died = str(marks / "plan.json"), str(marks / "died")
    ray.init(
        num_cpus=2, include_dashboard=False, runtime_env={"worker_process_setup_hook": dying_setting_hook(plan, died)}
    )
    yield ray, plan, died
    ray.shutdown()


def tiny_study(out) -> SwarmSizeStudy:
    return SwarmSizeStudy(
        prey=[4, 8], seeds=2, episode_steps=30, metrics_every=5, device="cpu", figures=False, out=str(out)
    )


TIMINGS = ("wall_s", "agent_steps_per_s")


def assert_same_study(here: dict, on_ray: dict, out_here, out_ray) -> None:
    """Same CSV bytes, same JSON numbers (timings aside)."""
    assert (out_ray / "swarm_size.csv").read_bytes() == (out_here / "swarm_size.csv").read_bytes()
    assert on_ray["nn_bin_edges"] == here["nn_bin_edges"]
    # As the JSON holds them: an undefined metric (NaN, e.g. local alignment without linked prey) is null.
    assert json_safe([{k: v for k, v in e.items() if k not in TIMINGS} for e in on_ray["results"]]) == json_safe(
        [{k: v for k, v in e.items() if k not in TIMINGS} for e in here["results"]]
    )
    assert not (out_ray / FINISHED_DIR).exists()  # swarm_size.json holds every setting now


@pytest.mark.slow
def test_study_on_ray_equals_the_run_here(ray_cluster, tmp_path):
    here = run_swarm_size_study(tiny_study(tmp_path / "here"), progress=False)
    on_ray = run_swarm_size_study(tiny_study(tmp_path / "ray"), progress=False, ray=RayOptions())
    assert_same_study(here, on_ray, tmp_path / "here", tmp_path / "ray")
    assert on_ray["ray"]["gpus_per_task"] == 0 and on_ray["ray"]["device"] == "cpu"
    assert on_ray["ray"]["settings_kept"] == 0 and len(on_ray["ray"]["nodes"]) == 1
    assert on_ray["config"]["jobs"] is None and on_ray["machine"]["device"] == "cpu"


@pytest.mark.slow
def test_a_dead_worker_is_rerun_and_finished_settings_are_kept(ray_cluster, tmp_path):
    ray, plan, died = ray_cluster
    here = run_swarm_size_study(tiny_study(tmp_path / "here"), progress=False)
    try:
        dead_workers_rerun_and_kept(ray, plan, died, here, tmp_path)
    finally:
        os.remove(plan)


def dead_workers_rerun_and_kept(ray, plan, died, here, tmp_path):
    # The N=8 setting's worker dies once: Ray reruns that task, and the study is complete and equal.
    with open(plan, "w", encoding="utf-8") as f:
        json.dump({"prey": 8, "wait_for": None}, f)
    on_ray = run_swarm_size_study(tiny_study(tmp_path / "retried"), progress=False, ray=RayOptions(max_retries=1))
    assert os.path.exists(died)
    assert_same_study(here, on_ray, tmp_path / "here", tmp_path / "retried")
    # No retries left: the study fails once N=4 has finished (its worker waits for N=4's kept file)...
    os.remove(died)
    kept = tmp_path / "kept" / FINISHED_DIR / "prey4_fov120_view100.json"
    with open(plan, "w", encoding="utf-8") as f:
        json.dump({"prey": 8, "wait_for": str(kept)}, f)
    with pytest.raises(ray.exceptions.RayError):
        run_swarm_size_study(tiny_study(tmp_path / "kept"), progress=False, ray=RayOptions(max_retries=0))
    assert os.path.exists(died) and kept.exists()
    # ...and a rerun runs N=8 only, keeping N=4: the same study as here.
    on_ray = run_swarm_size_study(tiny_study(tmp_path / "kept"), progress=False, ray=RayOptions())
    assert on_ray["ray"]["settings_kept"] == 1
    assert_same_study(here, on_ray, tmp_path / "here", tmp_path / "kept")


def checkpoint_tensors(path) -> dict:
    """Every tensor of a checkpoint's `*state_dict` entries (networks and optimizers, every team's)."""
    out = {}

    def walk(value, name, in_state):
        if isinstance(value, dict):
            for k, v in value.items():
                walk(v, f"{name}/{k}", in_state or str(k).endswith("state_dict"))
        elif isinstance(value, torch.Tensor) and in_state:
            out[name] = value

    walk(torch.load(path, map_location="cpu", weights_only=False), "", False)
    assert out, f"{path}: no state_dict tensors"
    return out


def assert_same_checkpoints(a, b) -> None:
    ta, tb = checkpoint_tensors(a), checkpoint_tensors(b)
    assert ta.keys() == tb.keys()
    assert all(torch.equal(ta[k], tb[k]) for k in ta)


@pytest.mark.slow
def test_training_sweep_on_ray_equals_the_runs_here_and_a_rerun_keeps_them(ray_cluster, tmp_path, one_thread):
    assert main(["sweep", "train", "--seeds", "0", "--out", str(tmp_path / "here"), *TINY_TRAIN]) == 0
    on_ray = ["sweep", "train", "--seeds", "0,1", "--out", str(tmp_path / "ray"), *TINY_TRAIN, "--ray"]
    assert main(on_ray) == 0
    assert_same_checkpoints(tmp_path / "here" / "seed0" / "model_1.pt", tmp_path / "ray" / "seed0" / "model_1.pt")
    summary = json.loads((tmp_path / "ray" / "sweep.json").read_text())
    assert [(r["seed"], r["status"], r["kept"]) for r in summary["runs"]] == [(0, "done", False), (1, "done", False)]
    assert summary["ray"]["gpus_per_task"] == 0
    assert main(on_ray) == 0  # a rerun keeps both runs
    summary = json.loads((tmp_path / "ray" / "sweep.json").read_text())
    assert [r["kept"] for r in summary["runs"]] == [True, True]


@pytest.mark.slow
def test_a_started_training_run_resumes_from_its_newest_checkpoint(tmp_path, one_thread):
    """A run whose worker died after its first checkpoint: the rerun resumes there and ends where an
    uninterrupted run ends."""
    assert main(["sweep", "train", "--seeds", "3", "--out", str(tmp_path), *TINY_TRAIN]) == 0
    run_dir = tmp_path / "seed3"
    uninterrupted = tmp_path / "uninterrupted.pt"
    os.replace(run_dir / "model_1.pt", uninterrupted)
    record = json.loads((run_dir / "sweep_run.json").read_text())
    (run_dir / "sweep_run.json").write_text(json.dumps(dict(record, status="running")))
    assert main(["sweep", "train", "--seeds", "3", "--out", str(tmp_path), *TINY_TRAIN]) == 0
    record = json.loads((run_dir / "sweep_run.json").read_text())
    assert record["status"] == "done" and record["resumed_from"].endswith("model_0.pt")
    assert_same_checkpoints(uninterrupted, run_dir / "model_1.pt")
    # Other options into the same directory: refused rather than mixed.
    assert main(["sweep", "train", "--seeds", "3", "--out", str(tmp_path), *TINY_TRAIN, "--gamma", "0.9"]) == 2


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["study", "swarm-size", "--ray", "--jobs", "2"], "--jobs"),
        (["study", "swarm-size", "--gpus-per-task", "1"], "give --ray too"),
        (["study", "swarm-size", "--ray", "--gpus-per-task", "1.5"], "gpus_per_task=1.5"),
        (["sweep", "train", "--seeds", "0,0"], "each once"),
        (["sweep", "train", "--seeds", "0", "--seed", "1"], "--seeds"),
        (["sweep", "train", "--vary", "train.sharing"], "--vary"),
        (["sweep", "train", "--vary", "sharing=parameter"], "env., train., runner. or teams."),
    ],
)
def test_bad_sweep_options_are_one_line_errors(capsys, argv, expected):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert expected in err and len(err.strip().splitlines()) == 1


def test_ray_missing_names_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as when it is not installed
    argv = [
        "study",
        "swarm-size",
        "--prey",
        "4",
        "--seeds",
        "1",
        "--episode-steps",
        "5",
        "--device",
        "cpu",
        "--out",
        str(tmp_path),
        "--no-progress",
        "--ray",
    ]
    assert main(argv) == 2
    assert "pip install 'aquarium-warp[distributed]'" in capsys.readouterr().err


def test_sweep_runs_are_settings_by_seeds(tmp_path):
    from aquarium_warp.training.sweep import TrainingSweep, parse_vary

    assert parse_vary("runner.actor.hidden_dims=[64,64],[32]") == ("runner.actor.hidden_dims", ("[64,64]", "[32]"))
    sweep = TrainingSweep(seeds=(0, 1), vary=(parse_vary("train.sharing=parameter,individual"),), out=str(tmp_path))
    sweep.validate()
    runs = sweep.runs()
    assert [(r.seed, r.sets) for r in runs] == [
        (0, ("train.sharing=parameter",)),
        (1, ("train.sharing=parameter",)),
        (0, ("train.sharing=individual",)),
        (1, ("train.sharing=individual",)),
    ]
    assert runs[3].run_dir == os.path.join(str(tmp_path), "train.sharing=individual", "seed1")
    assert dataclasses.replace(sweep, vary=()).runs()[0].run_dir == os.path.join(str(tmp_path), "seed0")


def csv_rows(path) -> list[dict]:
    import csv

    with open(path, encoding="utf-8", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_open_question_study_on_ray_equals_the_run_here(ray_cluster, tmp_path, one_thread):
    """`study group-hunting --ray`: every training run (and the NaivChase baseline) is a Ray task whose
    worker writes its policies; the rows equal those of the run here (timings aside), the JSON names the
    Ray run, a rerun keeps every task, and --jobs is refused beside --ray."""
    argv = [
        "study",
        "group-hunting",
        "--predators",
        "1,2",
        "--prey-conditions",
        "turnaway",
        "--share-radius",
        "100",
        "--seeds",
        "1",
        "--worlds",
        "4",
        "--iterations",
        "2",
        "--train-steps",
        "40",
        "--eval-worlds",
        "2",
        "--eval-steps",
        "40",
        "--device",
        "cpu",
        "--no-figures",
    ]
    assert main(argv + ["--out", str(tmp_path / "here")]) == 0
    on_ray = argv + ["--out", str(tmp_path / "ray"), "--ray"]
    assert main(on_ray) == 0
    here, ray_rows = (csv_rows(tmp_path / name / "group_hunting.csv") for name in ("here", "ray"))
    assert len(ray_rows) == 4  # turnaway and naivchase, 1 and 2 predators
    untimed = [[{k: v for k, v in r.items() if not k.endswith("_s")} for r in rows] for rows in (here, ray_rows)]
    assert untimed[0] == untimed[1]
    record = json.loads((tmp_path / "ray" / "group_hunting.json").read_text())
    assert record["jobs"] is None and record["tasks_kept"] == 0
    assert record["ray"]["device"] == "cpu" and record["ray"]["gpus_per_task"] == 0
    assert len(record["ray"]["nodes"]) == 1
    assert (tmp_path / "ray" / "policies" / "turnaway_share100_pred2_seed0").is_dir()
    assert main(on_ray) == 0  # a rerun keeps every task
    assert json.loads((tmp_path / "ray" / "group_hunting.json").read_text())["tasks_kept"] == 4
    assert main(on_ray + ["--jobs", "2"]) == 2
