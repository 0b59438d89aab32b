"""Seed-ensemble uncertainty of PDL+GRU: accuracy of the mean, calibration of the spread.

Data: the default benchmark (``make_benchmark()``, read from the skcath data
folder), catheter C1 only. The held-out (test) settings are those of the
first fold of ``SettingGroupKFold(n_splits=4, exclude_settings=["S00"])`` on
C1: S01-S04, 12 runs. The model is trained on the other 39 runs of C1
(S00 and S05-S16).

Model: ``Pipeline([("backbone", PDLBackbone()), ("residual",
SeedEnsembleRegressor(GRUResidual(max_epochs=6, module__hidden_size=64,
n_threads=1), n_estimators=5, random_state=0))])``: five PDL+GRU members that
share the (deterministic) backbone and differ by the seeds of their residual
learners. ``pipe.predict(X, return_std=True)`` gives the member mean and the
member standard deviation (``ddof=1``) per motion row and coordinate (mm).

Scaled spread (``--no-scaling`` skips it): a single factor ``s`` for the
standard deviation, fitted without the test runs. Within the training data,
the first fold of ``SettingGroupKFold(n_splits=4, exclude_settings=["S00"])``
(S05-S07, 9 runs) is held out as validation data, a second ensemble with the
same parameters is fitted on the remaining 30 runs, and ``s`` is the 68.3 %
quantile of the normalised errors ``|y - mu| / sigma`` over the validation
motion rows and coordinates, i.e. the factor that brings the validation
coverage at 1 sigma to the Gaussian 68.3 %. (The maximum-likelihood factor of
a Gaussian, the RMS of the normalised errors, is sensitive to the rows where
the members happen to agree, sigma near 0; the quantile is not.) The test
table then gives the coverage of ``s * sigma`` for the ensemble fitted on all
39 training runs. For comparison, a constant spread fitted the same way (the
68.3 % quantile of ``|y - mu|`` over the validation rows, the same for every
row and coordinate) tells whether the per-row sigma carries information
beyond its level; so does the Spearman rank correlation of ``|y - mu|`` and
sigma over the test motion rows, printed below the tables, with the rank
correlation over the test runs of each run's RMSE and its mean sigma.

Tables (Markdown): the mean per-run RMSE (mm, motion rows, runs weighted
equally) of the PDL backbone, of each single member and of the ensemble
mean; and for the raw, the scaled and the constant spread, the mean sigma
(mm), the median of the normalised error ``|y - mu| / sigma`` (0.674 for a
calibrated Gaussian), and the coverage (fraction of errors within 1 and 2
sigma, per coordinate and in 3-D, runs weighted equally;
``skcath.ensemble.coverage``) next to the Gaussian 68.3 % / 95.4 %.

Usage (from the repository root; about 3 minutes on two CPU cores, one torch
thread, two ensembles of five members)::

    nice -n 10 .venv/bin/python benchmarks/bench_uncertainty.py
"""

import argparse
import json
import sys
import time

import numpy as np
import pandas as pd
import torch
from _machine import machine_lines
from scipy.special import erf
from scipy.stats import norm, spearmanr
from sklearn.pipeline import Pipeline

from skcath import ID_COLUMNS
from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.ensemble import SeedEnsembleRegressor, coverage
from skcath.metrics import mean_per_run_rmse, per_run_rmse
from skcath.model_selection import SettingGroupKFold
from skcath.residuals import GRUResidual

CATHETER, SETTING, RUN = ID_COLUMNS

K = (1.0, 2.0)


def _take(X, y, rows):
    part = X.iloc[rows].reset_index(drop=True)
    for c in part.columns:
        if hasattr(part[c], "cat"):
            part[c] = part[c].cat.remove_unused_categories()
    return part, y[rows]


def _first_fold(X):
    """Train and held-out row positions of the first SettingGroupKFold fold (S00 never held out)."""
    cv = SettingGroupKFold(n_splits=4, exclude_settings=["S00"])
    return next(iter(cv.split(X)))


def _settings(X):
    return sorted(X[SETTING].astype(str).unique())


def _pipeline(args):
    residual = GRUResidual(
        max_epochs=args.epochs, module__hidden_size=args.hidden_size, n_threads=1
    )
    ensemble = SeedEnsembleRegressor(
        residual, n_estimators=args.n_estimators, random_state=args.seed, n_jobs=args.n_jobs
    )
    return Pipeline([("backbone", PDLBackbone()), ("residual", ensemble)])


def _fit(args, X, y, label):
    print(f"fitting {label} ({X[RUN].nunique()} runs) ...", file=sys.stderr, flush=True)
    start = time.perf_counter()
    pipe = _pipeline(args).fit(X, y)
    return pipe, time.perf_counter() - start


def _predict(pipe, X):
    """Member predictions, their mean and std (all rows), and the recordings with the backbone tip."""
    Xb = pipe["backbone"].transform(X)
    members = pipe["residual"].predict_members(Xb)
    return members, members.mean(axis=0), members.std(axis=0, ddof=1), Xb


def _calibration_row(name, y, mean, std, runs):
    z = np.abs(y - mean) / std
    per_coord = coverage(y, mean, std, k=K, runs=runs, multioutput="raw_values")
    return {
        "spread": name,
        "mean_sigma_mm": float(std.mean()),
        "median_abs_z": float(np.nanmedian(z)),
        "coverage_1": [*per_coord[0].tolist(), float(per_coord[0].mean())],
        "coverage_2": [*per_coord[1].tolist(), float(per_coord[1].mean())],
        "coverage_3d": coverage(y, mean, std, k=K, runs=runs, joint=True).tolist(),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n-estimators", type=int, default=5, help="members (default: 5)")
    parser.add_argument("--epochs", type=int, default=6, help="max_epochs per member (default: 6)")
    parser.add_argument("--hidden-size", type=int, default=64, help="GRU hidden size (default: 64)")
    parser.add_argument("--seed", type=int, default=0, help="random_state of the ensemble (default: 0)")
    parser.add_argument("--n-jobs", type=int, default=None,
                        help="members fitted in parallel (default: one at a time)")
    parser.add_argument("--no-scaling", action="store_true",
                        help="skip the validation ensemble and the scaled spread")
    parser.add_argument("--json", metavar="PATH", help="also write the results to this JSON file")
    args = parser.parse_args(argv)
    if args.n_estimators < 2 or args.epochs < 1 or args.hidden_size < 1:
        parser.error("--n-estimators must be >= 2, --epochs and --hidden-size >= 1")
    torch.set_num_threads(1)
    wall = time.perf_counter()

    print("loading the benchmark ...", file=sys.stderr, flush=True)
    data = make_benchmark()
    c1 = np.flatnonzero((data.X[CATHETER] == "C1").to_numpy())
    X_all, y_all = _take(data.X, np.asarray(data.y), c1)
    train_rows, test_rows = _first_fold(X_all)
    X, y = _take(X_all, y_all, train_rows)
    X_test, y_test = _take(X_all, y_all, test_rows)

    pipe, fit_s = _fit(args, X, y, "the ensemble")
    members, mean, std, Xb_test = _predict(pipe, X_test)
    motion = (X_test["phase"] == "motion").to_numpy()
    runs = X_test[RUN].astype(str).to_numpy()[motion]

    nominal = Xb_test[["b_x", "b_y", "b_z"]].to_numpy()
    member_rmse = [mean_per_run_rmse(y_test, m, X_test) for m in members]
    result = {
        "test_settings": _settings(X_test),
        "train_settings": _settings(X),
        "n_train_runs": int(X[RUN].nunique()),
        "n_test_runs": int(X_test[RUN].nunique()),
        "n_test_motion_rows": int(motion.sum()),
        "fit_s": fit_s,
        "rmse_pdl": mean_per_run_rmse(y_test, nominal, X_test),
        "rmse_members": member_rmse,
        "rmse_ensemble": mean_per_run_rmse(y_test, mean, X_test),
    }
    yt, mu, sd = y_test[motion], mean[motion], std[motion]
    rows = [_calibration_row("test: raw", yt, mu, sd, runs)]

    if not args.no_scaling:
        inner_train, valid = _first_fold(X)
        X_in, y_in = _take(X, y, inner_train)
        X_val, y_val = _take(X, y, valid)
        pipe_in, fit_in_s = _fit(args, X_in, y_in, "the validation ensemble")
        _, mean_v, std_v, _ = _predict(pipe_in, X_val)
        mv = (X_val["phase"] == "motion").to_numpy()
        z_v = np.abs(y_val[mv] - mean_v[mv]) / std_v[mv]
        scale = float(np.nanquantile(z_v, erf(1.0 / np.sqrt(2.0))))
        result.update(
            validation_settings=_settings(X_val),
            inner_train_settings=_settings(X_in),
            fit_validation_s=fit_in_s,
            scale=scale,
            validation_raw=_calibration_row(
                "validation: raw", y_val[mv], mean_v[mv], std_v[mv],
                X_val[RUN].astype(str).to_numpy()[mv],
            ),
        )
        rows.append(_calibration_row(f"test: scaled by s = {scale:.2f}", yt, mu, scale * sd, runs))
        # the same calibration with one constant spread for every row and coordinate
        width = float(np.nanquantile(np.abs(y_val[mv] - mean_v[mv]), erf(1.0 / np.sqrt(2.0))))
        result["constant_sigma_mm"] = width
        rows.append(_calibration_row(
            f"test: constant sigma = {width:.2f} mm", yt, mu, np.full_like(sd, width), runs
        ))
    result["spearman"] = [
        float(spearmanr(np.abs(yt[:, j] - mu[:, j]), sd[:, j], nan_policy="omit").statistic) for j in range(3)
    ]
    # per run: does a run with a wider spread have a larger error?
    run_rmse = per_run_rmse(y_test, mean, X_test)
    run_sigma = pd.DataFrame(sd).groupby(runs, sort=False).mean().mean(axis=1)
    result["spearman_runs"] = float(
        spearmanr(run_rmse.loc[run_sigma.index].to_numpy(), run_sigma.to_numpy()).statistic
    )
    result["calibration"] = rows
    result["wall_s"] = time.perf_counter() - wall

    # ------------------------------------------------------------------ report
    for line in machine_lines():
        print(line)
    print(f"torch {torch.__version__}, 1 thread; GRUResidual(max_epochs={args.epochs}, "
          f"module__hidden_size={args.hidden_size}, n_threads=1); "
          f"SeedEnsembleRegressor(n_estimators={args.n_estimators}, random_state={args.seed})")
    print(f"catheter C1; train: {result['n_train_runs']} runs ({', '.join(result['train_settings'])}); "
          f"test: {result['n_test_runs']} runs ({', '.join(result['test_settings'])}), "
          f"{result['n_test_motion_rows']:,} motion rows")
    if not args.no_scaling:
        print(f"scale fitted on validation settings {', '.join(result['validation_settings'])} "
              f"with an ensemble trained on {', '.join(result['inner_train_settings'])}")
    print(f"fit: {fit_s:.0f} s" + ("" if args.no_scaling else f", validation ensemble {result['fit_validation_s']:.0f} s")
          + f"; wall {result['wall_s']:.0f} s")
    print()
    print("| estimate | mean per-run RMSE (mm) |")
    print("|---|---:|")
    print(f"| PDL backbone | {result['rmse_pdl']:.3f} |")
    mr = np.array(member_rmse)
    print(f"| single member: mean (min-max) of {len(mr)} | {mr.mean():.3f} ({mr.min():.3f}-{mr.max():.3f}) |")
    print(f"| ensemble mean | {result['rmse_ensemble']:.3f} |")
    print()
    ref = erf(np.array(K) / np.sqrt(2.0))
    print("| data: spread | mean sigma (mm) | median abs(y - mu) / sigma | "
          "within 1 sigma: x / y / z / mean | 3-D, 1 sigma | "
          "within 2 sigma: x / y / z / mean | 3-D, 2 sigma |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    table = ([result["validation_raw"]] if not args.no_scaling else []) + rows
    for row in table:
        c1_, c2_ = (" / ".join(f"{v:.1%}" for v in row[f"coverage_{k}"]) for k in (1, 2))
        print(f"| {row['spread']} | {row['mean_sigma_mm']:.3f} | {row['median_abs_z']:.2f} | {c1_} | "
              f"{row['coverage_3d'][0]:.1%} | {c2_} | {row['coverage_3d'][1]:.1%} |")
    print(f"| Gaussian reference | | {norm.ppf(0.75):.2f} | {ref[0]:.1%} | {ref[0]:.1%} | {ref[1]:.1%} | {ref[1]:.1%} |")
    print()
    print("Spearman rank correlation of |y - mu| and sigma, test motion rows (x / y / z): "
          + " / ".join(f"{v:.2f}" for v in result["spearman"]))
    print(f"Spearman rank correlation of the run RMSE and the run's mean sigma, "
          f"{result['n_test_runs']} test runs: {result['spearman_runs']:.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
