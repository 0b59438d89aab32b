"""What can the sweep context carry, and what would knowing the shaft setting gain?

A diagnosis of the simulated benchmark and of the sweep-context encoder (the
numbers are in ``docs/studies/diagnosis.rst``), in these parts:

1. **Sweep probe.** Can the shaft setting be read off a run's sweep from the
   motor side alone? Hand-made sweep features (the mean torques of each ray
   in three magnitude bins, outward and return, and at the ray's end) are
   mapped by a ridge regression to the setting's bend level and direction,
   to the simulator's transmission parameters of the unit in that setting
   (``skcath.datasets.setting_parameters``), and to the run's own offset and
   gain drift at the start of its motion (the ``runs`` table of
   ``make_benchmark``). Cross-validated leave-one-setting-out within each
   catheter; R^2 per target.
2. **Context probe.** The same targets from the learned context ``z`` of a
   GRU residual trained on catheter ``--catheter`` (leave-one-setting-out
   ridge on ``z``, ``GRUResidual.encode_context``). The encoder saw every
   setting in training, so this says what ``z`` *holds*, not how well it
   generalises.
3. **Oracle bound.** PDL+GRU under setting-held-out cross-validation within
   ``--catheter`` (4 folds, S00 trained on but never tested) with: no
   context; the learned context (the default); the *true* parameters of the
   run's shaft setting as the context (``oracle``, 28 numbers: the
   transmission and kinematic parameters of ``setting_parameters``, the bend
   direction and the wrap); and both. The gap between "no context" and
   "oracle" bounds what any context could gain on this data. The oracle
   reaches the encoder as sweep rows (see :class:`KnownContext`); to leave
   the sweep frame of the residual untouched, the four models learn in each
   run's sweep frame, rotated here (``skcath.frames.sweep_frame``) as the
   learner's default ``frame="sweep"`` rotates it.
4. **Drift floor.** How far the tip moves during motion because of the
   per-run slow drift of tendon gains and motor offsets (invisible to the
   motors for the gains), from simulating the same runs with the drift
   switched off (``make_benchmark(run_variation=...)``); and PDL / PDL+GRU on
   that drift-free copy of the catheter.

``--parts ablation`` runs only the first two models of part 3 (no and
learned context) with the learner's own sweep frame. ``--parts memory`` (not
run by default): the same setting-held-out PDL+GRU trained on longer windows
or on whole motion sequences, to see whether a longer training memory lowers
the error.

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
from sklearn.base import clone
from sklearn.linear_model import RidgeCV
from sklearn.model_selection import GroupKFold, cross_val_predict
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone
from skcath.datasets import benchmark_catheter, make_benchmark, setting_parameters, shaft_settings
from skcath.frames import sweep_frame
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


def oracle_vector(catheter, setting):
    """The true parameters of a unit in a shaft setting as one vector (28 numbers).

    Gains (4), offsets (2), resting bend (2), coupling (2), twist, the
    setting-dependent routing (amplitudes and the phase of the first
    harmonic as cos, sin: 5), wind-up, no-load play width (2), play growth
    (2), dead zone (2), capstan exponents (2), bend direction (cos, sin) and
    wrap (rad).
    """
    p = setting_parameters(catheter, setting)
    route = p["routing"]
    return np.r_[
        p["gains"].ravel(), p["offsets"], p["rest_bend"], p["coupling"], p["twist"],
        route[0], np.cos(route[1]), np.sin(route[1]), route[2], route[4], p["windup"],
        p["w0"], p["growth"], p["dead_zone"], p["capstan_exponent"],
        setting.bend_vector(), setting.wrap,
    ]


def _run_settings(runs, random_state=0):
    """(run id, unit, shaft setting) of every run of a benchmark's ``runs`` table."""
    settings = {s.name: s for s in shaft_settings()}
    units = {name: benchmark_catheter(int(name[1:]), random_state) for name in runs["catheter"].unique()}
    for run, cat, setting in runs[["run", "catheter", "setting"]].itertuples(index=False):
        yield str(run), units[cat], settings[setting]


def run_truth(runs, random_state=0):
    """Probe targets of every run of a benchmark's ``runs`` table, indexed by run id.

    The setting's targets (:func:`setting_truth`) and the run's own offset
    and gain drift of axis 1 at its first motion sample (jitter plus slow
    drift), which the ``runs`` table holds.
    """
    rows = {run: setting_truth(unit, setting) for run, unit, setting in _run_settings(runs, random_state)}
    truth = pd.DataFrame.from_dict(rows, orient="index")
    own = runs.set_index(runs["run"].astype(str))
    truth["run offset drift at motion start, axis 1 (deg)"] = own["offset_drift1_deg"]
    truth["run gain drift at motion start, axis 1"] = own["gain_drift1"]
    return truth


def run_oracles(runs, random_state=0):
    """:func:`oracle_vector` of every run of a ``runs`` table (one row per run id)."""
    rows = {run: oracle_vector(unit, setting) for run, unit, setting in _run_settings(runs, random_state)}
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
    """The context ``z`` of every run of ``Xb``, one row per run id (order of first appearance)."""
    return pd.DataFrame(model.encode_context(Xb), index=pd.unique(Xb["run"].astype(str)))


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
        print(f"  {name}: {rows[-1]['RMSE (mm)']:.3f} mm ({rows[-1]['seconds']:.0f} s)", flush=True)
    out = pd.DataFrame(rows).set_index("model")
    out["ratio to PDL"] = out["RMSE (mm)"] / out["RMSE (mm)"].iloc[0]
    return out


# --------------------------------------------------------------------------- oracle
def sweep_frames(X):
    """Rotation ``R_SB`` of every row's run, from the run's sweep as the learners compute it.

    ``skcath.frames.sweep_frame`` on the sweep rows' motor angles and nominal
    tips ``b`` (the learners' ``frame="sweep"``); shape (n_rows, 3, 3).
    """
    runs = X["run"].astype(str).to_numpy()
    sweep = (X["phase"] == "sweep").to_numpy()
    q, b = X[["q1", "q2"]].to_numpy(), X[list(BACKBONE_COLUMNS)].to_numpy()
    frames = {run: sweep_frame(q[sweep & (runs == run)], b[sweep & (runs == run)], run=run)
              for run in pd.unique(runs)}
    return np.stack([frames[run] for run in runs])


class KnownContext:
    """PDL+GRU in the runs' sweep frames, its context encoder told given per-run vectors.

    A diagnosis device on the learner's public API. The learner sees each
    run in its sweep frame (nominal tips, references and targets rotated by
    :func:`sweep_frames`, ``frame="base"``), which is what its default
    ``frame="sweep"`` does, and the residual is rotated back and clipped as
    the learner does it. With ``known``, each run's vector, standardised
    over the runs of ``known``, reaches the encoder as sweep rows: two
    numbers per block of ``sweep_stride_s`` (in rows) in the torque columns, the
    motor columns held at the sweep's last angles (so that the first motion
    step keeps its true ``dq``), placed before the run's sweep
    (``keep_sweep``) or instead of it.

    Parameters
    ----------
    learner : GRUResidual
        The residual learner (its ``frame`` and ``clip`` are handled here).
    known : pandas.DataFrame or None
        One row per run id; None gives the learner the sweep alone.
    keep_sweep : bool
        Keep the run's own sweep after the known rows.
    """

    def __init__(self, learner, known=None, keep_sweep=True):
        self.learner = learner
        self.known = known
        self.keep_sweep = keep_sweep

    def _recordings(self, X, y=None):
        """Rotated recordings with the known rows, their targets and source rows (-1: added)."""
        R = sweep_frames(X)
        Xs = X.copy()
        for cols in (list(BACKBONE_COLUMNS), ["ref_x", "ref_y", "ref_z"]):
            Xs[cols] = np.einsum("nij,nj->ni", R, X[cols].to_numpy())
        ys = None if y is None else np.einsum("nij,nj->ni", R, y)
        source = np.arange(len(X))
        if self.known is not None:
            Xs, ys, source = self._with_known(Xs, ys)
        return Xs, ys, source, R

    def _with_known(self, X, y):
        z = self.known.to_numpy(dtype=float)
        scale = z.std(axis=0)
        z = (z - z.mean(axis=0)) / np.where(scale > 0, scale, 1.0)
        z = pd.DataFrame(np.c_[z, np.zeros((len(z), len(z.T) % 2))], index=self.known.index)
        stride = round(self.learner.sweep_stride_s * 10.0)  # samples of the 10 Hz runs
        parts, targets, sources = [], [], []
        runs = X["run"].astype(str).to_numpy()
        sweep = (X["phase"] == "sweep").to_numpy()
        for run in pd.unique(runs):
            rows = np.flatnonzero(runs == run)
            last = rows[sweep[rows]][-1]
            block = np.repeat(z.loc[run].to_numpy().reshape(-1, 2), stride, axis=0)
            added = X.iloc[np.full(len(block), last)].copy()
            added[["tau1", "tau2"]] = self.tau_mean_ + self.tau_scale_ * block
            added[["ref_x", "ref_y", "ref_z"]] = np.nan
            kept = rows if self.keep_sweep else rows[~sweep[rows]]
            first = X["t"].iloc[rows[0]] if self.keep_sweep else X["t"].iloc[last]
            step = 1.0 if self.keep_sweep else 0.0
            added["t"] = first - self.dt_ * (len(block) - np.arange(len(block)) - 1 + step)
            parts += [added, X.iloc[kept]]
            sources += [np.full(len(block), -1), kept]
            if y is not None:
                targets += [np.full((len(block), 3), np.nan), y[kept]]
        out = pd.concat(parts, ignore_index=True)
        for col in ("catheter", "setting", "run", "phase"):
            out[col] = out[col].astype(X[col].dtype)
        return out, (None if y is None else np.concatenate(targets)), np.concatenate(sources)

    def fit(self, X, y):
        sweep = (X["phase"] == "sweep").to_numpy()
        tau = X.loc[sweep, ["tau1", "tau2"]].to_numpy()
        # the added rows on the scale of the sweep torques (or as they are, without the sweep)
        self.tau_mean_ = tau.mean(axis=0) if self.keep_sweep else 0.0
        self.tau_scale_ = tau.std(axis=0) if self.keep_sweep else 1.0
        self.dt_ = float(np.median(np.diff(X["t"].to_numpy())))  # the sampling interval
        Xs, ys, _, _ = self._recordings(X, y)
        self.learner_ = clone(self.learner).set_params(frame="base", clip=None).fit(Xs, ys)
        return self

    def predict(self, X):
        Xs, _, source, R = self._recordings(X)
        r_sweep = np.empty((len(X), 3))
        r_sweep[source[source >= 0]] = self.learner_.predict_residual(Xs)[source >= 0]
        r = np.einsum("nji,nj->ni", R, r_sweep)
        if self.learner.clip is not None:
            r = np.clip(r, -self.learner.clip, self.learner.clip)
        return X[list(BACKBONE_COLUMNS)].to_numpy() + r


def oracle_bound(Xb, y, oracles, epochs, seed):
    """Setting-held-out RMSE of PDL+GRU with no, learned, oracle and both contexts."""
    common = {"max_epochs": epochs, "module__hidden_size": 64, "random_state": seed, "n_threads": 1}
    return _cross_validate(Xb, y, {
        "no context": lambda: KnownContext(GRUResidual(use_context=False, **common)),
        "learned context (default)": lambda: KnownContext(GRUResidual(**common)),
        "oracle setting parameters": lambda: KnownContext(GRUResidual(**common), oracles, False),
        "oracle + learned": lambda: KnownContext(GRUResidual(**common), oracles, True),
    })


# --------------------------------------------------------------------------- memory
def memory(Xb, y, epochs, seed):
    """Setting-held-out RMSE of PDL+GRU trained on longer windows or whole sequences."""
    common = {"max_epochs": epochs, "module__hidden_size": 64, "random_state": seed, "n_threads": 1}
    return _cross_validate(Xb, y, {
        "windows of 200 steps (default)": lambda: GRUResidual(**common),
        "windows of 600 steps, burn-in 100": lambda: GRUResidual(window_s=60.0, burn_in_s=10.0, **common),
        "whole motion sequences, 8 per batch": lambda: GRUResidual(window_s=None, batch_size=8, **common),
    })


# --------------------------------------------------------------------------- drift
def simulate_catheter(catheter, run_variation=None):
    """The benchmark's runs of one catheter, simulated again with changed run variation.

    Without a change the result equals the benchmark's rows of that catheter:
    same seeds, same field distortion.
    """
    unit = benchmark_catheter(int(catheter[1:]))
    return make_benchmark(catheters=[unit], run_variation=run_variation, cache=False)


def drift_motion(catheter):
    """How far the tip moves during motion when the per-run drift is switched off (mm, per kind)."""
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
    return pd.DataFrame(rows).set_index("removed")


def drift_free_learners(catheter, epochs, seed):
    """PDL / PDL+GRU without and with context on the drift-free copy of a catheter."""
    calm = simulate_catheter(catheter, DRIFTS["gain and offset drift"])
    Xb = PDLBackbone(n_jobs=1).fit(calm.X).transform(calm.X)
    return context_ablation(Xb, np.asarray(calm.y), epochs, seed)


# --------------------------------------------------------------------------- main
def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--catheter", default="C1")
    parser.add_argument("--epochs", type=int, default=25, help="GRU epochs per fit (default 25)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", nargs="+", default=["probe", "context", "oracle", "drift"],
                        choices=["probe", "context", "oracle", "ablation", "drift", "memory"])
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
    if {"context", "oracle", "ablation", "memory"} & set(args.parts):
        Xb = PDLBackbone(n_jobs=1).fit(X).transform(X)
    if "context" in args.parts:
        print(f"\n## 2. Context probe: R^2 from the learned z ({args.catheter}, {args.epochs} epochs)")
        print(run_context_probe(Xb, y, truth, args.epochs, args.seed).round(2).to_string())
    if "oracle" in args.parts:
        print(f"\n## 3. Oracle bound: PDL+GRU, settings held out within {args.catheter} (4 folds)")
        oracles = run_oracles(data.runs[data.runs["catheter"] == args.catheter])
        print(oracle_bound(Xb, y, oracles, args.epochs, args.seed).round(3).to_string())
    if "ablation" in args.parts:
        print(f"\n## 3. Context ablation: PDL+GRU, settings held out within {args.catheter} (4 folds)")
        print(context_ablation(Xb, y, args.epochs, args.seed).round(3).to_string())
    if "memory" in args.parts:
        print(f"\n## 5. Memory: longer training windows, settings held out within {args.catheter}")
        print(memory(Xb, y, args.epochs, args.seed).round(3).to_string())
    if "drift" in args.parts:
        print(f"\n## 4. Drift floor ({args.catheter})")
        print(drift_motion(args.catheter).round(2).to_string(), flush=True)
        print("\nthe same catheter simulated without gain and offset drift, settings held out:")
        print(drift_free_learners(args.catheter, args.epochs, args.seed).round(3).to_string())


if __name__ == "__main__":
    main()
