"""Error of PDL+GRU on recordings at other sample rates than the one it was fitted at.

A residual learner counts time in samples at the rate of its training runs
(``rate_hz_``); ``predict`` resamples a run recorded at another rate, or
with uneven times, onto ticks at that rate and interpolates the residual
back (``docs/residuals.rst``, *Sample rates*), and
:class:`skcath.online.OnlineEstimator` steps the model at its ticks when it
is given each sample's time. This script measures whether that keeps the
error of the rate the model was fitted at.

Data: catheter C1 of the simulated benchmark, its 17 shaft settings with
``--n-runs`` runs each, generated at every rate with
``make_benchmark(n_catheters=1, n_runs=..., rate_hz=...)``: the same runs
(motions, drifts, base poses) sampled at 10, 20, 40 and 100 Hz, with fresh
per-sample noise. Settings are held out with ``SettingGroupKFold(4)`` (the
quick schedule's folds, one seed): for every fold the pipeline
``Pipeline([("backbone", PDLBackbone()), ("residual", GRUResidual(...))])``
is fitted on the other settings at the fitted rate and predicts the held-out
settings' runs at every rate. The network has the quick schedule's size
(``module__hidden_size=64``, ``lr=1e-2``) and is trained for 12 epochs on
the 39 runs of a fold (3 runs per setting), about as many run-epochs as the
quick schedule's pretraining; its time scales are the defaults in seconds
(``window_s=20.0``, ``burn_in_s=5.0``, ``sweep_stride_s=4.0``) and the quick
schedule's ``window_step_s=20.0``, in samples at the fitted rate.
The error of PDL alone at every rate (all runs) is given beside: what the
residual learner has to correct.

Rows: fitted at 10 Hz, predicting at 10, 20, 40, 100 Hz and at 10 Hz with
every timestamp moved by a uniform ±10 % of a step (``jitter``; the values
stay those of the regular samples, as with a jittery clock); fitted at
40 Hz, predicting at 10, 40 and 100 Hz. Offline: the mean per-run RMSE
(mm) over the motion rows of all 17 held-out settings' runs. Streamed: the
first held-out run of every fold (4 runs), streamed with each sample's time
by ``OnlineEstimator(pipe, engine=...)``, and the offline error on the same
runs beside it. Goal: every rate within 10 % of the error at the fitted rate.

Usage (from the repository root)::

    nice -n 10 .venv/bin/python benchmarks/bench_rates.py
    nice -n 10 .venv/bin/python benchmarks/bench_rates.py --fit-rates 10 --rates 10 20 --n-runs 1
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.pipeline import Pipeline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine_lines  # noqa: E402

from skcath.backbones import PDLBackbone  # noqa: E402
from skcath.datasets import make_benchmark  # noqa: E402
from skcath.metrics import per_run_rmse  # noqa: E402
from skcath.model_selection import SettingGroupKFold  # noqa: E402
from skcath.online import OnlineEstimator  # noqa: E402
from skcath.residuals import GRUResidual  # noqa: E402

#: The quick schedule's network size and learning rate, and the epochs of this benchmark.
QUICK = {"module__hidden_size": 64, "max_epochs": 12, "lr": 1e-2}
#: The quick schedule's window step (s); the other time scales are the defaults.
WINDOW_STEP_S = 20.0
CHANNELS = ["q1", "q2", "tau1", "tau2"]


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fit-rates", type=float, nargs="+", default=[10.0, 40.0])
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 20.0, 40.0, 100.0],
                        help="rates predicted by the model fitted at 10 Hz")
    parser.add_argument("--rates-40", type=float, nargs="+", default=[10.0, 40.0, 100.0],
                        help="rates predicted by the model fitted at 40 Hz")
    parser.add_argument("--n-runs", type=int, default=3, help="runs per shaft setting")
    parser.add_argument("--n-folds", type=int, default=4)
    parser.add_argument("--epochs", type=int, default=QUICK["max_epochs"],
                        help="training epochs (a smaller number for a trial run)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--engine", default="auto", choices=["auto", "numba", "numpy"])
    parser.add_argument("--cache", action="store_true",
                        help="cache the generated data in the skcath data folder")
    parser.add_argument("--json", type=Path, help="write the raw results here")
    return parser.parse_args(argv)


def learner(args):
    """The quick schedule's GRU; its time scales in seconds count samples at the fitted rate."""
    params = {**QUICK, "max_epochs": args.epochs, "window_step_s": WINDOW_STEP_S}
    return GRUResidual(random_state=0, n_threads=args.threads, **params)


def held_out(X, settings):
    rows = X["setting"].astype(str).isin(settings).to_numpy()
    return X[rows].reset_index(drop=True), rows


def jittered(X, seed=0):
    """``X`` with every time moved by a uniform +-10 % of the run's step."""
    step = X.groupby("run", observed=True)["t"].transform(lambda t: np.median(np.diff(t)))
    rng = np.random.default_rng(seed)
    return X.assign(t=X["t"] + rng.uniform(-0.1, 0.1, len(X)) * step.to_numpy())


def backbone_error(X, y):
    """Mean per-run RMSE (mm) of PDL alone over the motion rows of all runs."""
    return float(per_run_rmse(y, PDLBackbone().fit(X).predict(X), X).mean())


def streamed(pipe, X, pred, engine):
    """``pred`` of the one run in ``X`` with its motion rows streamed, each with its time."""
    motion = (X["phase"] == "motion").to_numpy()
    est = OnlineEstimator(pipe, engine=engine).start(X[~motion])
    rows = X.loc[motion, ["t", *CHANNELS]].to_numpy()
    tips = pred.copy()  # the sweep rows (not scored)
    tips[motion] = [est.step(*r[1:], t=r[0]) for r in rows]
    return tips


def evaluate(fit_rate, rates, args, data):
    """Per-run errors of every held-out run at every rate, offline and streamed."""
    X_fit, y_fit = data(fit_rate)
    settings = X_fit["setting"].astype(str).to_numpy()
    cv = SettingGroupKFold(n_splits=args.n_folds)
    offline = {r: [] for r in rates}
    stream = {r: [] for r in rates}
    stream_offline = {r: [] for r in rates}
    seconds = {"fit": 0.0, "predict": {r: 0.0 for r in rates}, "stream": {r: 0.0 for r in rates}}
    for train, test in cv.split(X_fit):
        tested = sorted(set(settings[test]))
        pipe = Pipeline([("backbone", PDLBackbone()), ("residual", learner(args))])
        start = time.perf_counter()
        pipe.fit(X_fit.iloc[train], y_fit[train])
        seconds["fit"] += time.perf_counter() - start
        for rate in rates:
            X, y = data(rate)
            Xt, rows = held_out(X, tested)
            yt = y[rows]
            start = time.perf_counter()
            pred = pipe.predict(Xt)
            seconds["predict"][rate] += time.perf_counter() - start
            errors = per_run_rmse(yt, pred, Xt)
            offline[rate].append(errors)
            first = (Xt["run"] == Xt["run"].iloc[0]).to_numpy()
            start = time.perf_counter()
            tips = streamed(pipe, Xt[first].reset_index(drop=True), pred[first], args.engine)
            seconds["stream"][rate] += time.perf_counter() - start
            stream[rate].append(per_run_rmse(yt[first], tips, Xt[first].reset_index(drop=True)))
            stream_offline[rate].append(errors.iloc[:1])
        print(f"  fold {tested[0]}-{tested[-1]} done: offline RMSE "
              + ", ".join(f"{r if r == 'jitter' else f'{r:g} Hz'} "
                          f"{offline[r][-1].mean():.3f}" for r in rates), flush=True)
    return {
        rate: {
            "offline": float(pd.concat(offline[rate]).mean()),
            "n_runs": int(sum(len(e) for e in offline[rate])),
            "streamed": float(pd.concat(stream[rate]).mean()),
            "offline_streamed_runs": float(pd.concat(stream_offline[rate]).mean()),
            "streamed_runs": [str(r) for e in stream[rate] for r in e.index],
            "predict_s": seconds["predict"][rate],
            "stream_s": seconds["stream"][rate],
        }
        for rate in rates
    }, seconds["fit"]


def main(argv=None):
    args = parse_args(argv)
    cache = {}

    def data(rate):
        """(X, y) of catheter C1 at ``rate`` (Hz); the key "jitter" is 10 Hz with jittered times."""
        if rate not in cache:
            if rate == "jitter":
                X, y = data(10.0)
                cache[rate] = (jittered(X), y)
            else:
                start = time.perf_counter()
                bench = make_benchmark(n_catheters=1, n_runs=args.n_runs, rate_hz=rate,
                                       cache=args.cache)
                print(f"data at {rate:g} Hz: {len(bench.X)} rows in "
                      f"{time.perf_counter() - start:.0f} s", flush=True)
                X = bench.X.assign(run=bench.X["run"].astype(str))
                cache[rate] = (X, np.asarray(bench.y))
        return cache[rate]

    pdl = {}
    results = {}
    for fit_rate in args.fit_rates:
        rates = (list(args.rates) + ["jitter"]) if fit_rate == 10.0 else list(args.rates_40)
        start = time.perf_counter()
        per_rate, fit_s = evaluate(fit_rate, rates, args, data)
        for rate, r in per_rate.items():
            if rate not in pdl:
                pdl[rate] = backbone_error(*data(rate))
            r["pdl"] = pdl[rate]
        results[fit_rate] = per_rate
        print(f"fitted at {fit_rate:g} Hz: {time.perf_counter() - start:.0f} s "
              f"({fit_s:.0f} s fitting)", flush=True)

    print()
    for line in machine_lines():
        print(line)
    print()
    print("| fitted at | recorded at | PDL alone mm | offline RMSE mm (runs) | vs fitted rate | "
          "streamed RMSE mm | offline, same runs | streamed vs fitted rate |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for fit_rate, per_rate in results.items():
        base = per_rate[fit_rate]
        for rate, r in per_rate.items():
            name = "10 Hz, times ±10 %" if rate == "jitter" else f"{rate:g} Hz"
            print(f"| {fit_rate:g} Hz | {name} | {r['pdl']:.3f} | "
                  f"{r['offline']:.3f} ({r['n_runs']}) | "
                  f"{100 * (r['offline'] / base['offline'] - 1):+.1f} % | "
                  f"{r['streamed']:.3f} | {r['offline_streamed_runs']:.3f} | "
                  f"{100 * (r['streamed'] / base['streamed'] - 1):+.1f} % |")
    streamed_runs = {f"{k:g} Hz": v[k]["streamed_runs"] for k, v in results.items()}
    print(f"\nstreamed runs: {streamed_runs}")
    if args.json:
        args.json.write_text(json.dumps({str(k): v for k, v in results.items()}, indent=1))


if __name__ == "__main__":
    main()
