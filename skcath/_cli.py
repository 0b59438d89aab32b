"""Command-line interface: ``python -m skcath <command>``.

The library itself reports through :mod:`logging`; only this module writes to
standard output, because printing the summary table is the point of the
command.

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
import contextlib
import dataclasses
import logging
import sys
import time
import warnings
from collections.abc import Sequence

import joblib
import numpy as np
import pandas as pd

from . import datasets, protocol
from ._format import (
    CATHETER,
    MOTION,
    MOTOR_COLUMNS,
    PHASE,
    RUN,
    SETTING,
    SWEEP,
    TORQUE_COLUMNS,
)
from ._version import __version__
from .frames import FRAMES
from .io import read_recording
from .protocol import VARIANTS

__all__ = ["build_parser", "main", "summarize_benchmark", "format_table"]

PROG = "python -m skcath"

#: Hysteresis mechanisms offered by the simulator (see
#: :func:`skcath.datasets.make_benchmark`).
MECHANISMS = ("play", "bouc_wen", "dahl_creep")

_AXES = ("x", "y", "z")

#: The straight reference setting of the built-in benchmark, never evaluated.
STRAIGHT_SETTING = "S00"

#: joblib backends ``reproduce`` trains the models with.
BACKENDS = ("loky", "dask", "ray")


def _positive_int(text: str) -> int:
    """Parse a strictly positive integer for argparse."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _seed(text: str) -> int:
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


def _variant_names():
    return list(VARIANTS)


def _add_mechanism_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--mechanism",
        choices=MECHANISMS,
        default="play",
        help="hysteresis mechanism of the simulated tendon drive (default: %(default)s)",
    )


def _add_data_home_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--data-home",
        default=None,
        metavar="DIR",
        help="cache folder of the benchmark (default: $SKCATH_DATA, else ~/skcath_data)",
    )


def _add_seeds_argument(parser: argparse.ArgumentParser, help_text: str) -> None:
    """Add ``--seeds S [S ...]``, the non-negative seeds of the learned models."""
    parser.add_argument(
        "--seeds",
        type=_seed,
        nargs="+",
        default=None,
        metavar="S",
        help=help_text,
    )


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

    bench = commands.add_parser(
        "benchmark",
        help="generate (or load) the simulated benchmark and print a summary",
        description=(
            "Generate the default simulated benchmark with "
            "skcath.datasets.make_benchmark, or load it from the on-disk cache, "
            "and print a summary table."
        ),
    )
    _add_mechanism_argument(bench)
    bench.add_argument(
        "--n-catheters",
        type=_positive_int,
        default=4,
        metavar="N",
        help="number of simulated catheters (default: %(default)s)",
    )
    bench.add_argument(
        "--n-runs",
        type=_positive_int,
        default=3,
        metavar="N",
        help="number of repeated runs per catheter and shaft setting (default: %(default)s)",
    )
    bench.add_argument(
        "--random-state",
        type=_seed,
        default=0,
        metavar="S",
        help="seed of the simulator (default: %(default)s)",
    )
    _add_data_home_argument(bench)
    bench.add_argument(
        "--no-cache",
        action="store_true",
        help="always simulate, and neither read nor write the cache",
    )
    bench.add_argument(
        "--verbose",
        action="store_true",
        help="log the progress of the simulation to standard error",
    )
    bench.set_defaults(handler=_run_benchmark, command_parser=bench)

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
        "about three minutes on two CPU cores",
    )
    repro.add_argument(
        "--out",
        default="skcath_results",
        metavar="DIR",
        help="output folder for the CSV tables and PNG figures (default: %(default)s)",
    )
    repro.add_argument(
        "--n-jobs",
        type=int,
        default=-1,
        metavar="N",
        help="models trained in parallel, one CPU core each; -1 uses all cores (with --backend "
        "dask: the local cluster's worker processes, or, with --scheduler, all worker threads) "
        "(default: %(default)s)",
    )
    repro.add_argument(
        "--data",
        default=None,
        metavar="PATH",
        help="recordings in the long format (CSV or Parquet with p_x, p_y, p_z or sensor poses, "
        "see docs/data_format.rst) instead of the built-in benchmark",
    )
    _add_seeds_argument(repro, "seeds of the learned models (default: 0 1 2, or 0 with --quick)")
    repro.add_argument(
        "--variants",
        nargs="+",
        default=None,
        metavar="NAME",
        help="learned methods to run, among: " + ", ".join(repr(v) for v in _variant_names())
        + " (default: all; the tables of methods not run are left out)",
    )
    repro.add_argument(
        "--frame",
        choices=FRAMES,
        default=None,
        help="frame of the residual learners (their `frame` parameter): each run's sweep frame, "
        "or the base-sensor frame as in the paper (default: the learners' default, sweep)",
    )
    repro.add_argument(
        "--exclude-settings",
        nargs="*",
        default=None,
        metavar="SETTING",
        help="settings used for training but never evaluated (default: the straight setting "
        f"{STRAIGHT_SETTING} of the built-in benchmark, none with --data)",
    )
    repro.add_argument(
        "--backend",
        choices=BACKENDS,
        default="loky",
        help="where the models are trained: local worker processes (loky), or the workers of "
        "a dask.distributed cluster (dask) or a Ray cluster (ray); see docs/cluster.rst "
        "(default: %(default)s)",
    )
    repro.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="with --backend dask: address of a running dask scheduler, e.g. tcp://host:8786; "
        "with --backend ray: address of a running Ray cluster, e.g. auto or ray://host:10001 "
        "(default: start a local cluster of --n-jobs single-threaded worker processes)",
    )
    _add_mechanism_argument(repro)
    _add_data_home_argument(repro)
    repro.add_argument(
        "--no-figures",
        action="store_true",
        help="write the CSV tables only (the figures need matplotlib)",
    )
    repro.set_defaults(handler=_run_reproduce, command_parser=repro)

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
        type=_positive_int,
        nargs="+",
        default=[8, 6, 4, 3],
        metavar="N",
        help="numbers of rays kept, at least 3 (default: %(default)s)",
    )
    budget.add_argument(
        "--strides",
        type=_positive_int,
        nargs="+",
        default=[5, 20, 50],
        metavar="S",
        help="keep every S-th sweep sample, with all rays (default: %(default)s)",
    )
    budget.add_argument(
        "--n-rays-swept",
        type=_positive_int,
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
    _add_seeds_argument(budget, "seeds of PDL+GRU (default: those of the schedule)")
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
    budget.add_argument(
        "--out",
        default="skcath_results",
        metavar="DIR",
        help="output folder for the CSV tables and the PNG figure (default: %(default)s)",
    )
    budget.add_argument(
        "--n-jobs",
        type=int,
        default=-1,
        metavar="N",
        help="runs calibrated and models trained in parallel; -1 uses all cores (default: %(default)s)",
    )
    budget.add_argument(
        "--data",
        default=None,
        metavar="PATH",
        help="recordings in the long format (CSV or Parquet, see docs/data_format.rst) instead of "
        "the built-in benchmark",
    )
    budget.add_argument(
        "--exclude-settings",
        nargs="*",
        default=None,
        metavar="SETTING",
        help="settings never evaluated (default: the straight setting "
        f"{STRAIGHT_SETTING} of the built-in benchmark, none with --data)",
    )
    _add_mechanism_argument(budget)
    _add_data_home_argument(budget)
    budget.add_argument(
        "--no-figures",
        action="store_true",
        help="write the CSV tables only (the figure needs matplotlib)",
    )
    budget.set_defaults(handler=_run_calibration_budget, command_parser=budget)
    return parser


def _median(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(np.median(values)) if values.size else float("nan")


def summarize_benchmark(bunch) -> list[tuple[str, str]]:
    """Summarize a benchmark data set as ``(label, value)`` rows.

    Parameters
    ----------
    bunch : sklearn.utils.Bunch
        Output of :func:`skcath.datasets.make_benchmark`; the fields ``X``
        (long-format recording table), ``y`` (measured tip positions, mm,
        base frame), ``noise_floor`` (mm) and ``mechanism`` are used, ``runs``
        when present.

    Returns
    -------
    rows : list of tuple of str
        Labels and formatted values, in display order.
    """
    X = bunch.X
    y = np.asarray(bunch.y, dtype=float)
    if y.ndim != 2 or y.shape[1] != 3 or y.shape[0] != len(X):
        raise ValueError(
            f"y must have shape (n_samples, 3) with n_samples={len(X)}, got {y.shape}"
        )

    runs = getattr(bunch, "runs", None)
    if runs is not None and {CATHETER, SETTING} <= set(runs.columns):
        pairs = runs[[CATHETER, SETTING]]
    else:
        pairs = X[[CATHETER, SETTING]]
    pairs = pairs.astype(str).drop_duplicates()
    n_catheters = pairs[CATHETER].nunique()

    # Samples per run and per phase; a run missing one phase counts zero there.
    counts = (
        X.assign(_phase=X[PHASE].astype(str))
        .groupby([RUN, "_phase"], observed=True, sort=False)
        .size()
        .unstack(fill_value=0)
    )
    counts = counts.reindex(columns=[SWEEP, MOTION], fill_value=0)
    per_run = counts.sum(axis=1)

    # Per-axis span of the measured tip position in each run; rows with a
    # dropout in any coordinate are left out.
    finite = np.isfinite(y).all(axis=1)
    tip = pd.DataFrame(np.where(finite[:, None], y, np.nan), columns=list(_AXES))
    grouped = tip.groupby(X[RUN].to_numpy(), sort=False)
    spans = (grouped.max() - grouped.min()).to_numpy(dtype=float)
    with warnings.catch_warnings():
        # A run (or all runs) without a finite sample gives NaN, not a warning.
        warnings.simplefilter("ignore", RuntimeWarning)
        span = np.nanmedian(spans, axis=0) if len(spans) else np.full(3, np.nan)

    q = X[list(MOTOR_COLUMNS)].to_numpy(dtype=float)
    q_max = float(np.max(np.hypot(q[:, 0], q[:, 1]))) if len(q) else float("nan")

    rows = [
        ("mechanism", str(getattr(bunch, "mechanism", "?"))),
        ("runs", f"{len(counts)}"),
        ("catheters", f"{n_catheters}"),
        ("shaft settings (catheter x setting)", f"{len(pairs)}"),
        ("samples", f"{len(X)}"),
        (
            "samples per run (min / median / max)",
            f"{per_run.min()} / {_median(per_run):g} / {per_run.max()}",
        ),
        ("sweep samples per run (median)", f"{_median(counts[SWEEP]):g}"),
        ("motion samples per run (median)", f"{_median(counts[MOTION]):g}"),
        (
            "tip span x / y / z (median over runs, mm)",
            " / ".join(f"{v:.1f}" for v in span),
        ),
        ("max motor magnitude |q| (deg)", f"{q_max:.1f}"),
    ]
    for name in TORQUE_COLUMNS:
        tau = X[name].to_numpy(dtype=float)
        rows.append((f"{name} range (N mm)", f"[{np.min(tau):.3g}, {np.max(tau):.3g}]"))
    rows.append(("tracker dropouts (samples)", f"{int(np.sum(~np.isfinite(y).all(axis=1)))}"))
    rows.append(("sensor-noise floor (mm)", f"{float(bunch.noise_floor):.3f}"))
    return rows


def format_table(rows: Sequence[tuple[str, str]], title: str | None = None) -> str:
    """Format ``(label, value)`` rows as a two-column plain-text table.

    Parameters
    ----------
    rows : sequence of tuple of str
        Labels and values.
    title : str, optional
        Heading printed above the table.

    Returns
    -------
    table : str
        The table, without a trailing newline.
    """
    width = max((len(label) for label, _ in rows), default=0)
    value_width = max((len(value) for _, value in rows), default=0)
    lines = []
    if title:
        lines.append(title)
        lines.append("-" * max(len(title), width + 2 + value_width))
    lines.extend(f"{label:<{width}}  {value}" for label, value in rows)
    return "\n".join(lines)


def _cache_state(folder) -> dict:
    """Names and modification times of the files in the cache folder."""
    return {path.name: path.stat().st_mtime_ns for path in folder.iterdir() if path.is_file()}


def _run_benchmark(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    if args.verbose:
        logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")

    cache = not args.no_cache
    folder = None
    if cache:
        try:
            folder = datasets.get_data_home(args.data_home)
        except OSError as exc:
            parser.error(f"argument --data-home: cannot use it as the cache folder ({exc})")
    before = _cache_state(folder) if cache else None
    start = time.perf_counter()
    try:
        bunch = datasets.make_benchmark(
            n_catheters=args.n_catheters,
            n_runs=args.n_runs,
            mechanism=args.mechanism,
            random_state=args.random_state,
            data_home=args.data_home,
            cache=cache,
            verbose=args.verbose,
        )
    except ValueError as exc:
        # Parameter combinations the simulator rejects are usage errors.
        parser.error(str(exc))
    elapsed = time.perf_counter() - start

    # make_benchmark writes the cache only when it simulates.
    generated = not cache or _cache_state(folder) != before
    summary = summarize_benchmark(bunch)
    rows = [
        *summary[:1],
        ("random state", str(args.random_state)),
        *summary[1:],
        ("cache", f"{folder} ({'written' if generated else 'loaded'})" if cache else "disabled"),
        ("generation time (s)" if generated else "load time (s)", f"{elapsed:.1f}"),
    ]
    print(format_table(rows, title="skcath benchmark"))
    return 0


def _excluded_settings(args, parser, figures_need):
    """Settings never evaluated (the benchmark's straight one by default), after
    checking that matplotlib is installed when figures are to be drawn.

    ``figures_need`` starts the error message, e.g. ``"the figures need"``.
    """
    if not args.no_figures:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            parser.error(f'{figures_need} matplotlib: pip install "skcath[plot]", or pass --no-figures')
    if args.exclude_settings is not None:
        return args.exclude_settings
    return () if args.data is not None else (STRAIGHT_SETTING,)


def _load_reproduce_data(args, parser):
    """Recordings and targets for ``reproduce``: a file, or the built-in benchmark."""
    if args.data is not None:
        try:
            return read_recording(args.data)
        except (OSError, ValueError, ImportError) as exc:
            parser.error(f"argument --data: {exc}")
    try:
        bunch = datasets.make_benchmark(mechanism=args.mechanism, data_home=args.data_home)
    except (OSError, ValueError) as exc:
        parser.error(str(exc))
    return bunch.X, bunch.y


@contextlib.contextmanager
def _joblib_backend(args, parser):
    """The joblib backend of ``reproduce``: local processes, a dask or a Ray cluster.

    With ``--backend dask``, connects to ``--scheduler`` or starts a local
    cluster of ``--n-jobs`` worker processes of one thread each (each model
    trains with one torch thread), and closes what it opened on exit.
    ``--backend ray`` does the same with Ray.
    """
    if args.backend == "ray":
        with _ray_backend(args, parser):
            yield
        return
    if args.backend != "dask":
        yield
        return
    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if args.scheduler is not None:
            try:
                client = stack.enter_context(Client(args.scheduler, timeout="20s"))
            except OSError as exc:
                parser.error(f"argument --scheduler: cannot connect to {args.scheduler!r}: {exc}")
        else:
            n_workers = joblib.effective_n_jobs(args.n_jobs)  # -1: all cores
            cluster = stack.enter_context(
                LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                             dashboard_address=None)
            )
            client = stack.enter_context(Client(cluster))
        n_threads = sum(client.nthreads().values())
        print(f"dask cluster: {client.scheduler.address}, {n_threads} worker threads",
              file=sys.stderr, flush=True)
        stack.enter_context(joblib.parallel_config(backend="dask"))
        yield


@contextlib.contextmanager
def _ray_backend(args, parser):
    """Connect to the Ray cluster at ``--scheduler``, or start a local one of ``--n-jobs`` CPUs."""
    import ray
    from ray.util.joblib import register_ray

    register_ray()
    if args.scheduler is not None:
        try:
            ray.init(address=args.scheduler, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            parser.error(f"argument --scheduler: cannot connect to {args.scheduler!r}: {exc}")
    else:
        ray.init(num_cpus=joblib.effective_n_jobs(args.n_jobs), include_dashboard=False,
                 log_to_driver=False)
    try:
        n_cpus = int(ray.cluster_resources().get("CPU", 0))
        print(f"ray cluster: {n_cpus} CPUs", file=sys.stderr, flush=True)
        with joblib.parallel_config(backend="ray"):
            yield
    finally:
        ray.shutdown()


def _run_reproduce(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    if args.n_jobs == 0:
        parser.error("argument --n-jobs: expected a positive number of jobs or -1 (all cores), got 0")
    schedule = protocol.QUICK if args.quick else protocol.FULL
    if args.seeds is not None:
        schedule = dataclasses.replace(schedule, seeds=tuple(dict.fromkeys(args.seeds)))
    if args.variants is not None:
        unknown = [v for v in args.variants if v not in protocol.VARIANTS]
        if unknown:
            parser.error(f"argument --variants: unknown {unknown}; expected names among {list(protocol.VARIANTS)}")
        if "PDL+GRU" not in args.variants:
            parser.error("argument --variants: 'PDL+GRU' is required (Table I and the comparisons use it)")
        schedule = dataclasses.replace(schedule, variants=tuple(dict.fromkeys(args.variants)))
    if args.frame is not None:
        schedule = dataclasses.replace(schedule, model_params={**schedule.model_params, "frame": args.frame})
    exclude = _excluded_settings(args, parser, "the figures need")
    if args.scheduler is not None and args.backend == "loky":
        parser.error("argument --scheduler: only with --backend dask or --backend ray")
    if args.backend == "dask":
        try:
            import distributed  # noqa: F401
        except ImportError:
            parser.error('argument --backend: dask needs dask.distributed: pip install "skcath[dask]"')
    if args.backend == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            parser.error('argument --backend: ray needs Ray: pip install "skcath[ray]"')
    X, y = _load_reproduce_data(args, parser)
    with _joblib_backend(args, parser):
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


def _run_calibration_budget(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    if args.n_jobs == 0:
        parser.error("argument --n-jobs: expected a positive number of jobs or -1 (all cores), got 0")
    schedule = protocol.QUICK if args.schedule == "quick" else protocol.FULL
    if args.seeds is not None:
        schedule = dataclasses.replace(schedule, seeds=tuple(dict.fromkeys(args.seeds)))
    exclude = _excluded_settings(args, parser, "the figure needs")
    X, y = _load_reproduce_data(args, parser)
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
