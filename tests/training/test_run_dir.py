"""Issue 28: a training run owns its directory (no second run mixes into it, a dead owner's lock is
taken over), the whole run's memory is estimated and refused when it cannot fit, SIGINT/SIGTERM stop
at an iteration boundary with a checkpoint from which a resume continues bit for bit, and the finish
message says what ran."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

pytest.importorskip("rsl_rl")

import torch

from aquarium_warp.cli import main
from aquarium_warp.training import memory
from aquarium_warp.training.config import make_config
from aquarium_warp.training.run_dir import LOCK_NAME, check_same_run, claim_run_directory
from aquarium_warp.training.stop import StopRequest
from aquarium_warp.training.trainer import Trainer

TINY = [
    "--preset",
    "tiny",
    "--num-worlds",
    "4",
    "--device",
    "cpu",
    "--export",
    "none",
    "--quiet",
    "--max-steps",
    "20",
    "--set",
    "runner.num_steps_per_env=8",
]


def one_line(capsys, prefix: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith(prefix), err
    return err


def actor(path: str) -> dict:
    return torch.load(path, weights_only=False)["actor_state_dict"]


def same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# ------------------------------------------------------------------------------------ run directory
def test_a_non_empty_run_directory_is_refused(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "progress.csv").write_text("iteration\n0\n")
    assert main(["train", *TINY, "--iterations", "1", "--log-dir", str(run)]) == 2
    err = one_line(capsys, "aquarium-warp train: ")
    assert (
        f"--log-dir {run} is not empty (progress.csv): continue that run with --resume {run}, replace it "
        "with --overwrite" in err
    )
    assert sorted(os.listdir(run)) == sorted([LOCK_NAME, "progress.csv"])
    assert (run / "progress.csv").read_text() == "iteration\n0\n"
    assert (run / LOCK_NAME).read_text() == ""  # released
    assert main(["train", *TINY, "--resume", str(run), "--overwrite"]) == 2
    assert "give one of them" in one_line(capsys, "aquarium-warp train: ")


def test_a_locked_run_directory_is_refused_and_a_dead_owners_lock_taken_over(tmp_path, capsys):
    run = str(tmp_path / "run")
    held = claim_run_directory(run)
    assert main(["train", *TINY, "--iterations", "1", "--log-dir", run]) == 2
    assert f"--log-dir {run}: another run (process {os.getpid()}) is using it" in one_line(
        capsys, "aquarium-warp train: "
    )
    held.release()
    dead = int(
        subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True).stdout
    )
    with open(os.path.join(run, LOCK_NAME), "w") as f:  # as left by a killed run: its pid, no flock
        f.write(str(dead))
    said = []
    claimed = claim_run_directory(run, say=said.append)
    assert said == [f"aquarium-warp train: {run} was locked by process {dead}, which no longer runs; taking it over"]
    assert open(os.path.join(run, LOCK_NAME)).read() == str(os.getpid())
    claimed.release()
    # A lock file that names a live process which holds no lock on it, or no process at all
    for content, found in (
        (str(os.getppid()), f"names process {os.getppid()}, which runs but holds no lock on it (a reused process id?)"),
        ("0", "holds '0', not a process id"),
        ("half-written junk", "holds 'half-written junk', not a process id"),
    ):
        with open(os.path.join(run, LOCK_NAME), "w") as f:
            f.write(content)
        said.clear()
        claim_run_directory(run, say=said.append).release()
        assert said == [f"aquarium-warp train: the lock file of {run} {found}; taking it over"]


def test_a_refused_run_releases_its_lock(tmp_path, capsys, one_thread):
    """Refusals after the directory is claimed (the network's activation, the opponent's policy file)
    leave no pid in the lock: the corrected retry takes over no dead run."""
    run = tmp_path / "run"
    junk = tmp_path / "junk.pt"
    junk.write_text("not a policy")
    for bad, said in (
        (["--activation", "bogus"], "Invalid activation function 'bogus'"),
        (["--predator-policy", str(junk)], str(junk)),
    ):
        assert main(["train", *TINY, "--iterations", "1", "--log-dir", str(run), *bad]) == 2
        assert said in one_line(capsys, "aquarium-warp train: ")
        assert (run / LOCK_NAME).read_text() == ""
    assert main(["train", *TINY, "--iterations", "1", "--log-dir", str(run)]) == 0
    assert "taking it over" not in capsys.readouterr().out


# ------------------------------------------------------------------------------------------ run ids
def run_id(path) -> str:
    if str(path).endswith(".pt"):
        return torch.load(path, weights_only=False)["infos"]["aquarium"]["run_id"]
    with open(os.path.join(path, "config.json")) as f:
        return json.load(f)["run_id"]


def test_a_resume_into_another_runs_directory_is_refused(tmp_path, capsys, one_thread):
    """Issue 49: a checkpoint continues only in a directory of its own run (config.json's and the newest
    checkpoint's run id), or in an empty one, which then takes the run's id."""
    a, b, c = (tmp_path / name for name in "abc")
    for run in (a, b):  # two runs of one config: only their ids tell them apart
        assert main(["train", *TINY, "--iterations", "2", "--log-dir", str(run)]) == 0
    assert run_id(a) != run_id(b) and run_id(a / "model_1.pt") == run_id(a)
    before = {name: (a / name).read_bytes() for name in os.listdir(a) if os.path.isfile(a / name)}
    capsys.readouterr()
    foreign = b / "model_1.pt"
    assert main(["train", "--resume", str(foreign), "--log-dir", str(a), "--iterations", "3", "--quiet"]) == 2
    assert one_line(capsys, "aquarium-warp train: ") == (
        f"aquarium-warp train: {foreign} cannot continue in {a}: its config.json is of another run (run "
        f"{run_id(a)}, the checkpoint's is {run_id(b)}); resume into the checkpoint's own run directory or an empty one"
    )
    assert {name: (a / name).read_bytes() for name in before} == before  # nothing of a rewritten
    assert (a / LOCK_NAME).read_text() == ""
    # The directory's newest checkpoint from another run
    shutil.copy(foreign, a / "model_5.pt")
    assert main(["train", "--resume", str(a / "model_1.pt"), "--iterations", "3", "--quiet"]) == 2
    assert f"its model_5.pt is of another run (run {run_id(b)}, the checkpoint's is {run_id(a)})" in one_line(
        capsys, "aquarium-warp train: "
    )
    assert main(["train", "--resume", str(a), "--iterations", "7", "--quiet"]) == 2  # model_5.pt, into a
    assert f"its config.json is of another run (run {run_id(a)}, the checkpoint's is {run_id(b)})" in one_line(
        capsys, "aquarium-warp train: "
    )
    # An empty directory continues the run under its id
    assert main(["train", "--resume", str(foreign), "--log-dir", str(c), "--iterations", "3", "--quiet"]) == 0
    assert run_id(c) == run_id(c / "model_2.pt") == run_id(b)


def test_files_from_before_run_ids_are_told_apart_by_their_config(tmp_path):
    """A checkpoint or config.json without a run id: the config decides, less what a resume may change."""
    record = {"config": make_config("tiny", {"train": {"seed": 1, "iterations": 9}})}
    (tmp_path / "config.json").write_text(json.dumps(record))
    state = {"config": make_config("tiny", {"train": {"seed": 1, "iterations": 2}}), "run_id": "abc"}
    assert check_same_run(str(tmp_path), "elsewhere/model_1.pt", state) == "abc"
    state["config"]["train"]["seed"] = 2
    with pytest.raises(
        ValueError, match=r"its config.json is of another run \(train.seed differs from the checkpoint's\)"
    ):
        check_same_run(str(tmp_path), "elsewhere/model_1.pt", state)


def test_overwrite_replaces_the_earlier_run_only(tmp_path, capsys, one_thread):
    run = tmp_path / "run"
    assert main(["train", *TINY, "--iterations", "2", "--log-dir", str(run)]) == 0
    (run / "notes.txt").write_text("mine")
    (run / "model_7.pt").write_text("an earlier, longer run's checkpoint")
    assert main(["train", *TINY, "--iterations", "1", "--log-dir", str(run), "--overwrite"]) == 0
    names = sorted(n for n in os.listdir(run) if not n.startswith("events.out"))
    assert names == sorted([LOCK_NAME, "config.json", "git", "model_0.pt", "notes.txt", "progress.csv"])
    assert (run / "progress.csv").read_text().count("\n") == 2  # the header and iteration 0


# ------------------------------------------------------------------------------------------- memory
def test_a_run_that_cannot_fit_is_refused_with_the_estimate(monkeypatch):
    config = make_config("default", {"train": {"num_worlds": 1024, "device": "cpu"}})
    parts = memory.training_bytes(config)
    assert parts["total"] == parts["simulation"] + parts["rollout"] + parts["update"]
    # 32 steps x 16 prey rows x (29 observation floats + 16 logits + 6 scalars) x 4 bytes, + the done byte
    assert parts["rollout"] >= 1024 * 32 * 16 * (4 * (29 + 16 + 6) + 1)
    bigger = memory.training_bytes(make_config("default", {"train": {"num_worlds": 2048}}))
    assert bigger["total"] > 1.9 * parts["total"]
    monkeypatch.setattr(memory, "available_bytes", lambda device: int(parts["total"] / 0.9) + 1)
    memory.check_training_memory(config, "cpu")  # fits
    monkeypatch.setattr(memory, "available_bytes", lambda device: parts["total"])
    with pytest.raises(
        ValueError,
        match=r"^train.num_worlds=1024 needs about .* GiB on cpu \(simulation .*, "
        r"rollout storage .*, update .* GiB\), but only .* GiB is available: use "
        r"at most about 921 worlds",
    ):
        Trainer(config)


def test_a_huge_run_is_refused_before_anything_is_allocated(tmp_path, capsys):
    assert main(["train", "--num-worlds", "3000000", "--device", "cpu", "--log-dir", str(tmp_path / "run")]) == 2
    err = one_line(capsys, "aquarium-warp train: train.num_worlds=3000000 needs about ")
    assert "rollout storage" in err and "GiB is available" in err
    assert (tmp_path / "run" / LOCK_NAME).read_text() == ""  # released


# ------------------------------------------------------------------------------------------ signals
def test_a_second_signal_stops_at_once():
    # The handlers before (Python's default; SIG_IGN where a shell started the tests in the background)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    stop = StopRequest()
    with stop.catching():
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.name == "SIGTERM"
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before  # restored


@pytest.mark.slow
def test_ctrl_c_stops_at_an_iteration_boundary_and_the_resume_continues_bit_for_bit(
    tmp_path, capsys, monkeypatch, one_thread
):
    stopped, reference = str(tmp_path / "stopped"), str(tmp_path / "reference")
    handler = signal.getsignal(signal.SIGINT)
    assert main(["train", *TINY, "--iterations", "5", "--log-dir", reference]) == 0
    after = Trainer.after_iteration

    def interrupted(self, iteration):  # Ctrl-C during iteration 1 (the second)
        after(self, iteration)
        if iteration == 1:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(Trainer, "after_iteration", interrupted)
    capsys.readouterr()
    assert main(["train", *TINY, "--iterations", "5", "--log-dir", stopped, "--export", "jit"]) == 130
    captured = capsys.readouterr()
    assert (
        captured.err.strip().splitlines()[-1]
        == f"aquarium-warp train: stopped by SIGINT after iteration 2 of 5; continue with: aquarium-warp train "
        f"--resume {stopped}"
    )
    assert "2 iterations in" in captured.out and os.path.isfile(os.path.join(stopped, "exported", "policy.pt"))
    assert sorted(n for n in os.listdir(stopped) if n.startswith("model_")) == ["model_0.pt", "model_1.pt"]
    assert signal.getsignal(signal.SIGINT) is handler  # restored
    monkeypatch.undo()
    assert main(["train", "--resume", stopped, "--quiet", "--export", "none"]) == 0
    assert "3 iterations in" in capsys.readouterr().out.splitlines()[-1]
    assert same(actor(os.path.join(stopped, "model_4.pt")), actor(os.path.join(reference, "model_4.pt")))
    with open(os.path.join(stopped, "progress.csv")) as a, open(os.path.join(reference, "progress.csv")) as b:
        assert [r.split(",")[0] for r in a] == [r.split(",")[0] for r in b]  # every iteration once


def test_no_iterations_run_says_so(tmp_path, capsys, one_thread):
    run = str(tmp_path / "run")
    assert main(["train", *TINY, "--iterations", "0", "--log-dir", run]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last == (
        f"aquarium-warp train: no iterations to run (0 of 0 done); no checkpoint written, run config in {run}"
    )
    assert not [n for n in os.listdir(run) if n.startswith("model_")]
