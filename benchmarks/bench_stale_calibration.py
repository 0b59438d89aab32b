"""Residual trained on stale calibrations: recovery after a shaft change without the tracker.

After a shaft change, a motor-only re-sweep (``OnlineEstimator.resweep``)
renews the sweep context ``z`` but keeps the backbone's calibration of the
first sweep, taken in the old shaft configuration
(``benchmarks/bench_shaft_recovery.py``, ``docs/shaft_change.rst``). The
residual of the protocol never meets such a backbone in training: its
backbone and its context always come from the same sweep. This script
pretrains it on the default benchmark augmented with *stale copies*: for a
share of the runs ``r``, one extra run (a new run id, the same catheter,
setting, motor angles, torques and measured tip) whose backbone columns
``b_x, b_y, b_z`` on all its rows, sweep and motion, are the PDL tip of
``r``'s motor angles under the calibration of another run ``r'`` of the same
catheter in another setting, drawn at random. That is what the residual sees
after a motor-only re-sweep: the kept calibration on the new motor angles
(the sweep frame, ``frame="sweep"``, fitted on the copy's sweep rows from
those angles and that backbone, as ``resweep`` fits it), and the context of
the new sweep, which reads the motor angles and torques alone.

It then evaluates the pretrained catheter-held-out PDL+GRU (full schedule,
one seed, one torch thread) on ``make_benchmark(shaft_change=True,
resweep=True)`` as ``bench_shaft_recovery.py`` does (stale model,
motor-only re-sweep, tracked re-sweep, the probe "new calibration, old
context", and the model before the change), for the catheters asked.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_stale_calibration.py --catheters C1 --models models/
    .venv/bin/python benchmarks/bench_stale_calibration.py --catheters C1 --share 0 --models plain/

``--share 0`` pretrains the plain model (no copies), the baseline.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from _machine import machine_lines
from bench_shaft_recovery import METHODS, VARIANT, _error_table, _evaluate, _recalibrations
from sklearn.utils import Bunch

from skcath import ID_COLUMNS, MOTOR_COLUMNS, persist
from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone, pdl_tip
from skcath.datasets import make_benchmark
from skcath.protocol import FULL, LEARNER_COLUMNS, pretrain_models, protocol_folds

CATHETER, SETTING, RUN = ID_COLUMNS


def stale_copies(X_learner, y, params, *, share=1.0, keep_original=True, random_state=None):
    """The learner input and target with stale-calibration copies of a share of the runs appended.

    Parameters
    ----------
    X_learner : pandas.DataFrame
        Input of the residual learners (``learner_input``), one row per
        sample, its runs calibrated on their own sweeps.
    y : ndarray of shape (n_samples, 3)
        Measured tip positions (mm).
    params : dict
        Calibration (``PDLParams``) of every run, by run id, as
        ``PDLBackbone().fit(X).calibrate(X).params`` gives it.
    share : float, default=1.0
        Share of the runs, in ``[0, 1]``, that get a copy (drawn at random).
    keep_original : bool, default=True
        Keep the runs as they are, followed by the copies; False returns the
        copies alone.
    random_state : int or None
        Seed of the draws (runs copied, and the stale run of each copy).

    Returns
    -------
    X_augmented : pandas.DataFrame
        ``X_learner`` (if ``keep_original``) followed by the copies; a copy of run ``r`` has the
        run id ``"<r>/stale:<r'>"`` and the backbone columns
        ``pdl_tip(q of r, params[r'])`` (mm) on all its rows, with ``r'`` a
        run of the same catheter in another setting.
    y_augmented : ndarray of shape (n_augmented, 3)
        ``y`` (if ``keep_original``) followed by the copies' tips (those of
        the runs copied).
    """
    rng = np.random.default_rng(random_state)
    ids = X_learner[list(ID_COLUMNS)].astype(str)
    runs = ids.drop_duplicates(RUN).set_index(RUN)
    chosen = runs.index[rng.random(len(runs)) < share]
    positions = pd.Series(np.arange(len(ids))).groupby(ids[RUN].to_numpy()).indices
    frames, targets = [X_learner], [np.asarray(y, dtype=float)]
    for run in chosen:
        catheter, setting = runs.loc[run, CATHETER], runs.loc[run, SETTING]
        others = runs.index[(runs[CATHETER] == catheter) & (runs[SETTING] != setting)]
        stale = str(rng.choice(others))
        rows = positions[run]
        copy = X_learner.iloc[rows].copy()
        nominal = pdl_tip(copy[list(MOTOR_COLUMNS)].to_numpy(), params[stale])
        copy[list(BACKBONE_COLUMNS)] = nominal
        copy[RUN] = f"{run}/stale:{stale}"
        frames.append(copy)
        targets.append(targets[0][rows])
    if not keep_original:
        frames, targets = frames[1:], targets[1:]
    X_augmented = pd.concat([f.astype({RUN: str}) for f in frames], ignore_index=True)
    X_augmented[RUN] = pd.Categorical(X_augmented[RUN], categories=pd.unique(X_augmented[RUN]))
    return X_augmented, np.concatenate(targets)


def _pretrained(X_learner, y, catheters, seed, models_dir, tag):
    """The catheter-held-out PDL+GRU of the catheters asked (full schedule, one seed), and the seconds of each."""
    schedule = dataclasses.replace(FULL, name="recovery", seeds=(seed,), variants=(VARIANT,))
    folds = protocol_folds(X_learner, schedule, exclude_settings="S00", catheters=catheters).loco
    path = {f.catheter: Path(models_dir) / f"{VARIANT}-{tag}-seed{seed}-{f.catheter}.skcath" for f in folds}
    models, seconds = {}, {}
    for fold in folds:  # one at a time: one torch thread, one core
        if path[fold.catheter].exists():
            # this script's own files, joblib when kept by earlier versions
            models[fold.catheter] = persist.load(path[fold.catheter], allow_pickle=True)
            continue
        result = pretrain_models(X_learner, y, [fold], schedule, verbose=True)
        models[fold.catheter] = result.models[VARIANT, seed, fold.catheter]
        seconds[fold.catheter] = result.timings[0]["seconds"]
        path[fold.catheter].parent.mkdir(parents=True, exist_ok=True)
        persist.save(models[fold.catheter], path[fold.catheter])
    return models, seconds


def _only(data, catheters):
    """The shaft-change benchmark restricted to the changed runs of ``catheters`` (rows keep their labels)."""
    keep = data.runs[CATHETER].astype(str).isin(catheters)
    return Bunch(X=data.X, y=data.y, runs=data.runs[keep])


def _two_models(plain, stale):
    """Errors of a deployment with two residuals: the plain one after ``start``, the stale-trained one after ``resweep``."""
    out = plain.copy()
    out["GRU motor-only"] = stale["GRU motor-only"].to_numpy()
    return out


def _print_table(errors, dev, catheters, title):
    table = _error_table(errors, dev)
    if len(catheters) == 1:
        table = table.iloc[:1]
    print(f"\n### {title}\n")
    print(table.to_markdown(index=False, floatfmt=".2f"))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catheters", nargs="+", default=["C1"], help="catheters tested (held out in training)")
    parser.add_argument("--share", type=float, default=1.0, help="share of the runs copied (0: plain model)")
    parser.add_argument("--stale-only", action="store_true", help="train on the copies alone")
    parser.add_argument("--augment-seed", type=int, default=0, help="seed of the copies' draws")
    parser.add_argument("--seed", type=int, default=0, help="seed of the model")
    parser.add_argument("--engine", default="auto", choices=("auto", "numba", "numpy"))
    parser.add_argument("--dev-catheter", default="C1")
    parser.add_argument("--models", required=True, help="folder to keep the pretrained models in")
    parser.add_argument("--plain", default=None,
                        help="folder of the plain models (PDL+GRU-plain-seed<seed>-<catheter>.skcath): "
                             "also evaluates them, and the two-model deployment")
    args = parser.parse_args()

    torch.set_num_threads(1)
    for line in machine_lines():
        print(line)
    wall = time.perf_counter()
    default = make_benchmark()
    start = time.perf_counter()
    calibration = PDLBackbone().fit(default.X).calibrate(default.X)  # what learner_input calibrates
    X_learner = default.X.assign(**dict(zip(BACKBONE_COLUMNS, calibration.nominal.T)))[list(LEARNER_COLUMNS)]
    t_backbone = time.perf_counter() - start
    tag = "plain"
    y = default.y
    if args.share > 0:
        tag = f"stale{args.share:g}{'only' if args.stale_only else ''}-a{args.augment_seed}"
        X_learner, y = stale_copies(X_learner, y, calibration.params, share=args.share,
                                    keep_original=not args.stale_only, random_state=args.augment_seed)
    print(f"learner input: {X_learner[RUN].nunique()} runs, {len(X_learner)} rows ({tag})")
    models, seconds = _pretrained(X_learner, y, args.catheters, args.seed, args.models, tag)
    changed = _only(make_benchmark(shaft_change=True, resweep=True, cache=False), args.catheters)
    recalibrations = _recalibrations(default.X, args.catheters)  # the shaft-recovery bench's column (d)
    start = time.perf_counter()
    errors, _, _ = _evaluate(models, recalibrations, changed, args.engine)
    t_eval = time.perf_counter() - start
    print(f"\nbackbone calibration {t_backbone:.0f} s; pretraining (s per model): "
          + ", ".join(f"{c} {s:.0f}" for c, s in seconds.items())
          + f"; streaming {t_eval:.0f} s; total {time.perf_counter() - wall:.0f} s\n")
    for name, meaning in METHODS.items():
        print(f"- {name}: {meaning}")
    title = "Tip error after the change (mm, mean per-run RMSE)"
    _print_table(errors, args.dev_catheter, args.catheters, f"{title}, {tag}")
    if args.plain is not None:
        plain = {c: persist.load(Path(args.plain) / f"{VARIANT}-plain-seed{args.seed}-{c}.skcath",
                                 allow_pickle=True)  # kept by this script, joblib in earlier versions
                 for c in args.catheters}
        errors_plain, _, _ = _evaluate(plain, recalibrations, changed, args.engine)
        _print_table(errors_plain, args.dev_catheter, args.catheters, f"{title}, plain")
        both = _two_models(errors_plain, errors)
        _print_table(both, args.dev_catheter, args.catheters,
                     f"{title}: plain model after start, {tag} after resweep")


if __name__ == "__main__":
    main()
