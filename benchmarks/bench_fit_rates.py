"""Error of PDL+GRU fitted and tested at 10, 20, 40 and 100 Hz with the default time scales.

A residual learner gives its time scales in seconds (``window_s=20.0``,
``burn_in_s=5.0``, ``window_step_s=None``, i.e. 15 s, ``sweep_stride_s=4.0``)
and turns them into samples at the rate of its training runs, so that the
defaults mean the same physical time at any rate (``docs/residuals.rst``,
*Sample rates*). This script measures whether a model fitted at another rate
than 10 Hz with the defaults is as accurate as the one fitted at 10 Hz.

Data: catheter C1 of the simulated benchmark, its 17 shaft settings with
``--n-runs`` runs each, generated at every rate with
``make_benchmark(n_catheters=1, n_runs=..., rate_hz=...)``: the same runs
(motions, drifts, base poses) sampled at each rate, with fresh per-sample
noise. Settings are held out with ``SettingGroupKFold(--n-folds)`` (the
same folds at every rate; ``--max-folds`` evaluates only the first ones); for
every fold ``Pipeline([("backbone", PDLBackbone()), ("residual", GRUResidual(...))])``
is fitted on the other settings' runs and predicts the held-out settings'
runs, both at the same rate. The learner keeps every default but the network
size and the epochs, the same at every rate: the quick schedule's
``module__hidden_size=64`` and ``--epochs`` epochs (12 by default, about as
many run-epochs as the quick schedule's pretraining, as in
``benchmarks/bench_rates.py``), one seed. Reported: the mean per-run RMSE
(mm) over the motion rows of all held-out runs, its ratio to the 10 Hz one,
PDL alone on the same runs, and the time spent fitting. Goal: every rate
within 10 % of 10 Hz. The learner's ``rate_hz`` defaults to 10 Hz: its
network steps every 0.1 s whatever the recording's rate, the runs resampled
to it; ``--native`` adds, beside the defaults, the network stepping at the
recordings' own rate (``rate_hz=None``).

Usage (from the repository root)::

    nice -n 10 .venv/bin/python benchmarks/bench_fit_rates.py
    nice -n 10 .venv/bin/python benchmarks/bench_fit_rates.py --rates 10 40 --n-runs 1 --n-folds 2
    nice -n 10 .venv/bin/python benchmarks/bench_fit_rates.py --rates 10 100 40 20 \
        --n-runs 1 --n-folds 2 --max-folds 1 --native   # the short table of docs/studies/rates.rst
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
from skcath.residuals import GRUResidual  # noqa: E402

#: The quick schedule's network size: the only parameter set besides the epochs.
NETWORK = {"module__hidden_size": 64}


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 20.0, 40.0, 100.0],
                        help="rates (Hz) fitted and tested, in this order; the first is the "
                             "reference")
    parser.add_argument("--n-runs", type=int, default=3, help="runs per shaft setting")
    parser.add_argument("--n-folds", type=int, default=4)
    parser.add_argument("--max-folds", type=int, default=None,
                        help="evaluate only the first folds (the same ones at every rate)")
    parser.add_argument("--epochs", type=int, default=12, help="training epochs")
    parser.add_argument("--native", action="store_true",
                        help="also fit every rate other than 10 Hz with GRUResidual(rate_hz=None), "
                             "the network stepping at the recordings' own rate")
    parser.add_argument("--native-only", action="store_true",
                        help="fit every rate other than 10 Hz with rate_hz=None only")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--cache", action="store_true",
                        help="cache the generated data in the skcath data folder")
    parser.add_argument("--json", type=Path, help="write the raw results here")
    return parser.parse_args(argv)


DEFAULT = "defaults"  # the learner's own rate_hz (10 Hz)


def learner(args, model_rate=DEFAULT):
    """GRUResidual with its defaults, the quick schedule's network size and ``--epochs``."""
    rate = {} if model_rate == DEFAULT else {"rate_hz": model_rate}
    return GRUResidual(max_epochs=args.epochs, random_state=0, n_threads=args.threads,
                       **rate, **NETWORK)


def model_rates(rate, args):
    """How the learners fitted at ``rate`` step: the defaults, and the recordings' own rate."""
    if rate == 10.0 or not (args.native or args.native_only):
        return [DEFAULT]
    return [None] if args.native_only else [DEFAULT, None]


def evaluate(X, y, args, model_rate=DEFAULT):
    """Per-run errors of every held-out run, the fitted time scales and the fitting time."""
    cv = SettingGroupKFold(n_splits=args.n_folds)
    errors, fit_s, scales = [], 0.0, None
    for train, test in list(cv.split(X))[: args.max_folds]:
        pipe = Pipeline([("backbone", PDLBackbone()), ("residual", learner(args, model_rate))])
        start = time.perf_counter()
        pipe.fit(X.iloc[train], y[train])
        fit_s += time.perf_counter() - start
        Xt = X.iloc[test].reset_index(drop=True)
        errors.append(per_run_rmse(y[test], pipe.predict(Xt), Xt))
        residual = pipe.named_steps["residual"]
        scales = (residual.rate_hz_, residual.window_, residual.window_step_,
                  residual.burn_in_, residual.sweep_stride_)
        settings = sorted(set(X["setting"].iloc[test].astype(str)))
        print(f"  fold {settings[0]}-{settings[-1]}: RMSE {errors[-1].mean():.3f} mm, "
              f"{fit_s:.0f} s fitting so far", flush=True)
    return pd.concat(errors), scales, fit_s


def main(argv=None):
    args = parse_args(argv)
    results = {}
    for rate in args.rates:
        start = time.perf_counter()
        bench = make_benchmark(n_catheters=1, n_runs=args.n_runs, rate_hz=rate, cache=args.cache)
        X = bench.X.assign(run=bench.X["run"].astype(str)).reset_index(drop=True)
        y = np.asarray(bench.y)
        print(f"data at {rate:g} Hz: {len(X)} rows in {time.perf_counter() - start:.0f} s",
              flush=True)
        pdl_runs = per_run_rmse(y, PDLBackbone().fit(X).predict(X), X)
        for model_rate in model_rates(rate, args):
            errors, scales, fit_s = evaluate(X, y, args, model_rate)
            pdl = float(pdl_runs.loc[errors.index].mean())  # the same runs
            results[rate, model_rate] = {
                "rate": rate, "model_rate": model_rate, "rmse": float(errors.mean()),
                "n_runs": len(errors), "pdl": pdl, "fit_s": fit_s, "rate_hz_": scales[0],
                "samples": list(scales[1:]),
                "per_run": {str(k): float(v) for k, v in errors.items()},
            }
            print(f"{rate:g} Hz, rate_hz={model_rate}: RMSE {errors.mean():.3f} mm "
                  f"({fit_s:.0f} s fitting)", flush=True)
        if args.json:  # after every rate, so that a long run keeps what it measured
            args.json.write_text(json.dumps(list(results.values()), indent=1))

    print()
    for line in machine_lines():
        print(line)
    print()
    reference = results.get((args.rates[0], DEFAULT), next(iter(results.values())))["rmse"]
    print(f"| recorded at | GRUResidual | window, window step, burn-in, sweep stride "
          f"(samples) | PDL alone mm | PDL+GRU RMSE mm (runs) | vs {args.rates[0]:g} Hz | "
          "fitting s |")
    print("|---|---|---|---:|---:|---:|---:|")
    for (rate, model_rate), r in sorted(results.items(), key=lambda kv: (kv[0][0], str(kv[0][1]))):
        counts = ", ".join(str(c) for c in r["samples"])
        how = "defaults (rate_hz=10)" if model_rate == DEFAULT else "rate_hz=None"
        print(f"| {rate:g} Hz | {how} | {counts} | {r['pdl']:.3f} | {r['rmse']:.3f} "
              f"({r['n_runs']}) | {100 * (r['rmse'] / reference - 1):+.1f} % | "
              f"{r['fit_s']:.0f} |")


if __name__ == "__main__":
    main()
