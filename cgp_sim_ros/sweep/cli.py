"""``cgp-sim-sweep``: run a sweep file on Dask into Parquet tables, and draw its figures.

::

    cgp-sim-sweep run couzin_hysteresis                      # a built-in sweep, a LocalCluster (1 worker / core)
    cgp-sim-sweep run my_sweep.yaml -o sweeps/mine --workers 2
    cgp-sim-sweep run my_sweep.yaml --scheduler tcp://host:8786   # an existing Dask cluster
    cgp-sim-sweep run my_sweep.yaml --dry-run                # the plan: runs, tasks, what is left to run
    cgp-sim-sweep plot sweeps/couzin_hysteresis -o hysteresis.png
    cgp-sim-sweep list                                       # the built-in sweeps

Exit status: 0 every run finished; 1 some runs failed or were not finished (the tables hold the others;
run the same command again to retry what was not finished); 2 a bad sweep file or option, or a cluster that
cannot run it; 130 interrupted (Ctrl-C: what finished is kept, the same command resumes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .spec import SweepError, builtin_sweep_dir, builtin_sweep_names, load_sweep

#: LocalCluster worker processes --workers may ask for, and --retries per task
MAX_WORKERS = 256
MAX_RETRIES = 100


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cgp-sim-sweep", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run (or resume) a sweep; writes <out>/runs.parquet, flocks.parquet, ...")
    run.add_argument("sweep", help="a sweep file, or a built-in sweep's name (cgp-sim-sweep list)")
    run.add_argument("-o", "--out", type=Path, help="output directory (default: sweeps/<sweep name>)")
    run.add_argument("--scheduler", metavar="ADDRESS",
                     help="an existing Dask scheduler (tcp://host:8786) instead of a LocalCluster")
    run.add_argument("--workers", type=int, metavar="N", help="LocalCluster worker processes (default: one per core)")
    run.add_argument("--workers-write", action="store_true",
                     help="the workers write the fragments into the output directory themselves (it must be on a "
                          "filesystem every worker sees under the same path)")
    run.add_argument("--seeds", type=int, metavar="N", help="seeds 0..N-1 in every experiment (instead of the file's)")
    run.add_argument("--retry-failed", action="store_true", help="run the runs that failed before again")
    run.add_argument("--retries", type=int, default=2, metavar="N",
                     help="how often a task whose machinery failed is retried on other workers (default 2)")
    run.add_argument("--dry-run", action="store_true", help="print the plan and exit")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    plot = commands.add_parser("plot", help="the standard figure of a sweep's tables (needs matplotlib)")
    plot.add_argument("out", type=Path, help="a sweep's output directory")
    plot.add_argument("-o", "--output", type=Path, help="the figure (PNG, SVG, PDF; default <out>/<sweep>.png)")
    plot.add_argument("--x", metavar="KEY", help="the swept key on the x axis (default: the chain's key, or the "
                                                 "only swept key)")
    plot.add_argument("--flock", help="the flock (default: the only one)")
    plot.add_argument("--highly-parallel", type=float, default=0.97, metavar="P",
                      help="polarized runs above this p are 'highly parallel', below 'dynamic parallel' "
                           "(default 0.97; 1 to not split)")
    plot.add_argument("--title", help="the figure's title (default: the sweep file's title)")
    commands.add_parser("list", help="the built-in sweeps")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "list":
            return _list()
        if args.command == "plot":
            return _plot(args)
        return _run(args)
    except SweepError as exc:
        print(f"cgp-sim-sweep: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ncgp-sim-sweep: interrupted", file=sys.stderr)
        return 130


def _list() -> int:
    for name in builtin_sweep_names():
        sweep = load_sweep(builtin_sweep_dir() / f"{name}.yaml")
        print(f"{name}: {len(sweep.runs)} runs, {sweep.description}")
    return 0


def _run(args) -> int:
    from .engine import EngineError, pending_tasks, run_sweep, scheduler_address
    from .store import OutputError

    if args.seeds is not None and args.seeds < 1:
        print("cgp-sim-sweep: --seeds must be >= 1", file=sys.stderr)
        return 2
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        print(f"cgp-sim-sweep: --workers must be within 1..{MAX_WORKERS}", file=sys.stderr)
        return 2
    if args.retries < 0 or args.retries > MAX_RETRIES:
        print(f"cgp-sim-sweep: --retries must be within 0..{MAX_RETRIES}", file=sys.stderr)
        return 2
    try:
        if args.scheduler is not None:
            scheduler_address(args.scheduler)
    except EngineError as exc:
        print(f"cgp-sim-sweep: {exc}", file=sys.stderr)
        return 2
    sweep = load_sweep(args.sweep, seeds=args.seeds)
    out = args.out or Path("sweeps") / sweep.name
    if args.dry_run:
        todo, already = pending_tasks(sweep, out, args.retry_failed)
        print(f"{sweep.source}: {len(sweep.runs)} runs in {len(sweep.tasks)} tasks into {out}; {already} finished, "
              f"{sum(len(t.runs) for t in todo)} to run")
        for e in sweep.experiments:
            runs = [r for t in sweep.tasks if t.experiment is e for r in t.runs]
            print(f"  {e.name}: {len(runs)} runs of {e.duration:g} s (dt {e.dt:g} s, {e.ticks} ticks)"
                  + (f", chained along {e.chain_key}" + (" (reversed)" if e.chain_reverse else "") if e.chain_key
                     else ""))
        for run in sweep.refused:
            print(f"  refused by the scene loader: {run.refused}")
        return 0
    try:
        outcome = run_sweep(sweep, out, scheduler=args.scheduler, workers=args.workers,
                            retry_failed=args.retry_failed, workers_write=args.workers_write, retries=args.retries,
                            quiet=args.quiet)
    except (EngineError, OutputError) as exc:
        print(f"cgp-sim-sweep: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # writing the fragments or tables failed mid-sweep (disk full, ...): what finished is kept
        print(f"cgp-sim-sweep: cannot write {exc.filename or out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    tables = ", ".join(f"{name}.parquet ({rows} rows)" for name, rows in outcome.rows.items() if rows)
    print(f"ran {outcome.ran} runs ({outcome.failed} failed), {outcome.already_finished} were finished before; "
          f"{out}: {tables or 'no tables yet'}")
    for reason in outcome.not_finished:
        print(f"not finished (run the command again to retry): {reason}", file=sys.stderr)
    if outcome.interrupted:
        print("cgp-sim-sweep: interrupted; what finished is kept: run the same command to resume", file=sys.stderr)
    return outcome.exit_code


def _plot(args) -> int:
    from .plot import PlotError, plot

    try:
        path, table = plot(args.out, args.output, x=args.x, flock=args.flock, highly_parallel=args.highly_parallel,
                           title=args.title)
    except PlotError as exc:
        print(f"cgp-sim-sweep plot: {exc}", file=sys.stderr)
        return 2
    print(table)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
