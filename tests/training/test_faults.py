"""Issue 28's fault test: a tiny training, video and evaluation are killed (SIGKILL), interrupted (SIGINT,
SIGTERM) and starved (a full disk, simulated by the atomic writer failing as ENOSPC does). Nothing
written earlier is lost or left truncated, no partial file stays behind an interrupted writer (a killed
one's is removed by the next run), and a training resumed afterwards continues exactly as an
uninterrupted one (bit for bit on the CPU).

The interrupted commands run as processes of their own (`python -m aquarium_warp`), side by side."""

from __future__ import annotations

import errno
import glob
import os
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip("rsl_rl")
pytest.importorskip("imageio_ffmpeg")

import torch

from aquarium_warp import atomic
from aquarium_warp.cli import main
from aquarium_warp.training.trainer import Trainer

pytestmark = pytest.mark.slow
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
    "--save-interval",
    "1",
]
PREVIOUS = b"the previous file, whole"


def launch(argv: list[str], log: str) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "GIT_PYTHON_REFRESH": "quiet", "PYTHONUNBUFFERED": "1"}

    def default_sigint() -> None:  # a shell's background job inherits SIGINT ignored; a terminal's does not
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    with open(log, "w") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "aquarium_warp", *argv],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
            preexec_fn=default_sigint,
        )


def wait_for(condition, what: str, timeout: float = 180) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.05)


def partials(folder: str) -> list[str]:
    return [n for n in os.listdir(folder) if ".partial" in n]


def checkpoints(run: str) -> dict[int, str]:
    """`{i: path}` of the finished checkpoints model_<i>.pt (partial files are hidden: `atomic.py`)."""
    return {int(os.path.basename(p)[6:-3]): p for p in glob.glob(os.path.join(run, "model_*.pt"))}


def full_disk_for(monkeypatch, marker: str) -> None:
    """The atomic writer fails as a full disk makes it fail, for files whose name contains `marker`."""
    fsync = atomic._fsync

    def no_space(path):
        if marker in os.path.basename(path):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path)
        fsync(path)

    monkeypatch.setattr(atomic, "_fsync", no_space)


def reference_actor(run: str, iterations: int, tmp_path) -> dict:
    """The actor after `iterations` uninterrupted iterations of the run config in `run`'s checkpoints."""
    config = torch.load(checkpoints(run)[0], weights_only=False)["infos"]["aquarium"]["config"]
    config["train"]["iterations"] = iterations
    trainer = Trainer(config, log_dir=str(tmp_path / f"reference_{iterations}"))
    trainer.train()
    trainer.close()
    return torch.load(checkpoints(trainer.log_dir)[iterations - 1], weights_only=False)["actor_state_dict"]


def resume_and_compare(run: str, tmp_path) -> None:
    """Every checkpoint left is whole; a resume runs two more iterations and equals the uninterrupted run."""
    done = {i: torch.load(p, weights_only=False)["iter"] for i, p in checkpoints(run).items()}
    assert done and all(iters == i + 1 for i, iters in done.items()), done
    total = max(done.values()) + 2
    trainer = Trainer.resume(run, changes={"train": {"iterations": total}})
    trainer.train()
    trainer.close()
    resumed = torch.load(checkpoints(run)[total - 1], weights_only=False)["actor_state_dict"]
    expected = reference_actor(run, total, tmp_path)
    assert all(torch.equal(resumed[k], expected[k]) for k in expected), run


def test_killed_interrupted_and_starved_commands_lose_nothing(tmp_path, monkeypatch, capsys, one_thread):
    # ------------------------------------------------------------------ interrupted, as processes
    runs = {sig: str(tmp_path / f"train_{sig.name}") for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL)}
    procs = {
        ("train", sig): launch(["train", *TINY, "--iterations", "100000", "--log-dir", run], run + ".log")
        for sig, run in runs.items()
    }
    videos = {sig: str(tmp_path / f"video_{sig.name}") for sig in (signal.SIGINT, signal.SIGKILL)}
    for folder in videos.values():
        os.makedirs(folder)
        with open(os.path.join(folder, "v.mp4"), "wb") as f:
            f.write(PREVIOUS)
    evaluation = str(tmp_path / "eval")
    os.makedirs(evaluation)
    with open(os.path.join(evaluation, "summary.json"), "wb") as f:
        f.write(PREVIOUS)
    for sig, run in runs.items():
        wait_for(lambda run=run: len(checkpoints(run)) >= 2, f"two checkpoints in {run}")
        procs["train", sig].send_signal(sig)
    for sig, folder in videos.items():
        procs["video", sig] = launch(
            ["video", "--steps", "100000", "--device", "cpu", "--no-progress", "--out", os.path.join(folder, "v.mp4")],
            folder + ".log",
        )
    procs["eval"] = launch(
        ["eval", "--episodes", "64", "--seeds", "0", "1", "2", "3", "4", "--device", "cpu", "--out", evaluation],
        evaluation + ".log",
    )
    for sig, folder in videos.items():
        wait_for(lambda folder=folder: partials(folder), f"the video's partial file in {folder}")
        procs["video", sig].send_signal(sig)
    wait_for(lambda: "aquarium-warp eval:" in open(evaluation + ".log").read(), "the evaluation to start")
    procs["eval"].send_signal(signal.SIGINT)
    codes = {key: proc.wait(timeout=120) for key, proc in procs.items()}
    assert codes == {
        ("train", signal.SIGINT): 130,
        ("train", signal.SIGTERM): 143,
        ("train", signal.SIGKILL): -9,
        ("video", signal.SIGINT): 130,
        ("video", signal.SIGKILL): -9,
        "eval": 130,
    }, codes

    for sig in (signal.SIGINT, signal.SIGTERM):
        run = runs[sig]
        last = open(run + ".log").read().strip().splitlines()[-1]
        assert last.startswith(f"aquarium-warp train: stopped by {sig.name} after iteration ") and last.endswith(
            f"continue with: aquarium-warp train --resume {run}"
        ), last
        assert not partials(run)
    for sig, folder in videos.items():
        assert open(os.path.join(folder, "v.mp4"), "rb").read() == PREVIOUS
        assert bool(partials(folder)) == (sig == signal.SIGKILL)  # an interrupted writer cleans up
    assert open(videos[signal.SIGINT] + ".log").read().strip().splitlines()[-1] == "aquarium-warp video: interrupted"
    assert open(os.path.join(evaluation, "summary.json"), "rb").read() == PREVIOUS and not partials(evaluation)
    # (the evaluation's worker threads may still print a progress line after it)
    assert "aquarium-warp eval: interrupted" in open(evaluation + ".log").read().splitlines()

    # The next run into a killed writer's folder removes its partial file.
    killed = videos[signal.SIGKILL]
    assert (
        main(["video", "--steps", "2", "--device", "cpu", "--no-progress", "--out", os.path.join(killed, "v.mp4")]) == 0
    )
    assert not partials(killed) and open(os.path.join(killed, "v.mp4"), "rb").read() != PREVIOUS
    for run in runs.values():
        resume_and_compare(run, tmp_path)

    # ------------------------------------------------------------------ starved: a full disk
    starved = str(tmp_path / "train_full_disk")
    assert main(["train", *TINY, "--iterations", "2", "--log-dir", starved]) == 0
    before = {i: open(p, "rb").read() for i, p in checkpoints(starved).items()}
    full_disk_for(monkeypatch, "model_")
    capsys.readouterr()
    assert main(["train", "--resume", starved, "--iterations", "4", "--quiet", "--export", "none"]) == 1
    monkeypatch.undo()
    assert (
        capsys.readouterr().err.strip().splitlines()[-1]
        == f"aquarium-warp train: {starved}/model_2.pt: no space left on device"
    )
    assert {i: open(p, "rb").read() for i, p in checkpoints(starved).items()} == before and not partials(starved)
    resume_and_compare(starved, tmp_path)

    video = str(tmp_path / "video_full_disk")
    os.makedirs(video)
    with open(os.path.join(video, "v.mp4"), "wb") as f:
        f.write(PREVIOUS)
    full_disk_for(monkeypatch, "v.")
    assert (
        main(["video", "--steps", "2", "--device", "cpu", "--no-progress", "--out", os.path.join(video, "v.mp4")]) == 1
    )
    monkeypatch.undo()
    assert (
        capsys.readouterr().err.strip().splitlines()[-1]
        == f"aquarium-warp video: {video}/v.mp4: no space left on device"
    )
    assert open(os.path.join(video, "v.mp4"), "rb").read() == PREVIOUS and not partials(video)
