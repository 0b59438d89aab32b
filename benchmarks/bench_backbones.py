"""Backbone baselines on the simulated benchmark: PCC and PDL tip RMSE.

Calibrates both backbones on every run's own sweep and scores the motion rows
of the 16 bent shaft settings (48 runs per catheter, as in the paper), then
prints mean per-run RMSE per catheter and pooled, the share of runs where PDL
beats PCC, and the median run-bin RMSE by motor-input magnitude (10-degree
bins, as the paper's Fig. 5(b)).

Usage::

    python benchmarks/bench_backbones.py                 # default benchmark (play)
    python benchmarks/bench_backbones.py --mechanism all # the three mechanisms
"""

import argparse
import time

import numpy as np
import pandas as pd

from skcath.backbones import PCCBackbone, PDLBackbone
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


def evaluate(mechanism, n_catheters, random_state, n_jobs):
    data = make_benchmark(n_catheters=n_catheters, mechanism=mechanism, random_state=random_state)
    X, y = data.X, data.y
    bent = data.runs.loc[data.runs["bend_level"] != "straight", "run"].to_numpy()
    per_run, bins, times = {}, {}, {}
    for name, est in (("PCC", PCCBackbone(n_jobs=n_jobs)), ("PDL", PDLBackbone(n_jobs=n_jobs))):
        start = time.perf_counter()
        nominal = est.fit(X).predict(X)
        times[name] = time.perf_counter() - start
        per_run[name] = per_run_rmse(y, nominal, X).loc[bent]
        bins[name] = magnitude_bins(X, y, nominal, bent)
    table = pd.DataFrame(per_run)
    table["catheter"] = data.runs.set_index("run").loc[table.index, "catheter"].to_numpy()
    summary = table.groupby("catheter")[["PCC", "PDL"]].mean().T
    summary["pooled"] = table[["PCC", "PDL"]].mean()
    return summary, pd.DataFrame(bins).T, (table["PDL"] < table["PCC"]).mean(), data.noise_floor, times


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mechanism", default="play", choices=[*MECHANISMS, "all"])
    parser.add_argument("--n-catheters", type=int, default=4)
    parser.add_argument("--random-state", type=int, default=0)
    parser.add_argument("--n-jobs", type=int, default=2)
    args = parser.parse_args()
    mechanisms = MECHANISMS if args.mechanism == "all" else (args.mechanism,)
    pd.set_option("display.width", 120)
    for mechanism in mechanisms:
        summary, bins, frac, floor, times = evaluate(mechanism, args.n_catheters, args.random_state, args.n_jobs)
        print(f"\n== mechanism={mechanism}: mean per-run RMSE over motion rows, bent settings (mm)")
        print(summary.round(2).to_string())
        print("paper (real catheters):")
        print(pd.DataFrame(PAPER).T.to_string())
        print(f"PDL better than PCC on {frac:.0%} of runs; sensor-noise floor {floor:.2f} mm")
        print("median run-bin RMSE by motor-input magnitude |q| (deg):")
        print(bins.round(2).to_string())
        print("calibration time for all runs (s): " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()))


if __name__ == "__main__":
    main()
