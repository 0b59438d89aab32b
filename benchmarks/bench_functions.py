"""Time the small functions that the protocol and the backbones call many times.

Speed targets of these functions are checked here, not in the test suite,
whose machines are too noisy for timings:

* :func:`skcath.sweep.find_rays` on the sweep of one simulated run (about
  4,300 samples): at most 5 ms per call, because every backbone calibration
  and every ``OnlineEstimator.start`` calls it once per run;
* :func:`skcath.metrics.paired_reduction` on 204 runs in 68 clusters with
  2,000 bootstrap draws (the size of the protocol's paired tables): at most
  1 s per call, because the report computes eight of them.

Each is called ``--repeat`` times in rounds of ``--number`` calls; the table
gives the best round's time per call and its ratio to the target (below 1
meets it).

Usage::

    .venv/bin/python benchmarks/bench_functions.py [--repeat 5] [--number 10]
"""

import argparse
import time

import numpy as np

from _machine import machine_lines
from skcath.datasets import make_benchmark
from skcath.metrics import paired_reduction
from skcath.sweep import find_rays


def best_per_call(func, repeat, number):
    """Best, over ``repeat`` rounds, of the mean time (s) of ``number`` calls."""
    func()  # warm-up: imports, caches
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(number):
            func()
        best = min(best, (time.perf_counter() - start) / number)
    return best


def sweep_of_one_run():
    """Motor angles of the sweep of the first simulated run (deg)."""
    data = make_benchmark(n_catheters=1, n_runs=1, random_state=0)
    X = data.X
    rows = (X["run"] == X["run"].iloc[0]) & (X["phase"] == "sweep")
    return X.loc[rows, ["q1", "q2"]].to_numpy()


def clustered_errors(n_clusters=68, runs_per_cluster=3, seed=1):
    """Per-run errors of a baseline and a candidate, and their clusters (204 runs)."""
    rng = np.random.default_rng(seed)
    clusters = np.repeat([f"C1/S{k:02d}" for k in range(n_clusters)], runs_per_cluster)
    effect = np.repeat(rng.normal(2.0, 1.0, n_clusters), runs_per_cluster)
    baseline = rng.uniform(6.0, 10.0, clusters.size)
    candidate = baseline - effect - rng.normal(0.0, 0.3, clusters.size)
    return baseline, candidate, clusters


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5, help="rounds (default: 5)")
    parser.add_argument("--number", type=int, default=10, help="calls per round (default: 10)")
    args = parser.parse_args(argv)

    q = sweep_of_one_run()
    baseline, candidate, clusters = clustered_errors()
    cases = [
        (f"find_rays, {len(q)} sweep samples", lambda: find_rays(q), 5e-3),
        ("paired_reduction, 204 runs, 2000 draws",
         lambda: paired_reduction(baseline, candidate, clusters, n_bootstrap=2000, random_state=0),
         1.0),
    ]
    print("\n".join(machine_lines()))
    print(f"best of {args.repeat} rounds of {args.number} calls\n")
    print(f"{'function':42s} {'ms per call':>12s} {'target ms':>10s} {'ratio':>7s}")
    for name, func, target in cases:
        seconds = best_per_call(func, args.repeat, args.number)
        print(f"{name:42s} {1e3 * seconds:12.2f} {1e3 * target:10.0f} {seconds / target:7.2f}")


if __name__ == "__main__":
    main()
