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
- ``onnxruntime whole step (float64)``: the whole step of the started float64
  estimator, backbone and play included, written by
  ``skcath.online.export(est, path)`` and run by an onnxruntime CPU session
  with one thread, the sample given and the state fed back;
- ``online, MLP`` and ``online, backbone only``: the same loop for
  ``MLPResidual`` (default sizes) and ``NoResidual``, for scale, with each
  engine;
- with ``--hysteresis play pi``: ``online float64, hysteresis=KIND`` and
  ``online backbone only, hysteresis=KIND``, the GRU float64 and the
  backbone-only estimators again with ``PDLBackbone(hysteresis=KIND)`` in
  front (the same fitted GRU; each compared with its own ``predict``), with
  each engine.

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

Two checkouts back to back (``--compare-to PATH``): each runs the numba
rows, plain torch and the whole step in onnxruntime (where its skcath can
export it) in a process of its own, with ``PYTHONPATH`` set to the checkout
(this script from this checkout; the pipelines fitted by each checkout's own
code, with the same data and seeds). The two processes take turns, one round
of 1,000 steps of every variant at a time, the first to go alternating. The
table gives each checkout's p50 over all its steps, their ratio, the ratio
of the quietest rounds (the least p50 of a round, for a loaded machine) and
each p50 over the plain torch p50 of the same checkout. A checkout from
before the tip kernels steps the torch loop's backbone with its own
``_backbone``.

Where the time of one numba step goes (``--breakdown``): the whole step as
a user calls it, the call into the compiled step, a compiled call that does
nothing with the same arguments, the compiled step in a compiled loop, and
its pieces (backbone, GRU products, nonlinearities, head), each timed
in-process in batches of steps, least and median over the rounds, one table
(``benchmarks/_streaming_breakdown.py``).

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_streaming.py            # 20,000 steps per variant
    .venv/bin/python benchmarks/bench_streaming.py --steps 5000
    .venv/bin/python benchmarks/bench_streaming.py --hysteresis play pi --no-cold-compile
    git worktree add /tmp/c262 c262cec
    .venv/bin/python benchmarks/bench_streaming.py --compare-to /tmp/c262 --steps 10000
    .venv/bin/python benchmarks/bench_streaming.py --breakdown
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import json
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

from skcath.backbones import PDLBackbone  # noqa: E402
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
    try:
        from skcath.backbones import pdl_kernel
    except ImportError:  # a checkout from before the tip kernels (--compare-to)
        return est._backbone
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


class StepGraphLoop:
    """The estimator's whole step exported (``export(est, path)``) in onnxruntime (one thread)."""

    def __init__(self, est, path):
        import onnxruntime

        export(est, path)
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        self.session = onnxruntime.InferenceSession(
            str(path), options, providers=["CPUExecutionProvider"]
        )
        self.size = self.session.get_inputs()[1].shape[1]
        self.sample = np.empty((1, len(est.channels_)))
        self.no_reset = np.array([False])
        self.reset()

    def reset(self):
        self.feed = {"sample": self.sample, "state": np.zeros((1, self.size)),
                     "reset": np.array([True])}

    def step(self, *sample):
        self.sample[0] = sample
        tip, self.feed["state"], _ = self.session.run(None, self.feed)
        self.feed["reset"] = self.no_reset
        return tip[0]


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


def _with_hysteresis(pipes, X, kinds):
    """The GRU and backbone-only pipelines again with ``PDLBackbone(hysteresis=kind)``, by kind.

    The GRU residual is the one fitted on the backbone without hysteresis:
    for the timing its weights only need to be real.
    """
    train = X["setting"].isin(TRAIN_SETTINGS).to_numpy()
    out = {}
    for kind in kinds:
        backbone = PDLBackbone(hysteresis=kind).fit(X[train])
        for name in ("gru", "none"):
            out[f"{name}, hysteresis={kind}"] = Pipeline(
                [("backbone", backbone), ("residual", pipes[name]["residual"])])
    return out


def _prepare(engines, full=True, hysteresis=()):
    """Fit the pipelines, start the estimators, make the other loops; a dict of all of it."""
    data = make_benchmark(n_catheters=1, n_runs=1, random_state=0)
    X, y = data.X, np.asarray(data.y)
    t0 = time.perf_counter()
    pipes = {
        "gru": _fit(GRUResidual(max_epochs=1, n_threads=1, random_state=0), X, y),
        "mlp": _fit(MLPResidual(max_epochs=1, n_threads=1, random_state=0), X, y),
        "none": _fit(NoResidual(), X, y),
    }
    pipes.update(_with_hysteresis(pipes, X, hysteresis))
    fit_s = time.perf_counter() - t0
    run = X[(X["setting"] == TEST_SETTING).to_numpy()]
    motion = (run["phase"] == "motion").to_numpy()
    sweep = run[~motion]
    samples = [tuple(map(float, row)) for row in run.loc[motion, ["q1", "q2", "tau1", "tau2"]].to_numpy()]
    last_sweep = tuple(float(v) for v in sweep[["q1", "q2"]].to_numpy()[-1])
    estimators, start_s = {}, {}
    for pipe, dtype, label in [("gru", "float64", "online float64"),
                               ("gru", "float32", "online float32"),
                               ("mlp", "float64", "online, MLP (float64)"),
                               ("none", "float64", "online, backbone only"),
                               *((f"{p}, hysteresis={kind}", "float64",
                                  f"online {'float64' if p == 'gru' else 'backbone only'}, "
                                  f"hysteresis={kind}")
                                 for kind in hysteresis for p in ("gru", "none"))]:
        for engine in engines:
            name = f"{label}, {engine}"
            t0 = time.perf_counter()
            est = OnlineEstimator(pipes[pipe], dtype=dtype, engine=engine)
            estimators[name] = est.start(sweep)
            start_s[name] = time.perf_counter() - t0
    reference = estimators[f"online float64, {engines[0]}"]
    loops = {"plain torch GRUCell": TorchLoop(pipes["gru"], reference, last_sweep)}
    tmp = tempfile.TemporaryDirectory()
    if importlib.util.find_spec("onnxruntime") is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # notices of torch's legacy ONNX exporter
            if full:
                loops["onnxruntime float32"] = OnnxLoop(
                    pipes["gru"], estimators[f"online float32, {engines[0]}"], last_sweep,
                    Path(tmp.name) / "step.onnx", "float32",
                )
            if importlib.util.find_spec("skcath.online._export_step") is not None:
                loops["onnxruntime whole step (float64)"] = StepGraphLoop(
                    reference, Path(tmp.name) / "whole.onnx")
    return dict(pipes=pipes, run=run, motion=motion, sweep=sweep, samples=samples,
                estimators=estimators, start_s=start_s, loops=loops, fit_s=fit_s, tmp=tmp)


def _parity(prep):
    """Largest difference (mm) to float32 and float64 ``predict`` of each variant that has one."""
    pipes, run, motion, samples = prep["pipes"], prep["run"], prep["motion"], prep["samples"]
    pred32 = pipes["gru"].predict(run)[motion]
    pipe64 = copy.deepcopy(pipes["gru"])
    pipe64["residual"].module_.double()
    pred64 = pipe64.predict(run)[motion]
    parity = {}
    steppers = {name: est.reset().step for name, est in prep["estimators"].items()
                if name.startswith(("online float64", "online float32"))}
    for name, loop in prep["loops"].items():
        loop.reset()
        steppers[name] = loop.step
    for name, step in steppers.items():
        tips = np.array([step(*s) for s in samples])
        parity[name] = (np.abs(tips - pred32).max(), np.abs(tips - pred64).max())
    for name, est in prep["estimators"].items():  # --hysteresis: each against its own predict
        if "hysteresis=" in name:
            pipe = est.pipeline
            predicted = [pipe.predict(run)[motion]]
            if hasattr(pipe["residual"], "module_"):
                pipe64 = copy.deepcopy(pipe)
                pipe64["residual"].module_.double()
                predicted.append(pipe64.predict(run)[motion])
            est.reset()
            tips = np.array([est.step(*s) for s in samples])
            parity[name] = tuple(np.abs(tips - p).max() for p in (predicted * 2)[:2])
    return parity


def _variants(prep):
    """Name -> (step function, reset), the estimators stepped with ``out=``."""
    variants = {}
    for name, est in prep["estimators"].items():
        buf = np.empty(3)
        est.reset()

        def step(q1, q2, t1, t2, _s=est.step, _b=buf):
            return _s(q1, q2, t1, t2, out=_b)

        variants[name] = (step, est.reset)
    for name, loop in prep["loops"].items():
        loop.reset()
        variants[name] = (loop.step, loop.reset)
    return variants


def _run_rounds(variants, samples, n_steps, times=None, cursors=None):
    """Step every variant ``n_steps`` times, interleaved in rounds; ns per step by name."""
    times = {name: [] for name in variants} if times is None else times
    cursors = {name: 0 for name in variants} if cursors is None else cursors
    done = 0
    while done < n_steps:
        n = min(ROUND, n_steps - done)
        for name, (step, reset) in variants.items():
            cursors[name] = _timed(step, samples, reset, cursors[name], n, times[name])
        done += n
    return times


def _header(args, prep, cold, load, bench_s):
    print("# Streaming estimator: latency per step (backbone included)\n")
    for line in machine_lines():
        print(f"- {line}")
    print(f"- torch {torch.__version__}, 1 torch thread, 1 BLAS thread")
    print(f"- load average (1, 5, 15 min) before: {', '.join(f'{v:.2f}' for v in load[0])}; "
          f"after: {', '.join(f'{v:.2f}' for v in load[1])}")
    run, estimators, start_s = prep["run"], prep["estimators"], prep["start_s"]
    print(f"- pipelines fitted in {prep['fit_s']:.1f} s; timing loop {bench_s:.1f} s; "
          f"{args.steps} steps per variant; run {run['run'].iloc[0]} "
          f"({len(prep['samples'])} motion samples)")
    if "online float64, numba" not in estimators:
        print("- numba is not installed: numpy engine only")
        return
    import numba

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


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20000, help="timed steps per variant")
    parser.add_argument("--alloc-steps", type=int, default=5000, help="steps under tracemalloc")
    parser.add_argument("--no-cold-compile", action="store_true",
                        help="skip timing a compilation of the numba kernel from scratch")
    parser.add_argument("--compare-to", metavar="PATH",
                        help="time the numba rows of this checkout and of the checkout at PATH "
                             "back to back, each in a process of its own, in one table")
    parser.add_argument("--hysteresis", nargs="+", choices=["play", "pi"], default=[],
                        help="also time the GRU float64 and backbone-only estimators with "
                             "PDLBackbone(hysteresis=KIND), for each KIND given")
    parser.add_argument("--breakdown", action="store_true",
                        help="only time the pieces of the numba step in-process, one table "
                             "(benchmarks/_streaming_breakdown.py)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.compare_to:
        return compare(args.compare_to, args.steps)
    torch.set_num_threads(1)
    threadpool_limits(1)
    if args.worker:
        return _worker()
    if args.breakdown:
        return _breakdown()
    has_numba = importlib.util.find_spec("numba") is not None
    prep = _prepare(["numba", "numpy"] if has_numba else ["numpy"], hysteresis=args.hysteresis)
    cold = None
    if has_numba and not args.no_cold_compile:
        cold = _cold_compile(prep["pipes"]["gru"], prep["sweep"])
    parity = _parity(prep)
    variants = _variants(prep)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    times = _run_rounds(variants, prep["samples"], args.steps)
    bench_s = time.perf_counter() - t0
    load = (load_before, os.getloadavg())
    allocs = {name: _alloc(est, prep["samples"], args.alloc_steps)
              for name, est in prep["estimators"].items()}
    _header(args, prep, cold, load, bench_s)
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


def _breakdown():
    """``--breakdown``: the table of :mod:`_streaming_breakdown` for the numba rows."""
    from _streaming_breakdown import breakdown

    prep = _prepare(["numba"], full=False)
    for line in machine_lines():
        print(f"- {line}")
    load_before = os.getloadavg()
    breakdown({name.removeprefix("online").removesuffix(", numba").strip(" ,"): est
               for name, est in prep["estimators"].items()}, prep["samples"])
    print(f"\nload average (1, 5, 15 min) before: {', '.join(f'{v:.2f}' for v in load_before)}; "
          f"after: {', '.join(f'{v:.2f}' for v in os.getloadavg())}")


# ---------------------------------------------------------------------------
# two checkouts back to back
# ---------------------------------------------------------------------------
def _worker():
    """``--worker``: the numba rows of the skcath on ``sys.path``, timed on request.

    Prints the names of its variants (one JSON line), then for every line
    ``n`` read from stdin steps each variant ``n`` times (interleaved) and
    prints the ns of every step by name (one JSON line).
    """
    prep = _prepare(["numba"], full=False)
    variants = _variants(prep)
    cursors = {name: 0 for name in variants}
    print(json.dumps(list(variants)), flush=True)
    for line in sys.stdin:
        times = _run_rounds(variants, prep["samples"], int(line), cursors=cursors)
        print(json.dumps(times), flush=True)


def compare(other, n_steps):
    """Time this checkout and the one at ``other`` back to back; print one table.

    Each checkout runs :func:`_worker` in its own process (``PYTHONPATH`` set
    to the checkout, the script itself from this checkout); the two take turns,
    one round of ``ROUND`` steps per variant at a time, the first to go
    alternating, so that a change of the machine's load hits both alike.
    """
    roots = {"this": str(Path(__file__).resolve().parents[1]), "other": str(Path(other).resolve())}
    workers = {}
    for label, root in roots.items():  # both fit and start at once, then take turns
        env = dict(os.environ, PYTHONPATH=root, OMP_NUM_THREADS="1")
        workers[label] = subprocess.Popen([sys.executable, __file__, "--worker"], cwd=root,
                                          env=env, stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE, text=True)
    names = {label: json.loads(worker.stdout.readline()) for label, worker in workers.items()}
    times = {label: {name: [] for name in names[label]} for label in roots}
    load_before = os.getloadavg()
    order = list(roots)
    for k in range(0, n_steps, ROUND):
        for label in order if k // ROUND % 2 == 0 else order[::-1]:
            workers[label].stdin.write(f"{min(ROUND, n_steps - k)}\n")
            workers[label].stdin.flush()
            for name, t in json.loads(workers[label].stdout.readline()).items():
                times[label][name].extend(t)
    for worker in workers.values():
        worker.stdin.close()
        worker.wait()
    _compare_table(roots, times, (load_before, os.getloadavg()), n_steps)


def _compare_table(roots, times, load, n_steps):
    print("# Streaming step: this checkout against another, back to back\n")
    for line in machine_lines():
        print(f"- {line}")
    print(f"- this: {roots['this']}; other: {roots['other']}; {n_steps} steps per variant, "
          f"rounds of {ROUND} alternating between the two processes")
    print(f"- load average (1, 5, 15 min) before: {', '.join(f'{v:.2f}' for v in load[0])}; "
          f"after: {', '.join(f'{v:.2f}' for v in load[1])}\n")
    p50 = {label: {name: np.percentile(t, 50) / 1e3 for name, t in rows.items()}
           for label, rows in times.items()}
    # the quietest round: the least p50 of a round of ROUND steps
    best = {label: {name: np.median(np.reshape(t[: len(t) // ROUND * ROUND], (-1, ROUND)),
                                    axis=1).min() / 1e3 for name, t in rows.items()}
            for label, rows in times.items()}
    ref = {label: rows["plain torch GRUCell"] for label, rows in p50.items()}
    print("| variant | this p50 us | other p50 us | this / other | best round: this / other "
          "(us) | this / torch | other / torch |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name in dict.fromkeys([*p50["this"], *p50["other"]]):
        a, b = p50["this"].get(name), p50["other"].get(name)
        c, d = best["this"].get(name), best["other"].get(name)
        cells = [f"{a:.1f}" if a else "-", f"{b:.1f}" if b else "-",
                 f"{a / b:.2f}" if a and b else "-",
                 f"{c / d:.2f} ({c:.1f} / {d:.1f})" if c and d else "-",
                 f"{a / ref['this']:.3f}" if a else "-", f"{b / ref['other']:.3f}" if b else "-"]
        print(f"| {name} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
