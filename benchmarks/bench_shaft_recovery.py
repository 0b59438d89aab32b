"""Recovery after a shaft change without the tracker: a motor-only re-sweep.

On the simulated benchmark with every shaft repositioned during the motion and
a re-sweep at the change (``make_benchmark(shaft_change=True, resweep=True)``:
the part after the change is the run ``"<run>/after"``, its sweep rows the
re-sweep), this script

1. pretrains PDL+GRU on the *default* benchmark as the protocol pretrains its
   catheter-held-out model (the full schedule, :data:`skcath.protocol.FULL`,
   one seed): for each catheter, a model trained on the runs of the three
   other catheters, so that neither the tested catheter's settings nor its
   runs' motor trajectories were seen in training;
2. streams, for every changed run of the tested catheter, the motion after
   the re-sweep through :class:`skcath.online.OnlineEstimator`, one sample at
   a time, with the recurrent state restarted at the end of the re-sweep:

   (a) **stale**: started on the run's first sweep (calibration and context
       of the old shaft configuration);
   (b) **motor-only re-sweep**: the same, then ``resweep`` on the re-sweep
       without its reference columns (new context, kept calibration);
   (c) **tracked re-sweep**: ``start`` on the tracked re-sweep (new
       calibration and context), the bound;
   (d) **motor-only re-sweep with a recalibration**: ``resweep`` with a
       :class:`skcath.online.MotorRecalibration` fitted on the tracked
       sweeps of the default benchmark's three other catheters (the same
       catheters as the model), which renews the calibration from the
       motors as well;

   and the backbone alone, with the old (stale), the new (tracked) and the
   recalibrated calibration; the gap closed is ``(a - b) / (a - c)``, and
   ``(a - d) / (a - c)`` with the recalibration;
3. diagnoses the gap with two probes: the same network with the *new*
   calibration and the *old* context (the backbone's share of the gap), and
   how well the context ``z`` predicts the backbone's calibration (the
   calibrated PDL tip at 16 motor angles: 8 directions at 30 and 60 deg),
   by ridge regression cross-validated with one setting held out at a time
   within each catheter, from the first sweeps and from the re-sweeps, and
   the change of that calibration from the change of ``z``;
4. prints the tables in Markdown, with catheter ``C1`` (the development
   catheter, on which the setup was chosen) apart from the held-out
   ``C2``-``C4``, and draws the figure (``--figure``): the errors by
   catheter, the probe among them, and the error over time after the
   re-sweep on the held-out catheters.

Every model and the streaming use one torch thread; ``--n-jobs`` pretrains
that many models at once.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_shaft_recovery.py --n-jobs 2
    .venv/bin/python benchmarks/bench_shaft_recovery.py --models models/  # keep the pretrained models

The tip error is the mean per-run RMSE (mm) over the motion rows after the
re-sweep with a finite measured tip, runs weighted equally.
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
from sklearn.linear_model import RidgeCV
from sklearn.metrics import r2_score
from sklearn.model_selection import LeaveOneGroupOut, cross_val_predict
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler

from skcath import persist
from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone, pdl_tip
from skcath.datasets import make_benchmark
from skcath.online import MotorRecalibration, OnlineEstimator
from skcath.protocol import FULL, learner_input, pretrain_models, protocol_folds

VARIANT = "PDL+GRU"
REFERENCE = ["ref_x", "ref_y", "ref_z"]
CHANNELS = ["q1", "q2", "tau1", "tau2"]
#: The columns of the error table, in order: name -> what it is.
METHODS = {
    "PDL stale": "backbone alone, calibrated on the first sweep",
    "PDL tracked": "backbone alone, calibrated on the tracked re-sweep",
    "GRU before": "PDL+GRU before the change (first sweep, motion before the change)",
    "GRU stale": "(a) PDL+GRU, calibration and context of the first sweep",
    "GRU motor-only": "(b) PDL+GRU, kept calibration, context of the re-sweep (resweep)",
    "GRU tracked": "(c) PDL+GRU started on the tracked re-sweep",
    "PDL recalibrated": "backbone alone, calibration renewed from the motors (MotorRecalibration)",
    "GRU recalibrated": "(d) PDL+GRU, resweep with the calibration renewed from the motors",
    "GRU new calibration, old context": "probe: calibration of the re-sweep, context of the first sweep",
}
#: Motor angles of the calibration probe: 8 directions at 30 and 60 deg.
_PSI = np.deg2rad(np.arange(0.0, 360.0, 45.0))
PROBE_ANGLES = np.concatenate([r * np.column_stack([np.cos(_PSI), np.sin(_PSI)]) for r in (30.0, 60.0)])


def _pretrained(X_learner, y, seed, n_jobs, models_dir):
    """The catheter-held-out PDL+GRU of every catheter (full schedule, one seed), by catheter."""
    schedule = dataclasses.replace(FULL, name="recovery", seeds=(seed,), variants=(VARIANT,))
    folds = protocol_folds(X_learner, schedule, exclude_settings="S00").loco
    paths = {f.catheter: None if models_dir is None else Path(models_dir) / f"{VARIANT}-seed{seed}-{f.catheter}.skcath"
             for f in folds}
    if all(p is not None and p.exists() for p in paths.values()):
        # this script's own files, joblib when kept by earlier versions
        return {c: persist.load(p, allow_pickle=True) for c, p in paths.items()}, 0.0
    start = time.perf_counter()
    result = pretrain_models(X_learner, y, folds, schedule, n_jobs=n_jobs, verbose=True)
    models = {c: result.models[VARIANT, seed, c] for c in paths}
    for c, p in paths.items():
        if p is not None:
            p.parent.mkdir(parents=True, exist_ok=True)
            persist.save(models[c], p)
    return models, time.perf_counter() - start


def _pairs(data):
    """Per changed run: catheter, first sweep, tracked re-sweep, motion before and after the change."""
    X = data.X
    rows = {run: X[(X["run"] == run).to_numpy()] for run in data.runs["run"]}
    for _, after_row in data.runs[data.runs["before_run"].notna()].iterrows():
        before, after = rows[after_row["before_run"]], rows[after_row["run"]]
        sweep_b = (before["phase"] == "sweep").to_numpy()
        sweep_a = (after["phase"] == "sweep").to_numpy()
        yield {
            "run": after_row["before_run"],
            "catheter": after_row["catheter"],
            "setting": before["setting"].iloc[0],
            "setting_after": after_row["setting"],
            "first": before[sweep_b],
            "before": before[~sweep_b],
            "resweep": after[sweep_a],
            "after": after[~sweep_a],
            "y_before": data.y[before.index[~sweep_b]],
            "y_after": data.y[after.index[~sweep_a]],
        }


def _stream(est, motion):
    """Tips and backbone tips of stepping ``est`` through the motion rows, from a zero state."""
    est.reset()
    tips, nominal = [], []
    for sample in motion[CHANNELS].to_numpy().tolist():
        tips.append(est.step(*sample).copy())
        nominal.append(est.nominal_.copy())
    return np.array(tips), np.array(nominal)


def _rmse(pred, y):
    """RMSE (mm) over the rows with a finite measured tip, and the per-sample errors."""
    err = np.linalg.norm(pred - y, axis=1)
    return float(np.sqrt(np.nanmean(err**2))), err


def _new_calibration_old_context(model, pair, params):
    """Batch tips with the re-sweep's calibration and the first sweep's context (the probe)."""
    ids = {c: str(pair["first"][c].iloc[0]) for c in ("catheter", "setting", "run")}
    frame = pd.concat([pair["first"].assign(**ids), pair["after"].assign(**ids)])
    frame = frame.assign(phase=frame["phase"].astype(str))
    nominal = pdl_tip(frame[["q1", "q2"]].to_numpy(), params)
    frame = frame.assign(**{c: nominal[:, k] for k, c in enumerate(BACKBONE_COLUMNS)})
    return model.predict(frame)[len(pair["first"]):]


def _recalibrations(X_default, catheters):
    """Per catheter: a MotorRecalibration fitted on the tracked sweeps of the other catheters, and its fit time."""
    sweeps = X_default[(X_default["phase"] == "sweep").to_numpy()]
    out = {}
    for catheter in catheters:
        start = time.perf_counter()
        recalibration = MotorRecalibration().fit(sweeps[(sweeps["catheter"] != catheter).to_numpy()])
        out[catheter] = recalibration, time.perf_counter() - start
        print(f"recalibration for {catheter}: alpha {recalibration.alpha_:g}, held-out-catheter "
              f"grid error {recalibration.cv_rmse_[recalibration.alpha_]:.2f} mm against a change of "
              f"{recalibration.change_rmse_:.2f} mm ({recalibration.n_pairs_} pairs, "
              f"{out[catheter][1]:.0f} s)", flush=True)
    return out


def _evaluate(models, recalibrations, data, engine):
    """Per changed run: the errors of every method, the cost of the re-sweeps, and the probe's inputs."""
    backbone = PDLBackbone().fit(data.X)
    rows, traces, sweeps = [], [], []
    for pair in _pairs(data):
        model = models[pair["catheter"]]
        pipe = Pipeline([("backbone", backbone), ("residual", model)])
        est = OnlineEstimator(pipe, engine=engine)
        y = pair["y_after"]
        row = {k: pair[k] for k in ("run", "catheter", "setting", "setting_after")}
        est.start(pair["first"])
        old_params, z_old = est.backbone_params_, est.context_
        row["GRU before"] = _rmse(_stream(est, pair["before"])[0], pair["y_before"])[0]
        tips, nominal = _stream(est, pair["after"])
        row["GRU stale"], err_stale = _rmse(tips, y)
        row["PDL stale"] = _rmse(nominal, y)[0]
        start = time.perf_counter()
        est.resweep(pair["resweep"].drop(columns=REFERENCE))
        row["resweep s"] = time.perf_counter() - start
        row["GRU motor-only"], err_motor = _rmse(_stream(est, pair["after"])[0], y)
        est.start(pair["first"])
        start = time.perf_counter()
        est.resweep(pair["resweep"].drop(columns=REFERENCE),
                    recalibration=recalibrations[pair["catheter"]][0])
        row["recalibrate s"] = time.perf_counter() - start
        tips, nominal = _stream(est, pair["after"])
        row["GRU recalibrated"], err_recal = _rmse(tips, y)
        row["PDL recalibrated"] = _rmse(nominal, y)[0]
        start = time.perf_counter()
        est.start(pair["resweep"])
        row["start s"] = time.perf_counter() - start
        tips, nominal = _stream(est, pair["after"])
        row["GRU tracked"], err_tracked = _rmse(tips, y)
        row["PDL tracked"] = _rmse(nominal, y)[0]
        new_params, z_new = est.backbone_params_, est.context_
        probe = _new_calibration_old_context(model, pair, new_params)
        row["GRU new calibration, old context"] = _rmse(probe, y)[0]
        rows.append(row)
        t = pair["after"]["t"].to_numpy()
        traces.append(pd.DataFrame({"catheter": pair["catheter"], "run": pair["run"], "t": t - t[0],
                                    "stale": err_stale, "motor-only": err_motor, "tracked": err_tracked,
                                    "recalibrated": err_recal}))
        for kind, z, params, setting in (("first", z_old, old_params, pair["setting"]),
                                         ("resweep", z_new, new_params, pair["setting_after"])):
            sweeps.append({"catheter": pair["catheter"], "run": pair["run"], "kind": kind,
                           "setting": setting, "z": z, "signature": pdl_tip(PROBE_ANGLES, params).ravel()})
    return pd.DataFrame(rows), pd.concat(traces, ignore_index=True), pd.DataFrame(sweeps)


def _error_table(errors, dev):
    """Mean per-run RMSE (mm) of every method by catheter and for the held-out catheters, and the gap closed."""
    groups = [(f"{c} (development)" if c == dev else c, errors[errors["catheter"] == c])
              for c in sorted(errors["catheter"].unique())]
    held_out = sorted(c for c in errors["catheter"].unique() if c != dev)
    groups.append((f"held out ({', '.join(held_out)})", errors[errors["catheter"] != dev]))
    out = []
    for label, group in groups:
        mean = group[list(METHODS)].mean()
        a, b, c = mean["GRU stale"], mean["GRU motor-only"], mean["GRU tracked"]
        d = mean["GRU recalibrated"]
        out.append({"catheters": label, "runs": len(group), **mean.to_dict(),
                    "gap closed": (a - b) / (a - c), "gap closed, recalibrated": (a - d) / (a - c)})
    return pd.DataFrame(out)


def _ridge_r2(X, Y, groups):
    """R^2 (variance-weighted) of a ridge regression of Y on X, one group held out at a time."""
    model = make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-3, 3, 13)))
    pred = cross_val_predict(model, X, Y, groups=groups, cv=LeaveOneGroupOut())
    return r2_score(Y, pred, multioutput="variance_weighted")


def _probe_table(sweeps, dev):
    """How well the context predicts the backbone's calibration, per catheter."""
    out = []
    for catheter, group in sweeps.groupby("catheter"):
        row = {"catheter": f"{catheter} (development)" if catheter == dev else catheter}
        for kind in ("first", "resweep"):
            part = group[group["kind"] == kind]
            row[f"z -> calibration, {kind} sweeps"] = _ridge_r2(
                np.stack(part["z"]), np.stack(part["signature"]), part["setting"].to_numpy()
            )
        first = group[group["kind"] == "first"].set_index("run")
        second = group[group["kind"] == "resweep"].set_index("run").loc[first.index]
        dz = np.stack(second["z"]) - np.stack(first["z"])
        ds = np.stack(second["signature"]) - np.stack(first["signature"])
        row["change of z -> change of calibration"] = _ridge_r2(dz, ds, second["setting"].to_numpy())
        row["calibration change (mm RMS)"] = float(np.sqrt(np.mean(ds**2) * 3))
        out.append(row)
    return pd.DataFrame(out)


def _figure(table, traces, dev, path):
    """Bars of the error after the change, and the error over time after the re-sweep."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11.0, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax, ax_t = fig.subplots(1, 2, width_ratios=(1.2, 1.0))
    bars = ["PDL stale", "GRU stale", "GRU motor-only", "GRU new calibration, old context",
            "GRU recalibrated", "GRU tracked", "PDL tracked"]
    colours = ["#bbbbbb", "#d62728", "#ff7f0e", "#ffffff", "#1f77b4", "#2ca02c", "#7f7f7f"]
    width = 0.8 / len(bars)
    x = np.arange(len(table))
    for k, (name, colour) in enumerate(zip(bars, colours)):
        probe = name.startswith("GRU new calibration")
        ax.bar(x + (k - (len(bars) - 1) / 2) * width, table[name], width, color=colour,
               label=f"probe: {name[4:]}" if probe else name,
               edgecolor="#2ca02c" if probe else None, hatch="///" if probe else None)
    ax.set_xticks(x, [label.replace(" (", "\n(") for label in table["catheters"]])
    ax.set_ylabel("tip error after the change (mm, mean per-run RMSE)")
    ax.set_ylim(0.0, 1.35 * float(table[bars].to_numpy().max()))
    ax.legend(frameon=False, fontsize=8, ncol=3, loc="upper center")
    names = ["stale", "motor-only", "recalibrated", "tracked"]  # the streamed methods (a), (b), (d), (c)
    held = traces[traces["catheter"] != dev].copy()
    held["bin"] = (held["t"] // 10.0) * 10.0 + 5.0
    held[names] = held[names] ** 2
    per_run = held.groupby(["bin", "run"])[names].mean() ** 0.5
    curves = per_run.groupby(level="bin").mean()
    reach = per_run.groupby(level="bin").size()
    curves = curves[reach >= 0.9 * held["run"].nunique()]  # bins reached by 90 % of the runs
    for name, colour in zip(names, [colours[1], colours[2], colours[4], colours[5]]):
        ax_t.plot(curves.index, curves[name], color=colour, label=f"GRU {name}")
    ax_t.set_xlabel("time since the end of the re-sweep (s)")
    ax_t.set_ylabel("tip error (mm, mean of run RMSE per 10 s bin)")
    ax_t.set_ylim(bottom=0.0)
    ax_t.set_title("held-out catheters", fontsize=10)
    ax_t.legend(frameon=False, fontsize=8, loc="center right")
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-jobs", type=int, default=1, help="models pretrained in parallel")
    parser.add_argument("--engine", default="auto", choices=("auto", "numba", "numpy"))
    parser.add_argument("--dev-catheter", default="C1")
    parser.add_argument("--models", default=None, help="folder to keep the pretrained models in")
    parser.add_argument("--figure", default="docs/_static/shaft_recovery.png")
    args = parser.parse_args()

    torch.set_num_threads(1)  # the streaming and the probe; each pretrained model uses one thread too
    for line in machine_lines():
        print(line)
    wall = time.perf_counter()
    default = make_benchmark()
    changed = make_benchmark(shaft_change=True, resweep=True, cache=False)
    t_data = time.perf_counter() - wall
    start = time.perf_counter()
    X_learner = learner_input(default.X)
    t_backbone = time.perf_counter() - start
    models, t_pretrain = _pretrained(X_learner, default.y, args.seed, args.n_jobs, args.models)
    recalibrations = _recalibrations(default.X, sorted(models))
    start = time.perf_counter()
    errors, traces, sweeps = _evaluate(models, recalibrations, changed, args.engine)
    t_eval = time.perf_counter() - start
    print(
        f"\ndata {t_data:.0f} s, backbone calibration of the training runs {t_backbone:.0f} s, "
        f"pretraining {t_pretrain:.0f} s ({VARIANT}, {len(models)} models, seed {args.seed}), "
        f"streaming {t_eval:.0f} s ({len(errors)} changed runs); total {time.perf_counter() - wall:.0f} s"
    )
    print(
        f"cost per re-sweep (s, median [max] over runs): motor-only resweep "
        f"{errors['resweep s'].median():.2f} [{errors['resweep s'].max():.2f}], with the "
        f"recalibration {errors['recalibrate s'].median():.2f} [{errors['recalibrate s'].max():.2f}] "
        f"(fitting it: {np.median([t for _, t in recalibrations.values()]):.0f} s per catheter), "
        f"tracked start "
        f"{errors['start s'].median():.2f} [{errors['start s'].max():.2f}]\n"
    )
    for name, meaning in METHODS.items():
        print(f"- {name}: {meaning}")
    table = _error_table(errors, args.dev_catheter)
    print("\n### Tip error after the change (mm, mean per-run RMSE)\n")
    print(table.to_markdown(index=False, floatfmt=".2f"))
    held = errors[errors["catheter"] != args.dev_catheter]
    gap = (held["GRU stale"] - held["GRU motor-only"]) / (held["GRU stale"] - held["GRU tracked"])
    print(f"\nheld out, per run: gap closed median {gap.median():.2f} "
          f"[p10 {gap.quantile(0.1):.2f}, p90 {gap.quantile(0.9):.2f}]; motor-only better than "
          f"stale in {(held['GRU motor-only'] < held['GRU stale']).mean():.0%} of the runs")
    gap = (held["GRU stale"] - held["GRU recalibrated"]) / (held["GRU stale"] - held["GRU tracked"])
    print(f"with the recalibration: gap closed median {gap.median():.2f} "
          f"[p10 {gap.quantile(0.1):.2f}, p90 {gap.quantile(0.9):.2f}]; better than stale in "
          f"{(held['GRU recalibrated'] < held['GRU stale']).mean():.0%} of the runs, better than "
          f"the motor-only re-sweep in {(held['GRU recalibrated'] < held['GRU motor-only']).mean():.0%}")
    print("\n### What the context carries about the calibration (R^2, one setting held out)\n")
    print(_probe_table(sweeps, args.dev_catheter).to_markdown(index=False, floatfmt=".2f"))
    if args.figure:
        _figure(table, traces, args.dev_catheter, args.figure)
        print(f"\nfigure: {args.figure}")


if __name__ == "__main__":
    main()
