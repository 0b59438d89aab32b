"""Transfer to a new catheter: the residual pretrained on 1, 2 or 3 other catheters, with and without sweep adaptation.

Every catheter of the benchmark is held out in turn and the residual learner
is pretrained on ``k`` = 1, 2 and 3 of the other catheters, then applied as
is to the held-out catheter's runs: the catheter-held-out (LOCO) error when
a new catheter brings nothing but its own calibration sweep. Each model is
trained twice: on the nominal tip of the paper's PDL backbone
(``PDL+GRU (LOCO)``) and on that of the sweep-adapted backbone, the PDL
backbone whose motor angles pass through a play with the half-width
identified on the run's own tracked sweep (``PDL+GRU+adapt (LOCO)``,
``docs/backbones.rst``, "Hysteresis identified on the sweep").

For each benchmark (``--spreads``: the default ``make_benchmark()`` and the
wide unit spread of simulator version 5, ``make_benchmark(unit_spread=1.0)``,
both from the cache when they are there):

1. **Backbones.** PDL is calibrated on every run's own sweep
   (``skcath.protocol.learner_input``); the adapted PDL
   (``PDLBackbone(**ADAPTED_BACKBONE)``) too, with ``calibrate``, whose
   nominal tip is the adapted learners' input (the same as
   ``learner_input(X, adapt=True)``, which ``--quick-check`` verifies) and
   whose ``play_width_deg`` gives the table of identified play widths.
2. **Pretraining on k catheters** (``pretrain_models``). With ``--subsets
   all`` (the default) every set of ``k`` other catheters is trained on (3,
   3 and 1 sets per held-out catheter for ``k`` = 1, 2, 3) and each run's
   error is averaged over the sets; the table is printed a second time with
   the cyclic sets alone, the ``k`` catheters that follow the held-out one
   in cyclic order (C1 -> C2, C2+C3, C2+C3+C4; C4 -> C1, C1+C2, C1+C2+C3),
   which ``--subsets cyclic`` trains alone (half the pretraining).
   ``k = 3`` is the protocol's leave-one-catheter-out model. The training
   set is every row of the training catheters (the straight setting S00
   included, as in the protocol).
3. **Within the catheter** (``finetune_models``). The ``k = 3`` models are
   fine-tuned within the held-out catheter on the setting-held-out folds of
   the schedule, as ``run_protocol`` does: the within-catheter references
   ``PDL+GRU`` and ``PDL+GRU+adapt``.
4. **Scores.** Mean per-run RMSE (mm) over the motion rows of the bent
   settings (S00 is never scored), for C1 (``--tuning-catheter``, the
   catheter on which defaults are chosen), C2-C4 pooled and all four; and per
   cell the ratio ``PDL+GRU+adapt (LOCO)`` / ``PDL+GRU`` within the catheter
   (goal: at most 1.3, ``--goal``).

Schedule: ``QUICK`` (hidden size 64, windows every 200 steps, 4 pretraining
epochs at learning rate 1e-2, 3 fine-tuning epochs at 3e-3, four groups of
settings per catheter) with one seed (``--seed``), restricted to the two
learned methods. ``--quick-check`` runs everything end to end on a small
part of the data (the first run of S00-S04 of every catheter, hidden size
8, one epoch per stage) and checks the adapted input against
``learner_input``: a few minutes per benchmark.

The wall time of every part is printed as it ends, and the tables in
Markdown; ``--output-dir`` receives ``transfer.csv`` (the table),
``transfer_runs.csv`` (per-run RMSE of every model), ``transfer_cyclic.csv``
(the table from the cyclic sets, with ``--subsets all``),
``play_widths.csv`` and ``timings.csv``.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_transfer.py --quick-check
    nice -n 10 .venv/bin/python benchmarks/bench_transfer.py
"""

import argparse
import dataclasses
import itertools
import time
from pathlib import Path

import numpy as np
import pandas as pd
from _finetuned import within_predictions
from _machine import machine_lines

from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone
from skcath.datasets import SIMULATOR_VERSION, make_benchmark
from skcath.metrics import per_run_rmse
from skcath.protocol import (
    ADAPTED_BACKBONE,
    LEARNER_COLUMNS,
    QUICK,
    Fold,
    learner_input,
    pretrain_models,
    protocol_folds,
)

#: The setting never scored (kept for training), as in ``python -m skcath reproduce``.
STRAIGHT = "S00"

#: Learned method -> (its catheter-held-out name, the backbone method whose nominal tip it corrects).
LEARNED = {
    "PDL+GRU": ("PDL+GRU (LOCO)", "PDL"),
    "PDL+GRU+adapt": ("PDL+GRU+adapt (LOCO)", "PDL+adapt"),
}

#: Unit parameters of the simulator's play printed beside the identified widths.
PLAY_PARAMETERS = ("play_w0", "play_growth_base", "play_growth_scale", "mu")


class Clock:
    """Wall time of the parts of the benchmark, printed as each part ends."""

    def __init__(self):
        self.rows = []

    def part(self, benchmark, name, start, model_s=np.nan):
        seconds = time.perf_counter() - start
        self.rows.append({"benchmark": benchmark, "part": name, "wall_s": seconds, "model_s": model_s})
        extra = "" if np.isnan(model_s) else f" ({model_s:.0f} s of model training)"
        print(f"[{benchmark}] {name}: {seconds:.1f} s{extra}", flush=True)


def load(spread, quick_check):
    """Recordings, measured tips and unit parameters of one benchmark (a small part with ``quick_check``)."""
    data = make_benchmark() if spread is None else make_benchmark(unit_spread=spread)
    X, y = data.X, data.y
    if quick_check:
        keep = (X["setting"].astype(str) <= "S04") & X["run"].astype(str).str.endswith("-R1")
        X = X[keep.to_numpy()].reset_index(drop=True)
        for column in ("catheter", "setting", "run"):
            X[column] = X[column].cat.remove_unused_categories()
        y = y[keep.to_numpy()]
    units = pd.DataFrame(data.catheters).T[list(PLAY_PARAMETERS)].astype(float)
    return X, np.asarray(y, dtype=float), units


def adapted_input(X, n_jobs):
    """Input of the adapted learners and every run's identified play half-width (deg)."""
    calibration = PDLBackbone(**ADAPTED_BACKBONE, n_jobs=n_jobs).fit(X).calibrate(X)
    X_learner = X.assign(**dict(zip(BACKBONE_COLUMNS, calibration.nominal.T)))
    return X_learner[list(LEARNER_COLUMNS)], calibration.table["play_width_deg"]


def training_sets(catheters, k, subsets):
    """Groups of (held-out catheter, training catheters); each group trains every catheter once."""
    n = len(catheters)
    if subsets == "cyclic":
        return [[(c, tuple(sorted(catheters[(i + j) % n] for j in range(1, k + 1))))
                 for i, c in enumerate(catheters)]]
    combos = [list(itertools.combinations([o for o in catheters if o != c], k)) for c in catheters]
    return [[(c, combos[i][j]) for i, c in enumerate(catheters)] for j in range(len(combos[0]))]


def run_scores(y, pred, X, rows, **labels):
    """Per-run RMSE over motion rows of ``rows`` (one record per run, with ``labels``)."""
    X_rows = X.iloc[rows]
    rmse = per_run_rmse(y[rows], pred[rows], X_rows)
    catheter = X_rows.drop_duplicates("run").set_index("run")["catheter"].astype(str)
    if rmse.isna().any():
        raise RuntimeError(f"{labels}: some scored runs have no finite error.")
    return [{**labels, "run": str(run), "catheter": catheter[run], "rmse_mm": value}
            for run, value in rmse.items()]


def pretrain_on_subsets(inputs, y, X, folds, schedule, args, name, clock):
    """Catheter-held-out scores for k = 1, 2, 3 training catheters, and the k = 3 models."""
    catheters = [fold.catheter for fold in folds.loco]
    test = {fold.catheter: fold.test for fold in folds.loco}
    catheter_of = X["catheter"].astype(str)
    records, models = [], {}
    for k in range(1, len(catheters)):
        start, model_s = time.perf_counter(), 0.0
        for group in training_sets(catheters, k, args.subsets):
            # rows in the order of X: with k = 3, the protocol's catheter-held-out training set
            train = [Fold(c, np.flatnonzero(catheter_of.isin(others).to_numpy()), test[c])
                     for c, others in group]
            for variant, (loco_name, backbone) in LEARNED.items():
                out = pretrain_models(inputs[backbone], y, train, schedule, variants=[variant],
                                      predict=[variant], n_jobs=args.n_jobs)
                model_s += sum(t["seconds"] for t in out.timings)
                pred = np.full((len(X), 3), np.nan)
                for (_, _, c), values in out.predictions.items():
                    pred[test[c]] = values
                for c, others in group:
                    records += run_scores(y, pred, X, test[c], benchmark=name, method=loco_name, k=k,
                                          training="+".join(others))
                if k == len(catheters) - 1:
                    models[variant] = out.models
        clock.part(name, f"pretraining on {k} catheter(s)", start, model_s)
    return records, models


def finetune_within(inputs, y, X, folds, schedule, models, args, name, clock):
    """Within-catheter scores of the learned methods fine-tuned from the k = 3 models."""
    start, model_s, records = time.perf_counter(), 0.0, []
    k = len(folds.loco) - 1
    for variant, (_, backbone) in LEARNED.items():
        pred, timings = within_predictions(inputs[backbone], y, folds, schedule, models[variant], variant,
                                           args.n_jobs)
        model_s += sum(t["seconds"] for t in timings)
        for fold in folds.loco:
            records += run_scores(y, pred, X, fold.test, benchmark=name, method=variant, k=k,
                                  training="within")
    clock.part(name, "fine-tuning within the catheter", start, model_s)
    return records


def play_table(widths, X, units, name):
    """Identified half-widths per catheter (bent settings) beside the unit's play parameters."""
    runs = X.drop_duplicates("run").set_index("run")
    bent = runs.index[(runs["setting"].astype(str) != STRAIGHT).to_numpy()].astype(str)
    w = pd.DataFrame({"width": widths.reindex(bent), "catheter": runs.loc[bent, "catheter"].astype(str)})
    stats = w.groupby("catheter")["width"].agg(["count", "mean", "std", "min", "max"])
    stats.columns = ["runs", "width_mean_deg", "width_sd_deg", "width_min_deg", "width_max_deg"]
    table = stats.join(units).reset_index()
    table.insert(0, "benchmark", name)
    return table


def one_benchmark(spread, args, clock):
    """Every score, the play widths of one benchmark."""
    name = "default" if spread is None else f"unit_spread={spread:g}"
    start = time.perf_counter()
    X, y, units = load(spread, args.quick_check)
    clock.part(name, f"loading ({X['run'].nunique()} runs)", start)
    start = time.perf_counter()
    inputs = {"PDL": learner_input(X, n_jobs=args.n_jobs)}
    clock.part(name, "calibrating PDL", start)
    start = time.perf_counter()
    inputs["PDL+adapt"], widths = adapted_input(X, args.n_jobs)
    clock.part(name, "calibrating PDL+adapt (play identified on each sweep)", start)
    if args.quick_check:
        expected = learner_input(X, adapt=True, n_jobs=args.n_jobs)
        pd.testing.assert_frame_equal(inputs["PDL+adapt"], expected)
        print(f"[{name}] the adapted input equals learner_input(X, adapt=True)")
    folds = protocol_folds(X, args.schedule, exclude_settings=STRAIGHT)
    records = []
    for backbone, X_learner in inputs.items():
        pred = X_learner[list(BACKBONE_COLUMNS)].to_numpy()
        for fold in folds.loco:
            records += run_scores(y, pred, X, fold.test, benchmark=name, method=backbone, k=0,
                                  training="none")
    loco, models = pretrain_on_subsets(inputs, y, X, folds, args.schedule, args, name, clock)
    within = finetune_within(inputs, y, X, folds, args.schedule, models, args, name, clock)
    return pd.DataFrame(records + loco + within), play_table(widths, X, units, name)


def table_rows(n_catheters):
    """Rows of the table: (label, method, number of training catheters; 0 for a backbone)."""
    k_max = n_catheters - 1
    rows = [("PDL", "PDL", 0), ("PDL+adapt", "PDL+adapt", 0),
            (f"PDL+GRU, within (from {k_max})", "PDL+GRU", k_max),
            (f"PDL+GRU+adapt, within (from {k_max})", "PDL+GRU+adapt", k_max)]
    for method in ("PDL+GRU (LOCO)", "PDL+GRU+adapt (LOCO)"):
        rows += [(f"{method}, k={k}", method, k) for k in range(1, n_catheters)]
    return rows


def cyclic_only(runs):
    """The records of the backbones, the within references and the cyclic training sets only."""
    catheters = sorted(runs["catheter"].unique())
    cyclic = {
        (c, k, "+".join(others))
        for k in range(1, len(catheters))
        for c, others in training_sets(catheters, k, "cyclic")[0]
    }
    keys = zip(runs["catheter"], runs["k"], runs["training"])
    keep = [training in ("none", "within") or key in cyclic
            for key, training in zip(keys, runs["training"])]
    return runs[np.asarray(keep)]


def summarise(runs, tuning):
    """The table: mean per-run RMSE (mm) for the tuning catheter, the others pooled and all, and the ratios.

    A run scored by several models of one method and ``k`` (every set of
    ``k`` training catheters) counts once, with the mean of its errors.
    """
    per_run = runs.groupby(["benchmark", "method", "k", "run", "catheter"], sort=False)["rmse_mm"].mean()
    per_run = per_run.reset_index()
    groups = {tuning: per_run["catheter"] == tuning, "others": per_run["catheter"] != tuning,
              "all": per_run["catheter"].notna()}
    others = sorted(set(per_run["catheter"]) - {tuning})
    names = {tuning: tuning, "others": f"{others[0]}-{others[-1]}" if others else "others", "all": "all"}
    n_catheters = per_run["catheter"].nunique()
    table = {}
    for label, method, k in table_rows(n_catheters):
        row = {}
        for bench in pd.unique(per_run["benchmark"]):
            sel = (per_run["benchmark"] == bench) & (per_run["method"] == method) & (per_run["k"] == k)
            for group, mask in groups.items():
                row[f"{bench}: {names[group]}"] = per_run.loc[sel & mask, "rmse_mm"].mean()
        table[label] = row
    table = pd.DataFrame(table).T
    within = table.loc[f"PDL+GRU, within (from {n_catheters - 1})"]
    for k in range(1, n_catheters):
        table.loc[f"ratio adapt (LOCO), k={k} / PDL+GRU within"] = (
            table.loc[f"PDL+GRU+adapt (LOCO), k={k}"] / within
        )
    for k in range(1, n_catheters):
        table.loc[f"ratio PDL+GRU (LOCO), k={k} / PDL+GRU within"] = (
            table.loc[f"PDL+GRU (LOCO), k={k}"] / within
        )
    return table


def report_goal(table, goal):
    """Print how many cells of the ratio adapt (LOCO) / PDL+GRU within exceed ``goal``, and the largest."""
    ratios = table.loc[[r for r in table.index if r.startswith("ratio adapt")]]
    print(f"\ncells with ratio adapt (LOCO) / PDL+GRU within above {goal}: "
          f"{int((ratios > goal).to_numpy().sum())} of {ratios.size}; largest {ratios.to_numpy().max():.2f}")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spreads", nargs="+", default=["default", "1.0"],
                        help="benchmarks by unit spread: 'default' or a number in [0, 1] "
                             "(default: default 1.0)")
    parser.add_argument("--subsets", choices=("cyclic", "all"), default="all",
                        help="training catheters with k < 3: the k that follow the held-out one "
                             "in cyclic order, or every set of k (default: all)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the learned models (default: 0)")
    parser.add_argument("--n-jobs", type=int, default=2,
                        help="models trained in parallel, runs calibrated in parallel (default: 2)")
    parser.add_argument("--tuning-catheter", default="C1",
                        help="catheter reported apart, on which defaults are chosen (default: C1)")
    parser.add_argument("--goal", type=float, default=1.3,
                        help="goal of the ratio adapt (LOCO) / PDL+GRU within (default: 1.3)")
    parser.add_argument("--quick-check", action="store_true",
                        help="end-to-end check: run R1 of S00-S04, hidden size 8, one epoch per stage")
    parser.add_argument("--output-dir", type=Path, default=Path("skcath_results/transfer"),
                        help="folder of the CSV files (default: skcath_results/transfer)")
    args = parser.parse_args(argv)
    schedule = dataclasses.replace(QUICK, seeds=(args.seed,), variants=tuple(LEARNED))
    if args.quick_check:
        schedule = dataclasses.replace(
            schedule,
            model_params={**schedule.model_params, "module__hidden_size": 8},
            pretrain_params={**schedule.pretrain_params, "max_epochs": 1},
            finetune_params={**schedule.finetune_params, "max_epochs": 1},
        )
    args.schedule = schedule
    args.spreads = [None if s == "default" else float(s) for s in args.spreads]
    return args


def main(argv=None):
    args = parse_args(argv)
    print("\n".join(machine_lines()))
    print(f"simulator version {SIMULATOR_VERSION}; schedule {args.schedule}")
    clock, runs, widths = Clock(), [], []
    start = time.perf_counter()
    for spread in args.spreads:
        scores, play = one_benchmark(spread, args, clock)
        runs.append(scores)
        widths.append(play)
    runs, widths = pd.concat(runs, ignore_index=True), pd.concat(widths, ignore_index=True)
    table = summarise(runs, args.tuning_catheter)
    clock.part("all", "total", start)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    print("\nMean per-run RMSE over motion rows of the bent settings (mm); ratios below\n")
    print(table.reset_index(names="row").to_markdown(index=False, floatfmt=".2f"))
    report_goal(table, args.goal)
    if args.subsets == "all":
        cyclic = summarise(cyclic_only(runs), args.tuning_catheter)
        print("\nThe same with the cyclic training sets only (C1 -> C2, C2+C3, C2+C3+C4)\n")
        print(cyclic.reset_index(names="row").to_markdown(index=False, floatfmt=".2f"))
        report_goal(cyclic, args.goal)
        cyclic.to_csv(args.output_dir / "transfer_cyclic.csv", index_label="row")
    print("\nIdentified play half-width (deg), bent settings, and the units' play parameters\n")
    print(widths.to_markdown(index=False, floatfmt=".3g"))
    timings = pd.DataFrame(clock.rows)
    print("\nWall time (s)\n")
    print(timings.to_markdown(index=False, floatfmt=".1f"))
    table.to_csv(args.output_dir / "transfer.csv", index_label="row")
    runs.to_csv(args.output_dir / "transfer_runs.csv", index=False)
    widths.to_csv(args.output_dir / "play_widths.csv", index=False)
    timings.to_csv(args.output_dir / "timings.csv", index=False)
    print(f"\nwritten: {args.output_dir}/transfer.csv, transfer_runs.csv, play_widths.csv, timings.csv")


if __name__ == "__main__":
    main()
