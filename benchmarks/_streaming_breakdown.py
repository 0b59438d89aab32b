"""Where the time of one streaming step goes: ``bench_streaming.py --breakdown``.

For each started estimator on the numba engine, the same samples are stepped
by pieces of the step, each timed in-process with ``time.perf_counter_ns``
around a batch of ``BATCH`` steps (the time per step is the batch's time
over ``BATCH``); the pieces take turns batch by batch, ``rounds`` times, and
the table gives the least and the median over the rounds (µs per step):

- ``est.step``: ``est.step(q1, q2, tau1, tau2, out=buf)``, the whole step
  as a user calls it;
- ``compiled call``: ``est._call(buf, sample, True)``, the call into the
  compiled step that ``step`` makes (its Python checks left out);
- ``no-op call``: a compiled function that does nothing, called with the
  same arguments as the compiled call and in the same way (numba's
  dispatcher, or the entry point of the compiled function): the cost of a
  call from Python into compiled code with these arguments (numba's
  conversion of each);
- ``step in compiled loop``: the compiled step called from a compiled loop
  over the samples: the step's own work, no call from Python;
- ``backbone``, ``GRU gate product``, ``GRU candidate product``, ``gates,
  tanh, blend``, ``head``: the pieces of the step
  (``skcath.online._kernels``), each in a compiled loop on copies of the
  estimator's arrays;

and, by difference, ``Python in step`` (``est.step`` less the compiled call),
``call overhead`` (the no-op call) and ``rest of the step`` (the step in its
compiled loop less its pieces: the check of the sample, the features, the
clip and the loops' own cost).
"""

from __future__ import annotations

import time

import numba
import numpy as np

from skcath._kernel import JIT_OPTIONS, load_numba
from skcath.online import _kernels
from skcath.online._jit import step_kernel
from skcath.online._layout import (
    GRU_CAND,
    GRU_GATES,
    M_ANGLES,
    M_HEADER,
    M_N_GRU,
    M_N_HEAD,
    M_W,
)

BATCH = 200
load_numba()  # the kernels' compiled implementations declared to numba
# the options of the step's own kernels: numpy's error model lets the loops vectorise
_jit = numba.njit(**JIT_OPTIONS)


@_jit
def _step_loop(kernel, bound, out, q, n):
    for i in range(n):
        k = i % q.shape[0]
        kernel(*bound, out, (q[k, 0], q[k, 1], q[k, 2], q[k, 3]), True)


@_jit
def _backbone_loop(meta, f, theta, q, n):
    at = meta[M_ANGLES]
    total = 0.0
    for i in range(n):
        k = i % q.shape[0]
        f[at], f[at + 1] = q[k, 0], q[k, 1]
        x, y, z = _kernels._nominal_tip(meta, f, theta)
        total += x + y + z
    return total


@_jit
def _product_loop(meta, w, w32, buf, record, n):
    vectors = _kernels.gru_vectors(meta, buf, M_HEADER)  # v, x, x1, h, g, .., cand, tmp
    for _ in range(n):
        if record == GRU_GATES:
            _kernels.matvec(meta, M_HEADER + GRU_GATES, w, w32, vectors[0], vectors[4])
        else:
            _kernels.matvec(meta, M_HEADER + GRU_CAND, w, w32, vectors[2], vectors[9])


@_jit
def _nonlinear_loop(meta, buf, n):
    _, _, _, h, _, rz, r_pre, z_pre, hn, cand, tmp = _kernels.gru_vectors(meta, buf, M_HEADER)
    for _ in range(n):
        r, z = _kernels.gates(rz, r_pre, z_pre)
        a = _kernels.tanh_of_sum(cand, r, hn)
        _kernels.blend(h, z, a, tmp)


@_jit
def _head_loop(meta, f, w, w32, buf, n):
    for _ in range(n):
        _kernels._head(meta, f, w, w32, buf)


def _noop(meta, a64, anet, w32, out, sample, check):
    """Nothing, with the arguments of the compiled step (``skcath.online._jit.step_kernel``)."""
    return True


def _pieces(est, samples):
    """Name -> function of no arguments that steps ``BATCH`` times, for one estimator."""
    p = est._packed
    call = est._call
    kernel, bound = step_kernel, tuple(call.args)
    out = np.empty(3)
    q = np.array(samples)
    tuples = [samples[k % len(samples)] for k in range(BATCH)]
    noop = _jit(_noop)
    noop(*bound, out, tuples[0], True)
    if not hasattr(call.func, "overloads"):  # the step is called through its entry point
        noop = noop.overloads[noop.signatures[0]].entry_point
    step = est.step

    def user():
        for q1, q2, t1, t2 in tuples:
            step(q1, q2, t1, t2, out=out)

    def compiled_call():
        for s in tuples:
            call(out, s, True)

    def noop_call():
        for s in tuples:
            noop(*bound, out, s, True)

    pieces = {"est.step": user, "compiled call": compiled_call, "no-op call": noop_call,
              "step in compiled loop": lambda: _step_loop(kernel, bound, out, q, BATCH)}
    # the pieces work on copies: the estimator's state stays as it was
    meta, f, theta = p.meta, p.f.copy(), p.theta
    anet = p.anet.copy()
    buf, w = anet[: p.meta[M_W]], anet[p.meta[M_W] :]
    pieces["backbone"] = lambda: _backbone_loop(meta, f, theta, q, BATCH)
    if p.meta[M_N_GRU]:
        pieces["GRU gate product"] = lambda: _product_loop(meta, w, p.w32, buf, GRU_GATES, BATCH)
        pieces["GRU candidate product"] = lambda: _product_loop(meta, w, p.w32, buf, GRU_CAND,
                                                                BATCH)
        pieces["gates, tanh, blend"] = lambda: _nonlinear_loop(meta, buf, BATCH)
    if p.meta[M_N_HEAD]:
        pieces["head"] = lambda: _head_loop(meta, f, w, p.w32, buf, BATCH)
    return pieces


def _time(pieces, rounds):
    """Name -> array of µs per step, one per round; the pieces take turns round by round."""
    for fn in pieces.values():  # compile and warm up
        fn()
    times = {name: [] for name in pieces}
    for _ in range(rounds):
        for name, fn in pieces.items():
            t0 = time.perf_counter_ns()
            fn()
            times[name].append((time.perf_counter_ns() - t0) / BATCH / 1e3)
    return {name: np.asarray(t) for name, t in times.items()}


DERIVED = ("Python in step", "call overhead", "rest of the step")
ORDER = ("est.step", "Python in step", "compiled call", "call overhead", "step in compiled loop",
         "backbone", "GRU gate product", "GRU candidate product", "gates, tanh, blend", "head",
         "rest of the step")


def _summary(times):
    """Name -> (least, median) µs per step, the differences included."""
    least = {name: t.min() for name, t in times.items()}
    median = {name: float(np.median(t)) for name, t in times.items()}
    out = {name: (least[name], median[name]) for name in times}
    parts = [name for name in times if name in ORDER[5:]]
    for stat, values in enumerate((least, median)):
        derived = {
            "Python in step": values["est.step"] - values["compiled call"],
            "call overhead": values["no-op call"],
            "rest of the step": values["step in compiled loop"] - sum(values[n] for n in parts),
        }
        for name, v in derived.items():
            out.setdefault(name, [None, None])
            out[name] = list(out[name])
            out[name][stat] = v
    return out


def breakdown(estimators, samples, rounds=200):
    """Print the table of the module's docstring for ``estimators`` (label -> started estimator)."""
    columns = {}
    for label, est in estimators.items():
        est.reset()
        columns[label] = _summary(_time(_pieces(est, samples), rounds))
        est.reset()
    print(f"Least (median) µs per step over {rounds} rounds of {BATCH} steps of each piece:\n")
    print("| piece | " + " | ".join(columns) + " |")
    print("|---|" + "---:|" * len(columns))
    for name in ORDER:
        cells = []
        for col in columns.values():
            v = col.get(name)
            cells.append("-" if v is None else f"{v[0]:.2f} ({v[1]:.2f})")
        print(f"| {name} | " + " | ".join(cells) + " |")
