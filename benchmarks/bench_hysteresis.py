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
"""

import argparse
import time

import pandas as pd
from sklearn.utils import Bunch

from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
from skcath.datasets import MECHANISMS, make_benchmark
from skcath.metrics import mean_per_run_rmse

BACKBONES = {"PCC": PCCBackbone, "PDL": PDLBackbone, "Polynomial": PolynomialBackbone}


def measure(data, name, hysteresis):
    """Seconds per run, mean sweep RMSE and mean motion RMSE (mm) of one backbone."""
    backbone = BACKBONES[name](hysteresis=hysteresis)
    if name != "Polynomial":
        backbone.set_params(n_jobs=1)
    backbone.fit(data.X)
    n_runs = data.X["run"].nunique()
    start, cpu = time.perf_counter(), time.process_time()
    calibration = backbone.calibrate(data.X)
    seconds = (time.perf_counter() - start) / n_runs
    cpu_seconds = (time.process_time() - cpu) / n_runs
    motion = mean_per_run_rmse(data.y, calibration.nominal, data.X)
    return {"s/run": seconds, "CPU s/run": cpu_seconds, "sweep RMSE (mm)": calibration.table["rmse_mm"].mean(),
            "motion RMSE (mm)": motion}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mechanism", choices=[*MECHANISMS, "all"], default="all")
    parser.add_argument("--n-runs", type=int, default=1, help="runs per catheter (default 1)")
    parser.add_argument("--max-runs", type=int, default=None,
                        help="score the first runs only (default: all 17 of the catheter)")
    parser.add_argument("--random-state", type=int, default=0)
    parser.add_argument("--backbones", nargs="+", choices=list(BACKBONES), default=list(BACKBONES),
                        help="backbones measured (default: all three)")
    args = parser.parse_args(argv)
    mechanisms = MECHANISMS if args.mechanism == "all" else (args.mechanism,)
    rows = []
    for mechanism in mechanisms:
        data = make_benchmark(mechanism=mechanism, n_catheters=1, n_runs=args.n_runs,
                              random_state=args.random_state)
        if args.max_runs:
            keep = data.X["run"].isin(data.X["run"].unique()[: args.max_runs]).to_numpy()
            data = Bunch(X=data.X[keep], y=data.y[keep])
        first = data.X["run"].to_numpy() == data.X["run"].iloc[0]
        warm = Bunch(X=data.X[first], y=data.y[first])
        for name in args.backbones:
            options = (None, "pi") if name == "Polynomial" else (None, "play", "pi")
            for hysteresis in options:
                measure(warm, name, hysteresis)  # warm-up: compiles the kernels
                rows.append({"mechanism": mechanism, "backbone": name,
                             "hysteresis": str(hysteresis),
                             **measure(data, name, hysteresis)})
                print(*(f"{v:.3f}" if isinstance(v, float) else v for v in rows[-1].values()),
                      sep="\t", flush=True)
    table = pd.DataFrame(rows).set_index(["mechanism", "backbone", "hysteresis"])
    with pd.option_context("display.width", 140, "display.max_columns", None, "display.float_format", "{:.3f}".format):
        print(table)


if __name__ == "__main__":
    main()
