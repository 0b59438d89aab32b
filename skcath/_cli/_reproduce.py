"""The ``reproduce`` command: run the paper's evaluation protocol, print and write its results."""

from __future__ import annotations

import dataclasses

from .. import protocol
from ..frames import FRAMES
from ._arguments import add_experiment_arguments, experiment_data, with_seeds
from ._backends import add_backend_arguments, check_backend, joblib_backend

__all__ = ["add_reproduce_command"]


def add_reproduce_command(commands) -> None:
    """Add ``reproduce`` to the sub-commands ``commands``."""
    repro = commands.add_parser(
        "reproduce",
        help="run the paper's evaluation protocol and write its tables and figures",
        description=(
            "Run the evaluation protocol of skcath.protocol: PCC, PDL, PDL+GRU, its torque/context "
            "ablations and PDL+MLP, with shaft settings held out within each catheter and with "
            "whole catheters held out. Prints the tables and writes them as CSV, with the figures "
            "as PNG, to the output folder."
        ),
    )
    repro.add_argument(
        "--quick",
        action="store_true",
        help="short schedule (one seed, 4 setting folds per catheter, small networks): "
        "about nine minutes on two CPU cores",
    )
    repro.add_argument(
        "--variants",
        nargs="+",
        default=None,
        metavar="NAME",
        help="learned methods to run, among: " + ", ".join(repr(v) for v in protocol.VARIANTS)
        + " (default: all; the tables of methods not run are left out)",
    )
    repro.add_argument(
        "--frame",
        choices=FRAMES,
        default=None,
        help="frame of the residual learners (their `frame` parameter): each run's sweep frame, "
        "or the base-sensor frame as in the paper (default: the learners' default, sweep)",
    )
    add_experiment_arguments(repro)
    add_backend_arguments(repro)
    repro.set_defaults(handler=run_reproduce, command_parser=repro)


def _schedule(args, parser):
    """The schedule of ``--quick``, with the seeds, variants and frame the arguments give."""
    schedule = with_seeds(protocol.QUICK if args.quick else protocol.FULL, args)
    if args.variants is not None:
        unknown = [v for v in args.variants if v not in protocol.VARIANTS]
        if unknown:
            parser.error(
                f"argument --variants: unknown {unknown}; expected names among {list(protocol.VARIANTS)}"
            )
        required = [m for m in protocol.MAIN_METHODS if m in protocol.VARIANTS and m not in args.variants]
        if required:
            parser.error(
                f"argument --variants: {required[0]!r} is required (Table I and the comparisons use it)"
            )
        schedule = dataclasses.replace(schedule, variants=tuple(dict.fromkeys(args.variants)))
    if args.frame is not None:
        schedule = dataclasses.replace(schedule, model_params={**schedule.model_params, "frame": args.frame})
    return schedule


def run_reproduce(args, parser) -> int:
    """Run the protocol that ``args`` describe; print its tables and write its files."""
    schedule = _schedule(args, parser)
    check_backend(args, parser)
    X, y, exclude = experiment_data(args, parser)
    with joblib_backend(args, parser):
        try:
            result = protocol.run_protocol(
                X, y, schedule=schedule, exclude_settings=exclude, n_jobs=args.n_jobs, verbose=True,
            )
        except ValueError as exc:
            parser.error(str(exc))
    tables = protocol.compute_tables(result)
    print(protocol.format_report(tables, result), flush=True)
    paths = protocol.write_results(tables, args.out, figures=not args.no_figures)
    result.timings.to_csv(f"{args.out}/timings.csv", index=False, float_format="%.3g")
    print(f"\nwrote {len(paths) + 1} files to {args.out}", flush=True)
    return 0
