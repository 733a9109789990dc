"""Issue 28: files, paths and formats. Outputs are written atomically (`aquarium_warp/atomic.py`): a
failed or interrupted write leaves the previous file and no partial one; output locations are checked
before long work; unwritable paths, a full disk, damaged inputs and ragged configs end in one line
naming the path or field and the cause; repeated study values are refused by one rule."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import subprocess
import sys

import pytest

from aquarium_warp import atomic
from aquarium_warp.cli import main


def one_line(capsys, prefix: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith(prefix), err
    return err


def full_disk(monkeypatch) -> None:
    """Every atomic write fails as a full disk makes it fail: when its data reach the disk."""

    def no_space(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path)

    monkeypatch.setattr(atomic, "_fsync", no_space)


# ------------------------------------------------------------------------------------------- atomic
def test_a_failed_write_leaves_the_previous_file_and_no_partial(tmp_path, monkeypatch):
    path = tmp_path / "summary.json"
    path.write_text("previous")
    with pytest.raises(RuntimeError), atomic.atomic_open(path) as f:
        f.write("half of the new")
        raise RuntimeError("killed half-way")
    assert path.read_text() == "previous" and os.listdir(tmp_path) == ["summary.json"]
    full_disk(monkeypatch)
    with pytest.raises(OSError, match="No space") as info, atomic.atomic_open(path) as f:
        f.write("new")
    assert info.value.filename == str(path)  # the file asked for, not its temporary name
    assert path.read_text() == "previous" and os.listdir(tmp_path) == ["summary.json"]
    monkeypatch.undo()
    with atomic.atomic_open(path) as f:
        f.write("new")
    assert path.read_text() == "new"


def test_partial_files_of_dead_processes_are_removed_when_a_folder_is_checked(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    stale = tmp_path / f".video.{pid}.partial.mp4"
    mine = tmp_path / f".figure.{os.getpid()}.partial.png"
    for p in (stale, mine, tmp_path / "notes.partial.txt"):
        p.write_text("x")
    atomic.check_output_dir(str(tmp_path), "--out")
    assert sorted(os.listdir(tmp_path)) == sorted([mine.name, "notes.partial.txt"])


# ------------------------------------------------------------------------ unwritable or impossible paths
def _impossible(tmp_path) -> str:
    """A folder below a regular file: no permission bits involved, so this holds for root as well."""
    (tmp_path / "file").write_text("x")
    return str(tmp_path / "file" / "out")


@pytest.mark.parametrize(
    "argv",
    [
        ["train", "--preset", "tiny", "--device", "cpu", "--log-dir", "{bad}"],
        ["eval", "--device", "cpu", "--episodes", "1", "--seeds", "0", "--out", "{bad}"],
        ["eval", "--cross-play", "--device", "cpu", "--episodes", "1", "--seeds", "0", "--out", "{bad}"],
        [
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
            "{bad}",
        ],
        ["study", "fov-view", "--seeds", "1", "--episode-steps", "5", "--device", "cpu", "--out", "{bad}"],
        ["study", "flow", "--seeds", "1", "--episode-steps", "5", "--device", "cpu", "--out", "{bad}"],
        ["study", "group-hunting", "--seeds", "1", "--device", "cpu", "--out", "{bad}"],
        ["study", "many-eyes", "--seeds", "1", "--device", "cpu", "--out", "{bad}"],
        ["video", "--steps", "2", "--device", "cpu", "--no-progress", "--out", "{bad}/v.mp4"],
        ["video", "--steps", "2", "--device", "cpu", "--no-progress", "--out", "{folder}"],
    ],
    ids=lambda argv: " ".join(argv[:2]) + (" folder" if "{folder}" in argv else ""),
)
def test_an_impossible_output_location_is_refused_before_any_work(tmp_path, capsys, monkeypatch, argv):
    import aquarium_warp.env

    def no_world(*args, **kwargs):
        raise AssertionError("a world was built before the output location was checked")

    monkeypatch.setattr(aquarium_warp.env.BatchedAquarium, "__init__", no_world)
    bad = _impossible(tmp_path)
    folder = tmp_path / "folder.mp4"  # a folder named like a video
    folder.mkdir()
    argv = [a.replace("{bad}", bad).replace("{folder}", str(folder)) for a in argv]
    assert main(argv) == 2
    err = one_line(capsys, f"aquarium-warp {argv[0]}: ")
    option = "--log-dir" if argv[0] == "train" else "--out"
    assert option in err and (bad in err or argv[-1] in err), err


def test_bench_checks_its_output_folder_before_measuring(tmp_path, capsys, monkeypatch):
    import aquarium_warp.bench.suite as suite

    def measured(*args, **kwargs):
        raise AssertionError("the benchmark ran before its output folder was checked")

    monkeypatch.setattr(suite, "copy_bandwidth", measured)
    bad = _impossible(tmp_path)
    assert main(["bench", "--device", "cpu", "--out-dir", bad]) == 2
    err = one_line(capsys, "aquarium-warp bench: ")
    assert f"--out-dir {bad}: cannot write there ({tmp_path / 'file'} is a file, not a folder)" in err


def test_bench_fails_on_a_full_disk_when_its_figures_cannot_be_written(tmp_path, capsys, monkeypatch):
    pytest.importorskip("matplotlib")
    import aquarium_warp.bench.plots as plots

    def no_space(fig, path, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(plots, "write_figure", no_space)
    argv = ["bench", "--device", "cpu", "--agents", "16", "--worlds", "1", "--seconds", "0.01", "--repeats", "1"]
    argv += ["--warmup-steps", "1", "--no-original", "--no-heuristics", "--copy-mib", "4", "--quiet"]
    assert main(argv + ["--out-dir", str(tmp_path)]) == 1
    err = one_line(capsys, "aquarium-warp bench: ")
    assert err.endswith(".png: no space left on device") and str(tmp_path) in err, err
    assert json.loads((tmp_path / "scaling_cpu.json").read_text())["points"]  # the measurements are kept


def fake_ffmpeg(tmp_path, monkeypatch, script: str) -> None:
    """imageio-ffmpeg's ffmpeg replaced by a shell script (which reads a little of the frames, then fails)."""
    import imageio_ffmpeg

    exe = tmp_path / "ffmpeg"
    exe.write_text("#!/bin/sh\n" + script)
    exe.chmod(0o755)
    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", lambda: str(exe))


VIDEO = ["video", "--steps", "30", "--prey", "2", "--device", "cpu", "--no-progress", "--out"]


def test_a_full_disk_or_a_dying_ffmpeg_during_video_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / "v.mp4"
    # ffmpeg's words on a full disk (its last line, after others), as it writes its errors
    full = "head -c 100 > /dev/null; echo '[libx264 @ 0x1] frame=1' >&2; "
    full += "echo '[out#0/mp4 @ 0x2] Error writing trailer: No space left on device' >&2; exit 1\n"
    fake_ffmpeg(tmp_path, monkeypatch, full)
    assert main(VIDEO + [str(out)]) == 1
    assert one_line(capsys, "aquarium-warp video: ") == f"aquarium-warp video: {out}: no space left on device"
    # a kill (here a file size limit's signal) leaves no words of ffmpeg's: the signal is the cause
    fake_ffmpeg(tmp_path, monkeypatch, "head -c 100 > /dev/null; kill -XFSZ $$\n")
    assert main(VIDEO + [str(out)]) == 1
    err = one_line(capsys, "aquarium-warp video: ")
    assert err == f"aquarium-warp video: {out}: ffmpeg could not write the video (ffmpeg killed by SIGXFSZ)", err
    assert os.listdir(tmp_path) == ["ffmpeg"]  # no video, and no partial file


@pytest.mark.parametrize("path", ["/proc/v.mp4", "/sys/v.mp4"])
def test_video_refuses_a_file_its_folders_permissions_allow_but_cannot_be_created(path, capsys):
    """As root, /proc and /sys pass an access check; creating the file is the test, before any world."""
    if not os.path.isdir(os.path.dirname(path)):
        pytest.skip(f"no {os.path.dirname(path)} here")
    assert main(VIDEO + [path]) == 2
    one_line(capsys, f"aquarium-warp video: cannot write {path}: ")


@pytest.mark.slow
def test_a_ctrl_c_during_video_leaves_no_file_and_no_ffmpeg_output(tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C sends it: ffmpeg (its own session) says
    nothing about the frame the interrupt cut, and the command ends with 130 and one line."""
    pytest.importorskip("imageio_ffmpeg")
    import signal
    import time

    out = tmp_path / "v.mp4"
    argv = [sys.executable, "-m", "aquarium_warp", *VIDEO[:2], "3000", *VIDEO[3:], str(out)]
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: (os.setpgrp(), signal.signal(signal.SIGINT, signal.SIG_DFL)),
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not [n for n in os.listdir(tmp_path) if ".partial" in n]:
        time.sleep(0.2)  # until ffmpeg writes frames
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip() == "aquarium-warp video: interrupted", err
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------------------------ damaged inputs
@pytest.mark.parametrize(
    "name,text,expected",
    [
        ("missing.yaml", None, "--config {path}: cannot read it (No such file or directory)"),
        ("bad.yaml", "env: [1\n", "--config {path}: not valid YAML (ParserError"),
        ("bad.json", "{env", "--config {path}: not valid JSON ("),
    ],
)
def test_train_config_file_errors_are_one_line(tmp_path, capsys, name, text, expected):
    pytest.importorskip("yaml")
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    assert main(["train", "--config", str(path), "--log-dir", str(tmp_path / "run")]) == 2
    assert expected.format(path=path) in one_line(capsys, "aquarium-warp train: ")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("suffix", [".pt", ".onnx"])
@pytest.mark.parametrize("command", ["eval", "video"])
def test_a_corrupt_policy_file_is_named(tmp_path, capsys, suffix, command):
    pytest.importorskip("rsl_rl")
    path = tmp_path / f"policy{suffix}"
    path.write_bytes(b"garbage, not a policy\n")
    argv = (
        ["eval", "--prey", str(path), "--episodes", "1", "--seeds", "0", "--out", str(tmp_path / "out")]
        if command == "eval"
        else ["video", "--prey-policy", str(path), "--out", str(tmp_path / "v.mp4")]
    )
    assert main(argv + ["--device", "cpu"]) == 2
    assert f"{path}: not a readable policy file" in one_line(capsys, f"aquarium-warp {command}: ")


def test_ragged_flow_grid_and_blind_types_are_refused_naming_the_field():
    from aquarium_warp import AquariumConfig
    from aquarium_warp.config import FlowConfig, default_predator, default_prey

    for grid in ([[[1, 2], [3, 4]], [[1, 2]]], [[[1, 2], [3]]], [[[1, "a"]]]):
        with pytest.raises(ValueError, match=r"^flow\.grid=.*every row as long, every cell two numbers"):
            FlowConfig("grid", grid=grid)
    for kind, default in (("prey", default_prey), ("predator", default_predator)):
        blind = dataclasses.replace(default(), prey_slots=0, predator_slots=0)
        with pytest.raises(
            ValueError,
            match=rf"^{kind}\.predator_slots=0 and {kind}\.prey_slots=0: an observation "
            "needs at least one neighbour slot",
        ):
            AquariumConfig(**{kind: blind})
        AquariumConfig(**{kind: dataclasses.replace(default(), prey_slots=0, predator_slots=1)})  # one is enough


# ----------------------------------------------------------------------------------------- full disk
def test_a_full_disk_during_eval_keeps_the_previous_results(tmp_path, capsys, monkeypatch):
    pytest.importorskip("rsl_rl")
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("previous")
    full_disk(monkeypatch)
    argv = [
        "eval",
        "--episodes",
        "1",
        "--seeds",
        "0",
        "--max-steps",
        "5",
        "--prey-count",
        "2",
        "--device",
        "cpu",
        "--max-worlds",
        "2",
        "--out",
        str(out),
        "--no-figures",
    ]
    assert main(argv) == 1
    err = one_line(capsys, "aquarium-warp eval: ")
    assert err.endswith(": no space left on device") and str(out) in err, err
    assert (out / "summary.json").read_text() == "previous"
    assert not [n for n in os.listdir(out) if ".partial" in n]


# ------------------------------------------------------------------------------- consistent choices
@pytest.mark.parametrize(
    "argv,option",
    [
        (["study", "swarm-size", "--prey", "4,4"], "--prey"),
        (["study", "swarm-size", "--prey", "4,8", "--fov-angle", "90,90"], "--fov-angle"),
        (["study", "swarm-size", "--prey", "4", "--view-distance", "50,50"], "--view-distance"),
        (["study", "fov-view", "--fov", "60,60"], "--fov"),
        (["study", "fov-view", "--view", "50,100,50"], "--view"),
        (["study", "group-hunting", "--predators", "1,1"], "--predators"),
    ],
)
def test_every_study_refuses_repeated_values_naming_the_option(tmp_path, capsys, argv, option):
    assert main(argv + ["--device", "cpu", "--out", str(tmp_path)]) == 2
    err = one_line(capsys, "aquarium-warp study: ")
    assert f"{option}=" in err and "list each value once" in err, err
    assert os.listdir(tmp_path) == []


def test_studies_write_to_the_current_directory_by_default():
    from aquarium_warp.cli import build_parser

    parser = build_parser()
    for kind in ("swarm-size", "fov-view", "group-hunting", "many-eyes", "flow", "swarm", "phase"):
        out = parser.parse_args(["study", kind]).out
        assert not os.path.isabs(out) and os.path.dirname(out) == "" and "results" not in out, (kind, out)


def test_one_seed_heatmaps_show_no_interval(tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    pytest.importorskip("rsl_rl")
    from aquarium_warp.training import plots

    cells: dict[int, list[str]] = {}

    def texts(fig, path, **kwargs):
        cells[len(cells)] = [t.get_text() for ax in fig.axes for t in ax.texts]
        return str(path)

    monkeypatch.setattr(plots, "write_figure", texts)
    matrix = {"mean": [[0.25, 0.5]], "std": [[0.0, 0.0]]}
    for seeds in ([0], [0, 1]):
        result = {
            "cross_play": {
                "prey": ["random"],
                "predator": ["naivchase", "random"],
                "matrices": {"captures_per_prey": matrix},
            },
            "protocol": {"episodes": 2, "seeds": seeds},
        }
        plots.plot_cross_play(result, str(tmp_path / "heatmap.png"))
    assert cells[0] == ["0.25", "0.5"]
    assert cells[1] == ["0.25\n± 0", "0.5\n± 0"]


def test_an_empty_training_curve_says_why(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    pytest.importorskip("rsl_rl")
    from aquarium_warp.training.logger import CSV_FIELDS

    run = tmp_path / "run"
    run.mkdir()
    rows = [",".join(CSV_FIELDS)] + [
        ",".join(
            ""
            if f in ("captures", "captures_per_prey", "reward_per_agent", "opponent_reward_per_agent", "episode_length")
            else "1"
            if f != "iteration"
            else str(i)
            for f in CSV_FIELDS
        )
        for i in range(3)
    ]
    (run / "progress.csv").write_text("\n".join(rows) + "\n")
    assert main(["eval", "--curves", f"short={run}", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "note: no episode ended in the runs of 'short' (3 iteration(s) logged" in out, out
    assert os.path.isfile(tmp_path / "out" / "training_curves.png")


def test_counts_are_pluralised(tmp_path, capsys):
    pytest.importorskip("rsl_rl")
    from aquarium_warp.arguments import plural

    assert [plural(n, "predator") for n in (0, 1, 2)] == ["0 predators", "1 predator", "2 predators"]
    argv = [
        "eval",
        "--episodes",
        "1",
        "--seeds",
        "0",
        "--max-steps",
        "5",
        "--prey-count",
        "2",
        "--device",
        "cpu",
        "--max-worlds",
        "2",
        "--out",
        str(tmp_path),
        "--no-figures",
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "1 episode x 1 seed, 2 prey, 1 predator, 5 steps" in out, out
    json.loads((tmp_path / "summary.json").read_text())
    assert main(["demo", "--worlds", "1", "--steps", "1", "--device", "cpu"]) == 0
    assert "demo: 1 world x 17 agents on cpu, random actions, 1 step" in capsys.readouterr().out


@pytest.mark.slow
def test_onnx_export_prints_no_torchvision_notes(tmp_path):
    """torch.onnx's exporter logged four "torchvision is not installed" lines after every training run
    (its registry of torchvision operators, which no policy uses). In a fresh process: the registry
    logs once per process."""
    pytest.importorskip("rsl_rl")
    pytest.importorskip("onnx")
    import importlib.util

    if importlib.util.find_spec("torchvision") is not None:
        pytest.skip("torchvision is installed: the exporter has nothing to say")
    script = (
        "from aquarium_warp.training import Trainer, make_config\n"
        "t = Trainer(make_config('tiny', {'train': {'num_worlds': 2, 'device': 'cpu', 'iterations': 0}}))\n"
        f"print(t.export({str(tmp_path)!r}, formats=['onnx']))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "GIT_PYTHON_REFRESH": "quiet"},
    )
    assert result.returncode == 0, result.stderr
    assert os.path.isfile(tmp_path / "policy.onnx")
    assert "torchvision" not in result.stderr, result.stderr
