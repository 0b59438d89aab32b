"""Per-step latency and allocations of the streaming estimator, next to plain torch.

Data: the simulated benchmark with one catheter and one run per setting
(``make_benchmark(n_catheters=1, n_runs=1, random_state=0)``, cached in the
skcath data folder). A ``Pipeline([("backbone", PDLBackbone()),
("residual", GRUResidual())])`` with the default network sizes (GRU hidden
size 128, head 64, context 16, encoder 32) is fitted for one epoch on three
shaft settings (S02, S09, S13); the weights only need to be real, not good.
The motion samples of the run of setting S05 are then stepped one at a time,
cycled until ``--steps`` samples have been stepped (the state is reset at
every pass, so every pass reproduces ``predict`` on the run).

Variants, all with the backbone included (the same calibration of the run):

- ``online float64, numba`` / ``online float32, numba``:
  ``skcath.online.OnlineEstimator(pipe, dtype=..., engine="numba").step(q1,
  q2, tau1, tau2, out=buf)``, one compiled kernel per step (if numba is
  installed);
- ``online float64, numpy`` / ``online float32, numpy``: the same with
  ``engine="numpy"``, the numpy stepping kernels;
- ``plain torch GRUCell``: the loop a user would write in torch with the
  same weights: the backbone's tip kernel (``pdl_kernel`` on the run's
  calibration, ``backbone_params_``) for ``b``, the step features as a
  float32 tensor, normalised and concatenated with the context ``z`` in
  torch, one ``torch.nn.GRUCell`` step (weights copied from the fitted
  ``nn.GRU``), the head (``module_.head``), then ``sigma_e``, the rotation
  back to the base frame and the clip, under ``torch.no_grad()``;
- ``onnxruntime float32``: the graph written by
  ``skcath.online.export(pipe, path, "onnx")``, run by an onnxruntime CPU
  session with one thread, fed the same features (if onnxruntime is
  installed);
- ``online, MLP`` and ``online, backbone only``: the same loop for
  ``MLPResidual`` (default sizes) and ``NoResidual``, for scale, with each
  engine.

The numba step is compiled when numba's cache is empty and loaded from it
otherwise, by ``start``, outside the timed loop (``compile_seconds_``). The
script reports the time of a compilation from scratch: a separate Python
process loads the fitted GRU pipeline and starts an estimator with
``engine="numba"`` for float64 and float32 with an empty, temporary cache
(``NUMBA_CACHE_DIR``), and reports their ``compile_seconds_`` and the time
it took to import numba and skcath.

Each step is timed with ``time.perf_counter_ns``. The variants run
interleaved in rounds of 1,000 steps (A B C ..., then again) so that a
change of the machine's load hits all of them alike; p50 and p99 are over
all steps of a variant, and "ratio" is the variant's p50 over the plain torch
p50 of the same run. Torch uses one intra-op thread and numpy's BLAS one
thread (``threadpoolctl``): the whole loop runs on one core.

Allocations: with ``tracemalloc`` running, ``--alloc-steps`` steps of each
online variant (both engines) (``out=`` given, after 1,000 warm-up steps); "bytes/step" is
the growth of the traced memory over the loop divided by the steps, and
"peak B" the largest traced memory above the start during the loop.
tracemalloc sees Python's allocations, not those of numba's runtime; with
the environment variable ``NUMBA_NRT_STATS=1`` the script also prints the
allocations numba's runtime made per step in the same loop (numba counts
them only when the variable is set before it is imported).

The table also gives the largest difference to ``pipe.predict`` on the run
(mm): float32 ``predict`` as fitted, and float64 ``predict`` (a copy of the
pipeline with ``module_.double()``).

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_streaming.py            # 20,000 steps per variant
    .venv/bin/python benchmarks/bench_streaming.py --steps 5000
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
import warnings
from pathlib import Path

import joblib
import numpy as np
import torch
from sklearn.pipeline import Pipeline
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine_lines  # noqa: E402

from skcath.backbones import PDLBackbone, pdl_kernel  # noqa: E402
from skcath.datasets import make_benchmark  # noqa: E402
from skcath.online import OnlineEstimator, export, export_io  # noqa: E402
from skcath.residuals import GRUResidual, MLPResidual, NoResidual  # noqa: E402

TRAIN_SETTINGS = ["S02", "S09", "S13"]
TEST_SETTING = "S05"
ROUND = 1000


def _fit(residual, X, y):
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", residual)])
    train = X["setting"].isin(TRAIN_SETTINGS).to_numpy()
    return pipe.fit(X[train], y[train])


def _backbone(est):
    """The run's calibrated backbone as a function of one motor sample."""
    theta = est.backbone_params_.pack().tolist()
    return lambda q1, q2: pdl_kernel(theta, q1, q2)


class TorchLoop:
    """Plain torch stepping: ``GRUCell`` + head with the fitted weights."""

    def __init__(self, pipe, est, last_sweep):
        res = pipe["residual"]
        module = res.module_
        gru = module.gru
        cell = torch.nn.GRUCell(gru.input_size, gru.hidden_size)
        with torch.no_grad():
            cell.weight_ih.copy_(gru.weight_ih_l0)
            cell.weight_hh.copy_(gru.weight_hh_l0)
            cell.bias_ih.copy_(gru.bias_ih_l0)
            cell.bias_hh.copy_(gru.bias_hh_l0)
        self.cell = cell
        self.head = module.head
        self.mean = torch.tensor(res.x_scaler_.mean, dtype=torch.float32)
        self.scale = torch.tensor(res.x_scaler_.scale, dtype=torch.float32)
        self.z = torch.tensor(est.context_, dtype=torch.float32)
        self.R = est.rotation_
        self.sigma = res.sigma_e_
        self.clip = res.clip
        self.backbone = _backbone(est)  # the same tip kernel as the estimator's
        self.last_sweep = last_sweep
        self.reset()

    def reset(self):
        self.h = torch.zeros(1, self.cell.hidden_size)
        self.last = self.last_sweep[:2]

    def step(self, q1, q2, tau1, tau2):
        b = np.array(self.backbone(q1, q2))
        bs = self.R @ b
        dq1, dq2 = q1 - self.last[0], q2 - self.last[1]
        self.last = (q1, q2)
        with torch.no_grad():
            x = torch.tensor([q1, q2, dq1, dq2, tau1, tau2, *bs], dtype=torch.float32)
            v = torch.cat([(x - self.mean) / self.scale, self.z])[None]
            self.h = self.cell(v, self.h)
            f = self.head(self.h)[0].numpy()
        r = self.R.T @ (f * self.sigma)
        return b + np.clip(r, -self.clip, self.clip)


class OnnxLoop:
    """Stepping the exported ONNX graph in onnxruntime (one thread), backbone included."""

    def __init__(self, pipe, est, last_sweep, path, dtype):
        import onnxruntime

        export(pipe, path, "onnx", dtype=dtype)
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        self.session = onnxruntime.InferenceSession(
            str(path), options, providers=["CPUExecutionProvider"]
        )
        self.dtype = np.dtype(dtype)
        inputs, _ = export_io(pipe)
        self.hidden_shape = inputs["hidden"]
        self.features = np.empty((1, inputs["features"][1]), self.dtype)
        self.feed = {
            "features": self.features,
            "rotation": est.rotation_.astype(self.dtype),
            "context": est.context_[None].astype(self.dtype),
        }
        self.backbone = _backbone(est)
        self.last_sweep = last_sweep
        self.reset()

    def reset(self):
        self.feed["hidden"] = np.zeros(self.hidden_shape, self.dtype)
        self.last = self.last_sweep[:2]

    def step(self, q1, q2, tau1, tau2):
        bx, by, bz = self.backbone(q1, q2)
        self.features[0] = (q1, q2, q1 - self.last[0], q2 - self.last[1], tau1, tau2, bx, by, bz)
        self.last = (q1, q2)
        residual, self.feed["hidden"] = self.session.run(None, self.feed)
        return np.array([bx, by, bz]) + residual[0]


def _timed(step, samples, reset, start, n_steps, times):
    """Step ``n_steps`` samples from ``start`` (cycling, reset at each pass), appending ns per step.

    Returns the index of the next sample.
    """
    n = len(samples)
    i = start
    for _ in range(n_steps):
        if i == n:
            reset()
            i = 0
        q1, q2, t1, t2 = samples[i]
        t0 = time.perf_counter_ns()
        step(q1, q2, t1, t2)
        times.append(time.perf_counter_ns() - t0)
        i += 1
    return i


def _nrt_allocations():
    """Allocations counted by numba's runtime so far, or None when it does not count."""
    if os.environ.get("NUMBA_NRT_STATS") != "1" or "numba" not in sys.modules:
        return None
    from numba.core.runtime import rtsys

    return rtsys.get_allocation_stats().alloc


def _alloc(est, samples, n_steps):
    """Traced memory growth per step, peak above the start (bytes), numba allocations per step."""
    out = np.empty(3)
    est.reset()
    n = len(samples)
    for k in range(min(ROUND, n)):
        est.step(*samples[k], out=out)
    est.reset()
    nrt_before = _nrt_allocations()
    tracemalloc.start()
    tracemalloc.reset_peak()
    before = tracemalloc.get_traced_memory()[0]
    i = 0
    for _ in range(n_steps):
        if i == n:
            est.reset()
            i = 0
        q1, q2, t1, t2 = samples[i]
        est.step(q1, q2, t1, t2, out=out)
        i += 1
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    nrt_after = _nrt_allocations()
    nrt = None if nrt_before is None else (nrt_after - nrt_before) / n_steps
    return (current - before) / n_steps, peak - before, nrt


_COLD_COMPILE = """
import sys, time
t0 = time.perf_counter()
import joblib, numba
from skcath.online import OnlineEstimator
t1 = time.perf_counter()
pipe, sweep = joblib.load(sys.argv[1])
seconds = [OnlineEstimator(pipe, dtype=dtype, engine="numba").start(sweep).compile_seconds_
           for dtype in ("float64", "float32")]
print(t1 - t0, *seconds)
"""


def _cold_compile(pipe, sweep):
    """Seconds to import, and to compile the step for float64 and float32, cache empty."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "pipe.joblib"
        joblib.dump((pipe, sweep), path)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(folder) / "cache"))
        done = subprocess.run([sys.executable, "-c", _COLD_COMPILE, str(path)], env=env,
                              check=True, capture_output=True, text=True)
    return tuple(float(v) for v in done.stdout.split())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20000, help="timed steps per variant")
    parser.add_argument("--alloc-steps", type=int, default=5000, help="steps under tracemalloc")
    parser.add_argument("--no-cold-compile", action="store_true",
                        help="skip timing a compilation of the numba kernel from scratch")
    args = parser.parse_args(argv)
    has_numba = importlib.util.find_spec("numba") is not None
    torch.set_num_threads(1)
    threadpool_limits(1)

    data = make_benchmark(n_catheters=1, n_runs=1, random_state=0)
    X, y = data.X, np.asarray(data.y)
    t0 = time.perf_counter()
    pipes = {
        "gru": _fit(GRUResidual(max_epochs=1, n_threads=1, random_state=0), X, y),
        "mlp": _fit(MLPResidual(max_epochs=1, n_threads=1, random_state=0), X, y),
        "none": _fit(NoResidual(), X, y),
    }
    fit_s = time.perf_counter() - t0
    run = X[(X["setting"] == TEST_SETTING).to_numpy()]
    motion = (run["phase"] == "motion").to_numpy()
    sweep = run[~motion]
    samples = [tuple(map(float, row)) for row in run.loc[motion, ["q1", "q2", "tau1", "tau2"]].to_numpy()]
    last_sweep = tuple(float(v) for v in sweep[["q1", "q2"]].to_numpy()[-1])
    cold = _cold_compile(pipes["gru"], sweep) if has_numba and not args.no_cold_compile else None

    engines = ["numba", "numpy"] if has_numba else ["numpy"]
    if has_numba:
        import numba  # here, so that start_s leaves out the import
    estimators, start_s = {}, {}
    for pipe, dtype, label in [("gru", "float64", "online float64"),
                               ("gru", "float32", "online float32"),
                               ("mlp", "float64", "online, MLP (float64)"),
                               ("none", "float64", "online, backbone only")]:
        for engine in engines:
            name = f"{label}, {engine}"
            t0 = time.perf_counter()
            est = OnlineEstimator(pipes[pipe], dtype=dtype, engine=engine)
            estimators[name] = est.start(sweep)
            start_s[name] = time.perf_counter() - t0
    torch_loop = TorchLoop(pipes["gru"], estimators["online float64, numpy"], last_sweep)
    loops = {"plain torch GRUCell": torch_loop}
    tmp = tempfile.TemporaryDirectory()
    if importlib.util.find_spec("onnxruntime") is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # notices of torch's legacy ONNX exporter
            loops["onnxruntime float32"] = OnnxLoop(
                pipes["gru"], estimators["online float32, numpy"], last_sweep,
                Path(tmp.name) / "step.onnx", "float32",
            )

    # parity on one pass of the run
    pred32 = pipes["gru"].predict(run)[motion]
    pipe64 = copy.deepcopy(pipes["gru"])
    pipe64["residual"].module_.double()
    pred64 = pipe64.predict(run)[motion]
    parity = {}
    for name in [n for n in estimators if n.startswith(("online float64", "online float32"))]:
        est = estimators[name].reset()
        tips = np.array([est.step(*s) for s in samples])
        parity[name] = (np.abs(tips - pred32).max(), np.abs(tips - pred64).max())
    for name, loop in loops.items():
        loop.reset()
        tips = np.array([loop.step(*s) for s in samples])
        parity[name] = (np.abs(tips - pred32).max(), np.abs(tips - pred64).max())

    variants = {}
    for name, est in estimators.items():
        buf = np.empty(3)
        est.reset()

        def step(q1, q2, t1, t2, _s=est.step, _b=buf):
            return _s(q1, q2, t1, t2, out=_b)

        variants[name] = (step, est.reset)
    for name, loop in loops.items():
        loop.reset()
        variants[name] = (loop.step, loop.reset)
    times = {name: [] for name in variants}
    cursors = {name: 0 for name in variants}
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    done = 0
    while done < args.steps:
        n = min(ROUND, args.steps - done)
        for name, (step, reset) in variants.items():
            cursors[name] = _timed(step, samples, reset, cursors[name], n, times[name])
        done += n
    bench_s = time.perf_counter() - t0
    load_after = os.getloadavg()

    allocs = {}
    for name, est in estimators.items():
        allocs[name] = _alloc(est, samples, args.alloc_steps)

    print("# Streaming estimator: latency per step (backbone included)\n")
    for line in machine_lines():
        print(f"- {line}")
    print(f"- torch {torch.__version__}, 1 torch thread, 1 BLAS thread")
    print(f"- load average (1, 5, 15 min) before: {', '.join(f'{v:.2f}' for v in load_before)}; "
          f"after: {', '.join(f'{v:.2f}' for v in load_after)}")
    print(f"- pipelines fitted in {fit_s:.1f} s; timing loop {bench_s:.1f} s; "
          f"{args.steps} steps per variant; run {run['run'].iloc[0]} "
          f"({len(samples)} motion samples)")
    if has_numba:
        compiled = [estimators[f"online {d}, numba"].compile_seconds_ for d in ("float64", "float32")]
        print(f"- numba {numba.__version__}; `start` of the GRU float64 / float32 estimators "
              f"(numba engine, step compiled or loaded from numba's cache in "
              f"{compiled[0]:.2f} s / {compiled[1]:.2f} s): "
              f"{start_s['online float64, numba']:.2f} s / "
              f"{start_s['online float32, numba']:.2f} s (numpy engine: "
              f"{start_s['online float64, numpy']:.2f} s / "
              f"{start_s['online float32, numpy']:.2f} s)")
        if cold is not None:
            print(f"- numba step compiled from scratch (empty cache, separate process): "
                  f"float64 {cold[1]:.1f} s, float32 {cold[2]:.1f} s, after importing numba "
                  f"and skcath in {cold[0]:.1f} s")
    else:
        print("- numba is not installed: numpy engine only")
    print()
    ref = np.percentile(times["plain torch GRUCell"], 50)
    print("| variant | p50 us | p99 us | p50 / torch p50 | bytes/step | peak B | "
          "max diff to predict float32 (mm) | max diff to predict float64 (mm) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name in variants:
        t = np.asarray(times[name]) / 1e3
        p50, p99 = np.percentile(t, 50), np.percentile(t, 99)
        alloc = allocs.get(name)
        a = f"{alloc[0]:.2f} | {alloc[1]:,}" if alloc else "- | -"
        par = parity.get(name)
        d = f"{par[0]:.1e} | {par[1]:.1e}" if par else "- | -"
        print(f"| {name} | {p50:.1f} | {p99:.1f} | {p50 * 1e3 / ref:.2f} | {a} | {d} |")
    nrt = {name: alloc[2] for name, alloc in allocs.items() if alloc[2] is not None}
    if nrt:
        print("\nAllocations of numba's runtime per step (NUMBA_NRT_STATS=1), same loops: "
              + "; ".join(f"{name}: {v:.2f}" for name, v in nrt.items()))


if __name__ == "__main__":
    main()
