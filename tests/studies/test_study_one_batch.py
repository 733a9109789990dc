"""Every setting of a study in one batch (per-world prey counts, FOV angles and view distances;
`aquarium_warp.studies.swarm_size.one_batch_config`) against the independent path of one batch per
setting: exact where the worlds are the same (a single setting; setting 0's worlds when the capacity does
not change; the prey at reset), statistically elsewhere (random draws are keyed by world and slot, so
other worlds draw other episodes); and `aquarium-warp study fov-view` (CSV, JSON, heatmap, bad lists)."""

from __future__ import annotations

import csv
import json
import math

import pytest

from aquarium_warp import BatchedAquarium
from aquarium_warp.cli import main
from aquarium_warp.studies.swarm_size import SwarmSizeStudy, one_batch_config, run_swarm_size_study

METRICS = (
    "captures",
    "captures_per_prey",
    "polarization",
    "cohesion",
    "nn_mean",
    "groups",
    "largest_group",
    "predator_distance",
    "prey_alive",
    "episode_length",
)


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def both_paths(tmp_path, **settings) -> tuple[dict, dict]:
    """The summaries of the same study run one batch per setting and in one batch."""
    return tuple(
        run_swarm_size_study(
            SwarmSizeStudy(one_batch=one, out=str(tmp_path / str(one)), figures=False, **settings), progress=False
        )
        for one in (False, True)
    )


def metric_rows(rows):
    return [{k: v for k, v in r.items() if k in METRICS} for r in rows]


def assert_agree(per_setting: dict, one_batch: dict, names, sigmas: float = 4.0) -> None:
    """Every setting's mean over seeds on the two paths differs by at most `sigmas` standard errors of the
    difference (independent seeds on each path: sqrt(sem_a^2 + sem_b^2)); at 4 sigma a correct one-batch
    path fails with a chance of about 6e-5 per comparison (normal means), and the seeds are fixed."""
    for a, b in zip(per_setting["results"], one_batch["results"]):
        assert (a["prey"], a["fov_angle"], a["view_distance"]) == (b["prey"], b["fov_angle"], b["view_distance"])
        for name in names:
            ma, mb = a["metrics"][name], b["metrics"][name]
            margin = sigmas * math.hypot(ma["sem"], mb["sem"])
            assert abs(ma["mean"] - mb["mean"]) <= margin + 1e-9, (a["prey"], a["fov_angle"], name, ma, mb)


def test_single_setting_is_identical_on_both_paths(device, tmp_path):
    per_setting, one_batch = both_paths(
        tmp_path, prey=[8], seeds=2, episode_steps=30, metrics_every=5, fov_angles=[200.0], respawn=False, device=device
    )
    assert per_setting["path"] == "one batch per setting" and one_batch["path"].startswith("one batch:")
    assert one_batch["config"]["one_batch"] and one_batch["wall_time_s"] > 0
    assert read_csv(tmp_path / "True" / "swarm_size.csv") == read_csv(tmp_path / "False" / "swarm_size.csv")
    assert one_batch["results"][0]["population"] == per_setting["results"][0]["population"]


def test_one_batch_prey_at_reset_are_those_of_their_own_batch(device):
    """Prey slots come first and are drawn by world and slot: the first setting's worlds start with the prey
    of a batch of that setting alone, though every world has the largest count's slots."""
    study = SwarmSizeStudy(prey=[4, 16], seeds=3)
    settings = study.settings()
    cfg = one_batch_config(study, settings)
    assert cfg.prey_count == (4,) * 3 + (16,) * 3 and cfg.capacity == 17
    together = BatchedAquarium(cfg, num_worlds=6, device=device, seed=5)
    alone = BatchedAquarium(settings[0]["config"], num_worlds=3, device=device, seed=5)
    together.reset()
    alone.reset()
    a, b = together.state.torch, alone.state.torch
    assert b.position.shape[1] == 5
    assert (a.position[:3, :4] == b.position[:, :4]).all() and (a.heading[:3, :4] == b.heading[:, :4]).all()
    assert a.alive[:3, :4].all() and not a.alive[:3, 4:16].any() and a.alive[3:, :17].all()


def test_swarm_size_one_batch_agrees_with_one_batch_per_size(device, tmp_path):
    per_setting, one_batch = both_paths(
        tmp_path, prey=[4, 24], seeds=16, episode_steps=80, metrics_every=8, device=device
    )
    names = ("captures_per_prey", "polarization", "nn_mean", "groups", "largest_group", "predator_distance")
    assert_agree(per_setting, one_batch, names)
    # The sizes differ by far more than the margin, so swapped or mixed worlds would fail the comparison.
    for summary in (per_setting, one_batch):
        small, large = (e["metrics"]["groups"] for e in summary["results"])
        assert large["mean"] - small["mean"] > 8 * math.hypot(small["sem"], large["sem"])
    # Respawn on: every world keeps its own prey count, and every episode has all its steps.
    for entry in one_batch["results"]:
        assert entry["metrics"]["prey_alive"]["mean"] == entry["prey"]
        assert entry["metrics"]["episode_length"]["mean"] == 80


def test_one_batch_refuses_what_sizes_the_arrays(tmp_path):
    for change, words in ((dict(constant_density=True), "constant density"), (dict(reproduction=True), "max_prey")):
        with pytest.raises(ValueError, match=words):
            run_swarm_size_study(
                SwarmSizeStudy(prey=[4, 8], one_batch=True, out=str(tmp_path), **change), progress=False
            )


@pytest.mark.parametrize(
    "argv",
    [
        ["study", "swarm-size", "--prey", "4,8", "--one-batch", "--jobs", "2"],
        ["study", "fov-view", "--fov", "90,180", "--view", "50", "--jobs", "2"],
    ],
)
def test_one_batch_refuses_jobs(argv, tmp_path, capsys):
    """One batch runs in this process: `--jobs` (settings at once, a batch each) would be ignored."""
    assert main([*argv, "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--jobs 2" in err and "one batch" in err
    assert (
        main(
            [
                *argv[:-1],
                "1",
                "--out",
                str(tmp_path),
                "--no-progress",
                "--seeds",
                "1",
                "--episode-steps",
                "5",
                "--no-figures",
            ]
        )
        == 0
    )  # one job is what one batch does


def test_cli_fov_view_writes_csv_json_and_heatmap(device, tmp_path, capsys):
    out = tmp_path / "fv"
    rc = main(
        [
            "study",
            "fov-view",
            "--fov",
            "60,360",
            "--view",
            "50,100,...,200",
            "--prey",
            "8",
            "--seeds",
            "2",
            "--episode-steps",
            "20",
            "--metrics-every",
            "5",
            "--device",
            device,
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0 and "fov_view.csv" in capsys.readouterr().out
    rows = read_csv(out / "fov_view.csv")
    assert [(float(r["fov_angle"]), float(r["view_distance"]), int(r["seed"])) for r in rows] == [
        (f, v, s) for f in (60.0, 360.0) for v in (50.0, 100.0, 200.0) for s in (0, 1)
    ]
    assert all(int(r["prey"]) == 8 and float(r["episode_length"]) == 20 for r in rows)
    summary = json.loads((out / "fov_view.json").read_text())
    assert summary["study"] == "fov-view" and summary["config"]["one_batch"]
    assert summary["path"].startswith("one batch:")
    entry = summary["results"][3]
    assert (entry["fov_angle"], entry["view_distance"]) == (360.0, 50.0)
    assert entry["metrics"]["captures_per_prey"]["seeds"] == [float(r["captures_per_prey"]) for r in rows[6:8]]
    assert (out / "captures_fov_view.png").stat().st_size > 10_000 and not (out / "swarm_size.json").exists()


def test_fov_view_one_batch_agrees_with_one_batch_per_setting(device, tmp_path):
    settings = dict(
        kind="fov-view",
        prey=[24],
        fov_angles=[30.0, 360.0],
        view_distances=[40.0, 300.0],
        seeds=12,
        episode_steps=80,
        metrics_every=8,
        device=device,
    )
    per_setting, one_batch = both_paths(tmp_path, **settings)
    # Every world has 24 prey (one capacity), so setting 0's worlds are the same worlds on both paths.
    rows = [read_csv(tmp_path / str(one) / "fov_view.csv") for one in (False, True)]
    assert metric_rows(rows[0][:12]) == metric_rows(rows[1][:12])
    assert_agree(
        per_setting, one_batch, ("captures_per_prey", "polarization", "nn_mean", "groups", "predator_distance")
    )
    # Seeing far and all around makes TurnAway prey flee together: the settings differ beyond the margin.
    for summary in (per_setting, one_batch):
        blind, seeing = (summary["results"][i]["metrics"]["polarization"] for i in (0, 3))
        assert abs(seeing["mean"] - blind["mean"]) > 8 * math.hypot(blind["sem"], seeing["sem"])


@pytest.mark.parametrize(
    "argv, option",
    [
        (["--fov", "60,abc"], "--fov"),
        (["--fov", "0,90"], "--fov"),
        (["--fov", "90,400"], "--fov"),
        (["--view", "50,-1"], "--view"),
        (["--view", "50,100,...,99"], "--view"),
    ],
)
def test_fov_view_bad_lists_are_one_line_errors(argv, option, tmp_path, capsys):
    assert main(["study", "fov-view", *argv, "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("aquarium-warp study:") and option in err
