"""What can the sweep context carry?

A diagnosis of the simulated benchmark and of the sweep-context encoder (the
numbers in ``docs/diagnosis.rst`` were measured on simulator version 4 by an
earlier version of this script), in these parts:

1. **Sweep probe.** Can the shaft setting be read off a run's sweep from the
   motor side alone? Hand-made sweep features (the mean torques of each ray
   in three magnitude bins, outward and return, and at the ray's end) are
   mapped by a ridge regression to the setting's bend level and direction
   and to the simulator's transmission parameters of the unit in that
   setting (``skcath.datasets.setting_parameters``). Cross-validated
   leave-one-setting-out within each catheter; R^2 per target.
2. **Context probe.** The same targets from the learned context ``z`` of a
   GRU residual trained on catheter ``--catheter`` (leave-one-setting-out
   ridge on ``z``, read from the network's context encoder with a torch
   forward hook while the estimator predicts). The encoder saw every setting
   in training, so this says what ``z`` *holds*, not how well it
   generalises.
3. **Context ablation.** PDL+GRU under setting-held-out cross-validation
   within ``--catheter`` (4 folds, S00 trained on but never tested), without
   and with the learned context.
4. **Drift floor.** How far the tip moves during motion because of the
   per-run slow drift of tendon gains and motor offsets (invisible to the
   motors for the gains), from simulating the same runs with the drift
   switched off (``make_benchmark(run_variation=...)``); and PDL / PDL+GRU on
   that drift-free copy of the catheter.

5. **Memory** (``--parts memory``, not run by default): the same
   setting-held-out PDL+GRU trained on longer windows or on whole motion
   sequences, to see whether a longer training memory lowers the error.

The version of this script that measured ``docs/diagnosis.rst`` also probed
each run's own drift at the start of the motion and gave the encoder the
true setting parameters instead of the sweep (an "oracle" context); both
read the simulator's and the learner's internals and are not part of this
script.

Usage::

    python benchmarks/diagnose_context.py                 # C1, 25 epochs
    python benchmarks/diagnose_context.py --epochs 5      # quick look
    python benchmarks/diagnose_context.py --parts probe   # only the cheap probe

Defaults and the catheter were chosen on C1 only, as elsewhere in skcath.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from sklearn.linear_model import RidgeCV
from sklearn.model_selection import GroupKFold, cross_val_predict
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone
from skcath.datasets import benchmark_catheter, make_benchmark, setting_parameters, shaft_settings
from skcath.metrics import mean_per_run_rmse
from skcath.model_selection import SettingGroupKFold
from skcath.residuals import GRUResidual
from skcath.sweep import find_rays

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_lines  # noqa: E402

#: Magnitude bins (fractions of each ray's amplitude) of the sweep probe.
_BINS = ((0.2, 0.45), (0.45, 0.7), (0.7, 0.95))
#: The per-run drift, switched off one part at a time and both together.
DRIFTS = {
    "gain drift only": {"gain_drift": 0.0},
    "offset drift only": {"offset_drift_deg": 0.0},
    "gain and offset drift": {"gain_drift": 0.0, "offset_drift_deg": 0.0},
}


# --------------------------------------------------------------------------- truth
def setting_truth(catheter, setting):
    """Probe targets of one run: its shaft setting and the unit's parameters in it."""
    params = setting_parameters(catheter, setting)
    bend = setting.bend_vector()
    return {
        "shaft wrap (deg)": setting.bend_deg,
        "bend direction cos": bend[0],
        "bend direction sin": bend[1],
        "play growth, axis 1": params["growth"][0],
        "dead zone, axis 1 (deg)": params["dead_zone"][0],
        "motor offset, axis 1 (deg)": params["offsets"][0],
    }


def run_truth(runs, random_state=0):
    """Probe targets of every run of a benchmark's ``runs`` table, indexed by run id."""
    settings = {s.name: s for s in shaft_settings()}
    units = {name: benchmark_catheter(int(name[1:]), random_state) for name in runs["catheter"].unique()}
    rows = {
        run: setting_truth(units[cat], settings[setting])
        for run, cat, setting in runs[["run", "catheter", "setting"]].itertuples(index=False)
    }
    return pd.DataFrame.from_dict(rows, orient="index")


# --------------------------------------------------------------------------- probes
def sweep_probe_features(q, tau, run):
    """Mean torques per ray, magnitude bin and direction of travel, and at the ray ends."""
    rays = find_rays(q, run=run)
    rho, _ = rays.polar(q)
    outward = np.gradient(rho) > 0
    feats = []
    for k in range(rays.n_rays):
        on = rays.labels == k
        amp = rays.amplitudes[k]
        for lo, hi in _BINS:
            inside = on & (rho >= lo * amp) & (rho < hi * amp)
            for way in (outward, ~outward):
                sel = inside & way
                feats.extend(tau[sel].mean(axis=0) if sel.any() else (0.0, 0.0))
        end = on & (rho >= 0.95 * amp)
        feats.extend(tau[end].mean(axis=0) if end.any() else (0.0, 0.0))
    return np.asarray(feats)


def probe_r2(features, targets, groups):
    """Leave-one-setting-out R^2 of a ridge regression from features to each target."""
    out = {}
    for name in targets.columns:
        t = targets[name].to_numpy(dtype=float)
        if t.std() < 1e-12:
            continue
        model = make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-3, 3, 13)))
        n_splits = len(np.unique(groups))
        p = cross_val_predict(model, features, t, groups=groups, cv=GroupKFold(n_splits=n_splits))
        out[name] = 1.0 - ((p - t) ** 2).sum() / ((t - t.mean()) ** 2).sum()
    return out


def run_sweep_probe(X, truth):
    """R^2 of the sweep probe, one column per catheter."""
    sweep = X[X["phase"] == "sweep"]
    cols = {}
    for cat, Xc in sweep.groupby("catheter", observed=True, sort=True):
        feats, runs, groups = [], [], []
        for run, g in Xc.groupby("run", observed=True, sort=False):
            q = g[["q1", "q2"]].to_numpy()
            tau = g[["tau1", "tau2"]].to_numpy()
            feats.append(sweep_probe_features(q, tau, run))
            runs.append(str(run))
            groups.append(str(g["setting"].iloc[0]))
        targets = truth.loc[runs].reset_index(drop=True)
        cols[cat] = probe_r2(np.array(feats), targets, np.array(groups))
    return pd.DataFrame(cols)


def learned_contexts(model, Xb):
    """The context ``z`` of every run of ``Xb`` (one row per run, in order of first appearance).

    A forward hook on the network's context encoder collects its output while
    the estimator predicts; the runs go through the network in that order.
    """
    contexts = []
    hook = model.module_.encoder.register_forward_hook(
        lambda module, inputs, output: contexts.append(output.detach().numpy())
    )
    try:
        model.predict_residual(Xb)
    finally:
        hook.remove()
    z = np.concatenate(contexts)
    runs = pd.unique(Xb["run"].astype(str))
    if len(z) != len(runs):
        raise RuntimeError(f"the encoder ran on {len(z)} sequences for {len(runs)} runs")
    return pd.DataFrame(z, index=runs)


def run_context_probe(Xb, y, truth, epochs, seed):
    """R^2 of a ridge probe on the learned context z of a GRU trained on all of ``Xb``."""
    model = GRUResidual(max_epochs=epochs, module__hidden_size=64, random_state=seed, n_threads=1)
    model.fit(Xb, y)
    z = learned_contexts(model, Xb)
    groups = Xb.groupby("run", observed=True)["setting"].first().astype(str).loc[z.index]
    targets = truth.loc[z.index].reset_index(drop=True)
    return pd.Series(probe_r2(z.to_numpy(), targets, groups.to_numpy()), name="learned z")


# --------------------------------------------------------------------------- ablation
def context_ablation(Xb, y, epochs, seed):
    """Setting-held-out RMSE of PDL+GRU without and with the learned context."""
    common = {"max_epochs": epochs, "module__hidden_size": 64, "random_state": seed, "n_threads": 1}
    return _cross_validate(Xb, y, {
        "no context": lambda: GRUResidual(use_context=False, **common),
        "learned context (default)": lambda: GRUResidual(**common),
    })


def _cross_validate(Xb, y, models):
    folds = list(SettingGroupKFold(n_splits=4, exclude_settings=["S00"]).split(Xb))
    tested = np.zeros(len(Xb), dtype=bool)
    for _, test in folds:
        tested[test] = True
    b = Xb[list(BACKBONE_COLUMNS)].to_numpy()
    rows = [{"model": "PDL (backbone alone)",
             "RMSE (mm)": mean_per_run_rmse(y[tested], b[tested], Xb[tested]), "seconds": 0.0}]
    for name, make in models.items():
        start = time.perf_counter()
        pred = np.full_like(y, np.nan)
        for train, test in folds:
            model = make().fit(Xb.iloc[train], y[train])
            pred[test] = model.predict(Xb.iloc[test])
        rows.append({"model": name, "RMSE (mm)": mean_per_run_rmse(y[tested], pred[tested], Xb[tested]),
                     "seconds": time.perf_counter() - start})
    out = pd.DataFrame(rows).set_index("model")
    out["ratio to PDL"] = out["RMSE (mm)"] / out["RMSE (mm)"].iloc[0]
    return out


# --------------------------------------------------------------------------- memory
def memory(Xb, y, epochs, seed):
    """Setting-held-out RMSE of PDL+GRU trained on longer windows or whole sequences."""
    common = {"max_epochs": epochs, "module__hidden_size": 64, "random_state": seed, "n_threads": 1}
    return _cross_validate(Xb, y, {
        "windows of 200 steps (default)": lambda: GRUResidual(**common),
        "windows of 600 steps, burn-in 100": lambda: GRUResidual(window=600, burn_in=100, **common),
        "whole motion sequences, 8 per batch": lambda: GRUResidual(window=None, batch_size=8, **common),
    })


# --------------------------------------------------------------------------- drift
def simulate_catheter(catheter, run_variation=None):
    """The benchmark's runs of one catheter, simulated again with changed run variation.

    Without a change the result equals the benchmark's rows of that catheter:
    same seeds, same field distortion.
    """
    unit = benchmark_catheter(int(catheter[1:]))
    return make_benchmark(catheters=[unit], run_variation=run_variation, cache=False)


def drift_floor(catheter, epochs, seed):
    """Tip motion caused by the per-run drift, and the learners on a drift-free copy."""
    base = simulate_catheter(catheter)
    motion = (base.X["phase"] == "motion").to_numpy()
    runs = base.X["run"].astype(str).to_numpy()
    bent = (base.X["setting"] != "S00").to_numpy()
    rows = []
    for name, changes in DRIFTS.items():
        other = simulate_catheter(catheter, changes)
        d = np.linalg.norm(base.y_true - other.y_true, axis=1)
        per_run = [np.sqrt(np.mean(d[(runs == r) & motion] ** 2)) for r in np.unique(runs[bent])]
        rows.append({"removed": name, "tip RMS change during motion (mm)": float(np.mean(per_run))})
    moved = pd.DataFrame(rows).set_index("removed")

    calm = simulate_catheter(catheter, DRIFTS["gain and offset drift"])
    Xb = PDLBackbone(n_jobs=1).fit(calm.X).transform(calm.X)
    return moved, context_ablation(Xb, np.asarray(calm.y), epochs, seed)


# --------------------------------------------------------------------------- main
def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--catheter", default="C1")
    parser.add_argument("--epochs", type=int, default=25, help="GRU epochs per fit (default 25)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", nargs="+", default=["probe", "context", "ablation", "drift"],
                        choices=["probe", "context", "ablation", "drift", "memory"])
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    for line in machine_lines():
        print(line)
    data = make_benchmark()
    truth = run_truth(data.runs)
    keep = (data.X["catheter"] == args.catheter).to_numpy()
    X = data.X[keep].reset_index(drop=True)
    y = np.asarray(data.y)[keep]
    pd.set_option("display.width", 140)
    if "probe" in args.parts:
        print("\n## 1. Sweep probe: leave-one-setting-out R^2 from sweep torques, per catheter")
        print(run_sweep_probe(data.X, truth).round(2).to_string())
    Xb = None
    if {"context", "ablation", "memory"} & set(args.parts):
        Xb = PDLBackbone(n_jobs=1).fit(X).transform(X)
    if "context" in args.parts:
        print(f"\n## 2. Context probe: R^2 from the learned z ({args.catheter}, {args.epochs} epochs)")
        print(run_context_probe(Xb, y, truth, args.epochs, args.seed).round(2).to_string())
    if "ablation" in args.parts:
        print(f"\n## 3. Context ablation: PDL+GRU, settings held out within {args.catheter} (4 folds)")
        print(context_ablation(Xb, y, args.epochs, args.seed).round(3).to_string())
    if "memory" in args.parts:
        print(f"\n## 5. Memory: longer training windows, settings held out within {args.catheter}")
        print(memory(Xb, y, args.epochs, args.seed).round(3).to_string())
    if "drift" in args.parts:
        moved, learners = drift_floor(args.catheter, args.epochs, args.seed)
        print(f"\n## 4. Drift floor ({args.catheter})")
        print(moved.round(2).to_string())
        print("\nthe same catheter simulated without gain and offset drift, settings held out:")
        print(learners.round(3).to_string())


if __name__ == "__main__":
    main()
