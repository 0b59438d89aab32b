"""What can the sweep context carry, and what would knowing the shaft setting gain?

A diagnosis of the simulated benchmark and of the sweep-context encoder, in
four parts (the numbers are in ``docs/residuals.rst``, section *What the
context can and cannot carry*):

1. **Sweep probe.** Can the shaft setting be read off a run's sweep from the
   motor side alone? Hand-made sweep features (the mean torques of each ray
   in four magnitude bins, outward and return) are mapped by a ridge
   regression to the setting's bend level, bend direction and the simulator's
   transmission parameters, and to the run's own offset drift. Cross-validated
   leave-one-setting-out within each catheter; R^2 per target.
2. **Context probe.** The same targets from the learned context ``z`` of a
   GRU residual trained on catheter ``--catheter`` (leave-one-setting-out
   ridge on ``z``). The encoder saw every setting in training, so this says
   what ``z`` *holds*, not how well it generalises.
3. **Oracle bound.** PDL+GRU under setting-held-out cross-validation within
   ``--catheter`` (4 folds, S00 trained on but never tested) with: no context;
   the learned context (the default); the *true* setting parameters as the
   context (``oracle``: the simulator's transmission and kinematic parameters
   of the run's shaft setting, fed to the encoder instead of the sweep); and
   both. The gap between "no context" and "oracle" bounds what any context
   could gain on this data.
4. **Drift floor.** How far the tip moves during motion because of the
   per-run slow drift of tendon gains and motor offsets (invisible to the
   motors for the gains), from simulating the same runs with the drift
   switched off; and PDL / PDL+GRU on that drift-free copy of the catheter.

5. **Memory** (``--parts memory``, not run by default): the same
   setting-held-out PDL+GRU trained on longer windows or on whole motion
   sequences, to see whether a longer training memory lowers the error.

Usage::

    python benchmarks/diagnose_context.py                 # C1, 25 epochs (~15 min on 2 cores)
    python benchmarks/diagnose_context.py --epochs 5      # quick look
    python benchmarks/diagnose_context.py --parts probe   # only the cheap probes

Defaults and the catheter were chosen on C1 only, as elsewhere in skcath.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
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

import skcath.datasets._simulator as _simulator
from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone
from skcath.datasets import make_benchmark
from skcath.datasets._benchmark import _benchmark_field, benchmark_specs
from skcath.datasets._catheter import configure
from skcath.metrics import mean_per_run_rmse
from skcath.model_selection import SettingGroupKFold
from skcath.residuals import GRUResidual
from skcath.residuals._features import Standardizer, step_feature_names, sweep_feature_names
from skcath.sweep import find_rays

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_lines  # noqa: E402

#: Magnitude bins (fractions of each ray's amplitude) of the sweep probe.
_BINS = ((0.2, 0.45), (0.45, 0.7), (0.7, 0.95))


# --------------------------------------------------------------------------- truth
def setting_truth(spec):
    """Probe targets of one run: its shaft setting and its own drift at motion start."""
    cfg = configure(spec.catheter, spec.setting)
    draw = _simulator._draw_run(spec)
    start = draw["n_sweep"]
    offset_now = draw["q"][start] - draw["u"][start]
    bend = spec.setting.bend_vector()
    return {
        "shaft wrap (deg)": spec.setting.bend_deg,
        "bend direction cos": bend[0],
        "bend direction sin": bend[1],
        "play growth, axis 1": cfg["growth"][0],
        "dead zone, axis 1 (deg)": cfg["dead_zone"][0],
        "motor offset, axis 1 (deg)": cfg["offsets"][0],
        "run offset drift at motion start, axis 1 (deg)": offset_now[0] - cfg["offsets"][0],
        "run gain drift at motion start, axis 1": draw["gain_scale"][start, 0] - 1.0,
    }


def oracle_vector(spec):
    """The true parameters of the run's shaft setting, as the oracle context (one row)."""
    c = configure(spec.catheter, spec.setting)
    routing = c["routing"]
    return np.r_[
        c["gains"].ravel(), c["offsets"], c["rest_bend"], c["coupling"], c["twist"],
        routing[0], np.cos(routing[1]), np.sin(routing[1]), routing[2], routing[4],
        c["windup"], c["growth"], c["dead_zone"], c["capstan_exponent"],
        spec.setting.bend_vector(), spec.setting.wrap,
    ]


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


def run_sweep_probe(X, specs):
    """R^2 of the sweep probe, one column per catheter."""
    sweep = X[X["phase"] == "sweep"]
    cols = {}
    for cat, Xc in sweep.groupby("catheter", observed=True, sort=True):
        feats, truth, groups = [], [], []
        for run, g in Xc.groupby("run", observed=True, sort=False):
            q = g[["q1", "q2"]].to_numpy()
            tau = g[["tau1", "tau2"]].to_numpy()
            feats.append(sweep_probe_features(q, tau, run))
            truth.append(setting_truth(specs[str(run)]))
            groups.append(str(g["setting"].iloc[0]))
        cols[cat] = probe_r2(np.array(feats), pd.DataFrame(truth), np.array(groups))
    return pd.DataFrame(cols)


def run_context_probe(Xb, y, specs, epochs, seed):
    """R^2 of a ridge probe on the learned context z of a GRU trained on all of ``Xb``."""
    model = GRUResidual(max_epochs=epochs, module__hidden_size=64, random_state=seed, n_threads=1)
    model.fit(Xb, y)
    _, _, sweep, _, _ = model._sequences(Xb)
    values, lengths = model._context_input(sweep)
    with torch.no_grad():
        z = model.module_.encoder(torch.as_tensor(values), torch.as_tensor(lengths)).numpy()
    runs = [str(r) for r in sweep.runs]
    truth = pd.DataFrame([setting_truth(specs[r]) for r in runs])
    groups = np.array([specs[r].setting.name for r in runs])
    return pd.Series(probe_r2(z, truth, groups), name="learned z")


# --------------------------------------------------------------------------- oracle
class KnownContextGRU(GRUResidual):
    """GRU residual whose context encoder reads given per-run vectors.

    ``run_context`` (class attribute: run id -> 1-D array) is repeated along
    every step of the run's sweep sequence; with ``keep_sweep`` the vectors
    are appended to the normal sweep features ``[q, tau]``, otherwise they
    replace them. A diagnosis device: the vectors are the simulator's truth.
    """

    run_context: dict = {}
    keep_sweep: bool = False

    def _sequences(self, X, y=None, **kwargs):
        F, motion, sweep, e, rotations = super()._sequences(X, y, **kwargs)
        known = np.stack([self.run_context[str(r)] for r in sweep.runs]).astype(sweep.values.dtype)
        extra = np.where(sweep.mask[..., None], known[:, None, :], 0.0).astype(sweep.values.dtype)
        values = np.concatenate([sweep.values, extra], axis=2) if self.keep_sweep else extra
        columns = tuple(f"known{i}" for i in range(known.shape[1]))
        columns = (*sweep.columns, *columns) if self.keep_sweep else columns
        sweep = dataclasses.replace(sweep, values=values, columns=columns)
        return F, motion, sweep, e, rotations

    def _fit_statistics(self, F, e):
        super()._fit_statistics(F, e)
        # statistics of the training runs only, one row per run
        known = np.stack([self.run_context[str(r)] for r in pd.unique(F["run"].astype(str))])
        stats = Standardizer.fit(known)
        if self.keep_sweep:
            stats = Standardizer(
                mean=np.r_[self.s_scaler_.mean, stats.mean],
                scale=np.r_[self.s_scaler_.scale, stats.scale],
            )
        self.s_scaler_ = stats

    def initialize_module(self):
        n_known = len(next(iter(self.run_context.values())))
        n_sweep = len(sweep_feature_names(self.use_torque)) if self.keep_sweep else 0
        kwargs = self.get_params_for("module")
        kwargs.update(
            n_features=len(step_feature_names(self.use_torque)),
            n_sweep_features=n_sweep + n_known,
            use_context=self.use_context,
        )
        self.module_ = self.initialized_instance(self.module, kwargs)
        return self


class KnownAndSweepContextGRU(KnownContextGRU):
    """:class:`KnownContextGRU` whose encoder also reads the sweep ``[q, tau]``."""

    keep_sweep = True


def oracle_bound(Xb, y, specs, epochs, seed):
    """Setting-held-out RMSE of PDL+GRU with no, learned, oracle and both contexts."""
    runs = pd.unique(Xb["run"].astype(str))
    KnownContextGRU.run_context = {r: oracle_vector(specs[r]) for r in runs}
    common = {"max_epochs": epochs, "module__hidden_size": 64, "random_state": seed, "n_threads": 1}
    models = {
        "no context": lambda: GRUResidual(use_context=False, **common),
        "learned context (default)": lambda: GRUResidual(**common),
        "oracle setting parameters": lambda: KnownContextGRU(**common),
        "oracle + learned": lambda: KnownAndSweepContextGRU(**common),
    }
    return _cross_validate(Xb, y, models)


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
@contextlib.contextmanager
def run_variation(**changes):
    """Temporarily change the simulator's per-run variation (a simulator ablation)."""
    old = dict(_simulator.RUN_VARIATION)
    _simulator.RUN_VARIATION.update(changes)
    try:
        yield
    finally:
        _simulator.RUN_VARIATION.clear()
        _simulator.RUN_VARIATION.update(old)


def simulate_catheter(catheter, **changes):
    """The benchmark's runs of one catheter, re-simulated with changed run variation.

    With no changes the result equals the benchmark's rows of that catheter:
    same seeds, same field distortion.
    """
    specs = [s for s in benchmark_specs() if s.catheter.name == catheter]
    with run_variation(**changes):
        return _simulator.simulate_runs(specs, field=_benchmark_field())


def drift_floor(catheter, epochs, seed):
    """Tip motion caused by the per-run drift, and the learners on a drift-free copy."""
    base = simulate_catheter(catheter)
    motion = (base.X["phase"] == "motion").to_numpy()
    runs = base.X["run"].astype(str).to_numpy()
    bent = (base.X["setting"] != "S00").to_numpy()
    rows = []
    for name, changes in {
        "gain drift only": {"gain_drift": 0.0},
        "offset drift only": {"offset_drift_deg": 0.0},
        "gain and offset drift": {"gain_drift": 0.0, "offset_drift_deg": 0.0},
    }.items():
        other = simulate_catheter(catheter, **changes)
        d = np.linalg.norm(base.y_true - other.y_true, axis=1)
        per_run = [np.sqrt(np.mean(d[(runs == r) & motion] ** 2)) for r in np.unique(runs[bent])]
        rows.append({"removed": name, "tip RMS change during motion (mm)": float(np.mean(per_run))})
    moved = pd.DataFrame(rows).set_index("removed")

    calm = simulate_catheter(catheter, gain_drift=0.0, offset_drift_deg=0.0)
    Xb = PDLBackbone(n_jobs=1).fit(calm.X).transform(calm.X)
    common = {"max_epochs": epochs, "module__hidden_size": 64, "random_state": seed, "n_threads": 1}
    learners = _cross_validate(Xb, np.asarray(calm.y), {
        "no context": lambda: GRUResidual(use_context=False, **common),
        "learned context (default)": lambda: GRUResidual(**common),
    })
    return moved, learners


# --------------------------------------------------------------------------- main
def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--catheter", default="C1")
    parser.add_argument("--epochs", type=int, default=25, help="GRU epochs per fit (default 25)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", nargs="+", default=["probe", "context", "oracle", "drift"],
                        choices=["probe", "context", "oracle", "drift", "memory"])
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    for line in machine_lines():
        print(line)
    data = make_benchmark()
    specs = {s.run: s for s in benchmark_specs()}
    keep = (data.X["catheter"] == args.catheter).to_numpy()
    X = data.X[keep].reset_index(drop=True)
    y = np.asarray(data.y)[keep]
    pd.set_option("display.width", 140)
    if "probe" in args.parts:
        print("\n## 1. Sweep probe: leave-one-setting-out R^2 from sweep torques, per catheter")
        print(run_sweep_probe(data.X, specs).round(2).to_string())
    Xb = None
    if {"context", "oracle", "memory"} & set(args.parts):
        Xb = PDLBackbone(n_jobs=1).fit(X).transform(X)
    if "context" in args.parts:
        print(f"\n## 2. Context probe: R^2 from the learned z ({args.catheter}, {args.epochs} epochs)")
        print(run_context_probe(Xb, y, specs, args.epochs, args.seed).round(2).to_string())
    if "oracle" in args.parts:
        print(f"\n## 3. Oracle bound: PDL+GRU, settings held out within {args.catheter} (4 folds)")
        print(oracle_bound(Xb, y, specs, args.epochs, args.seed).round(3).to_string())
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
