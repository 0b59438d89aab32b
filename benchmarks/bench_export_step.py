"""The exported whole step of a started estimator: parity with ``predict``, file sizes, speed.

Data: the simulated instrument of ``N`` motors (``make_benchmark(n_catheters=1,
n_runs=1, n_motors=N, random_state=0)``, cached in the skcath data folder).
Each pipeline is fitted on the run of shaft setting S02 (its sweep and its
first ``--train-motion`` motion samples) for ``--epochs`` epochs, with the
default network sizes (GRU hidden size 128, head 64, context 16; MLP
hidden size 128); the weights only need to be real, not good. The run of
setting S05 is the test run: an :class:`~skcath.online.OnlineEstimator` is
started on its sweep and exported with ``skcath.online.export(est, path)``,
and the graph is stepped by onnxruntime (CPU, one thread) through every
motion sample of the run from ``reset=True``.

Parity: for every case (PCC and PDL, each with and without the play of
``hysteresis="play"``, and the polynomial backbone on one, two and three
motors; GRU, MLP and ``NoResidual``; two motors also without the torques, the
residual with ``use_torque=False``), the largest difference of the graph's
tip to ``pipe.predict`` (float32, as fitted) and to the float64
``OnlineEstimator.step`` over the run's motion samples (mm), the size of
the ONNX file and its number of nodes.

Speed: for the PDL backbone with GRU, MLP and no residual, one step of the
ONNX graph in onnxruntime (``intra_op_num_threads=1``; ``session.run`` with
the sample, the state and the reset flag, the state fed back) beside
``OnlineEstimator.step`` in float64 with each engine (numba if installed,
numpy), with ``out=`` given. The variants run interleaved in rounds of
1,000 steps, cycling over the run's motion samples (reset at each pass);
p50 and p99 over ``--steps`` steps per variant, timed with
``time.perf_counter_ns``; numpy's BLAS limited to one thread.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_export_step.py
    .venv/bin/python benchmarks/bench_export_step.py --epochs 1 --steps 5000
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import onnx
from sklearn.pipeline import Pipeline
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine_lines  # noqa: E402

from skcath import motor_columns  # noqa: E402
from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone  # noqa: E402
from skcath.datasets import make_benchmark  # noqa: E402
from skcath.online import OnlineEstimator, export  # noqa: E402
from skcath.residuals import GRUResidual, MLPResidual, NoResidual  # noqa: E402

ROUND = 1000
BACKBONES = {"PCC": PCCBackbone, "PDL": PDLBackbone, "Polynomial": PolynomialBackbone}
RESIDUALS = {"GRU": GRUResidual, "MLP": MLPResidual, "none": NoResidual}
CASES = [
    *((b, play, r, 2, True) for b in ("PCC", "PDL") for play in (False, True)
      for r in ("GRU", "MLP", "none")),
    *(("Polynomial", False, r, n, True) for n in (1, 2, 3) for r in ("GRU", "MLP", "none")),
    ("PDL", False, "GRU", 2, False),
    ("Polynomial", False, "GRU", 2, False),
]


def _rows(n_motors, setting, n_motion, torques):
    bench = make_benchmark(n_catheters=1, n_runs=1, n_motors=n_motors, random_state=0, cache=True)
    X, y = bench.X, np.asarray(bench.y, dtype=float)
    keep = (X["setting"].astype(str) == setting).to_numpy()
    motion = (X["phase"] == "motion").to_numpy()
    if n_motion is not None:
        keep = keep & (~motion | (np.cumsum(keep & motion) <= n_motion))
    X = X[keep].reset_index(drop=True)
    if not torques:
        X = X.drop(columns=list(motor_columns(X)[1]))
    return X, y[keep]


def _pipeline(case, args, cache):
    backbone_name, play, residual_name, n_motors, torques = case
    key = (backbone_name, play, n_motors, torques)
    if key not in cache:
        train, y = _rows(n_motors, "S02", args.train_motion, torques)
        backbone = BACKBONES[backbone_name](**({"hysteresis": "play"} if play else {}))
        backbone.fit(train)
        cache[key] = (backbone, backbone.transform(train), y)
    backbone, Xb, y = cache[key]
    Est = RESIDUALS[residual_name]
    params = dict(max_epochs=args.epochs, n_threads=1, random_state=0, use_torque=torques)
    residual = NoResidual() if Est is NoResidual else Est(**params)
    return Pipeline([("backbone", backbone), ("residual", residual.fit(Xb, y))])


def _session(path):
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


class GraphLoop:
    """The exported step in onnxruntime, its state fed back."""

    def __init__(self, path):
        self.session = _session(path)
        self.size = self.session.get_inputs()[1].shape[1]
        self.reset()

    def reset(self):
        self.feed = {"state": np.zeros((1, self.size)), "reset": np.array([True])}

    def step(self, sample):
        self.feed["sample"] = sample[None]
        tip, self.feed["state"], _ = self.session.run(None, self.feed)
        self.feed["reset"] = np.array([False])
        return tip[0]


class EstimatorLoop:
    """``OnlineEstimator.step`` with ``out=`` given."""

    def __init__(self, est):
        self.est, self.out = est, np.empty(3)

    def reset(self):
        self.est.reset()

    def step(self, sample):
        return self.est.step(*sample, out=self.out)


def _label(case):
    backbone_name, play, residual_name, n_motors, torques = case
    name = f"{backbone_name}{' + play' if play else ''}, {residual_name}, {n_motors} motor(s)"
    return name + ("" if torques else ", no torques")


def parity(args, workdir):
    """Rows of the parity table; the started PDL estimators of two motors, for the speed."""
    cache, rows, started = {}, [], {}
    for case in CASES:
        pipe = _pipeline(case, args, cache)
        run, _ = _rows(case[3], "S05", None, case[4])
        motion = (run["phase"] == "motion").to_numpy()
        est = OnlineEstimator(pipe, engine="numpy").start(run[~motion])
        path = Path(workdir) / f"step{len(rows)}.onnx"
        export(est, path)
        samples = run.loc[motion, list(est.channels_)].to_numpy()
        loop = GraphLoop(path)
        tips = np.array([loop.step(s) for s in samples])
        steps = np.array([est.step(*s) for s in samples])
        predicted = pipe.predict(run)[motion]
        rows.append((_label(case), len(samples), np.abs(tips - predicted).max(),
                     np.abs(tips - steps).max(), os.path.getsize(path),
                     len(onnx.load(path).graph.node)))
        print(f"  {rows[-1][0]}: done", flush=True)
        if case[:2] == ("PDL", False) and case[3:] == (2, True):
            started[case[2]] = (pipe, run[~motion], samples, path)
    return rows, started


def _timed(loop, samples, at, n, times):
    for _ in range(n):
        if at == len(samples):
            loop.reset()
            at = 0
        t0 = time.perf_counter_ns()
        loop.step(samples[at])
        times.append(time.perf_counter_ns() - t0)
        at += 1
    return at


def speed(started, n_steps):
    """Rows ``(variant, p50, p99)`` (µs) of the interleaved timing."""
    engines = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])
    variants = {}
    for residual_name, (pipe, sweep, samples, path) in started.items():
        variants[f"onnxruntime graph, 1 thread, {residual_name}"] = (GraphLoop(path), samples)
        for engine in engines:
            est = OnlineEstimator(pipe, engine=engine).start(sweep)
            variants[f"OnlineEstimator {engine}, float64, {residual_name}"] = (
                EstimatorLoop(est), samples)
    times = {name: [] for name in variants}
    at = dict.fromkeys(variants, 0)
    for loop, samples in variants.values():  # warm-up
        _timed(loop, samples, 0, 200, [])
        loop.reset()
    while min(len(t) for t in times.values()) < n_steps:
        for name, (loop, samples) in variants.items():
            at[name] = _timed(loop, samples, at[name], ROUND, times[name])
    return [(name, np.percentile(t, 50) / 1e3, np.percentile(t, 99) / 1e3)
            for name, t in times.items()]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=1, help="training epochs (default 1)")
    parser.add_argument("--train-motion", type=int, default=600,
                        help="motion samples of the training run (default 600)")
    parser.add_argument("--steps", type=int, default=10000, help="timed steps per variant")
    args = parser.parse_args(argv)
    for line in machine_lines():
        print(line)
    import onnxruntime
    import torch

    print(f"torch {torch.__version__}, onnxruntime {onnxruntime.__version__}")
    print(f"command: {' '.join(sys.argv)}")
    print("load average at the start: {:.1f} {:.1f} {:.1f}".format(*os.getloadavg()))
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as workdir, threadpool_limits(1), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows, started = parity(args, workdir)
        timing = speed(started, args.steps)
    print("load average at the end: {:.1f} {:.1f} {:.1f}".format(*os.getloadavg()))
    print("\n| case | motion samples | max abs(graph - predict) (mm) "
          "| max abs(graph - step) (mm) | ONNX file (kB) | nodes |")
    print("|---|---|---|---|---|---|")
    for label, n, d_predict, d_step, size, nodes in rows:
        print(f"| {label} | {n} | {d_predict:.1e} | {d_step:.1e} | {size / 1e3:.1f} | {nodes} |")
    print("\n| variant (PDL, two motors) | p50 (µs) | p99 (µs) |")
    print("|---|---|---|")
    for name, p50, p99 in timing:
        print(f"| {name} | {p50:.1f} | {p99:.1f} |")


if __name__ == "__main__":
    main()
