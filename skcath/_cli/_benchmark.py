"""The ``benchmark`` command: generate (or load) the simulated benchmark and print a summary."""

from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Sequence

import numpy as np
import pandas as pd

from .. import datasets
from .._format import CATHETER, MOTION, MOTOR_COLUMNS, PHASE, RUN, SETTING, SWEEP, TORQUE_COLUMNS
from ._arguments import add_benchmark_arguments, positive_int, seed

__all__ = ["add_benchmark_command", "format_table", "summarize_benchmark"]

_AXES = ("x", "y", "z")


def add_benchmark_command(commands) -> None:
    """Add ``benchmark`` to the sub-commands ``commands``."""
    bench = commands.add_parser(
        "benchmark",
        help="generate (or load) the simulated benchmark and print a summary",
        description=(
            "Generate the default simulated benchmark with "
            "skcath.datasets.make_benchmark, or load it from the on-disk cache, "
            "and print a summary table."
        ),
    )
    bench.add_argument(
        "--n-catheters",
        type=positive_int,
        default=4,
        metavar="N",
        help="number of simulated catheters (default: %(default)s)",
    )
    bench.add_argument(
        "--n-runs",
        type=positive_int,
        default=3,
        metavar="N",
        help="number of repeated runs per catheter and shaft setting (default: %(default)s)",
    )
    bench.add_argument(
        "--random-state",
        type=seed,
        default=0,
        metavar="S",
        help="seed of the simulator (default: %(default)s)",
    )
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
    add_benchmark_arguments(bench)
    bench.set_defaults(handler=run_benchmark, command_parser=bench)


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


def run_benchmark(args, parser) -> int:
    """Print the summary of the benchmark that ``args`` describe."""
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
