"""Choose the full protocol's training schedule on catheter C1.

The full protocol (``python -m skcath reproduce``) pretrains every learned
method on the other catheters and fine-tunes it once per held-out setting,
so its cost is ``pretrain epochs x (4 catheters)`` plus ``fine-tune epochs x
(64 folds)`` per method and seed. This script compares schedules on C1 only,
for one learned method (PDL+GRU by default) with one seed, exactly as the
protocol trains it:

1. pretrain on C2-C4 for ``E_p`` epochs (learning rate 1e-2, cosine);
   applied to C1 as is, this model gives the catheter-held-out (LOCO) error;
2. for each of C1's 16 bent settings, fine-tune that model on C1's other
   settings (S00 included) for ``E_f`` epochs and predict the held-out runs
   (:class:`~skcath.model_selection.LeaveOneSettingOut`).

It prints, per schedule, C1's mean per-run RMSE with setting held out and
with the catheter held out, their ratios to PDL and to each other, and the
measured seconds per pretraining and per fine-tuned fold (one torch thread).
One pretrained model serves every fine-tuning schedule with the same
pretraining epochs.

Usage::

    python benchmarks/select_schedule.py                       # the default grid (~6 CPU-min)
    python benchmarks/select_schedule.py --grid 30:2:3e-3 20:8:3e-3 --n-jobs 2
    python benchmarks/select_schedule.py --grid 30:2:3e-3:64 30:2:3e-3:32 \
        --sweep-stride-s 2.0 --sweep-pooling subsample       # the earlier context input
    python benchmarks/select_schedule.py --method "PDL+GRU (no context)"

Each grid entry is ``PRETRAIN_EPOCHS:FINETUNE_EPOCHS:FINETUNE_LR`` with an
optional ``:FINETUNE_BATCH_SIZE`` (default 64; pretraining always uses 64).
``--sweep-stride-s`` (s) and ``--sweep-pooling`` set how the sweep is shortened
for the context encoder in both stages; ``--method`` the learned method
(:data:`skcath.protocol.VARIANTS`: its learner and inputs);
``--param KEY=VALUE`` (repeatable) sets any other learner parameter in both
stages (``--param module__hidden_size=64``), and ``--pretrain-batch-size``
the pretraining's batch size. Nothing here looks at C2-C4's test errors.
"""

from __future__ import annotations

import argparse
import ast
import sys
import time
from collections import defaultdict

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.frozen import FrozenEstimator

from skcath.backbones import BACKBONE_COLUMNS
from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse
from skcath.model_selection import LeaveOneSettingOut
from skcath.protocol import PROPOSED_METHOD, VARIANTS, learner_input, make_learner

#: The schedules compared by default (pretrain epochs, fine-tune epochs, fine-tune lr).
DEFAULT_GRID = (
    "30:2:3e-3", "30:2:3e-3:32", "30:4:3e-3",
)


def _parse(entry):
    try:
        parts = entry.split(":")
        if len(parts) not in (3, 4):
            raise ValueError
        batch = int(parts[3]) if len(parts) == 4 else 64
        return int(parts[0]), int(parts[1]), float(parts[2]), batch
    except ValueError:
        raise SystemExit(
            f"--grid entries must read PRETRAIN_EPOCHS:FINETUNE_EPOCHS:FINETUNE_LR[:BATCH_SIZE] "
            f"(e.g. 30:2:3e-3 or 30:2:3e-3:32); got {entry!r}."
        ) from None


#: Learner parameters that the schedule itself sets.
_SCHEDULE_KEYS = {"max_epochs", "lr", "batch_size", "pretrained", "random_state", "n_threads"}

#: Learner inputs that the method sets (--method).
_METHOD_KEYS = {"use_torque", "use_context"}


def _param(entry):
    key, sep, value = entry.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--param must read KEY=VALUE; got {entry!r}.")
    if key in _SCHEDULE_KEYS:
        raise argparse.ArgumentTypeError(
            f"--param {key} is set by the schedule (--grid, --pretrain-batch-size, "
            "--seed); give another parameter."
        )
    if key in _METHOD_KEYS:
        raise argparse.ArgumentTypeError(
            f"--param {key} is set by the method; choose it with --method among {list(VARIANTS)}."
        )
    try:
        return key, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return key, value  # a plain string such as frame=base


def _learner(method, seed, context, **params):
    return make_learner(method, random_state=seed, n_threads=1, **context, **params)


def _pretrain(method, epochs, seed, context, batch, X, y):
    start = time.perf_counter()
    model = _learner(method, seed, context, max_epochs=epochs, lr=1e-2, batch_size=batch).fit(X, y)
    return epochs, model, time.perf_counter() - start


def _finetune(method, key, pretrained, seed, context, X_train, y_train, X_test, test):
    _, epochs, lr, batch = key
    start = time.perf_counter()
    model = _learner(method, seed, context, max_epochs=epochs, lr=lr, batch_size=batch,
                     pretrained=FrozenEstimator(pretrained))
    pred = model.fit(X_train, y_train).predict(X_test)
    return key, test, pred, time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", nargs="+", default=list(DEFAULT_GRID),
                        help="schedules PRETRAIN:FINETUNE:LR (default: %(default)s)")
    parser.add_argument("--catheter", default="C1", help="catheter evaluated (default: C1)")
    parser.add_argument("--method", choices=list(VARIANTS), default=PROPOSED_METHOD,
                        metavar="NAME",
                        help=f"learned method, among {list(VARIANTS)} (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random_state (default: 0)")
    parser.add_argument("--n-jobs", type=int, default=1, help="models trained in parallel")
    parser.add_argument("--sweep-stride-s", type=float, default=4.0,
                        help="sweep seconds per context-encoder step (default: 4.0)")
    parser.add_argument("--sweep-pooling", choices=("mean", "subsample"), default="mean",
                        help="how a block of the sweep becomes one step (default: mean)")
    parser.add_argument("--param", type=_param, action="append", default=[],
                        metavar="KEY=VALUE", help="another learner parameter, both stages")
    parser.add_argument("--pretrain-batch-size", type=int, default=64,
                        help="batch size of the pretraining (default: 64)")
    args = parser.parse_args(argv)
    grid = [_parse(entry) for entry in args.grid]
    context = {"sweep_stride_s": args.sweep_stride_s, "sweep_pooling": args.sweep_pooling,
               **dict(args.param)}

    data = make_benchmark()
    X, y = data.X.reset_index(drop=True), np.asarray(data.y)
    if args.catheter not in set(X["catheter"].astype(str)):
        raise SystemExit(f"--catheter {args.catheter!r} is not in the benchmark.")
    Xb = learner_input(X, n_jobs=args.n_jobs)
    held = (X["catheter"].astype(str) == args.catheter).to_numpy()
    X_other, y_other = Xb[~held], y[~held]
    Xc, yc = Xb[held].reset_index(drop=True), y[held]
    folds = list(LeaveOneSettingOut(exclude_settings=["S00"]).split(Xc))

    parallel = Parallel(n_jobs=args.n_jobs, max_nbytes=None)
    pre_epochs = sorted({pre for pre, *_ in grid})
    print(f"pretraining {len(pre_epochs)} models on the other catheters ...", file=sys.stderr)
    pretrained = {
        epochs: (model, seconds)
        for epochs, model, seconds in parallel(
            delayed(_pretrain)(args.method, epochs, args.seed, context, args.pretrain_batch_size,
                               X_other, y_other) for epochs in pre_epochs
        )
    }
    print(f"fine-tuning {len(grid)} x {len(folds)} models ...", file=sys.stderr)
    tasks = (
        delayed(_finetune)(args.method, key, pretrained[key[0]][0], args.seed, context,
                           Xc.iloc[train], yc[train], Xc.iloc[test], test)
        for key in grid for train, test in folds
    )
    predictions = defaultdict(lambda: np.full_like(yc, np.nan))
    seconds = defaultdict(list)
    for key, test, pred, took in parallel(tasks):
        predictions[key][test] = pred
        seconds[key].append(took)

    evaluated = np.zeros(len(Xc), dtype=bool)
    for _, test in folds:
        evaluated[test] = True
    Xe, ye = Xc[evaluated], yc[evaluated]
    pdl = mean_per_run_rmse(ye, Xe[list(BACKBONE_COLUMNS)].to_numpy(), Xe)
    loco = {epochs: mean_per_run_rmse(ye, model.predict(Xe), Xe)
            for epochs, (model, _) in pretrained.items()}
    rows = []
    for key in grid:
        pre, fine, lr, batch = key
        within = mean_per_run_rmse(ye, predictions[key][evaluated], Xe)
        rows.append({
            "pretrain epochs": pre, "fine-tune epochs": fine, "fine-tune lr": lr,
            "fine-tune batch": batch,
            "setting held out (mm)": within, "ratio to PDL": within / pdl,
            "catheter held out (mm)": loco[pre], "LOCO / setting held out": loco[pre] / within,
            "pretrain (s)": pretrained[pre][1],
            "fine-tune fold (s, median)": float(np.median(seconds[key])),
        })
    table = pd.DataFrame(rows)
    print(f"catheter {args.catheter}, {args.method}, seed {args.seed}, pretraining batch "
          f"{args.pretrain_batch_size}, learner {context}; PDL {pdl:.3f} mm")
    print(table.to_markdown(index=False, floatfmt=".3f"))
    return table


if __name__ == "__main__":
    main()
