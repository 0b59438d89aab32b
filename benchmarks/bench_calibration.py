"""Time and final cost of the backbone calibrations against scipy's least_squares.

For every bent-shaft run of a simulated benchmark (settings S01-S16 of
``make_benchmark(n_catheters=1, n_runs=3)``: 48 runs, about 4300 sweep rows
each), this script calibrates both geometric backbones on the run's sweep rows
(reference tip positions ``ref_x, ref_y, ref_z`` as targets, ray labels from
:func:`skcath.sweep.find_rays`) with

- ``ours``: :func:`skcath.backbones.calibrate_pdl` and
  :func:`skcath.backbones.calibrate_pcc`, as the estimators call them
  (``max_iter=100``; PCC with ``q0`` and ``S_m`` from the sweep's rays), i.e.
  :func:`skcath.backbones.levenberg_marquardt`;
- ``scipy lm`` and ``scipy trf``: the very same calls, with ``solver=`` an
  adapter that hands the same residual function, the same analytic Jacobian
  and the same initial guess to :func:`scipy.optimize.least_squares`
  (``method="lm"`` or ``"trf"``).
  Everything else (input checks, neutral tip and basis, per-ray linear
  initial guess for PDL, data-driven initial guess for PCC, bookkeeping) is
  the same code, so the timings differ by the solver only.

Tolerances passed to scipy: ``ftol`` and ``xtol`` as given to our solver
(PDL: ``ftol=1e-6``, ``xtol=1e-12``; PCC: ``ftol=xtol=1e-12``),
``x_scale="jac"`` (our solver scales the damping by ``diag(J^T J)``, as
MINPACK does), ``gtol`` disabled for trf (our solver has no gradient test)
and at its smallest allowed value (machine epsilon) for lm, and scipy's
default ``max_nfev`` (100 x the number of parameters). The stopping tests are
not identical: ours stops when an accepted step lowers the cost by less than
``ftol`` times the cost or is shorter than ``xtol (xtol + |x|)``; trf uses the
same two tests but counts the ``ftol`` one only for a step whose actual
reduction is more than a quarter of the reduction predicted by the
Gauss-Newton model; MINPACK's lm requires the actual and the predicted
relative reductions to be below ``ftol`` (and their ratio at most 2), and
scales its step test.

Beside the time, the table gives each solver's final cost relative to the
best known minimum: per solver call (one per PDL ray, one for PCC), the
lowest cost reached by any of the three solvers or by an untimed scipy lm
run with every tolerance at 1e-15.

Only the calibration call is timed (``time.perf_counter``; ``find_rays``
and the data generation are not), each one ``--repeat`` times, keeping the
minimum; the garbage collector is off during a timed call and BLAS is limited
to one thread (threadpoolctl, else the thread-count environment variables).

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_calibration.py
    .venv/bin/python benchmarks/bench_calibration.py --n-runs 16 --repeat 5

The data are generated when the script runs (``make_benchmark(cache=False)``,
a few seconds) unless ``--cache`` is given. The table is printed in Markdown.
Targets: median calibration time at most 20 ms (PDL) and 50 ms (PCC) on a
2-core machine, at a final cost no higher than scipy's.
"""

import argparse
import contextlib
import gc
import json
import os
import sys
import time

try:
    from threadpoolctl import threadpool_info, threadpool_limits
except ImportError:  # pin the BLAS threads before numpy is imported
    threadpool_info = threadpool_limits = None
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                 "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS"):
        os.environ[_var] = "1"

import numpy as np
from scipy.optimize import least_squares

from _machine import machine_lines
from skcath import MOTOR_COLUMNS, REFERENCE_COLUMNS
from skcath.backbones import LMResult, calibrate_pcc, calibrate_pdl, levenberg_marquardt
from skcath.datasets import MECHANISMS, make_benchmark
from skcath.sweep import check_sweep_references, find_rays

SOLVERS = ("ours", "scipy lm", "scipy trf")
MODELS = ("PDL", "PCC")
TARGET_MS = {"PDL": 20.0, "PCC": 50.0}
MAX_ITER = 100  # PCCBackbone / PDLBackbone default
RUNS_PER_CATHETER = 48  # settings S01-S16 x 3 repeats
COST_RTOL = 1e-6
REFERENCE = "reference"  # untimed scipy lm run to its tolerance floor
TIGHT_TOL = 1e-15
# Where the square root of the PDL reconstruction is clamped, the cost has a
# kink and the steps creep (one ray took 60,000 evaluations to stop at
# 1e-15); the reference is the best of all solvers per call anyway.
TIGHT_MAX_NFEV = 2000
EPS = float(np.finfo(float).eps)


# ---------------------------------------------------------------------------
# solvers
# ---------------------------------------------------------------------------
def _scipy_solver(method, counts, tight=False):
    """Drop-in for ``levenberg_marquardt`` that calls ``scipy.optimize.least_squares``.

    ``fun(x, jac=True) -> (r, J)`` and ``fun(x, jac=False) -> r`` is the
    residual protocol of our solver; the PDL ray problems cache the last
    evaluation, so the Jacobian at a point where the residuals were just
    computed reuses them, whichever solver asks. ``max_iter`` (accepted steps)
    and ``damping`` have no counterpart: scipy keeps its default ``max_nfev``
    and its own initial trust region.
    """

    def solve(fun, x0, *, max_iter=100, ftol=1e-12, xtol=1e-12, damping=1e-3, retract=None):
        if retract is not None:
            raise NotImplementedError("least_squares has no manifold retraction")
        options = {"ftol": ftol, "xtol": xtol, "gtol": EPS if method == "lm" else None}
        if tight:  # reference minimum: tolerances at their floor
            options = {"ftol": TIGHT_TOL, "xtol": TIGHT_TOL, "gtol": TIGHT_TOL,
                       "max_nfev": TIGHT_MAX_NFEV}
        res = least_squares(
            lambda x: fun(x, jac=False),
            x0,
            jac=lambda x: fun(x, jac=True)[1],
            method=method,
            x_scale="jac",
            **options,
        )
        if counts is not None:
            counts["nfev"] += int(res.nfev)
            counts["njev"] += int(res.njev if res.njev is not None else 0)
            counts["calls"] += 1
            counts["max_nfev_hit"] += int(res.status == 0)
            counts["costs"].append(float(res.cost))
        return LMResult(res.x, float(res.cost), int(res.njev or 0), bool(res.status > 0))

    return solve


def _counting_ours(original, counts):
    """Our solver with residual / Jacobian evaluations counted (untimed pass only)."""

    def solve(fun, x0, **kwargs):
        def counted(x, jac=True):
            counts["njev" if jac else "nfev"] += 1
            return fun(x, jac=jac)

        counts["calls"] += 1
        result = original(counted, x0, **kwargs)
        counts["costs"].append(float(result.cost))
        return result

    return solve


def _solver(name, counts=None):
    """The named solver, for the ``solver=`` argument of the calibrations."""
    if name == "ours":
        return levenberg_marquardt if counts is None else _counting_ours(levenberg_marquardt, counts)
    if name == REFERENCE:
        return _scipy_solver("lm", counts, tight=True)
    return _scipy_solver(name.split()[1], counts)


def _calibrate(model, sweep, solver):
    """One calibration of ``model`` on a run's sweep with ``solver``; returns its info dict."""
    q, ref, rays = sweep["q"], sweep["ref"], sweep["rays"]
    if model == "PDL":
        return calibrate_pdl(
            q, ref, rays.labels, rays.directions, rays.neutral,
            q_neutral=rays.q_neutral, max_iter=MAX_ITER, return_info=True, solver=solver,
        )[1]
    return calibrate_pcc(
        q, ref, q0=rays.q_neutral, S_m=rays.amplitude, max_iter=MAX_ITER, return_info=True,
        solver=solver,
    )[1]


def _check_calls(model, name, counts, sweep):
    """Raise unless the calibration called the substituted solver once per problem."""
    expected = sweep["rays"].n_rays if model == "PDL" else 1
    if counts["calls"] != expected:
        raise RuntimeError(
            f"{model} with solver {name!r} made {counts['calls']} solver call(s), expected "
            f"{expected}: calibrate_{model.lower()} no longer calls its solver once per "
            "problem; update this script."
        )


def _timed(model, sweep, solver):
    """Seconds of one calibration call, with the garbage collector off."""
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        start = time.perf_counter()
        _calibrate(model, sweep, solver)
        return time.perf_counter() - start
    finally:
        if gc_was_enabled:
            gc.enable()


# ---------------------------------------------------------------------------
# data and measurement
# ---------------------------------------------------------------------------
def _sweeps(args):
    """Sweep rows (q, ref, rays) of the first ``--n-runs`` bent-shaft runs."""
    n_catheters = -(-args.n_runs // RUNS_PER_CATHETER)
    start = time.perf_counter()
    data = make_benchmark(n_catheters=n_catheters, n_runs=3, mechanism=args.mechanism,
                          cache=args.cache)
    gen_s = time.perf_counter() - start
    X = data.X
    bent = data.runs.loc[data.runs["bend_level"] != "straight", "run"].tolist()[: args.n_runs]
    is_sweep = (X["phase"] == "sweep").to_numpy()
    run_of_row = X["run"].astype(str).to_numpy()
    q_all = X[list(MOTOR_COLUMNS)].to_numpy()
    ref_all = X[list(REFERENCE_COLUMNS)].to_numpy()
    sweeps = []
    for run in bent:
        rows = np.flatnonzero(is_sweep & (run_of_row == run))
        q, ref = q_all[rows], ref_all[rows]
        rays = find_rays(q, run=run)
        check_sweep_references(ref, rays, run=run)
        sweeps.append({"run": run, "q": q, "ref": ref, "rays": rays})
    return sweeps, gen_s


def _measure(sweeps, repeat, progress):
    """Per run, model and solver: best time (s), cost, RMSE, evaluation counts.

    Also, per run and model, the cost of the reference minimum: per solver
    call (one per PDL ray, one for PCC), the lowest of the three solvers'
    costs and of an untimed scipy lm run with every tolerance at 1e-15 (at
    most ``TIGHT_MAX_NFEV`` evaluations), summed over the calls.
    """
    results = []
    for i, sweep in enumerate(sweeps):
        row = {"run": sweep["run"], "n_sweep": len(sweep["q"])}
        for model in MODELS:
            for name in SOLVERS:
                counts = {"nfev": 0, "njev": 0, "calls": 0, "max_nfev_hit": 0, "costs": []}
                info = _calibrate(model, sweep, _solver(name, counts))  # untimed: result, counts
                _check_calls(model, name, counts, sweep)
                row[(model, name)] = {
                    "cost": info["cost"],
                    "rmse_mm": info["rmse_mm"],
                    "converged": bool(info["converged"]),
                    **counts,
                    "times_s": [],
                }
            tight = {"nfev": 0, "njev": 0, "calls": 0, "max_nfev_hit": 0, "costs": []}
            _calibrate(model, sweep, _solver(REFERENCE, tight))
            _check_calls(model, REFERENCE, tight, sweep)
            per_call = np.array([tight["costs"]] + [row[(model, s)]["costs"] for s in SOLVERS])
            row[(model, REFERENCE)] = float(per_call.min(axis=0).sum())
        for _ in range(repeat):  # interleave the solvers within each repeat
            for model in MODELS:
                for name in SOLVERS:
                    row[(model, name)]["times_s"].append(_timed(model, sweep, _solver(name)))
        for model in MODELS:
            for name in SOLVERS:
                entry = row[(model, name)]
                entry["seconds"] = min(entry["times_s"])
                entry["excess"] = entry["cost"] / row[(model, REFERENCE)] - 1.0
        results.append(row)
        if progress:
            print(f"  {i + 1}/{len(sweeps)} {sweep['run']}", file=sys.stderr, flush=True)
    return results


# ---------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------
def _results_for(results, model, name):
    return [row[(model, name)] for row in results]


def _summary(results):
    out = []
    for model in MODELS:
        ours = _results_for(results, model, "ours")
        for name in SOLVERS:
            r = _results_for(results, model, name)
            ms = 1e3 * np.array([x["seconds"] for x in r])
            cost = np.array([x["cost"] for x in r])
            entry = {
                "model": model,
                "solver": name,
                "median_ms": float(np.median(ms)),
                "p90_ms": float(np.percentile(ms, 90)),
                "median_cost": float(np.median(cost)),
                "median_rmse_mm": float(np.median([x["rmse_mm"] for x in r])),
                "median_excess": float(np.median([x["excess"] for x in r])),
                "max_excess": float(np.max([x["excess"] for x in r])),
                "n_excess": int(sum(x["excess"] > COST_RTOL for x in r)),
                "median_njev": float(np.median([x["njev"] for x in r])),
                "median_nfev": float(np.median([x["nfev"] for x in r])),
                "not_converged": int(sum(not x["converged"] for x in r)),
                "max_nfev_hit": int(sum(x["max_nfev_hit"] for x in r)),
            }
            if name != "ours":
                ours_ms = 1e3 * np.array([x["seconds"] for x in ours])
                time_ratio = ms / ours_ms
                cost_ratio = np.array([x["cost"] for x in ours]) / cost
                entry.update(
                    time_ratio_median=float(np.median(time_ratio)),
                    time_ratio_min=float(time_ratio.min()),
                    cost_ratio_max=float(cost_ratio.max()),
                    cost_ratio_min=float(cost_ratio.min()),
                    n_cost_higher=int(np.sum(cost_ratio > 1.0 + COST_RTOL)),
                    n_cost_lower=int(np.sum(cost_ratio < 1.0 - COST_RTOL)),
                )
            out.append(entry)
    return out


def _table(summary, n_runs):
    head = (
        "| backbone | solver | median ms | p90 ms | target ms | time scipy / ours "
        "(median; min) | median cost mm² | cost ours / scipy - 1: max | runs > 1e-6 "
        "| cost ours / scipy - 1: min | cost / minimum - 1: median; max; runs > 1e-6 "
        "| median sweep RMSE mm | Jacobians / residuals per run (median) |"
    )
    rule = "|" + "|".join(["---", "---"] + ["---:"] * 11) + "|"
    rows = [head, rule]
    for e in summary:
        ours = e["solver"] == "ours"
        target = f"{TARGET_MS[e['model']]:g}" if ours else ""
        ratio = "" if ours else f"{e['time_ratio_median']:.2f}; {e['time_ratio_min']:.2f}"
        cmax = "" if ours else f"{e['cost_ratio_max'] - 1.0:+.1e}"
        nhigh = "" if ours else f"{e['n_cost_higher']} / {n_runs}"
        cmin = "" if ours else f"{e['cost_ratio_min'] - 1.0:+.1e}"
        rows.append(
            f"| {e['model']} | {e['solver']} | {e['median_ms']:.1f} | {e['p90_ms']:.1f} | {target} "
            f"| {ratio} | {e['median_cost']:.1f} | {cmax} | {nhigh} | {cmin} "
            f"| {e['median_excess']:.1e}; {e['max_excess']:.1e}; {e['n_excess']} "
            f"| {e['median_rmse_mm']:.4f} | {e['median_njev']:.0f} / {e['median_nfev']:.0f} |"
        )
    return "\n".join(rows)


def _reading(summary):
    lines = []
    by = {(e["model"], e["solver"]): e for e in summary}
    for model in MODELS:
        ours = by[(model, "ours")]
        met = ours["median_ms"] <= TARGET_MS[model]
        parts = [
            f"{model}: ours {ours['median_ms']:.1f} ms median "
            f"({'meets' if met else 'MISSES'} the {TARGET_MS[model]:g} ms target)"
        ]
        for name in SOLVERS[1:]:
            e = by[(model, name)]
            parts.append(
                f"{name} {e['time_ratio_median']:.2f}x our time; our cost higher on "
                f"{e['n_cost_higher']} run(s) (by up to {e['cost_ratio_max'] - 1.0:.1e}), "
                f"lower on {e['n_cost_lower']}"
            )
        flags = [f"{e['solver']}: {e['not_converged']} not converged, {e['max_nfev_hit']} hit max_nfev"
                 for e in summary if e["model"] == model and (e["not_converged"] or e["max_nfev_hit"])]
        lines.append("; ".join(parts) + (" [" + "; ".join(flags) + "]" if flags else "") + ".")
    return lines


def _thread_pools():
    """Thread pools loaded in this process and their current sizes (threadpoolctl)."""
    if threadpool_info is None:
        return "BLAS threads: 1 via the environment variables (threadpoolctl not installed)"
    pools = ", ".join(f"{p['internal_api']} {p['num_threads']}" for p in threadpool_info())
    return f"thread pools while timing (threadpoolctl): {pools}"


def _machine():
    from _machine import source_digest

    import skcath.datasets

    lines = machine_lines()
    # fingerprint the simulator sources, so a table can be matched to the code
    lines.append(f"SIMULATOR_VERSION = {skcath.datasets.SIMULATOR_VERSION!r}, "
                 f"sha1 of skcath/datasets/*.py {source_digest(skcath.datasets)}")
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n-runs", type=int, default=48,
                        help="bent-shaft runs (sweeps) to calibrate (default: 48 = S01-S16 x 3)")
    parser.add_argument("--repeat", type=int, default=3,
                        help="timed calls per run and solver; the minimum is kept (default: 3)")
    parser.add_argument("--mechanism", choices=MECHANISMS, default="play",
                        help="hysteresis mechanism of the simulated data (default: play)")
    parser.add_argument("--cache", action="store_true",
                        help="load / save the data in the skcath data folder instead of generating them")
    parser.add_argument("--json", metavar="PATH", help="also write the raw results to this JSON file")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    if args.n_runs < 1:
        parser.error("--n-runs must be >= 1")

    # numpy, scipy (and, through skcath, scikit-learn's OpenMP) are imported
    # above, so the limit reaches every BLAS / OpenMP pool they loaded.
    limiter = threadpool_limits(limits=1) if threadpool_limits else contextlib.nullcontext()
    with limiter:
        pools = _thread_pools()
        print("generating the data ...", file=sys.stderr, flush=True)
        sweeps, gen_s = _sweeps(args)
        print(f"calibrating {len(sweeps)} sweeps ...", file=sys.stderr, flush=True)
        load_before = os.getloadavg()[0]
        start = time.perf_counter()
        results = _measure(sweeps, args.repeat, progress=True)
        measure_s = time.perf_counter() - start
        load_after = os.getloadavg()[0]
    summary = _summary(results)
    n_sweep = [r["n_sweep"] for r in results]

    print("\n".join(_machine()))
    print(pools)
    print(f"1-minute load average: {load_before:.2f} before, {load_after:.2f} after the measurement "
          f"(the benchmark itself adds about 1)")
    print(f"data: make_benchmark(mechanism={args.mechanism!r}), {len(results)} bent-shaft runs, "
          f"{min(n_sweep)}-{max(n_sweep)} sweep rows each (median {np.median(n_sweep):.0f}); "
          f"generated in {gen_s:.1f} s; measured in {measure_s:.1f} s; "
          f"time = min of {args.repeat} calls\n")
    print(_table(summary, len(results)))
    print()
    print("\n".join(_reading(summary)))
    if args.json:
        raw = [
            {"run": r["run"], "n_sweep": r["n_sweep"],
             **{f"{m} {s}": r[(m, s)] for m in MODELS for s in SOLVERS},
             **{f"{m} minimum cost": r[(m, REFERENCE)] for m in MODELS}}
            for r in results
        ]
        with open(args.json, "w") as f:
            json.dump({"machine": _machine() + [pools], "loadavg": [load_before, load_after],
                       "args": vars(args), "summary": summary, "runs": raw},
                      f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
