"""Training over two processes (`torchrun --nproc_per_node=2`, gloo on the CPU): the ranks hold the same
parameters after every update, rank 0 logs the episode statistics summed over the ranks, and a run
stopped and resumed continues exactly on every rank (tests/training/distributed_worker.py is each rank)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import pytest
import torch

from aquarium_warp.cli import main
from aquarium_warp.training import Trainer, distributed, make_config

WORKER = os.path.join(os.path.dirname(__file__), "distributed_worker.py")


def torchrun(
    out: str, team: str, iterations: int, tag: str, resume: bool = False, gpu: str | None = None, train=None
) -> list[dict]:
    """Run the worker on two ranks, on the CPU, both on GPU 0 (`gpu="shared"`, gloo) or on GPUs 0 and 1
    (`gpu="own"`, NCCL), with further `train` settings; each rank's record."""
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "1",
        "GIT_PYTHON_REFRESH": "quiet",
        **({"AQUARIUM_WORKER_GPU": gpu} if gpu else {}),
        **({"AQUARIUM_WORKER_TRAIN": json.dumps(train)} if train else {}),
    }
    env.pop("WORLD_SIZE", None)
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node=2",
        WORKER,
        out,
        team,
        str(iterations),
        tag,
    ] + (["resume"] if resume else [])
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    records = []
    for rank in range(2):
        with open(os.path.join(out, f"{tag}_rank{rank}.json"), encoding="utf-8") as f:
            records.append(json.load(f))
    return records


def check_reduced_logs(run_dir: str, records: list[dict], team: str, csv_name: str) -> int:
    """Rank 0's progress rows equal the statistics combined from both ranks' sums and counts; how many
    iterations had ended episodes."""
    with open(os.path.join(run_dir, csv_name), newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(records[0]["stats"][team])
    with_episodes = 0
    for it, row in enumerate(rows):
        both = [sum(values) for values in zip(*(r["stats"][team][it] for r in records))]
        k = (len(both) - 2) // 2  # snapshot: k sums, k counts, row reward total and row count
        sums, counts = both[:k], both[k : 2 * k]
        assert int(row["episodes_logged"]) == int(counts[0])
        assert float(row["mean_row_reward"]) == pytest.approx(both[-2] / both[-1], rel=1e-12)
        if counts[0]:
            with_episodes += 1
            assert float(row["captures"]) == pytest.approx(sums[0] / counts[0], rel=1e-12)
            assert float(row["episode_length"]) == pytest.approx(sums[3] / counts[3], rel=1e-12)
        else:
            assert row["captures"] == ""
    return with_episodes


@pytest.mark.slow
def test_two_ranks_agree_log_sums_and_keep_their_states(tmp_path):
    records = torchrun(str(tmp_path), "prey", 3, "run")
    run_dir = os.path.join(tmp_path, "run")
    assert [r["seed"] for r in records] == [0, 1]
    with open(os.path.join(run_dir, "config.json"), encoding="utf-8") as f:
        assert json.load(f)["distributed"] == {"world_size": 2, "seeds": [0, 1]}
    # the same parameters after every update, different worlds
    assert sorted(records[0]["params"]) == ["0", "1", "2"]
    assert records[0]["params"] == records[1]["params"]
    assert records[0]["final_sim"] != records[1]["final_sim"]
    # on CUDA the rollout would replay graphs, and the update too (cut at its all-reduces: loop.graph_plan)
    assert [r["graphable"] for r in records] == [{"prey": [True, True]}] * 2
    assert check_reduced_logs(run_dir, records, "prey", "progress.csv") >= 1
    # one file holds both ranks' simulations (each with its own seed)
    state = torch.load(os.path.join(run_dir, "model_2.pt"), weights_only=False)["infos"]["aquarium"]
    assert state["world_size"] == 2 and len(state["ranks"]) == 1
    assert [state["seed"], state["ranks"][0]["seed"]] == [0, 1]
    assert state["vec_env"]["env"]["seed"] == 0 and state["ranks"][0]["vec_env"]["env"]["seed"] == 1
    with pytest.raises(ValueError, match="2 process.*WORLD_SIZE.*this run has 1"):
        Trainer.resume(run_dir)


@pytest.mark.slow
@pytest.mark.parametrize("team", ["prey", "both"])
def test_stop_and_resume_continues_exactly_on_every_rank(tmp_path, team):
    straight, split = str(tmp_path / "straight"), str(tmp_path / "split")
    os.makedirs(straight)
    os.makedirs(split)
    whole = torchrun(straight, team, 4, "whole")
    torchrun(split, team, 2, "first")
    resumed = torchrun(split, team, 2, "resumed", resume=True)
    teams = ["prey", "predator"] if team == "both" else ["prey"]
    for rank in range(2):
        assert resumed[rank]["params"] == {k: v for k, v in whole[rank]["params"].items() if int(k) >= 2}
        assert resumed[rank]["final_params"] == whole[rank]["final_params"]
        assert resumed[rank]["final_sim"] == whole[rank]["final_sim"]
    assert whole[0]["params"] == whole[1]["params"]
    for name in teams:
        csv_name = f"progress_{name}.csv" if team == "both" else "progress.csv"
        check_reduced_logs(os.path.join(straight, "run"), whole, name, csv_name)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_nodes_join_through_the_rendezvous(tmp_path):
    """Two torchrun launchers, one per "node" (both on this host), meet at a c10d rendezvous and run
    `aquarium-warp train` as one run of two ranks (gloo on the CPU): both finish, rank 0's checkpoint
    holds both ranks' states and the logged agent-steps count both ranks' worlds."""
    run_dir = str(tmp_path / "run")
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "GIT_PYTHON_REFRESH": "quiet"}
    env.pop("WORLD_SIZE", None)
    worlds, steps, iterations = 4, 16, 2
    launchers = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "torch.distributed.run",
                "--nnodes=2",
                "--nproc_per_node=1",
                f"--node_rank={node}",
                "--rdzv_backend=c10d",
                f"--rdzv_endpoint=127.0.0.1:{port}",
                "--rdzv_id=two-nodes",
                "-m",
                "aquarium_warp",
                "train",
                "--preset",
                "tiny",
                "--device",
                "cpu",
                "--num-worlds",
                str(worlds),
                "--num-steps-per-env",
                str(steps),
                "--iterations",
                str(iterations),
                "--export",
                "none",
                "--quiet",
                "--log-dir",
                run_dir,
            ],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for node in range(2)
    ]
    outputs = []
    try:
        for launcher in launchers:
            outputs.append(launcher.communicate(timeout=300)[0])
    finally:
        for launcher in launchers:
            if launcher.poll() is None:
                launcher.kill()
    assert [launcher.returncode for launcher in launchers] == [0, 0], "\n".join(o[-3000:] for o in outputs)
    state = torch.load(os.path.join(run_dir, f"model_{iterations - 1}.pt"), weights_only=False)["infos"]["aquarium"]
    assert state["world_size"] == 2 and len(state["ranks"]) == 1
    assert [state["seed"], state["ranks"][0]["seed"]] == [0, 1]
    assert state["vec_env"]["env"]["seed"] == 0 and state["ranks"][0]["vec_env"]["env"]["seed"] == 1
    with open(os.path.join(run_dir, "progress.csv"), newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    prey = make_config("tiny")["env"]["prey_count"]
    assert [int(row["agent_steps"]) for row in rows] == [2 * worlds * prey * steps * (i + 1) for i in range(iterations)]


@pytest.mark.parametrize(
    "env, message",
    [
        ({"WORLD_SIZE": "two"}, "WORLD_SIZE='two' must be an integer"),
        ({"WORLD_SIZE": "0"}, "WORLD_SIZE=0 must be >= 1"),
        ({"WORLD_SIZE": "2", "RANK": "2"}, r"RANK=2 must be in \[0, WORLD_SIZE=2\)"),
        ({"WORLD_SIZE": "2", "LOCAL_RANK": "-1"}, r"LOCAL_RANK=-1 must be in \[0, WORLD_SIZE=2\)"),
    ],
)
def test_bad_torchrun_environment_is_named(monkeypatch, env, message):
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    with pytest.raises(ValueError, match=message):
        distributed.world()


def test_rank_devices():
    assert distributed.rank_device("cpu", 1) == "cpu"
    with pytest.raises(ValueError, match="train.device='mps'"):
        distributed.rank_device("mps", 0)
    with pytest.raises(ValueError, match="LOCAL_RANK=99"):
        distributed.rank_device("cuda:0", 99)


def test_torchrun_needs_a_log_dir(monkeypatch, capsys):
    monkeypatch.setenv("WORLD_SIZE", "2")
    assert main(["train", "--preset", "tiny", "--device", "cpu"]) == 2
    assert "--log-dir is required under torchrun" in capsys.readouterr().err


@pytest.mark.usefixtures("cuda_device")  # the ranks share GPU 0
@pytest.mark.parametrize("team", ["prey", "both"])
def test_ranks_on_a_gpu_replay_their_rollouts_and_their_update_cut_at_its_all_reduces(tmp_path, team):
    """Two ranks on CUDA (sharing one GPU, through gloo): each replays its rollout from CUDA graphs and
    its update from graphs cut at the gradients' all-reduces, which run eagerly between them (gloo waits
    on the host for its sums; NCCL's in-stream sum needs a GPU per rank, which this test does not have).
    The ranks hold the same parameters after every update, rank 0 logs the statistics summed over both,
    and the parameters equal those of the eager update (`train.graph_update=false`) bit for bit."""
    learners = 2 if team == "both" else 1
    runs = {}
    for graph_update in ("auto", False):
        out = str(tmp_path / str(graph_update))
        os.makedirs(out)
        records = torchrun(out, team, 3, "gpu", gpu="shared", train={"graph_update": graph_update})
        split = "split" if graph_update == "auto" else False
        assert [r["graphs"] for r in records] == [[True, [split] * learners]] * 2
        assert sorted(records[0]["params"]) == ["0", "1", "2"]
        assert records[0]["params"] == records[1]["params"]
        assert records[0]["final_sim"] != records[1]["final_sim"]
        for name in ["prey", "predator"] if team == "both" else ["prey"]:
            csv_name = f"progress_{name}.csv" if team == "both" else "progress.csv"
            assert check_reduced_logs(os.path.join(out, "run"), records, name, csv_name) >= 1
        runs[graph_update] = records
    assert runs["auto"][0]["params"] == runs[False][0]["params"]
    assert runs["auto"][0]["final_params"] == runs[False][0]["final_params"]


def check_nccl_run(out: str, team: str, pool_every: int, graph_update) -> list[dict]:
    """Two ranks on GPUs 0 and 1 (NCCL) with `train.graph_update=graph_update`: both replay their
    rollouts and capture their updates as asked, hold the same parameters after every update, and rank
    0 logs the statistics summed over both; each rank's record."""
    teams = ["prey", "predator"] if team == "both" else ["prey"]
    captured = {True: True, "auto": "split", False: False}[graph_update]
    os.makedirs(out)
    records = torchrun(out, team, 3, "nccl", gpu="own", train={"pool_every": pool_every, "graph_update": graph_update})
    assert [r["graphs"] for r in records] == [[True, [captured] * len(teams)]] * 2
    assert records[0]["params"] == records[1]["params"]
    assert records[0]["final_sim"] != records[1]["final_sim"]
    for name in teams:
        csv_name = f"progress_{name}.csv" if team == "both" else "progress.csv"
        assert check_reduced_logs(os.path.join(out, "run"), records, name, csv_name) >= 1
    with open(os.path.join(out, "run", "config.json"), encoding="utf-8") as f:
        assert json.load(f)["cuda_graphs"]["update"] == dict.fromkeys(teams, captured)
    return records


def needs_two_gpus() -> None:
    if torch.cuda.device_count() < 2:
        pytest.skip("needs 2 GPUs: NCCL wants one per rank")


@pytest.mark.usefixtures("cuda_device")
@pytest.mark.parametrize("team,pool_every", [("prey", 0), ("both", 1)], ids=["prey", "both+pool"])
def test_ranks_on_their_own_gpus_replay_the_update_cut_at_its_all_reduces_by_default(tmp_path, team, pool_every):
    """Two ranks on GPUs 0 and 1 (NCCL), default settings (`train.graph_update="auto"`): each replays its
    rollout from CUDA graphs and its update from graphs cut at the all-reduces, which run eagerly between
    them; the parameters equal those of the eager update bit for bit (two ranks' sum is one rounding)."""
    needs_two_gpus()
    runs = {
        graph_update: check_nccl_run(str(tmp_path / f"graph_update_{graph_update}"), team, pool_every, graph_update)
        for graph_update in ("auto", False)
    }
    assert runs["auto"][0]["params"] == runs[False][0]["params"]
    assert runs["auto"][0]["final_params"] == runs[False][0]["final_params"]


@pytest.mark.usefixtures("cuda_device")
@pytest.mark.parametrize("team,pool_every", [("prey", 0), ("both", 0), ("both", 1)], ids=["prey", "both", "both+pool"])
def test_ranks_on_their_own_gpus_capture_the_update_with_its_all_reduce(tmp_path, team, pool_every):
    """Two ranks on GPUs 0 and 1 (NCCL) with `train.graph_update=true` replay rollout and update, the
    update's all-reduce inside its graph, as one process does: for one team, both teams and both with
    the opponent pool. The ranks hold the same parameters after every update, rank 0 logs the
    statistics summed over both, and the captured update gives the eager update's parameters bit for
    bit (two ranks' sum is one rounding, whichever NCCL algorithm adds them)."""
    needs_two_gpus()
    runs = {
        graph_update: check_nccl_run(str(tmp_path / f"graph_update_{graph_update}"), team, pool_every, graph_update)
        for graph_update in (True, False)
    }
    assert runs[True][0]["params"] == runs[False][0]["params"]
    assert runs[True][0]["final_params"] == runs[False][0]["final_params"]
