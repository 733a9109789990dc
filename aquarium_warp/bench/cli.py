"""`aquarium-warp bench`'s options, and the suite as a command (`main`)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from ..arguments import DEVICE_HELP
from ..atomic import describe_os_error
from .settings import BenchSettings

if TYPE_CHECKING:
    from .peers import Peers

DESCRIPTION = "`aquarium-warp bench`: the scaling benchmark suite (library and command line)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The suite's options (`settings_from_args` turns them into `BenchSettings`)."""
    parser.add_argument("--device", default=None, help=DEVICE_HELP)
    parser.add_argument(
        "--agents",
        default="16,64,...,1000000",
        help="agents of the one-world sweep (and agents per world of the load series), default "
        "density; '...' continues the progression "
        "(default 16,64,...,1000000)",
    )
    parser.add_argument("--worlds", default="1,16,...,65536", help="worlds of 17 agents (default 1,16,...,65536)")
    parser.add_argument(
        "--load-agents",
        type=int,
        default=None,
        metavar="L",
        help="add the load series: each N of --agents up to L in max(1, round(L / N)) worlds, "
        "about L agents in flight at every point, so that per-agent time compares across "
        "world sizes at equal load (default: off)",
    )
    parser.add_argument("--seconds", type=float, default=1.0, help="length of each timed run (default 1)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per point; the median is reported")
    parser.add_argument("--warmup-steps", type=int, default=5, help="untimed steps before each point's timing")
    parser.add_argument("--stage-repeats", type=int, default=10, help="steps timed command by command")
    parser.add_argument(
        "--max-agents-in-flight",
        type=int,
        default=4_194_304,
        help="skip points with more agents than this (default 4,194,304)",
    )
    parser.add_argument("--no-eager", action="store_true", help="do not time the eager step (CUDA)")
    parser.add_argument("--no-stages", action="store_true", help="no per-stage timing")
    parser.add_argument("--no-heuristics", action="store_true", help="do not time the heuristic policies")
    parser.add_argument(
        "--original",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="measure the original marl-aquarium 0.1.10 on the CPU; it is installed from the package "
        "index into a throwaway virtual environment (default: not measured; only through "
        "benchmarks/bench_scaling.py of the source tree)",
    )
    parser.add_argument(
        "--original-json",
        default=None,
        help="use a stored measurement of the original (e.g. benchmarks/results/original_cpu.json) "
        "instead of measuring it",
    )
    parser.add_argument("--original-seconds", type=float, default=3.0, help="length of each timed run of the original")
    parser.add_argument(
        "--vmas",
        action="store_true",
        help="measure VMAS simple_tag at the same agent counts (only through benchmarks/bench_scaling.py)",
    )
    parser.add_argument(
        "--vmas-max-agents-per-env",
        type=int,
        default=256,
        help="skip VMAS points with more agents per env (its per-agent Python loops are slow)",
    )
    parser.add_argument("--vmas-max-envs", type=int, default=65536, help="skip VMAS points with more envs")
    parser.add_argument("--vmas-budget", type=float, default=20.0, help="timed seconds per VMAS point at most")
    parser.add_argument(
        "--budget",
        type=float,
        default=None,
        help="seconds; once the suite ran this long, the remaining points are skipped (noted)",
    )
    parser.add_argument(
        "--out-dir",
        default=".",
        help="where the JSON and figures go (default: the current "
        "directory; the committed results are in benchmarks/results)",
    )
    parser.add_argument("--no-plots", action="store_true", help="write the JSON only, no figures")
    parser.add_argument(
        "--git-commit", default=None, help="the commit of a copy without git history (a checkout's is read from git)"
    )
    parser.add_argument("--copy-mib", type=int, default=None, help="MiB of the copy-bandwidth test")
    parser.add_argument("--cpu-threads", type=int, default=None, help="CPU threads of the env (default: all cores)")
    parser.add_argument("--quiet", action="store_true", help="print nothing (the JSON and figures are still written)")
    parser.add_argument(
        "--replot",
        default=None,
        metavar="JSON",
        help="only redraw the figures of an existing scaling_<device>.json, next to it",
    )


def settings_from_args(args: argparse.Namespace) -> BenchSettings:
    """The `BenchSettings` of parsed `add_arguments` options."""
    return BenchSettings(
        device=args.device,
        agents=args.agents,
        worlds=args.worlds,
        load_agents=args.load_agents,
        seconds=args.seconds,
        repeats=args.repeats,
        warmup_steps=args.warmup_steps,
        stage_repeats=args.stage_repeats,
        max_agents_in_flight=args.max_agents_in_flight,
        eager=not args.no_eager,
        stages=not args.no_stages,
        heuristics=not args.no_heuristics,
        original=args.original,
        original_json=args.original_json,
        original_seconds=args.original_seconds,
        vmas=args.vmas,
        vmas_max_agents_per_env=args.vmas_max_agents_per_env,
        vmas_max_envs=args.vmas_max_envs,
        vmas_budget_s=args.vmas_budget,
        budget_s=args.budget,
        out_dir=args.out_dir,
        plots=not args.no_plots,
        git_commit=args.git_commit,
        copy_bytes=None if args.copy_mib is None else args.copy_mib << 20,
        cpu_threads=args.cpu_threads,
        quiet=args.quiet,
    )


def run_from_args(args: argparse.Namespace, peers: Peers | None = None) -> int:
    """Run the suite (or `--replot`) for parsed options; `peers`: as `run_bench` takes them."""
    from .suite import replot, run_bench  # torch and Warp: not for `--help`

    if args.replot:
        figures = replot(args.replot)
        print(f"redrew {', '.join(str(f) for f in figures)}")
        return 0
    run_bench(settings_from_args(args), peers)
    return 0


def main(argv: list[str] | None = None, peers: Peers | None = None, prog: str = "aquarium-warp bench") -> int:
    """The command line of the suite: 0 when it ran, 2 on bad options, 1 when its files could not be
    written (the message on stderr)."""
    parser = argparse.ArgumentParser(prog=prog, description=DESCRIPTION)
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_from_args(args, peers)
    except ValueError as error:
        print(f"{prog}: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # a full disk, a file that cannot be written: its path and the cause
        print(f"{prog}: {describe_os_error(error)}", file=sys.stderr)
        return 1
