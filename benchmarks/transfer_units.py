"""How many training catheters a new catheter needs: one catheter held out after pretraining on k units.

The protocol's catheter-held-out model learns from three catheter units, and
three units are three samples of what differs between units. This script
asks whether the gap between a new catheter and a known one is one of
method or one of data: it draws a larger family of the same simulated
catheters (``make_benchmark(n_catheters=1 + max(k))``; units C1-C4 are
those of the default benchmark, run for run), holds one catheter out
(``--held-out``, C1 by default), and pretrains PDL+GRU with the full
schedule (one seed) on the first ``k`` other units (C2 ... C(k+1) for C1;
C1, C3, ... for C2) for each ``k`` of ``--units``. For every ``k`` it reports
the held-out catheter's mean per-run RMSE over the motion rows of its bent
settings:

* ``PDL+GRU (LOCO)``: the pretrained model applied to it as is;
* ``PDL+GRU+adapt (LOCO)``: the sweep-adapted method (the backbone with the
  play identified on each run's own sweep), continuing the PDL+GRU model as
  the full protocol does (``Schedule.adapt_pretrain_params``);
* with ``--within``, both models fine-tuned within the held-out catheter on
  the setting-held-out folds, as ``python -m skcath reproduce`` does (the
  within-catheter errors).

``k = 3`` is the protocol's catheter-held-out model. Nothing is chosen
from these numbers.

Usage (from the repository root)::

    .venv/bin/python benchmarks/transfer_units.py --units 3 7 --n-jobs 2
    .venv/bin/python benchmarks/transfer_units.py --units 3 5 7 11 15 --within --n-jobs 2
"""

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse
from skcath.protocol import (
    ADAPTED_METHOD,
    FULL,
    PROPOSED_METHOD,
    Fold,
    learner_input,
    pretrain_models,
    protocol_folds,
)

sys.path.insert(0, str(Path(__file__).parent))
from _finetuned import within_predictions  # noqa: E402
from _machine import machine_lines  # noqa: E402

def training_folds(X, held_out, test, units):
    """One fold per k: the held-out catheter's test rows, trained on the first k other units (``C1@k``)."""
    catheter = X["catheter"].astype(str)
    others = [c for c in catheter.unique() if c != held_out]
    return {k: Fold(f"{held_out}@{k}", np.flatnonzero(catheter.isin(others[:k]).to_numpy()), test)
            for k in units}, others


def units_label(names):
    """``["C1", "C3", "C4", "C5"]`` -> ``"C1, C3-C5"``: units named ``C<number>``, runs compressed."""
    numbers = [int(name[1:]) for name in names]
    spans = []
    for n in numbers:
        if spans and n == spans[-1][1] + 1:
            spans[-1][1] = n
        else:
            spans.append([n, n])
    return ", ".join(f"C{a}" if a == b else f"C{a}-C{b}" for a, b in spans)


def within_scores(X, y, folds, schedule, variant, model, n_jobs):
    """The held-out catheter's RMSE after fine-tuning ``model`` on each setting-held-out fold."""
    catheter, test = folds.loco[0].catheter, folds.loco[0].test
    pred, timings = within_predictions(X, y, folds, schedule, {(variant, schedule.seeds[0], catheter): model},
                                       variant, n_jobs)
    return mean_per_run_rmse(y[test], pred[test], X.iloc[test]), sum(t["seconds"] for t in timings)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", nargs="+", type=int, default=[3, 7], help="training units k")
    parser.add_argument("--within", action="store_true", help="also fine-tune within the held-out catheter")
    parser.add_argument("--held-out", default="C1", help="catheter held out (C1: the tuning catheter)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-jobs", type=int, default=1)
    parser.add_argument("--output", default=None, help="CSV file for the table")
    parser.add_argument("--check", action="store_true",
                        help="end-to-end check: hidden size 8, one epoch per stage, first repeats only")
    args = parser.parse_args()
    units = sorted(set(args.units))
    if units[0] < 1:
        raise SystemExit(f"--units must be positive; got {units}.")

    start = time.perf_counter()
    data = make_benchmark(n_catheters=1 + units[-1])
    X_data, y = data.X, np.asarray(data.y, dtype=float)
    names = list(X_data["catheter"].astype(str).unique())
    if args.held_out not in names:
        raise SystemExit(f"--held-out must be one of the {len(names)} units drawn for k <= {units[-1]} "
                         f"({names[0]}-{names[-1]}); got {args.held_out!r}.")
    schedule = dataclasses.replace(FULL, name="transfer-units", seeds=(args.seed,))
    if args.check:
        keep = X_data["run"].astype(str).str.endswith("-R1").to_numpy()
        X_data, y = X_data[keep].reset_index(drop=True), y[keep]
        one = {"max_epochs": 1}
        schedule = dataclasses.replace(
            schedule, model_params={**schedule.model_params, "module__hidden_size": 8},
            pretrain_params={**schedule.pretrain_params, **one},
            finetune_params={**schedule.finetune_params, **one},
            adapt_pretrain_params={**schedule.adapt_pretrain_params, **one})
    inputs = {PROPOSED_METHOD: learner_input(X_data, n_jobs=args.n_jobs),
              ADAPTED_METHOD: learner_input(X_data, adapt=True, n_jobs=args.n_jobs)}
    folds = protocol_folds(inputs[PROPOSED_METHOD], schedule, exclude_settings="S00", catheters=[args.held_out])
    test = folds.loco[0].test
    by_k, others = training_folds(inputs[PROPOSED_METHOD], args.held_out, test, units)
    print(f"data and backbones: {time.perf_counter() - start:.0f} s", flush=True)

    rows = {k: {"training units": units_label(others[:k])} for k in units}
    starts = {}
    for variant in (PROPOSED_METHOD, ADAPTED_METHOD):
        X = inputs[variant]
        keys = {k: (variant, args.seed, by_k[k].catheter) for k in units}
        cont = None if variant == PROPOSED_METHOD else {keys[k]: starts[k] for k in units}
        out = pretrain_models(X, y, list(by_k.values()), schedule, variants=(variant,), predict=(variant,),
                              continue_from=cont, n_jobs=args.n_jobs)
        seconds = {t["catheter"]: t["seconds"] for t in out.timings}
        for k in units:
            model = out.models[keys[k]]
            rows[k][f"{variant} (LOCO)"] = mean_per_run_rmse(y[test], out.predictions[keys[k]], X.iloc[test])
            rows[k][f"{variant} pretraining (s)"] = seconds[by_k[k].catheter]
            if variant == PROPOSED_METHOD:
                starts[k] = model
            if args.within:
                rows[k][f"{variant} (within)"], rows[k][f"{variant} fine-tuning (s)"] = within_scores(
                    X, y, folds, schedule, variant, model, args.n_jobs)
            print(f"k={k} {variant}: " + ", ".join(f"{n} {v:.3f}" for n, v in rows[k].items()
                                                   if n.startswith(variant) and isinstance(v, float)),
                  flush=True)

    print("\n".join(machine_lines()))
    print(f"{args.held_out} held out, seed {args.seed}, full schedule; mean per-run RMSE (mm) of the bent settings; "
          f"wall {time.perf_counter() - start:.0f} s")
    table = pd.DataFrame.from_dict(rows, orient="index").rename_axis("k")
    print(table.round(3).to_markdown())
    if args.output:
        table.to_csv(args.output)


if __name__ == "__main__":
    main()
