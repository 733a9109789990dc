"""`aquarium-warp study swarm-size` (aquarium_warp/studies/swarm_size.py): list parsing, a tiny sweep through the CLI
writing its CSV, JSON and figures, the prey FOV / view-distance sweep with constant density and
population traces, and trained policies through `aquarium_warp.training.export.load_policy`."""

from __future__ import annotations

import csv
import json
import os
import sys

import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.arguments import parse_list
from aquarium_warp.cli import main
from aquarium_warp.drivers import make_driver
from aquarium_warp.studies.swarm_size import SwarmSizeStudy, parse_world_size, run_swarm_size_study


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_parse_lists():
    assert parse_list("4,8,...,64", int) == [4, 8, 16, 32, 64]
    assert parse_list("4,8,16,...,4096", int)[-1] == 4096 and len(parse_list("4,8,...,4096", int)) == 11
    assert parse_list("30,60,...,180") == [30.0, 60.0, 90.0, 120.0, 150.0, 180.0]
    assert parse_list("120, 240") == [120.0, 240.0]
    assert parse_world_size("800") == (800.0, 800.0) and parse_world_size("640x480") == (640.0, 480.0)
    for bad in ("", "4,...", "4,8,...,99", "a,b", "4,...,8,16", "8,4,...,1"):
        with pytest.raises(ValueError):
            parse_list(bad, int)


@pytest.mark.slow
def test_cli_tiny_sweep_writes_csv_json_and_figures(device, tmp_path, capsys):
    out = tmp_path / "study"
    rc = main(
        [
            "study",
            "swarm-size",
            "--prey",
            "4,8",
            "--seeds",
            "2",
            "--episode-steps",
            "30",
            "--metrics-every",
            "5",
            "--device",
            device,
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    rows = read_csv(out / "swarm_size.csv")
    assert [(int(r["prey"]), int(r["seed"])) for r in rows] == [(4, 0), (4, 1), (8, 0), (8, 1)]
    for r in rows:
        assert float(r["episode_length"]) == 30 and float(r["prey_alive"]) == int(r["prey"])
        assert 0.0 <= float(r["polarization"]) <= 1.0 + 1e-6 and float(r["groups"]) >= 1
        assert float(r["captures_per_prey"]) == pytest.approx(float(r["captures"]) / int(r["prey"]), rel=1e-5)
    summary = json.loads((out / "swarm_size.json").read_text())
    assert summary["config"]["seeds"] == 2 and summary["config"]["linking_distance"] == 50.0
    assert [e["prey"] for e in summary["results"]] == [4, 8]
    stats = summary["results"][1]["metrics"]["captures"]
    assert stats["n"] == 2 and stats["mean"] == pytest.approx(sum(stats["seeds"]) / 2)
    assert len(summary["results"][0]["nn_distribution"]) == len(summary["nn_bin_edges"]) - 1
    assert "population" not in summary["results"][0]  # respawn on: populations do not change
    for name in (
        "captures_vs_size.png",
        "polarization_groups_vs_size.png",
        "spacing_vs_size.png",
        "nn_distribution.png",
    ):
        assert (out / name).stat().st_size > 10_000, name
    assert not (out / "population.png").exists()
    assert "wrote" in capsys.readouterr().out
    # Uniform-random references by the same kernels: 4 scattered prey are 4 groups (almost surely).
    baseline = summary["results"][0]["uniform_baseline"]
    assert 3.5 <= baseline["groups"] <= 4.0 and 0.0 < baseline["polarization"] < 1.0
    # --replot redraws the figures from the JSON alone.
    (out / "captures_vs_size.png").unlink()
    assert main(["study", "swarm-size", "--replot", "--out", str(out), "--device", device]) == 0
    assert (out / "captures_vs_size.png").exists()


@pytest.mark.slow
def test_fov_and_view_sweep_constant_density_and_populations(device, tmp_path):
    study = SwarmSizeStudy(
        prey=[4, 16],
        seeds=2,
        episode_steps=25,
        metrics_every=5,
        fov_angles=[90.0, 240.0],
        view_distances=[150.0],
        constant_density=True,
        respawn=False,
        device=device,
        out=str(tmp_path),
        jobs=2,
    )
    summary = run_swarm_size_study(study, progress=False)
    rows = read_csv(tmp_path / "swarm_size.csv")
    assert len(rows) == 2 * 2 * 2
    assert {(float(r["fov_angle"]), float(r["view_distance"])) for r in rows} == {(90.0, 150.0), (240.0, 150.0)}
    # Constant density: the 16-prey arena is the given 800 x 800, the 4-prey one half as wide.
    widths = {int(r["prey"]): float(r["world_width"]) for r in rows}
    assert widths == {4: 400.0, 16: 800.0}
    entry = summary["results"][0]
    assert entry["population"]["step"] == [0, 5, 10, 15, 20]
    prey = entry["population"]["prey_alive"]
    assert prey[0] == entry["prey"] and all(b <= a for a, b in zip(prey, prey[1:]))
    assert (tmp_path / "population.png").exists() and len(summary["figures"]) == 5


def test_bad_policy_names(tmp_path):
    with pytest.raises(ValueError, match="neither a heuristic"):
        run_swarm_size_study(
            SwarmSizeStudy(prey=[4], seeds=1, episode_steps=5, prey_policy="nope", out=str(tmp_path)), progress=False
        )
    assert (
        main(
            [
                "study",
                "swarm-size",
                "--prey",
                "4",
                "--predator-policy",
                "turnaway",
                "--out",
                str(tmp_path),
                "--no-progress",
            ]
        )
        == 2
    )


def test_trained_policy_without_training_package(device, tmp_path, monkeypatch):
    path = tmp_path / "policy.pt"
    path.write_bytes(b"not read")
    monkeypatch.setitem(sys.modules, "aquarium_warp.training.export", None)  # import fails
    study = SwarmSizeStudy(
        prey=[4],
        seeds=1,
        episode_steps=5,
        prey_policy=str(path),
        device=device,
        out=str(tmp_path / "out"),
        figures=False,
    )
    with pytest.raises(ValueError, match="trained policies need aquarium_warp.training"):
        run_swarm_size_study(study, progress=False)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_trained_policy_file(device, tmp_path):
    """A TorchScript policy in the export format (`logits`, `forward`, embedded metadata) drives the prey."""
    pytest.importorskip("aquarium_warp.training.export")

    class Policy(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.bias = torch.nn.Parameter(torch.zeros(16))
            with torch.no_grad():
                self.bias[4] = 1.0  # always east

        @torch.jit.export
        def logits(self, obs: torch.Tensor) -> torch.Tensor:
            return obs[:, :1] * 0.0 + self.bias

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            return torch.argmax(self.logits(obs), dim=-1)

    meta = {
        "format_version": 1,
        "team": "prey",
        "observation_size": 29,
        "action_count": 16,
        "group_size": 1,
        "sharing": "parameter",
    }
    path = str(tmp_path / "policy.pt")
    torch.jit.save(torch.jit.script(Policy()), path, _extra_files={"aquarium_policy.json": json.dumps(meta)})
    env = BatchedAquarium(AquariumConfig(prey_count=8), num_worlds=3, device=device)
    policy = make_driver(path, env, "prey")
    actions = policy()
    assert actions.shape == (3, 8) and actions.dtype == torch.int32 and (actions == 4).all()
    with pytest.raises(ValueError, match="trained for 'prey'"):
        make_driver(path, env, "predator")
    study = SwarmSizeStudy(
        prey=[8],
        seeds=2,
        episode_steps=40,
        metrics_every=1,
        prey_policy=path,
        device=device,
        out=str(tmp_path / "out"),
        figures=False,
    )
    summary = run_swarm_size_study(study, progress=False)
    assert summary["config"]["prey_policy"] == path and summary["results"][0]["metrics"]["captures"]["n"] == 2
    assert os.path.exists(tmp_path / "out" / "swarm_size.csv")
