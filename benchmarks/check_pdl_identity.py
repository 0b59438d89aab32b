"""The PDL calibrations of this tree against another checkout's: bit for bit, and their CPU time.

For every run of each benchmark, the PDL backbone (``n_jobs=1``) is calibrated
on the run alone with ``hysteresis=None``, ``"play"`` and ``"pi"``, once with
the package of this tree and once with the package of another checkout (e.g.
``git worktree add /tmp/pdlbase <commit>``), each in a process of its own
(``PYTHONPATH`` set to the checkout), the baseline first. A run differs when
anything of its calibration is not exactly equal (``np.array_equal``, NaN equal
to NaN): its table row (the parameters' ``to_dict``, ``rmse_mm``, ``n_iter``,
``converged``, the play's half-width, the PI's parameters), its parameters'
arrays or its nominal tips. The script prints, per benchmark and hysteresis,
the number of runs, the number that differ (0 when the trees compute the same
numbers) and the median and largest CPU seconds (``time.process_time``, after a
warm-up calibration that compiles the kernels) of one run's ``calibrate`` in
each tree, with the ratio this tree / baseline of the medians and of the sums.
``--repeat N`` runs both checkouts N times, alternately, keeps each run's
smallest CPU seconds (a loaded machine only ever adds time) and checks that
each checkout repeats its own numbers.

Benchmarks: ``C1``, the 51 runs of catheter C1 of ``make_benchmark()``;
``play``, ``bouc_wen``, ``dahl_creep``, the 17 runs of
``make_benchmark(mechanism=..., n_catheters=1, n_runs=1)``; ``mixed``, runs of
``make_benchmark(mechanism="mixed", unit_spread=1.0)`` evenly spaced (as
``bench_hysteresis.py --mechanism mixed --max-runs``).

Usage (from the repository root; one core)::

    git worktree add /tmp/pdlbase 2961bc5
    OMP_NUM_THREADS=1 python benchmarks/check_pdl_identity.py --baseline /tmp/pdlbase
    OMP_NUM_THREADS=1 python benchmarks/check_pdl_identity.py --baseline /tmp/pdlbase \\
        --benchmarks mixed --max-runs 10 --repeat 2
"""

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

BENCHMARKS = ("C1", "play", "bouc_wen", "dahl_creep", "mixed")
HYSTERESIS = ("None", "play", "pi")
ROOT = Path(__file__).resolve().parents[1]


def load(name, max_runs):
    """The recordings of one benchmark, its first ``max_runs`` runs (evenly spaced ones for ``mixed``)."""
    from skcath.datasets import make_benchmark

    if name == "C1":
        data = make_benchmark()
        X = data.X[data.X["run"].str.startswith("C1-")]
    elif name == "mixed":
        X = make_benchmark(mechanism="mixed", unit_spread=1.0).X
    else:
        X = make_benchmark(mechanism=name, n_catheters=1, n_runs=1, random_state=0).X
    runs = pd.unique(X["run"])
    if max_runs and max_runs < len(runs):
        runs = (runs[np.linspace(0, len(runs) - 1, max_runs).round().astype(int)]
                if name == "mixed" else runs[:max_runs])
    return X, runs


def outputs(calibration, run):
    """Everything one run's calibration returns, as arrays and plain values."""
    params = calibration.params[run]
    arrays = {name: np.asarray(getattr(params, name))
              for name in ("coef", "p0", "basis", "q_neutral", "directions", "rho0")}
    return {"table": calibration.table.loc[run].to_dict(), "nominal": np.asarray(calibration.nominal),
            "play_width": calibration.play_widths[run], **arrays}


def work(args):
    """Calibrate every run alone with the package on ``sys.path``; pickle the outputs and CPU seconds."""
    from skcath.backbones import PDLBackbone

    results = {}
    for name in args.benchmarks:
        X, runs = load(name, args.max_runs)
        for hysteresis in args.hysteresis:
            backbone = PDLBackbone(hysteresis=None if hysteresis == "None" else hysteresis, n_jobs=1).fit(X)
            backbone.calibrate(X[X["run"] == runs[0]])  # warm-up: compiles the kernels
            for run in runs:
                X_run = X[X["run"] == run]
                cpu = time.process_time()
                calibration = backbone.calibrate(X_run)
                results[name, hysteresis, run] = (outputs(calibration, run), time.process_time() - cpu)
    with open(args.worker, "wb") as f:
        pickle.dump(results, f)


def same(a, b):
    """Whether two outputs of :func:`outputs` are exactly equal (NaN equal to NaN)."""
    if a.keys() != b.keys() or a["table"].keys() != b["table"].keys():
        return False
    pairs = [(a[k], b[k]) for k in a if k != "table"] + [(a["table"][k], b["table"][k]) for k in a["table"]]
    for u, v in pairs:
        u, v = np.asarray(u), np.asarray(v)
        if u.dtype.kind == "f" or v.dtype.kind == "f":
            if not np.array_equal(u, v, equal_nan=True):
                return False
        elif not np.array_equal(u, v):
            return False
    return True


def run_tree(path, args, out):
    """Run :func:`work` in a process importing the package of the checkout ``path``."""
    env = {**os.environ, "PYTHONPATH": str(path), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    command = [sys.executable, __file__, "--worker", out, "--benchmarks", *args.benchmarks,
               "--hysteresis", *args.hysteresis, "--max-runs", str(args.max_runs or 0)]
    subprocess.run(command, env=env, check=True, cwd=path)
    with open(out, "rb") as f:
        return pickle.load(f)


def fastest(results):
    """The outputs of the first of repeated :func:`work` results, with each run's smallest CPU seconds."""
    first = results[0]
    for other in results[1:]:
        if any(not same(first[key][0], other[key][0]) for key in first):
            raise RuntimeError("a checkout gave different numbers when run again")
    return {key: (first[key][0], min(r[key][1] for r in results)) for key in first}


def compare(before, after):
    """Per benchmark and hysteresis: runs, runs that differ, CPU seconds per run before and after."""
    rows = []
    keys = pd.MultiIndex.from_tuples(list(before)).droplevel(2).unique()
    for name, hysteresis in keys:
        runs = [key for key in before if key[:2] == (name, hysteresis)]
        cpu_before = np.array([before[key][1] for key in runs])
        cpu_after = np.array([after[key][1] for key in runs])
        rows.append({
            "benchmark": name, "hysteresis": hysteresis, "runs": len(runs),
            "differ": sum(not same(before[key][0], after[key][0]) for key in runs),
            "median CPU s before": np.median(cpu_before), "max before": cpu_before.max(),
            "median CPU s after": np.median(cpu_after), "max after": cpu_after.max(),
            "ratio of medians": np.median(cpu_after) / np.median(cpu_before),
            "ratio of sums": cpu_after.sum() / cpu_before.sum(),
        })
    return pd.DataFrame(rows).set_index(["benchmark", "hysteresis"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="checkout whose package is the reference")
    parser.add_argument("--benchmarks", nargs="+", choices=BENCHMARKS, default=list(BENCHMARKS))
    parser.add_argument("--hysteresis", nargs="+", choices=HYSTERESIS, default=list(HYSTERESIS))
    parser.add_argument("--max-runs", type=int, default=0,
                        help="the first runs of each benchmark only (evenly spaced for mixed; default 0: all)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="run both checkouts this many times, alternately, and keep each run's "
                             "smallest CPU seconds (default 1)")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return work(args)
    if args.baseline is None:
        parser.error("--baseline (a checkout of the reference commit) is required")
    with tempfile.TemporaryDirectory() as tmp:
        rounds = [(run_tree(args.baseline.resolve(), args, os.path.join(tmp, f"before{i}.pkl")),
                   run_tree(ROOT, args, os.path.join(tmp, f"after{i}.pkl"))) for i in range(args.repeat)]
    table = compare(*(fastest([r[i] for r in rounds]) for i in (0, 1)))
    with pd.option_context("display.width", 160, "display.max_columns", None,
                           "display.float_format", "{:.3f}".format):
        print(table)
    print(f"runs that differ: {int(table['differ'].sum())} of {int(table['runs'].sum())}")
    return int(table["differ"].sum() > 0)


if __name__ == "__main__":
    sys.exit(main())
