"""Arguments shared by the commands, each declared once, and what they mean.

Every command adds the groups it needs with one ``add_*_arguments`` call;
the helpers below them turn the parsed arguments into what the library
takes (the recordings, the settings never evaluated, the schedule's seeds).
"""

from __future__ import annotations

import argparse
import dataclasses

from .. import datasets
from ..io import read_recording

#: The straight reference setting of the built-in benchmark, never evaluated.
STRAIGHT_SETTING = "S00"


def positive_int(text: str) -> int:
    """Parse a strictly positive integer for argparse."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def seed(text: str) -> int:
    """Parse a non-negative integer seed for argparse."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a non-negative integer seed, got {text!r}"
        ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {value}")
    return value


def n_jobs(text: str) -> int:
    """Parse a joblib number of jobs for argparse: a positive integer, or negative (-1: all cores)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if value == 0:
        raise argparse.ArgumentTypeError(
            "expected a positive number of jobs or -1 (all cores), got 0"
        )
    return value


def add_benchmark_arguments(parser: argparse.ArgumentParser) -> None:
    """``--mechanism`` and ``--data-home``: which simulated benchmark, and where it is cached."""
    group = parser.add_argument_group("built-in benchmark")
    group.add_argument(
        "--mechanism",
        choices=datasets.MECHANISMS,
        default="play",
        help="hysteresis mechanism of the simulated tendon drive (default: %(default)s)",
    )
    group.add_argument(
        "--data-home",
        default=None,
        metavar="DIR",
        help="cache folder of the benchmark (default: $SKCATH_DATA, else ~/skcath_data)",
    )


def add_recordings_arguments(parser: argparse.ArgumentParser) -> None:
    """``--data`` and ``--exclude-settings``: the recordings and the settings never evaluated."""
    group = parser.add_argument_group("recordings")
    group.add_argument(
        "--data",
        default=None,
        metavar="PATH",
        help="recordings in the long format (CSV or Parquet with p_x, p_y, p_z or sensor poses, "
        "see docs/data_format.rst) instead of the built-in benchmark",
    )
    group.add_argument(
        "--exclude-settings",
        nargs="*",
        default=None,
        metavar="SETTING",
        help="settings used for training but never evaluated (default: the straight setting "
        f"{STRAIGHT_SETTING} of the built-in benchmark, none with --data)",
    )


def add_training_arguments(parser: argparse.ArgumentParser) -> None:
    """``--n-jobs`` and ``--seeds``: parallel work and the seeds of the learned models."""
    group = parser.add_argument_group("training")
    group.add_argument(
        "--n-jobs",
        type=n_jobs,
        default=-1,
        metavar="N",
        help="runs calibrated and models trained in parallel, one CPU core each; -1 uses all "
        "cores (default: %(default)s)",
    )
    group.add_argument(
        "--seeds",
        type=seed,
        nargs="+",
        default=None,
        metavar="S",
        help="seeds of the learned models (default: those of the schedule)",
    )


def add_output_arguments(parser: argparse.ArgumentParser) -> None:
    """``--out`` and ``--no-figures``: where the results go, and whether figures are drawn."""
    group = parser.add_argument_group("output")
    group.add_argument(
        "--out",
        default="skcath_results",
        metavar="DIR",
        help="output folder for the CSV tables and PNG figures (default: %(default)s)",
    )
    group.add_argument(
        "--no-figures",
        action="store_true",
        help="write the CSV tables only (the figures need matplotlib)",
    )


def add_experiment_arguments(parser: argparse.ArgumentParser) -> None:
    """The groups of a command that trains and evaluates on recordings and writes results."""
    for add_group in (
        add_training_arguments,
        add_recordings_arguments,
        add_benchmark_arguments,
        add_output_arguments,
    ):
        add_group(parser)


def experiment_data(args, parser):
    """Recordings, targets and the settings never evaluated that the arguments name.

    Exits with a usage error when figures are to be drawn without matplotlib
    or the recordings cannot be read. The recordings are the file of
    ``--data``, or the built-in benchmark, whose straight setting is not
    evaluated unless ``--exclude-settings`` says otherwise.
    """
    if not args.no_figures:
        try:
            import matplotlib  # noqa: F401  (an optional dependency: only probed)
        except ImportError:
            parser.error('the figures need matplotlib: pip install "skcath[plot]", or pass --no-figures')
    if args.exclude_settings is not None:
        exclude = args.exclude_settings
    else:
        exclude = () if args.data is not None else (STRAIGHT_SETTING,)
    if args.data is not None:
        try:
            X, y = read_recording(args.data)
        except (OSError, ValueError, ImportError) as exc:
            parser.error(f"argument --data: {exc}")
        return X, y, exclude
    try:
        bunch = datasets.make_benchmark(mechanism=args.mechanism, data_home=args.data_home)
    except (OSError, ValueError) as exc:
        parser.error(str(exc))
    return bunch.X, bunch.y, exclude


def with_seeds(schedule, args):
    """``schedule`` with the seeds of ``--seeds`` (repeats dropped), if given."""
    if args.seeds is None:
        return schedule
    return dataclasses.replace(schedule, seeds=tuple(dict.fromkeys(args.seeds)))
