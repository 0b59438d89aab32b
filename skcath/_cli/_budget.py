"""The ``calibration-budget`` command: tip error against the size of the calibration sweep."""

from __future__ import annotations

from .. import protocol
from ._arguments import add_experiment_arguments, experiment_data, positive_int, with_seeds

__all__ = ["add_budget_command"]


def add_budget_command(commands) -> None:
    """Add ``calibration-budget`` to the sub-commands ``commands``."""
    budget = commands.add_parser(
        "calibration-budget",
        help="tip error against the size of the calibration sweep (fewer rays, fewer samples)",
        description=(
            "Reduce every evaluated run's calibration sweep to fewer rays (every sample) or to "
            "every s-th sample (all rays) with skcath.sweep.reduce_sweep, calibrate the PCC and PDL "
            "backbones on the reduced sweep, apply a PDL+GRU trained on full sweeps (pretrained on "
            "the other catheters, fine-tuned with shaft settings held out, as in reproduce), and "
            "score them all on the unchanged motion rows. Prints the table of mean per-run RMSE "
            "and writes it as CSV, with the figure as PNG, to the output folder."
        ),
    )
    budget.add_argument(
        "--rays",
        type=positive_int,
        nargs="+",
        default=[8, 6, 4, 3],
        metavar="N",
        help="numbers of rays kept, at least 3 (default: %(default)s)",
    )
    budget.add_argument(
        "--strides",
        type=positive_int,
        nargs="+",
        default=[5, 20, 50],
        metavar="S",
        help="keep every S-th sweep sample, with all rays (default: %(default)s)",
    )
    budget.add_argument(
        "--n-rays-swept",
        type=positive_int,
        default=8,
        metavar="N",
        help="rays of the recorded sweeps, evenly spaced (default: %(default)s)",
    )
    budget.add_argument(
        "--schedule",
        choices=("quick", "full"),
        default="quick",
        help="training schedule of PDL+GRU, as in reproduce (default: %(default)s)",
    )
    budget.add_argument(
        "--backbones-only",
        action="store_true",
        help="score PCC and PDL only, without training PDL+GRU (about a third of the time)",
    )
    budget.add_argument(
        "--catheters",
        nargs="+",
        default=None,
        metavar="ID",
        help="catheters evaluated (default: all); the others still serve for pretraining",
    )
    add_experiment_arguments(budget)
    budget.set_defaults(handler=run_calibration_budget, command_parser=budget)


def run_calibration_budget(args, parser) -> int:
    """Score the budgets that ``args`` describe; print the table and write its files."""
    schedule = with_seeds(protocol.QUICK if args.schedule == "quick" else protocol.FULL, args)
    X, y, exclude = experiment_data(args, parser)
    try:
        result = protocol.run_calibration_budget(
            X, y, rays=args.rays, strides=args.strides, n_rays_swept=args.n_rays_swept,
            learned=not args.backbones_only, schedule=schedule, catheters=args.catheters,
            exclude_settings=exclude, n_jobs=args.n_jobs, verbose=True,
        )
    except ValueError as exc:
        parser.error(str(exc))
    print(protocol.format_budget_report(result), flush=True)
    paths = protocol.write_budget_results(result, args.out, figure=not args.no_figures)
    print(f"\nwrote {len(paths)} files to {args.out}", flush=True)
    return 0
