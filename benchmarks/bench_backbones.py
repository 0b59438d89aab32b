"""Backbone baselines on the simulated benchmark: PCC and PDL tip RMSE.

Calibrates both backbones on every run's own sweep and scores the motion rows
of the 16 bent shaft settings (48 runs per catheter, as in the paper), then
prints mean per-run RMSE per catheter and pooled, the share of runs where PDL
beats PCC, and the median run-bin RMSE by motor-input magnitude (10-degree
bins, as the paper's Fig. 5(b)).

The summary also gives, per catheter and pooled over the same runs, the
backbones' sweep-fit RMSE (``rmse_mm`` of ``calibrate``) and, with
``--hysteresis play``, the mean half-width of the play identified on each
run's sweep (deg); ``--hysteresis play`` calibrates both backbones with
``hysteresis="play"``.

With ``--one-run`` it times instead, on the first run of the benchmark
(one catheter), ``predict`` (calibration included) and the evaluation of the
calibrated backbone on the run's rows (``pcc_tip``, ``pdl_tip``): the best of
seven calls, after one call that compiles the loop over the rows (or loads
it from numba's cache). Run it with and without ``NUMBA_DISABLE_JIT=1`` to
compare the compiled loop with the same loop run as Python.

Usage::

    python benchmarks/bench_backbones.py                 # default benchmark (play)
    python benchmarks/bench_backbones.py --mechanism all # the three mechanisms
    python benchmarks/bench_backbones.py --hysteresis play  # backbones with a play
    python benchmarks/bench_backbones.py --one-run       # times on one run
    NUMBA_DISABLE_JIT=1 python benchmarks/bench_backbones.py --one-run
"""

import argparse
import os
import time

import numpy as np
import pandas as pd

from skcath.backbones import PCCBackbone, PDLBackbone, pcc_tip, pdl_tip
from skcath.datasets import MECHANISMS, make_benchmark
from skcath.metrics import per_run_rmse

PAPER = {"PCC": {"C1": 7.4, "C2": 9.0, "C3": 8.3, "C4": 7.7, "pooled": 8.1},
         "PDL": {"C1": 6.9, "C2": 7.4, "C3": 7.2, "C4": 6.5, "pooled": 7.0}}


def magnitude_bins(X, y, nominal, runs):
    """Median over runs of the per-run RMSE in 10-degree motor-magnitude bins (mm)."""
    rows = X["run"].isin(runs).to_numpy() & (X["phase"] == "motion").to_numpy()
    rho = np.hypot(X["q1"].to_numpy(), X["q2"].to_numpy())[rows]
    err2 = np.sum((nominal[rows] - y[rows]) ** 2, axis=1)
    frame = pd.DataFrame({"run": X["run"].to_numpy()[rows], "bin": np.minimum(rho // 10, 5), "e2": err2})
    per_bin = frame.groupby(["run", "bin"], observed=True)["e2"].mean().pow(0.5)
    return per_bin.groupby("bin").median().rename(lambda b: f"{int(10 * b)}-{int(10 * b + 10)}")


def evaluate(mechanism, n_catheters, random_state, n_jobs, hysteresis=None):
    """Scores of both backbones on the bent settings of a benchmark.

    Returns the summary (rows ``PCC``, ``PDL``: motion RMSE; ``PCC sweep``,
    ``PDL sweep``: sweep-fit RMSE; ``PCC width``, ``PDL width``: play
    half-width in deg; columns: catheters and ``pooled``), the magnitude
    bins, the share of runs where PDL beats PCC, the noise floor and the
    calibration times (s).
    """
    data = make_benchmark(n_catheters=n_catheters, mechanism=mechanism, random_state=random_state)
    X, y = data.X, data.y
    bent = data.runs.loc[data.runs["bend_level"] != "straight", "run"].to_numpy()
    per_run, bins, times = {}, {}, {}
    for name, Est in (("PCC", PCCBackbone), ("PDL", PDLBackbone)):
        start = time.perf_counter()
        calibration = Est(hysteresis=hysteresis, n_jobs=n_jobs).fit(X).calibrate(X)
        times[name] = time.perf_counter() - start
        per_run[name] = per_run_rmse(y, calibration.nominal, X).loc[bent]
        per_run[f"{name} sweep"] = calibration.table.loc[bent, "rmse_mm"]
        per_run[f"{name} width"] = calibration.table.loc[bent, "play_width_deg"]
        bins[name] = magnitude_bins(X, y, calibration.nominal, bent)
    table = pd.DataFrame(per_run)
    table["catheter"] = data.runs.set_index("run").loc[table.index, "catheter"].to_numpy()
    columns = list(per_run)
    summary = table.groupby("catheter")[columns].mean().T
    summary["pooled"] = table[columns].mean()
    return summary, pd.DataFrame(bins).T, (table["PDL"] < table["PCC"]).mean(), data.noise_floor, times


def _best_of(n, func, *args):
    """Shortest of ``n`` timed calls (s)."""
    times = []
    for _ in range(n):
        start = time.perf_counter()
        func(*args)
        times.append(time.perf_counter() - start)
    return min(times)


def one_run_times(random_state, hysteresis=None):
    """Print the times of ``predict`` and of the tip evaluation on one run."""
    X = make_benchmark(n_catheters=1, n_runs=1, random_state=random_state).X
    run = X[(X["run"] == X["run"].iloc[0]).to_numpy()]
    q = run[["q1", "q2"]].to_numpy()
    flag = os.environ.get("NUMBA_DISABLE_JIT", "unset")
    print(f"run {run['run'].iloc[0]} ({len(run)} rows); NUMBA_DISABLE_JIT={flag}; "
          f"hysteresis={hysteresis}; best of 7 calls")
    for est, tip in ((PCCBackbone(hysteresis=hysteresis), pcc_tip),
                     (PDLBackbone(hysteresis=hysteresis), pdl_tip)):
        calibration = est.fit(X).calibrate(run)  # compiles (or loads) the loop over the rows
        params = calibration.params[run["run"].iloc[0]]
        predict_s = _best_of(7, est.predict, run)
        tip_s = _best_of(7, tip, q, params)
        print(f"{type(est).__name__}: predict {1e3 * predict_s:.1f} ms, "
              f"{tip.__name__} on the run's rows {1e3 * tip_s:.2f} ms")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mechanism", default="play", choices=[*MECHANISMS, "all"])
    parser.add_argument("--n-catheters", type=int, default=4)
    parser.add_argument("--random-state", type=int, default=0)
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--hysteresis", default="none", choices=["none", "play"],
                        help="the backbones' hysteresis parameter (none: None)")
    parser.add_argument("--one-run", action="store_true",
                        help="time predict and the tip evaluation on one run instead")
    args = parser.parse_args()
    hysteresis = None if args.hysteresis == "none" else args.hysteresis
    if args.one_run:
        one_run_times(args.random_state, hysteresis)
        return
    mechanisms = MECHANISMS if args.mechanism == "all" else (args.mechanism,)
    pd.set_option("display.width", 120)
    for mechanism in mechanisms:
        summary, bins, frac, floor, times = evaluate(mechanism, args.n_catheters, args.random_state,
                                                     args.n_jobs, hysteresis)
        print(f"\n== mechanism={mechanism}, hysteresis={hysteresis}: mean per-run RMSE over motion "
              "rows, bent settings (mm)")
        print(summary.loc[["PCC", "PDL"]].round(2).to_string())
        print("sweep fit (calibration rmse_mm, mm) and play half-width (deg), mean over the same runs:")
        print(summary.drop(index=["PCC", "PDL"]).round(2).to_string())
        print("paper (real catheters):")
        print(pd.DataFrame(PAPER).T.to_string())
        print(f"PDL better than PCC on {frac:.0%} of runs; sensor-noise floor {floor:.2f} mm")
        print("median run-bin RMSE by motor-input magnitude |q| (deg):")
        print(bins.round(2).to_string())
        print("calibration time for all runs (s): " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()))


if __name__ == "__main__":
    main()
