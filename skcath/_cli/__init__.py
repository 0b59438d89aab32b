"""Command-line interface: ``python -m skcath <command>``.

The library itself reports through :mod:`logging`; only this package writes
to standard output, because printing the summary table is the point of the
command. Arguments that several commands share are declared once, in
``_arguments``; each command has its own module.

Commands
--------
benchmark
    Generate (or load from the cache) the default simulated benchmark with
    :func:`skcath.datasets.make_benchmark` and print a summary table.
reproduce
    Run the paper's evaluation protocol (:mod:`skcath.protocol`) on the
    benchmark or on recordings from a file, print its tables and write them
    as CSV with the figures as PNG.
calibration-budget
    Score the backbones and PDL+GRU on sweeps reduced to fewer rays or fewer
    samples (:func:`skcath.protocol.run_calibration_budget`), print the table
    and write it as CSV with the figure as PNG.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from .._version import __version__
from ..datasets import MECHANISMS
from ._benchmark import add_benchmark_command, format_table, summarize_benchmark
from ._budget import add_budget_command
from ._reproduce import add_reproduce_command

__all__ = ["MECHANISMS", "build_parser", "format_table", "main", "summarize_benchmark"]

PROG = "python -m skcath"


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser of ``python -m skcath``.

    Returns
    -------
    parser : argparse.ArgumentParser
        Parser with one sub-command per task. Invalid arguments make it exit
        with status 2 and a message on standard error.
    """
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=(
            "Tip-position estimation for tendon-driven catheters from motor "
            "measurements."
        ),
    )
    parser.add_argument("--version", action="version", version=f"skcath {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="command")
    commands.required = True
    for add_command in (add_benchmark_command, add_reproduce_command, add_budget_command):
        add_command(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; defaults to ``sys.argv[1:]``.

    Returns
    -------
    status : int
        Exit status: 0 on success. Invalid arguments raise ``SystemExit(2)``
        after printing a message to standard error.
    """
    parser = build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else list(argv))
    return args.handler(args, args.command_parser)
