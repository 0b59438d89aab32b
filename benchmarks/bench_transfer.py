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

**Units that differ in kind** (``--mechanism mixed``): the benchmarks are
``make_benchmark(mechanism="mixed", unit_spread=...)``, unit ``Ck`` with the
hysteresis mechanism ``k mod 3`` (C1 play, C2 Bouc-Wen, C3 Dahl friction with
creep, C4 play), and a table per catheter names each one's mechanism.
``--hysteresis none play pi`` chooses the identifications of each run's
hysteresis on its own sweep, each a backbone and a learned method trained on
its nominal tip: ``none`` (``PDL``, ``PDL+GRU``), ``play`` (``PDL+adapt``,
``PDL+GRU+adapt``: the backbones' ``hysteresis="play"``) and ``pi``
(``PDL+pi``, ``PDL+GRU+pi``: ``hysteresis="pi"``, skipped with a message
where the backbones do not have it). PCC is calibrated with each
identification too (``PCC``, ``PCC+adapt``, ``PCC+pi``). ``--held-out`` tests
some catheters only, ``--ks`` some numbers of training catheters only,
``--schedule full`` the protocol's full schedule (``--max-epochs`` caps its
pretraining epochs; the heading then says so), ``--backbones-only`` the
backbones alone (``--no-pdl``: PCC alone).

Schedule: ``QUICK`` (hidden size 64, windows every 200 steps, 4 pretraining
epochs at learning rate 1e-2, 3 fine-tuning epochs at 3e-3, four groups of
settings per catheter) with one seed (``--seed``; ``--seeds`` for several,
each run's error averaged over them), restricted to the two
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
    nice -n 10 .venv/bin/python benchmarks/bench_transfer.py --mechanism mixed --spreads 1.0 \
        --backbones-only --hysteresis none play
"""

import argparse
import dataclasses
import itertools
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
from _finetuned import within_predictions
from _machine import machine_lines
from sklearn.utils._param_validation import StrOptions

from skcath.backbones import BACKBONE_COLUMNS, PCCBackbone, PDLBackbone
from skcath.datasets import SIMULATOR_VERSION, make_benchmark
from skcath.metrics import per_run_rmse
from skcath.protocol import (
    ADAPTED_BACKBONE,
    FULL,
    LEARNER_COLUMNS,
    QUICK,
    Fold,
    learner_input,
    pretrain_models,
    protocol_folds,
)

#: The setting never scored (kept for training), as in ``python -m skcath reproduce``.
STRAIGHT = "S00"


class Identification(NamedTuple):
    """One identification of each run's hysteresis on its sweep, and the methods that use it."""

    hysteresis: str  # the backbones' ``hysteresis`` (None: the motor angles as they are)
    backbone: str  # the PDL backbone's method name; PCC's is "PCC" + its suffix
    learned: str  # the learned method on the backbone's nominal tip
    variant: str  # the protocol's learned variant it is trained as
    ratio: str  # its name in the ratio rows


#: The identifications of ``--hysteresis``.
IDENTIFICATIONS = {
    "none": Identification(None, "PDL", "PDL+GRU", "PDL+GRU", "PDL+GRU"),
    "play": Identification("play", "PDL+adapt", "PDL+GRU+adapt", "PDL+GRU+adapt", "adapt"),
    "pi": Identification("pi", "PDL+pi", "PDL+GRU+pi", "PDL+GRU+adapt", "pi"),
}

#: Unit parameters of the simulator's play printed beside the identified widths.
PLAY_PARAMETERS = ("play_w0", "play_growth_base", "play_growth_scale", "mu")


def backbone_hysteresis():
    """The values of ``hysteresis`` the backbones accept besides None."""
    return sorted(o for c in PDLBackbone._parameter_constraints["hysteresis"]
                  if isinstance(c, StrOptions) for o in c.options)


def has_hysteresis(name):
    """Whether the backbones accept ``hysteresis=name``."""
    return name in backbone_hysteresis()


def loco_name(ident):
    return f"{ident.learned} (LOCO)"


def pcc_name(ident):
    return "PCC" + ident.backbone[len("PDL"):]


class Clock:
    """Wall time of the parts of the benchmark, printed as each part ends."""

    def __init__(self):
        self.rows = []

    def part(self, benchmark, name, start, model_s=np.nan):
        seconds = time.perf_counter() - start
        self.rows.append({"benchmark": benchmark, "part": name, "wall_s": seconds, "model_s": model_s})
        extra = "" if np.isnan(model_s) else f" ({model_s:.0f} s of model training)"
        print(f"[{benchmark}] {name}: {seconds:.1f} s{extra}", flush=True)


def load(spread, mechanism, quick_check):
    """Recordings, measured tips, unit parameters and each unit's mechanism (a small part with ``quick_check``)."""
    kwargs = {} if spread is None else {"unit_spread": spread}
    data = make_benchmark(mechanism=mechanism, **kwargs)
    X, y = data.X, data.y
    if quick_check:
        keep = (X["setting"].astype(str) <= "S04") & X["run"].astype(str).str.endswith("-R1")
        X = X[keep.to_numpy()].reset_index(drop=True)
        for column in ("catheter", "setting", "run"):
            X[column] = X[column].cat.remove_unused_categories()
        y = y[keep.to_numpy()]
    units = pd.DataFrame(data.catheters).T[list(PLAY_PARAMETERS)].astype(float)
    mechanisms = data.get("mechanisms") or {name: data.mechanism for name in data.catheters}
    return X, np.asarray(y, dtype=float), units, mechanisms


def adapted_input(X, n_jobs):
    """Input of the adapted learners and every run's identified play half-width (deg)."""
    calibration = PDLBackbone(**ADAPTED_BACKBONE, n_jobs=n_jobs).fit(X).calibrate(X)
    X_learner = X.assign(**dict(zip(BACKBONE_COLUMNS, calibration.nominal.T)))
    return X_learner[list(LEARNER_COLUMNS)], calibration.table["play_width_deg"]


def backbone_inputs(X, args, name, clock):
    """The learners' input of every identification, the PCC predictions, and the play widths."""
    inputs, pcc, widths = {}, {}, None
    for ident in args.identifications:
        start = time.perf_counter()
        if args.pdl and ident.hysteresis == "play":
            inputs[ident.backbone], widths = adapted_input(X, args.n_jobs)
        elif args.pdl:
            params = {} if ident.hysteresis is None else {"hysteresis": ident.hysteresis}
            inputs[ident.backbone] = learner_input(X, n_jobs=args.n_jobs, **params)
        if args.pdl:
            clock.part(name, f"calibrating {ident.backbone}", start)
        if not args.pcc:
            continue
        start = time.perf_counter()
        pcc[pcc_name(ident)] = PCCBackbone(hysteresis=ident.hysteresis, n_jobs=args.n_jobs).fit(X).predict(X)
        clock.part(name, f"calibrating {pcc_name(ident)}", start)
    return inputs, pcc, widths


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
    """Catheter-held-out scores for the ``--ks`` numbers of training catheters, and the models of the largest."""
    catheters = sorted(X["catheter"].astype(str).unique())
    test = {fold.catheter: fold.test for fold in folds.loco}
    catheter_of = X["catheter"].astype(str)
    records, models = [], {}
    for k in args.ks or range(1, len(catheters)):
        start, model_s = time.perf_counter(), 0.0
        for group in training_sets(catheters, k, args.subsets):
            # rows in the order of X: with k = 3, the protocol's catheter-held-out training set
            train = [Fold(c, np.flatnonzero(catheter_of.isin(others).to_numpy()), test[c])
                     for c, others in group if c in test]
            for ident in args.identifications:
                out = pretrain_models(inputs[ident.backbone], y, train, schedule, variants=[ident.variant],
                                      predict=[ident.variant], n_jobs=args.n_jobs)
                model_s += sum(t["seconds"] for t in out.timings)
                preds = {}
                for (_, seed, c), values in out.predictions.items():
                    preds.setdefault(seed, np.full((len(X), 3), np.nan))[test[c]] = values
                for seed, pred in preds.items():
                    for fold in train:
                        records += run_scores(y, pred, X, fold.test, benchmark=name, method=loco_name(ident),
                                              k=k, training="+".join(dict(group)[fold.catheter]), seed=seed)
                if k == len(catheters) - 1:
                    models[ident.learned] = out.models
        clock.part(name, f"pretraining on {k} catheter(s)", start, model_s)
    return records, models


def finetune_within(inputs, y, X, folds, schedule, models, args, name, clock):
    """Within-catheter scores of the learned methods fine-tuned from the k = n - 1 models."""
    start, model_s, records = time.perf_counter(), 0.0, []
    k = X["catheter"].nunique() - 1
    for ident, seed in itertools.product(args.identifications, schedule.seeds):
        pretrained = {key: model for key, model in models[ident.learned].items() if key[1] == seed}
        pred, timings = within_predictions(inputs[ident.backbone], y, folds,
                                           dataclasses.replace(schedule, seeds=(seed,)), pretrained,
                                           ident.variant, args.n_jobs)
        model_s += sum(t["seconds"] for t in timings)
        for fold in folds.loco:
            records += run_scores(y, pred, X, fold.test, benchmark=name, method=ident.learned, k=k,
                                  training="within", seed=seed)
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


def benchmark_name(spread, mechanism):
    name = "default" if spread is None else f"unit_spread={spread:g}"
    return name if mechanism == "play" else f"{mechanism}, {name}"


def one_benchmark(spread, args, clock):
    """Every score, the play widths and the units' mechanisms of one benchmark."""
    name = benchmark_name(spread, args.mechanism)
    start = time.perf_counter()
    X, y, units, mechanisms = load(spread, args.mechanism, args.quick_check)
    clock.part(name, f"loading ({X['run'].nunique()} runs)", start)
    inputs, pcc, widths = backbone_inputs(X, args, name, clock)
    if args.quick_check and "PDL+adapt" in inputs:
        expected = learner_input(X, adapt=True, n_jobs=args.n_jobs)
        pd.testing.assert_frame_equal(inputs["PDL+adapt"], expected)
        print(f"[{name}] the adapted input equals learner_input(X, adapt=True)")
    folds = protocol_folds(X, args.schedule, exclude_settings=STRAIGHT, catheters=args.held_out)
    predictions = {**pcc, **{b: X_learner[list(BACKBONE_COLUMNS)].to_numpy() for b, X_learner in inputs.items()}}
    records = []
    for backbone, pred in predictions.items():
        for fold in folds.loco:
            records += run_scores(y, pred, X, fold.test, benchmark=name, method=backbone, k=0,
                                  training="none")
    within = []
    if not args.backbones_only:
        loco, models = pretrain_on_subsets(inputs, y, X, folds, args.schedule, args, name, clock)
        k_max = X["catheter"].nunique() - 1
        if args.within and k_max in (args.ks or [k_max]):
            within = finetune_within(inputs, y, X, folds, args.schedule, models, args, name, clock)
        records += loco
    play = None if widths is None else play_table(widths, X, units, name)
    return pd.DataFrame(records + within), play, {(name, c): m for c, m in mechanisms.items()}


def table_rows(runs, identifications):
    """Rows of the table (label, method, number of training catheters; 0 for a backbone), the ks, the within k."""
    within = runs["training"] == "within"
    k_max = int(runs.loc[within, "k"].max()) if within.any() else 0
    ks = sorted(set(runs.loc[(runs["k"] > 0) & ~within, "k"].astype(int)))
    methods = set(runs["method"])
    rows = [(pcc_name(i), pcc_name(i), 0) for i in identifications if pcc_name(i) in methods]
    rows += [(i.backbone, i.backbone, 0) for i in identifications]
    rows += [(f"{i.learned}, within (from {k_max})", i.learned, k_max) for i in identifications]
    for ident in identifications:
        rows += [(f"{loco_name(ident)}, k={k}", loco_name(ident), k) for k in ks]
    return rows, ks, k_max


def cells(per_run, groups, rows):
    """Mean per-run RMSE of every row (label, method, k) in every group (column name -> mask)."""
    table = {}
    for label, method, k in rows:
        sel = (per_run["method"] == method) & (per_run["k"] == k)
        table[label] = {column: per_run.loc[sel & mask, "rmse_mm"].mean() for column, mask in groups.items()}
    return pd.DataFrame(table).T


def add_ratios(table, identifications, ks, k_max):
    """Ratio rows: each learned method (LOCO) / PDL+GRU within, each backbone / PDL."""
    label = f"PDL+GRU, within (from {k_max})"
    within = table.loc[label] if label in table.index and table.loc[label].notna().any() else None
    for ident in sorted(identifications, key=lambda i: i.hysteresis != "play"):
        for k in ks if within is not None else ():
            table.loc[f"ratio {ident.ratio} (LOCO), k={k} / PDL+GRU within"] = (
                table.loc[f"{loco_name(ident)}, k={k}"] / within
            )
    for ident in identifications:
        if ident.hysteresis is not None:
            if "PDL" in table.index:
                table.loc[f"ratio {ident.backbone} / PDL"] = table.loc[ident.backbone] / table.loc["PDL"]
            if "PCC" in table.index:
                table.loc[f"ratio {pcc_name(ident)} / PCC"] = table.loc[pcc_name(ident)] / table.loc["PCC"]
    return table.dropna(how="all")


def mean_per_run(runs):
    """A run scored by several models of one method and ``k`` (sets of ``k`` catheters, seeds) counts once."""
    per_run = runs.groupby(["benchmark", "method", "k", "run", "catheter"], sort=False)["rmse_mm"].mean()
    return per_run.reset_index()


def summarise(runs, tuning, identifications):
    """The table: mean per-run RMSE (mm) for the tuning catheter, the others pooled and all, and the ratios."""
    per_run = mean_per_run(runs)
    others = sorted(set(per_run["catheter"]) - {tuning})
    groups = {}
    for bench in pd.unique(per_run["benchmark"]):
        of_bench = per_run["benchmark"] == bench
        groups[f"{bench}: {tuning}"] = of_bench & (per_run["catheter"] == tuning)
        if others:
            groups[f"{bench}: {others[0]}-{others[-1]}"] = of_bench & (per_run["catheter"] != tuning)
        groups[f"{bench}: all"] = of_bench
    rows, ks, k_max = table_rows(runs, identifications)
    return add_ratios(cells(per_run, groups, rows), identifications, ks, k_max)


def per_catheter(runs, mechanisms, identifications):
    """The table with one column per held-out catheter, named with its mechanism."""
    per_run = mean_per_run(runs)
    groups = {}
    for bench in pd.unique(per_run["benchmark"]):
        for catheter in sorted(set(per_run.loc[per_run["benchmark"] == bench, "catheter"])):
            label = f"{bench}: {catheter} ({mechanisms[bench, catheter]})"
            groups[label] = (per_run["benchmark"] == bench) & (per_run["catheter"] == catheter)
    rows, ks, k_max = table_rows(runs, identifications)
    return add_ratios(cells(per_run, groups, rows), identifications, ks, k_max)


def report_goal(table, goal):
    """Print how many cells of the ratio adapt (LOCO) / PDL+GRU within exceed ``goal``, and the largest."""
    ratios = table.loc[[r for r in table.index if r.startswith("ratio adapt")]]
    if ratios.size:
        print(f"\ncells with ratio adapt (LOCO) / PDL+GRU within above {goal}: "
              f"{int((ratios > goal).to_numpy().sum())} of {ratios.size}; largest {ratios.to_numpy().max():.2f}")


def cyclic_only(runs, catheters):
    """The records of the backbones, the within references and the cyclic training sets only."""
    cyclic = {
        (c, k, "+".join(others))
        for k in range(1, len(catheters))
        for c, others in training_sets(catheters, k, "cyclic")[0]
    }
    keys = zip(runs["catheter"], runs["k"], runs["training"])
    keep = [training in ("none", "within") or key in cyclic
            for key, training in zip(keys, runs["training"])]
    return runs[np.asarray(keep)]

def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spreads", nargs="+", default=["default", "1.0"],
                        help="benchmarks by unit spread: 'default' or a number in [0, 1] "
                             "(default: default 1.0)")
    parser.add_argument("--mechanism", default="play", choices=("play", "bouc_wen", "dahl_creep", "mixed"),
                        help="hysteresis mechanism of the benchmarks; 'mixed': unit Ck with mechanism "
                             "k mod 3 (default: play)")
    parser.add_argument("--hysteresis", nargs="+", default=["none", "play"], choices=tuple(IDENTIFICATIONS),
                        help="identifications of each run's hysteresis on its sweep (default: none play)")
    parser.add_argument("--held-out", nargs="+", default=None,
                        help="catheters held out and scored (default: every one)")
    parser.add_argument("--ks", nargs="+", type=int, default=None,
                        help="numbers of training catheters (default: 1 .. n - 1)")
    parser.add_argument("--schedule", choices=("quick", "full"), default="quick",
                        help="the protocol's schedule, with the seeds of --seed (default: quick)")
    parser.add_argument("--max-epochs", type=int, default=None,
                        help="pretraining epochs instead of the schedule's (default: the schedule's)")
    parser.add_argument("--no-within", dest="within", action="store_false",
                        help="skip the within-catheter references (fine-tuning the k = n - 1 models)")
    parser.add_argument("--no-pcc", dest="pcc", action="store_false", help="skip the PCC backbones")
    parser.add_argument("--backbones-only", action="store_true", help="the backbones alone, no learning")
    parser.add_argument("--no-pdl", dest="pdl", action="store_false",
                        help="with --backbones-only: skip the PDL backbones (their rows and ratios are left out)")
    parser.add_argument("--subsets", choices=("cyclic", "all"), default="all",
                        help="training catheters with k < n - 1: the k that follow the held-out one "
                             "in cyclic order, or every set of k (default: all)")
    parser.add_argument("--seed", "--seeds", dest="seeds", type=int, nargs="+", default=[0],
                        help="seeds of the learned models; each run's error is averaged over them (default: 0)")
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
    if not args.pdl and not (args.backbones_only and args.pcc):
        parser.error("--no-pdl: only with --backbones-only and without --no-pcc (the learners need PDL)")
    missing = [h for h in args.hysteresis if h != "none" and not has_hysteresis(h)]
    for h in missing:
        print(f"skipping --hysteresis {h}: this skcath's backbones have no hysteresis={h!r} "
              f"(PDLBackbone accepts hysteresis in {backbone_hysteresis()})")
    args.identifications = [IDENTIFICATIONS[h] for h in dict.fromkeys(args.hysteresis) if h not in missing]
    if not args.identifications:
        parser.error("--hysteresis: none of the identifications asked for is available")
    learned = tuple(dict.fromkeys(i.variant for i in args.identifications))
    schedule = dataclasses.replace(QUICK if args.schedule == "quick" else FULL, seeds=tuple(args.seeds),
                                   variants=learned)
    if args.max_epochs is not None:
        schedule = dataclasses.replace(
            schedule, pretrain_params={**schedule.pretrain_params, "max_epochs": args.max_epochs})
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


def print_table(title, table, goal):
    print(f"\n{title}\n")
    print(table.reset_index(names="row").to_markdown(index=False, floatfmt=".2f"))
    report_goal(table, goal)


def main(argv=None):
    args = parse_args(argv)
    print("\n".join(machine_lines()))
    print(f"simulator version {SIMULATOR_VERSION}; schedule {args.schedule}")
    clock, runs, widths, mechanisms = Clock(), [], [], {}
    start = time.perf_counter()
    for spread in args.spreads:
        scores, play, units = one_benchmark(spread, args, clock)
        runs.append(scores)
        widths += [] if play is None else [play]
        mechanisms.update(units)
    runs = pd.concat(runs, ignore_index=True)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    runs.to_csv(args.output_dir / "transfer_runs.csv", index=False)  # first: the tables cannot lose the runs
    table = summarise(runs, args.tuning_catheter, args.identifications)
    by_catheter = per_catheter(runs, mechanisms, args.identifications)
    clock.part("all", "total", start)
    epochs = args.schedule.pretrain_params["max_epochs"]
    learning = ("backbones alone" if args.backbones_only else
                f"schedule {args.schedule.name} ({epochs} pretraining epochs), seeds {args.seeds}")
    print_table(f"Mean per-run RMSE over motion rows of the bent settings (mm), {learning}; ratios below",
                table, args.goal)
    print_table("The same per held-out catheter (its mechanism in brackets)", by_catheter, args.goal)
    if args.subsets == "all" and not args.backbones_only:
        catheters = sorted({catheter for _, catheter in mechanisms})
        cyclic = summarise(cyclic_only(runs, catheters), args.tuning_catheter, args.identifications)
        print_table("The same with the cyclic training sets only (C1 -> C2, C2+C3, C2+C3+C4)", cyclic, args.goal)
        cyclic.to_csv(args.output_dir / "transfer_cyclic.csv", index_label="row")
    if widths:
        widths = pd.concat(widths, ignore_index=True)
        print("\nIdentified play half-width (deg), bent settings, and the units' play parameters\n")
        print(widths.to_markdown(index=False, floatfmt=".3g"))
        widths.to_csv(args.output_dir / "play_widths.csv", index=False)
    timings = pd.DataFrame(clock.rows)
    print("\nWall time (s)\n")
    print(timings.to_markdown(index=False, floatfmt=".1f"))
    table.to_csv(args.output_dir / "transfer.csv", index_label="row")
    by_catheter.to_csv(args.output_dir / "transfer_catheters.csv", index_label="row")
    timings.to_csv(args.output_dir / "timings.csv", index=False)
    print(f"\nwritten: {args.output_dir}/transfer.csv, transfer_catheters.csv, transfer_runs.csv, "
          + ("play_widths.csv, " if len(widths) else "") + "timings.csv")


if __name__ == "__main__":
    main()
