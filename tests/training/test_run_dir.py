"""Issue 28: a training run owns its directory (no second run mixes into it, a dead owner's lock is
taken over), the whole run's memory is estimated and refused when it cannot fit, SIGINT/SIGTERM stop
at an iteration boundary with a checkpoint from which a resume continues bit for bit, and the finish
message says what ran."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

pytest.importorskip("rsl_rl")

import torch

from aquarium_warp.cli import main
from aquarium_warp.training import memory
from aquarium_warp.training.config import make_config
from aquarium_warp.training.run_dir import LOCK_NAME, claim_run_directory
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
