"""Residual learners under setting-held-out cross-validation within a catheter.

For each catheter, every bent shaft setting is held out in turn with all its
repeats (``LeaveOneGroupOut`` over settings, 16 folds); the pipeline
``backbone -> residual`` is fitted on the other 15 settings and scored by the
mean per-run RMSE (mm) of the held-out runs' motion rows. The held-out runs
give only their sweeps, to calibrate the backbone and encode the context.
Variants: PDL alone, PDL+GRU, PDL+GRU without sweep context, PDL+MLP.

This is plain scikit-learn: ``cross_validate(Pipeline, X, y, groups=setting,
cv=LeaveOneGroupOut(), scoring=run_rmse_scorer)``; folds run in parallel with
``--n-jobs`` (each fold uses one torch thread).

Usage::

    python benchmarks/eval_residuals.py                    # catheter C1, one seed
    python benchmarks/eval_residuals.py --catheters C1 C2 C3 C4
    python benchmarks/eval_residuals.py --max-epochs 5     # quick check
    python benchmarks/eval_residuals.py --frame base       # residual in the base-sensor frame
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.model_selection import LeaveOneGroupOut, cross_validate
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.frames import FRAMES
from skcath.metrics import run_rmse_scorer
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_lines  # noqa: E402

PAPER_C1 = {"PDL": 6.9, "PDL+GRU": 3.6, "PDL+GRU (no context)": 3.6, "PDL+MLP": None}


def variants(seed, max_epochs, frame=None):
    """Residual step of every variant (one torch thread each: folds run in parallel)."""
    extra = {} if max_epochs is None else {"max_epochs": max_epochs}
    if frame is not None:
        extra["frame"] = frame
    common = {"random_state": seed, "n_threads": 1, **extra}
    return {
        "PDL": NoResidual(),
        "PDL+GRU": GRUResidual(**common),
        "PDL+GRU (no context)": GRUResidual(use_context=False, **common),
        "PDL+MLP": MLPResidual(**common),
    }


def evaluate(X, y, residual, n_jobs):
    """Per-fold held-out scores of ``PDL -> residual``, folds = settings."""
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", residual)])
    groups = X["setting"].astype(str).to_numpy()
    out = cross_validate(
        pipe, X, y, groups=groups, cv=LeaveOneGroupOut(), scoring=run_rmse_scorer,
        n_jobs=n_jobs, return_indices=True,
    )
    held_out = [groups[idx[0]] for idx in out["indices"]["test"]]
    return pd.Series(-out["test_score"], index=held_out), out["fit_time"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catheters", nargs="+", default=["C1"])
    parser.add_argument("--variants", nargs="+", default=None,
                        help="subset of: PDL, 'PDL+GRU', 'PDL+GRU (no context)', 'PDL+MLP'")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-epochs", type=int, default=None,
                        help="override the learners' max_epochs (default: their default)")
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--frame", choices=FRAMES, default=None,
                        help="the learners' frame parameter (default: their default, sweep)")
    args = parser.parse_args()

    data = make_benchmark()
    names = args.variants or list(variants(args.seed, args.max_epochs, args.frame))
    rows, folds = {}, []
    for catheter in args.catheters:
        keep = ((data.X["catheter"] == catheter) & (data.X["setting"] != "S00")).to_numpy()
        X = data.X[keep].reset_index(drop=True)
        y = np.asarray(data.y)[keep]
        for name in names:
            residual = variants(args.seed, args.max_epochs, args.frame)[name]
            start = time.perf_counter()
            scores, fit_times = evaluate(X, y, residual, args.n_jobs)
            wall = time.perf_counter() - start
            rows[(catheter, name)] = {
                "RMSE (mm)": scores.mean(),
                "fold fit (s, median)": float(np.median(fit_times)),
                "wall (s)": wall,
            }
            folds.append(scores.rename(f"{catheter} {name}"))
            print(f"{catheter} {name}: {scores.mean():.2f} mm ({wall:.0f} s)", flush=True)
    table = pd.DataFrame(rows).T
    for catheter in args.catheters:
        if (catheter, "PDL") in table.index:
            base = table.loc[(catheter, "PDL"), "RMSE (mm)"]
            for name in names:
                table.loc[(catheter, name), "ratio to PDL"] = table.loc[(catheter, name), "RMSE (mm)"] / base
    print("\n".join(machine_lines()))
    print(f"setting-held-out CV (16 folds per catheter), seed {args.seed}, "
          f"max_epochs={args.max_epochs or 'default'}, n_jobs={args.n_jobs}")
    print(table.round(3).to_string())
    print("\nper-fold RMSE (mm):")
    print(pd.concat(folds, axis=1).round(2).to_string())


if __name__ == "__main__":
    main()
