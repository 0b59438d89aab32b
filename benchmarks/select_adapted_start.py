"""Choose how the full protocol pretrains the sweep-adapted method, on catheter C1.

PDL+GRU+adapt differs from PDL+GRU only by its backbone (the play of each
run identified on its own tracked sweep), so its pretraining can continue
PDL+GRU's pretrained model (same seed, same training catheters C2-C4)
instead of starting from scratch. This script compares, on C1 only and with
one seed, exactly as the protocol trains and fine-tunes:

* ``scratch``: PDL+GRU+adapt pretrained from scratch (the schedule's 30
  epochs at 1e-2);
* ``EPOCHS:LR``: PDL+GRU+adapt continuing PDL+GRU's pretrained model for
  that many epochs at that learning rate (cosine to 0);
* ``control EPOCHS:LR``: PDL+GRU continuing its own pretrained model in the
  same way, on the backbone without the play (is the gain the play's, or
  that of more epochs?).

For each it prints C1's mean per-run RMSE with the catheter held out (the
pretrained model applied to C1) and with the setting held out (fine-tuned
on C1's other settings, as the protocol does), and the seconds of the
pretraining. PDL+GRU's own pretrained model is the first row.

``--sweep-finetune`` adds a trial of the other kind of adaptation:
PDL+GRU's held-out-catheter model fine-tuned on each C1 run's own tracked
sweep (a copy of the sweep rows relabelled as motion, the sweep itself as
the context), then applied to that run's motion. It uses the first repeat
of every bent setting (16 runs).

Usage::

    python benchmarks/select_adapted_start.py --n-jobs 2      # ~15 CPU-min
    python benchmarks/select_adapted_start.py --models models/  # keep/reuse PDL+GRU's model
    python benchmarks/select_adapted_start.py --grid --controls --no-scratch --sweep-finetune

Nothing here looks at C2-C4's test errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.base import clone
from sklearn.frozen import FrozenEstimator

from skcath import persist
from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse
from skcath.protocol import (
    ADAPTED_METHOD,
    FULL,
    PROPOSED_METHOD,
    learner_input,
    pretrain_models,
    protocol_folds,
)

sys.path.insert(0, str(Path(__file__).parent))
from _finetuned import within_predictions  # noqa: E402
from _machine import machine_lines  # noqa: E402

CATHETER = "C1"
DEFAULT_GRID = ("5:3e-3", "10:3e-3", "10:1e-2")
#: Fine-tuning on the run's own sweep: (epochs, learning rate).
SWEEP_FINETUNES = ((5, 1e-3), (5, 3e-3), (20, 1e-3))


def _parse(entry):
    try:
        epochs, lr = entry.split(":")
        return int(epochs), float(lr)
    except ValueError:
        raise SystemExit(f"--grid entries must read EPOCHS:LR (e.g. 5:3e-3); got {entry!r}.") from None


def _scores(X, y, folds, schedule, variant, pretrained, n_jobs):
    """C1's RMSE with the catheter held out and, after fine-tuning, with the setting held out."""
    test = folds.loco[0].test
    model = pretrained[variant, schedule.seeds[0], CATHETER]
    loco = mean_per_run_rmse(y[test], model.predict(X.iloc[test]), X.iloc[test])
    pred, _ = within_predictions(X, y, folds, schedule, pretrained, variant, n_jobs)
    return loco, mean_per_run_rmse(y[test], pred[test], X.iloc[test])


def _plain_model(X, y, folds, schedule, models_dir):
    """PDL+GRU pretrained on the other catheters (loaded from ``models_dir`` if kept there)."""
    path = None if models_dir is None else Path(models_dir) / f"{PROPOSED_METHOD}-seed{schedule.seeds[0]}-{CATHETER}.skcath"
    if path is not None and path.exists():
        # this script's own file, joblib when kept by earlier versions
        return persist.load(path, allow_pickle=True), 0.0
    start = time.perf_counter()
    model = pretrain_models(X, y, folds.loco, schedule, variants=(PROPOSED_METHOD,)).models
    model = model[PROPOSED_METHOD, schedule.seeds[0], CATHETER]
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        persist.save(model, path)
    return model, time.perf_counter() - start


def _continued(X, y, folds, schedule, variant, start_model, epochs, lr):
    """``variant`` pretrained by continuing ``start_model`` (epochs None: from scratch)."""
    key = (variant, schedule.seeds[0], CATHETER)
    if epochs is None:
        return pretrain_models(X, y, folds.loco, schedule, variants=(variant,))
    schedule = dataclasses.replace(schedule, adapt_pretrain_params={"max_epochs": epochs, "lr": lr})
    return pretrain_models(X, y, folds.loco, schedule, variants=(variant,), continue_from={key: start_model})


def _sweep_copy(run_rows, y_run):
    """A run made of ``run_rows``' sweep and a copy of it relabelled as motion, and its targets."""
    sweep = (run_rows["phase"].astype(str) == "sweep").to_numpy()
    first = run_rows[sweep].assign(run="sweep-copy", phase="sweep")
    copy = first.assign(phase="motion", t=first["t"] + first["t"].iloc[-1] + 0.1)
    return pd.concat([first, copy], ignore_index=True), np.concatenate([y_run[sweep], y_run[sweep]])


def sweep_finetune(X, y, model, seed):
    """Per C1 run (first repeats): motion RMSE before and after fine-tuning on its own sweep."""
    rows = []
    runs = [r for r in X["run"].astype(str).unique() if r.endswith("-R1")]
    for run in runs:
        idx = np.flatnonzero((X["run"].astype(str) == run).to_numpy())
        R, y_run = X.iloc[idx], y[idx]
        motion = (R["phase"].astype(str) == "motion").to_numpy()
        row = {"run": run, "unadapted": mean_per_run_rmse(y_run, model.predict(R), R)}
        X_fit, y_fit = _sweep_copy(R, y_run)
        for epochs, lr in SWEEP_FINETUNES:
            tuned = clone(model).set_params(pretrained=FrozenEstimator(model), max_epochs=epochs, lr=lr,
                                            batch_size=32, random_state=seed).fit(X_fit, y_fit)
            row[f"{epochs} epochs, lr {lr:g}"] = mean_per_run_rmse(y_run[motion], tuned.predict(R)[motion],
                                                                    R[motion])
        rows.append(row)
    return pd.DataFrame(rows).set_index("run")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", nargs="*", default=list(DEFAULT_GRID), help="EPOCHS:LR entries")
    parser.add_argument("--controls", nargs="*", default=["5:3e-3"],
                        help="EPOCHS:LR entries of the control (PDL+GRU continuing itself)")
    parser.add_argument("--no-scratch", action="store_true", help="skip the from-scratch row")
    parser.add_argument("--sweep-finetune", action="store_true", help="add the sweep fine-tuning trial")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-jobs", type=int, default=1, help="fine-tuned folds in parallel")
    parser.add_argument("--models", default=None, help="folder to keep PDL+GRU's pretrained model in")
    args = parser.parse_args()
    grid, controls = [_parse(e) for e in args.grid], [_parse(e) for e in args.controls]

    data = make_benchmark()
    schedule = dataclasses.replace(FULL, name="adapted-start", seeds=(args.seed,))
    inputs = {PROPOSED_METHOD: learner_input(data.X, n_jobs=args.n_jobs),
              ADAPTED_METHOD: learner_input(data.X, adapt=True, n_jobs=args.n_jobs)}
    folds = protocol_folds(inputs[PROPOSED_METHOD], schedule, exclude_settings="S00", catheters=[CATHETER])
    y = data.y
    plain, seconds = _plain_model(inputs[PROPOSED_METHOD], y, folds, schedule, args.models)
    key = (PROPOSED_METHOD, args.seed, CATHETER)
    rows = {f"{PROPOSED_METHOD} (30 epochs from scratch)":
            (*_scores(inputs[PROPOSED_METHOD], y, folds, schedule, PROPOSED_METHOD, {key: plain}, args.n_jobs),
             seconds)}
    runs = [(ADAPTED_METHOD, None, None)] * (not args.no_scratch)
    runs += [(ADAPTED_METHOD, e, lr) for e, lr in grid] + [(PROPOSED_METHOD, e, lr) for e, lr in controls]
    for variant, epochs, lr in runs:
        start = time.perf_counter()
        pre = _continued(inputs[variant], y, folds, schedule, variant, plain, epochs, lr)
        seconds = time.perf_counter() - start
        label = (f"{variant} (30 epochs from scratch)" if epochs is None
                 else f"{variant} continuing {PROPOSED_METHOD}, {epochs} epochs at {lr:g}")
        rows[label] = (*_scores(inputs[variant], y, folds, schedule, variant, pre.models, args.n_jobs), seconds)
        print(f"{label}: catheter held out {rows[label][0]:.3f}, setting held out {rows[label][1]:.3f} mm",
              flush=True)

    print("\n".join(machine_lines()))
    print(f"{CATHETER}, seed {args.seed}, full schedule; mean per-run RMSE (mm) of the bent settings")
    table = pd.DataFrame(rows, index=["catheter held out", "setting held out", "pretraining (s)"]).T
    print(table.round(3).to_string())
    if args.sweep_finetune:
        frame = inputs[PROPOSED_METHOD]
        keep = (frame["catheter"].astype(str) == CATHETER).to_numpy() & (frame["setting"].astype(str) != "S00").to_numpy()
        trial = sweep_finetune(inputs[PROPOSED_METHOD][keep], np.asarray(y)[keep], plain, args.seed)
        print(f"\n{PROPOSED_METHOD} (catheter held out) fine-tuned on each run's own tracked sweep, "
              f"{CATHETER} first repeats: motion RMSE (mm)")
        print(trial.round(2).to_string())
        print("mean:\n" + trial.mean().round(3).to_string())


if __name__ == "__main__":
    main()
