"""Time saving and loading a fitted PDL+GRU pipeline and a started streaming estimator.

``skcath.persist.save`` writes the pickle-free skops format by default; the
target is that its save and its load each take at most twice the time of
``format="joblib"`` (a pickle, loaded with ``allow_pickle=True``). The
pipeline is a PDL backbone and a default-sized :class:`GRUResidual`
(hidden size 64) trained for ``--epochs`` epochs on three runs of one
simulated catheter (the training length does not change the file); the
streaming estimator is an :class:`OnlineEstimator` started on a sweep of
that catheter, with a :class:`ShaftChangeDetector`, after 100 steps.

Each save and load is timed ``--repeat`` times (after one warm-up); the
table gives the median per call, the file size, and the ratio of the
default format's time to joblib's (at most 2 meets the target). Loading
also checks that the loaded pipeline predicts bit for bit as the saved one
(and the estimator steps on as the saved one).

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_persist.py [--repeat 20] [--epochs 1]
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from sklearn.pipeline import Pipeline

import skcath
from _machine import machine_lines
from skcath import persist
from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.online import OnlineEstimator, ShaftChangeDetector
from skcath.residuals import GRUResidual

FORMATS = {"joblib": {"allow_pickle": True}, "skops": {}}


def fitted_pipeline(epochs):
    """PDL + default GRU, trained on runs S01-S03 of one catheter, and its training rows."""
    bench = make_benchmark(n_catheters=1, n_runs=1)
    keep = bench.X["setting"].astype(str).isin(["S01", "S02", "S03"]).to_numpy()
    X, y = bench.X[keep].reset_index(drop=True), np.asarray(bench.y, dtype=float)[keep]
    pipe = Pipeline([("backbone", PDLBackbone()),
                     ("residual", GRUResidual(max_epochs=epochs, random_state=0, n_threads=1))])
    return pipe.fit(X, y), X


def started_estimator(pipe, X):
    """The pipeline streaming the S03 run after its sweep, 100 steps in, and 100 more samples."""
    run = X[(X["setting"].astype(str) == "S03").to_numpy()]
    sweep = run[(run["phase"] == "sweep").to_numpy()]
    samples = run.loc[(run["phase"] == "motion").to_numpy(), ["q1", "q2", "tau1", "tau2"]]
    est = OnlineEstimator(pipe, detector=ShaftChangeDetector()).start(sweep)
    samples = samples.to_numpy()
    for sample in samples[:100]:
        est.step(*sample)
    return est, samples[100:200]


def timed(func, repeat):
    """Median seconds of ``repeat`` calls of ``func`` (after one warm-up) and its last result."""
    out = func()
    seconds = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = func()
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds), out


def measure(obj, same, repeat, folder):
    """Save and load times (s) and file size (bytes) per format; ``same`` checks a loaded copy."""
    rows = {}
    for fmt, options in FORMATS.items():
        path = Path(folder) / f"{fmt}.skcath"
        save, _ = timed(lambda: persist.save(obj, path, format=fmt), repeat)
        load, loaded = timed(lambda: persist.load(path, **options), repeat)
        if not same(loaded):
            raise AssertionError(f"the {fmt} copy does not behave as the saved object")
        rows[fmt] = (save, load, path.stat().st_size)
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=20, help="timed calls per measurement")
    parser.add_argument("--epochs", type=int, default=1, help="training epochs of the GRU")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    pipe, X = fitted_pipeline(args.epochs)
    expected = pipe.predict(X)
    est, samples = started_estimator(pipe, X)

    with tempfile.TemporaryDirectory() as folder:
        reference = Path(folder) / "reference.skcath"
        persist.save(est, reference, format="joblib")
        results = {
            "PDL+GRU pipeline": measure(
                pipe, lambda loaded: np.array_equal(loaded.predict(X), expected),
                args.repeat, folder),
            "started OnlineEstimator": measure(
                est, lambda loaded: same_stream(loaded, reference, samples), args.repeat, folder),
        }

    print(f"skcath {skcath.__version__}; {args.repeat} timed calls each (median), "
          f"GRU trained {args.epochs} epoch(s)")
    for line in machine_lines():
        print(line)
    print()
    print("| object | format | save (ms) | load (ms) | file (kB) | save / joblib | load / joblib |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, rows in results.items():
        base_save, base_load, _ = rows["joblib"]
        for fmt, (save, load, size) in rows.items():
            print(f"| {name} | {fmt}{' (default)' if fmt == 'skops' else ''} | {save * 1e3:.1f} | "
                  f"{load * 1e3:.1f} | {size / 1e3:.0f} | {save / base_save:.2f} | "
                  f"{load / base_load:.2f} |")


def same_stream(loaded, reference_path, samples):
    """Whether ``loaded`` steps on as a fresh (joblib) copy of the saved estimator does."""
    reference = persist.load(reference_path, allow_pickle=True)
    return np.array_equal([loaded.step(*s) for s in samples],
                          [reference.step(*s) for s in samples])


if __name__ == "__main__":
    main()
