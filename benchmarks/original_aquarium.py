"""Measure the ORIGINAL ``marl-aquarium==0.1.10`` environment on the CPU.

The original package pins old dependencies (numpy 1.22.4, gymnasium 0.28.1,
pettingzoo 1.24.2, pygame 2.1.3) that clash with ``aquarium-warp``'s own, so it
is installed into a throwaway virtual environment (default
``~/.cache/aquarium-warp/original-venv``) with ``pip install --no-deps``, next
to current numpy / gymnasium / pettingzoo / pygame and ``moviepy==1.0.3``
(which its ``utils.py`` imports). No torch is installed there.

Each measurement runs in a fresh process using that venv's python
(``benchmarks/_original_aquarium_child.py``); see that file for the exact
method. The median over ``repeats`` runs is reported.

Import use (from other benchmark scripts)::

    from benchmarks.original_aquarium import measure_original
    res = measure_original(seconds=10, repeats=3, which="raw")
    res["env_steps_per_s"], res["agent_steps_per_s"]

Command line::

    python benchmarks/original_aquarium.py [--seconds 10] [--repeats 3]
        [--which raw,parallel] [--venv PATH] [--out PATH] [-O]

Writes ``benchmarks/results/original_cpu.json``. Exit code 2 when the venv
cannot be created / the package cannot be installed (e.g. no network), 3 when
a measurement fails.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # aquarium_warp without an install
CHILD_SCRIPT = HERE / "_original_aquarium_child.py"
RESULT_MARKER = "ORIGINAL_AQUARIUM_RESULT_JSON:"  # must match the child script
DEFAULT_VENV = Path(os.path.expanduser("~/.cache/aquarium-warp/original-venv"))
DEFAULT_OUT = HERE / "results" / "original_cpu.json"

ORIGINAL_REQ = "marl-aquarium==0.1.10"
# Imports of the original (current versions are fine; moviepy must be 1.0.3,
# moviepy 2.x removed ``moviepy.video.compositing.concatenate``).
RUNTIME_REQS = ["numpy", "gymnasium", "pettingzoo", "pygame", "moviepy==1.0.3"]

# What "the venv works" means: the package at the right version imports, both
# entry points exist, and torch is absent.
_CHECK_CODE = r"""
import sys
from importlib import metadata
assert sys.version_info >= (3, 10), sys.version
assert metadata.version("marl-aquarium") == "0.1.10", metadata.version("marl-aquarium")
from marl_aquarium.env.aquarium import raw_env
from marl_aquarium import aquarium_v0
assert callable(aquarium_v0.parallel_env)
try:
    metadata.version("torch")
except metadata.PackageNotFoundError:
    pass
else:
    raise AssertionError("torch is installed in the original venv")
print("ok")
"""


class OriginalSetupError(RuntimeError):
    """The venv with the original package could not be created or installed."""


class OriginalRunError(RuntimeError):
    """A measurement subprocess failed."""


# --------------------------------------------------------------------------- venv


def _venv_python(venv: Path) -> Path:
    if os.name == "nt":
        return venv / "Scripts" / "python.exe"
    return venv / "bin" / "python"


def _child_env() -> dict:
    env = dict(os.environ)
    env.update(
        {
            "PYGAME_HIDE_SUPPORT_PROMPT": "1",  # pygame prints a banner on import
            "SDL_VIDEODRIVER": "dummy",
            "SDL_AUDIODRIVER": "dummy",
            "PYTHONHASHSEED": "0",
            "PYTHONDONTWRITEBYTECODE": "1",
        }
    )
    # Never let the parent's venv / path leak into the child.
    for key in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV"):
        env.pop(key, None)
    return env


def _venv_works(venv: Path) -> bool:
    py = _venv_python(venv)
    if not py.exists():
        return False
    try:
        proc = subprocess.run(
            [str(py), "-c", _CHECK_CODE],
            capture_output=True,
            text=True,
            timeout=120,
            env=_child_env(),
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return proc.returncode == 0 and proc.stdout.strip().endswith("ok")


def _run_pip(py: Path, args: list[str], what: str, verbose: bool) -> None:
    cmd = [str(py), "-m", "pip", "install", "--disable-pip-version-check", *args]
    if verbose:
        print(f"[original] $ {' '.join(cmd)}", file=sys.stderr, flush=True)
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, env=_child_env())
    except subprocess.TimeoutExpired as exc:
        raise OriginalSetupError(f"pip install of {what} timed out after {exc.timeout:.0f} s") from exc
    if proc.returncode != 0:
        tail = "\n".join((proc.stdout + "\n" + proc.stderr).strip().splitlines()[-25:])
        raise OriginalSetupError(
            f"pip install of {what} failed (exit {proc.returncode}). Is the package index "
            f"reachable (network / proxy / PIP_INDEX_URL)? Last pip output:\n{tail}"
        )


def ensure_original_venv(venv: Path | str = DEFAULT_VENV, *, verbose: bool = True) -> dict:
    """Create (or reuse) the venv holding the original package.

    Returns ``{"venv": str, "python": str, "reused": bool, "setup_s": float}``.
    Raises :class:`OriginalSetupError` with a readable message on failure.
    """
    venv = Path(venv).expanduser()
    t0 = time.perf_counter()
    if _venv_works(venv):
        return {
            "venv": str(venv),
            "python": str(_venv_python(venv)),
            "reused": True,
            "setup_s": time.perf_counter() - t0,
        }

    if venv.exists():
        if verbose:
            print(f"[original] existing venv at {venv} is broken/incomplete; recreating", file=sys.stderr)
        shutil.rmtree(venv)
    venv.parent.mkdir(parents=True, exist_ok=True)
    if verbose:
        print(f"[original] creating venv {venv} ({sys.executable} -m venv)", file=sys.stderr, flush=True)
    try:
        proc = subprocess.run([sys.executable, "-m", "venv", str(venv)], capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired as exc:
        raise OriginalSetupError("`python -m venv` timed out") from exc
    if proc.returncode != 0:
        raise OriginalSetupError(
            f"`{sys.executable} -m venv {venv}` failed (exit {proc.returncode}):\n"
            f"{(proc.stdout + proc.stderr).strip()}\n"
            "(on Debian/Ubuntu the python3-venv package may be missing)"
        )
    py = _venv_python(venv)
    _run_pip(py, ["--no-deps", ORIGINAL_REQ], ORIGINAL_REQ, verbose)
    _run_pip(py, RUNTIME_REQS, ", ".join(RUNTIME_REQS), verbose)
    if not _venv_works(venv):
        proc = subprocess.run([str(py), "-c", _CHECK_CODE], capture_output=True, text=True, env=_child_env())
        raise OriginalSetupError(
            f"venv {venv} was installed but the original package does not import:\n"
            f"{(proc.stdout + proc.stderr).strip()[-3000:]}"
        )
    return {"venv": str(venv), "python": str(py), "reused": False, "setup_s": time.perf_counter() - t0}


# --------------------------------------------------------------------------- measuring


def _run_child(
    py: str,
    which: str,
    run: int,
    seconds: float,
    warmup: float,
    env_kwargs: dict | None,
    optimize: bool,
) -> dict:
    cmd = [str(py)]
    if optimize:
        cmd.append("-O")
    cmd += [
        str(CHILD_SCRIPT),
        "--which",
        which,
        "--run",
        str(run),
        "--seconds",
        repr(float(seconds)),
        "--warmup",
        repr(float(warmup)),
        "--env-kwargs",
        json.dumps(env_kwargs or {}),
    ]
    # Generous: construction + warm-up + window; large configs step slowly.
    timeout = 300 + 5 * (seconds + warmup)
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=_child_env(), cwd=str(HERE))
    except subprocess.TimeoutExpired as exc:
        raise OriginalRunError(f"{which} run {run} timed out after {timeout:.0f} s") from exc
    result = None
    for line in proc.stdout.splitlines():
        if line.startswith(RESULT_MARKER):
            result = json.loads(line[len(RESULT_MARKER) :])
    if proc.returncode != 0 or result is None:
        tail = "\n".join((proc.stdout + "\n" + proc.stderr).strip().splitlines()[-30:])
        raise OriginalRunError(f"{which} run {run} failed (exit {proc.returncode}):\n{tail}")
    return result


def measure_original(
    seconds: float = 10.0,
    repeats: int = 3,
    which: str = "raw",
    *,
    warmup: float = 2.0,
    env_kwargs: dict | None = None,
    optimize: bool = False,
    venv: Path | str = DEFAULT_VENV,
    verbose: bool = False,
) -> dict:
    """Time the original marl-aquarium 0.1.10 with random actions, no rendering.

    ``which``: ``"raw"`` (``marl_aquarium.env.aquarium.raw_env``) or
    ``"parallel"`` (``marl_aquarium.aquarium_v0.parallel_env``, the PettingZoo
    parallel->AEC->parallel round trip). ``env_kwargs`` are passed to the
    constructor (default config when empty). ``optimize=True`` runs the child
    with ``python -O`` (asserts stripped; needed for >1 predator, see the
    behaviour reference section 13).

    Each repeat is a fresh process with ``random.seed(run)`` before
    construction. Returns medians plus the per-run records::

        {"which", "env_steps_per_s", "agent_steps_per_s", "peak_rss_mb",
         "runs": [...], "seconds", "repeats", "warmup_s", "env_kwargs",
         "optimize", "versions", "venv"}

    Raises OriginalSetupError / OriginalRunError.
    """
    if which not in ("raw", "parallel"):
        raise ValueError(f"which must be 'raw' or 'parallel', not {which!r}")
    if repeats < 1:
        raise ValueError("repeats must be >= 1")
    info = ensure_original_venv(venv, verbose=verbose)
    runs = []
    for run in range(repeats):
        r = _run_child(info["python"], which, run, seconds, warmup, env_kwargs, optimize)
        if verbose:
            print(
                f"[original] {which} run {run}: {r['env_steps_per_s']:.1f} env-steps/s, "
                f"{r['agent_steps_per_s']:.0f} agent-steps/s ({r['steps']} steps, "
                f"{r['resets_in_window']} resets)",
                file=sys.stderr,
                flush=True,
            )
        runs.append(r)
    return {
        "which": which,
        "entry_point": (
            "marl_aquarium.env.aquarium.raw_env" if which == "raw" else "marl_aquarium.aquarium_v0.parallel_env"
        ),
        "env_steps_per_s": statistics.median(r["env_steps_per_s"] for r in runs),
        "agent_steps_per_s": statistics.median(r["agent_steps_per_s"] for r in runs),
        "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
        "seconds": seconds,
        "repeats": repeats,
        "warmup_s": warmup,
        "env_kwargs": env_kwargs or {},
        "optimize": optimize,
        "versions": runs[0]["versions"],
        "venv": info["venv"],
        "runs": runs,
    }


# --------------------------------------------------------------------------- CLI


def _machine_info() -> dict:
    from aquarium_warp.records import cpu_model

    info = {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "host_python": sys.version.split()[0],
    }
    try:
        info["loadavg_1_5_15"] = list(os.getloadavg())
    except OSError:
        pass
    model = cpu_model()
    if model is not None:
        info["cpu_model"] = model
    return info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="timed window per run (s)")
    ap.add_argument("--repeats", type=int, default=3, help="fresh-process runs per entry point")
    ap.add_argument("--warmup", type=float, default=2.0, help="warm-up per run (s, >= 2 recommended)")
    ap.add_argument("--which", default="raw,parallel", help="comma list of raw,parallel")
    ap.add_argument("--venv", default=str(DEFAULT_VENV))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    ap.add_argument("-O", "--optimize", action="store_true", help="run the original under python -O")
    ap.add_argument("--env-kwargs", default="{}", help="JSON constructor kwargs (default config if empty)")
    ap.add_argument("--setup-only", action="store_true", help="only create/check the venv")
    args = ap.parse_args(argv)

    whiches = [w.strip() for w in args.which.split(",") if w.strip()]
    for w in whiches:
        if w not in ("raw", "parallel"):
            ap.error(f"--which: unknown entry point {w!r}")
    env_kwargs = json.loads(args.env_kwargs)

    try:
        setup = ensure_original_venv(args.venv, verbose=True)
    except OriginalSetupError as exc:
        print(f"ERROR: could not set up the original marl-aquarium venv at {args.venv}:\n{exc}", file=sys.stderr)
        return 2
    print(
        f"[original] venv {setup['venv']} {'reused' if setup['reused'] else 'created'} in {setup['setup_s']:.1f} s",
        file=sys.stderr,
    )
    if args.setup_only:
        return 0

    from aquarium_warp.records import command_line, git_info

    machine = _machine_info()  # load average taken before our own runs add to it
    results = {}
    try:
        for w in whiches:
            results[w] = measure_original(
                seconds=args.seconds,
                repeats=args.repeats,
                which=w,
                warmup=args.warmup,
                env_kwargs=env_kwargs,
                optimize=args.optimize,
                venv=args.venv,
                verbose=True,
            )
    except (OriginalSetupError, OriginalRunError) as exc:
        print(f"ERROR: measuring the original failed:\n{exc}", file=sys.stderr)
        return 3

    print()
    print(
        f"original marl-aquarium 0.1.10, CPU, random actions, no rendering "
        f"({args.repeats} runs x {args.seconds:g} s, median)"
    )
    hdr = f"{'entry point':<40} {'env-steps/s':>12} {'agent-steps/s':>14} {'runs (env-steps/s)':>28} {'RSS MB':>7}"
    print(hdr)
    print("-" * len(hdr))
    for r in results.values():
        per_run = ", ".join(f"{x['env_steps_per_s']:.1f}" for x in r["runs"])
        print(
            f"{r['entry_point']:<40} {r['env_steps_per_s']:>12.1f} {r['agent_steps_per_s']:>14.0f} "
            f"{per_run:>28} {r['peak_rss_mb']:>7.1f}"
        )

    doc = {
        "benchmark": "original marl-aquarium 0.1.10, CPU, random actions, no rendering",
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "method": {
            "seconds": args.seconds,
            "repeats": args.repeats,
            "warmup_s_min": args.warmup,
            "min_steps": 3,
            "fresh_process_per_run": True,
            "seeding": "random.seed(run) before construction; actions numpy default_rng(run)",
            "resets_included": True,
            "agent_steps": "sum over timed steps of len(env.agents) before the step",
            "statistic": "median over runs",
            "optimize": args.optimize,
            "env_kwargs": env_kwargs,
        },
        "machine": machine,
        "command": command_line(argv, Path(__file__).name),
        "git": git_info(),
        "venv": {"path": setup["venv"], "reused": setup["reused"], "setup_s": setup["setup_s"]},
        "versions": next(iter(results.values()))["versions"] if results else {},
        "results": results,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
