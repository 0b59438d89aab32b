"""Per-run hysteresis identified on the sweep: the play against Prandtl-Ishlinskii.

For each hysteresis mechanism of the simulator (``make_benchmark(mechanism=...,
n_catheters=1, n_runs=...)``) and each backbone (PCC, PDL, Polynomial), the
backbone alone is calibrated on every run's own sweep with ``hysteresis=None``,
``"play"`` and ``"pi"``, and the script prints, as means over the runs: the
seconds of ``calibrate`` per run (one core: ``n_jobs=1``, one thread; after a
warm-up call that compiles the kernels) in wall-clock time and in CPU time of the
process (which a loaded machine inflates less), the sweep-fit RMSE (``rmse_mm`` of
``calibrate``, mm) and the motion RMSE (mm, mean per-run RMSE over the motion
rows). The Polynomial backbone has no play, so its ``"play"`` row is left out.

Usage (from the repository root)::

    OMP_NUM_THREADS=1 python benchmarks/bench_hysteresis.py
    OMP_NUM_THREADS=1 python benchmarks/bench_hysteresis.py --mechanism dahl_creep --max-runs 4
    OMP_NUM_THREADS=1 python benchmarks/bench_hysteresis.py --backbones PDL PCC --max-runs 4
    OMP_NUM_THREADS=1 python benchmarks/bench_hysteresis.py --mechanism mixed --max-runs 10 --per-run --backbones PDL
"""

import argparse
import time

import numpy as np
import pandas as pd
from sklearn.utils import Bunch

from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
from skcath.datasets import MECHANISMS, make_benchmark
from skcath.metrics import mean_per_run_rmse

BACKBONES = {"PCC": PCCBackbone, "PDL": PDLBackbone, "Polynomial": PolynomialBackbone}


def timed_calibrate(backbone, X):
    """The calibration of ``X`` and its wall-clock and CPU seconds."""
    start, cpu = time.perf_counter(), time.process_time()
    calibration = backbone.calibrate(X)
    return calibration, time.perf_counter() - start, time.process_time() - cpu


def per_run_seconds(backbone, X):
    """Median and largest wall-clock and CPU seconds of ``calibrate`` on each run of ``X`` alone."""
    runs = X["run"].to_numpy()
    times = np.array([timed_calibrate(backbone, X[runs == run])[1:] for run in pd.unique(runs)])
    return {"median s": np.median(times[:, 0]), "max s": times[:, 0].max(),
            "median CPU s": np.median(times[:, 1]), "max CPU s": times[:, 1].max()}


def measure(data, name, hysteresis, per_run=False):
    """Seconds per run, mean sweep RMSE and mean motion RMSE (mm) of one backbone."""
    backbone = BACKBONES[name](hysteresis=hysteresis)
    if name != "Polynomial":
        backbone.set_params(n_jobs=1)
    backbone.fit(data.X)
    n_runs = data.X["run"].nunique()
    calibration, seconds, cpu_seconds = timed_calibrate(backbone, data.X)
    motion = mean_per_run_rmse(data.y, calibration.nominal, data.X)
    row = {"s/run": seconds / n_runs, "CPU s/run": cpu_seconds / n_runs,
           "sweep RMSE (mm)": calibration.table["rmse_mm"].mean(), "motion RMSE (mm)": motion}
    return {**row, **(per_run_seconds(backbone, data.X) if per_run else {})}


def load(mechanism, args):
    """The recordings of one mechanism, the first ``--max-runs`` runs (evenly spaced ones for ``mixed``)."""
    if mechanism == "mixed":
        data = make_benchmark(mechanism="mixed", unit_spread=1.0)
    else:
        data = make_benchmark(mechanism=mechanism, n_catheters=1, n_runs=args.n_runs,
                              random_state=args.random_state)
    if args.max_runs:
        runs = pd.unique(data.X["run"])
        chosen = (runs[np.linspace(0, len(runs) - 1, args.max_runs).round().astype(int)]
                  if mechanism == "mixed" else runs[: args.max_runs])
        keep = data.X["run"].isin(chosen).to_numpy()
        data = Bunch(X=data.X[keep], y=data.y[keep])
    return data


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mechanism", choices=[*MECHANISMS, "mixed", "all"], default="all",
                        help="'mixed': the four units of make_benchmark(mechanism='mixed', unit_spread=1.0); "
                             "'all': each of the three mechanisms (default: all)")
    parser.add_argument("--n-runs", type=int, default=1, help="runs per catheter (default 1)")
    parser.add_argument("--max-runs", type=int, default=None,
                        help="score the first runs only (default: all 17 of the catheter)")
    parser.add_argument("--random-state", type=int, default=0)
    parser.add_argument("--backbones", nargs="+", choices=list(BACKBONES), default=list(BACKBONES),
                        help="backbones measured (default: all three)")
    parser.add_argument("--per-run", action="store_true",
                        help="also calibrate each run alone: median and largest seconds of one run")
    args = parser.parse_args(argv)
    mechanisms = MECHANISMS if args.mechanism == "all" else (args.mechanism,)
    rows = []
    for mechanism in mechanisms:
        data = load(mechanism, args)
        first = data.X["run"].to_numpy() == data.X["run"].iloc[0]
        warm = Bunch(X=data.X[first], y=data.y[first])
        for name in args.backbones:
            options = (None, "pi") if name == "Polynomial" else (None, "play", "pi")
            for hysteresis in options:
                measure(warm, name, hysteresis)  # warm-up: compiles the kernels
                rows.append({"mechanism": mechanism, "backbone": name,
                             "hysteresis": str(hysteresis),
                             **measure(data, name, hysteresis, args.per_run)})
                print(*(f"{v:.3f}" if isinstance(v, float) else v for v in rows[-1].values()),
                      sep="\t", flush=True)
    table = pd.DataFrame(rows).set_index(["mechanism", "backbone", "hysteresis"])
    with pd.option_context("display.width", 140, "display.max_columns", None, "display.float_format", "{:.3f}".format):
        print(table)


if __name__ == "__main__":
    main()
