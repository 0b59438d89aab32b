"""Tables of the protocol's results, computed from held-out predictions.

Learned methods are evaluated per seed and their errors averaged over the
seeds (per run, per CDF point, per run-bin), as in the paper.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .. import _format as fmt
from ..metrics import (
    error_cdf,
    paired_reduction,
    per_run_rmse,
    rmse_by_motor_magnitude,
    rmse_over_time,
)
from ._protocol import LOCO_METHOD

__all__ = ["compute_tables", "MAIN_METHODS", "COMPARISONS", "TORQUE_CONTEXT"]

#: Methods of Table I and of the distribution figures.
MAIN_METHODS = ("PCC", "PDL", "PDL+GRU")

#: Table II: (torque, context) -> method.
TORQUE_CONTEXT = {
    ("No", "No"): "PDL+GRU (no torque, no context)",
    ("Yes", "No"): "PDL+GRU (no context)",
    ("No", "Yes"): "PDL+GRU (no torque)",
    ("Yes", "Yes"): "PDL+GRU",
}

#: Paired comparisons: label -> (baseline, candidate); the reduction is baseline - candidate.
COMPARISONS = {
    "PCC -> PDL+GRU": ("PCC", "PDL+GRU"),
    "PDL -> PDL+GRU": ("PDL", "PDL+GRU"),
    "PDL+MLP -> PDL+GRU": ("PDL+MLP", "PDL+GRU"),
    "torque (with context)": ("PDL+GRU (no torque)", "PDL+GRU"),
    "torque (without context)": ("PDL+GRU (no torque, no context)", "PDL+GRU (no context)"),
    "context (with torque)": ("PDL+GRU (no context)", "PDL+GRU"),
    "context (without torque)": ("PDL+GRU (no torque, no context)", "PDL+GRU (no torque)"),
    "catheter held out -> setting held out": (LOCO_METHOD, "PDL+GRU"),
}

#: Grid of the error CDF (mm).
CDF_GRID = np.round(np.arange(0.0, 30.0 + 1e-9, 0.25), 2)


def _seed_mean(frames, keys, value="rmse_mm"):
    """Average the ``value`` column of per-seed long tables over seeds, per key."""
    table = pd.concat(frames, ignore_index=True)
    return table.groupby(keys, sort=False, observed=True)[value].mean().reset_index()


#: Time bins are shown only where at least this fraction of the runs still has motion.
TIME_COVERAGE = 0.9


def _covered_bins(bins, n_runs):
    """Drop the late time bins that only the longest runs reach (their means are not comparable)."""
    counts = bins.groupby(["method", "bin_left"], sort=False)[fmt.RUN].transform("nunique")
    return bins[counts >= TIME_COVERAGE * n_runs].reset_index(drop=True)


def _run_info(X):
    runs = X.drop_duplicates(fmt.RUN)[[fmt.RUN, fmt.CATHETER, fmt.SETTING]].copy()
    for column in runs:
        runs[column] = runs[column].astype(str)
    return runs.set_index(fmt.RUN)


def _by_catheter(run_rmse, methods, catheters):
    """Mean per-run RMSE per catheter and pooled (rows: methods)."""
    rows = {}
    for method in methods:
        sub = run_rmse[run_rmse["method"] == method]
        if sub.empty:
            continue
        row = sub.groupby("catheter", sort=False)["rmse_mm"].mean().reindex(catheters)
        row["pooled"] = sub["rmse_mm"].mean()
        rows[method] = row
    return pd.DataFrame(rows).T


def compute_tables(result, *, n_bootstrap=2000, random_state=0):
    """Every table of the protocol from :func:`run_protocol`'s result.

    Parameters
    ----------
    result : sklearn.utils.Bunch
        Output of :func:`run_protocol`.
    n_bootstrap : int, default=2000
        Resamples of the setting-cluster bootstrap of paired reductions.
    random_state : int, default=0
        Seed of the bootstrap.

    Returns
    -------
    tables : dict of pandas.DataFrame
        ``table_1`` (PCC, PDL, PDL+GRU: mean per-run RMSE per catheter and
        pooled, mm), ``table_2`` (torque x context ablation), ``residual_learners``
        (PDL+MLP vs PDL+GRU), ``loco`` (catheter held out), ``cdf_at_5mm`` (%),
        ``magnitude`` (median run-bin RMSE per 10 deg bin), ``time`` (mean
        run-bin RMSE per 10 s bin), ``paired`` (paired reductions with 95 %
        setting-cluster intervals), and the long tables the figures use:
        ``run_rmse``, ``run_rmse_by_seed``, ``cdf``, ``magnitude_bins``,
        ``time_bins``, ``example``.
    """
    X, y, predictions = result.X, result.y, result.predictions
    info = _run_info(X)
    catheters = list(pd.unique(info[fmt.CATHETER]))

    per_seed, run_tables, cdfs, mags, times = [], [], [], [], []
    for method, by_seed in predictions.items():
        seed_runs, seed_cdf, seed_mag, seed_time = [], [], [], []
        for seed, pred in by_seed.items():
            rmse = per_run_rmse(y, pred, X).rename("rmse_mm").reset_index()
            rmse[fmt.RUN] = rmse[fmt.RUN].astype(str)
            per_seed.append(rmse.assign(method=method, seed=seed))
            seed_runs.append(rmse)
            cdf = error_cdf(y, pred, X, CDF_GRID)
            seed_cdf.append(pd.DataFrame({"error_mm": cdf.index.to_numpy(), "fraction": cdf.to_numpy()}))
            for store, table in ((seed_mag, rmse_by_motor_magnitude(y, pred, X)),
                                 (seed_time, rmse_over_time(y, pred, X))):
                table = table.copy()
                table[fmt.RUN] = table[fmt.RUN].astype(str)
                store.append(table[[fmt.RUN, "bin_left", "bin_right", "rmse_mm"]])
        runs = _seed_mean(seed_runs, [fmt.RUN])
        runs = runs.join(info, on=fmt.RUN)
        run_tables.append(runs.assign(method=method))
        cdfs.append(_seed_mean(seed_cdf, ["error_mm"], "fraction").assign(method=method))
        mags.append(_seed_mean(seed_mag, [fmt.RUN, "bin_left", "bin_right"]).assign(method=method))
        times.append(_seed_mean(seed_time, [fmt.RUN, "bin_left", "bin_right"]).assign(method=method))

    run_rmse = pd.concat(run_tables, ignore_index=True)[
        ["method", fmt.CATHETER, fmt.SETTING, fmt.RUN, "rmse_mm"]]
    run_rmse_by_seed = pd.concat(per_seed, ignore_index=True)
    run_rmse_by_seed = run_rmse_by_seed.join(info, on=fmt.RUN)[
        ["method", "seed", fmt.CATHETER, fmt.SETTING, fmt.RUN, "rmse_mm"]]
    cdf = pd.concat(cdfs, ignore_index=True)[["method", "error_mm", "fraction"]]
    magnitude_bins = pd.concat(mags, ignore_index=True)[["method", fmt.RUN, "bin_left", "bin_right", "rmse_mm"]]
    time_bins = pd.concat(times, ignore_index=True)[["method", fmt.RUN, "bin_left", "bin_right", "rmse_mm"]]
    time_bins = _covered_bins(time_bins, len(info))

    tables = {
        "table_1": _by_catheter(run_rmse, MAIN_METHODS, catheters),
        "run_rmse": run_rmse,
        "run_rmse_by_seed": run_rmse_by_seed,
        "cdf": cdf,
        "magnitude_bins": magnitude_bins,
        "time_bins": time_bins,
    }
    table_2 = _by_catheter(run_rmse, TORQUE_CONTEXT.values(), catheters)
    if len(table_2) > 1:  # an ablation table needs at least one ablated variant
        names = {m: tc for tc, m in TORQUE_CONTEXT.items()}
        table_2.index = pd.MultiIndex.from_tuples([names[m] for m in table_2.index], names=["torque", "context"])
        tables["table_2"] = table_2

    wide = run_rmse.pivot(index=fmt.RUN, columns="method", values="rmse_mm")
    clusters = info[fmt.CATHETER] + "/" + info[fmt.SETTING]
    paired_rows = []
    for label, (base, cand) in COMPARISONS.items():
        if base not in wide or cand not in wide:
            continue
        for scope in [*catheters, "pooled"]:
            runs = wide.index if scope == "pooled" else info.index[info[fmt.CATHETER] == scope]
            runs = wide.index.intersection(runs)
            res = paired_reduction(
                wide.loc[runs, base], wide.loc[runs, cand], clusters.loc[runs],
                n_bootstrap=n_bootstrap, random_state=random_state,
            )
            paired_rows.append({
                "comparison": label, "baseline": base, "candidate": cand, "scope": scope,
                "reduction_mm": res.reduction_mm, "ci_low_mm": res.ci_low_mm, "ci_high_mm": res.ci_high_mm,
                "reduction_pct": res.reduction_pct, "fraction_improved": res.fraction_improved,
                "n_runs": res.n_runs,
            })
    paired = pd.DataFrame(paired_rows)
    tables["paired"] = paired

    if "PDL+MLP" in wide and "PDL+GRU" in wide:
        learners = _by_catheter(run_rmse, ("PDL+MLP", "PDL+GRU"), catheters)
        sub = paired[paired["comparison"] == "PDL+MLP -> PDL+GRU"].set_index("scope")
        for column in ("reduction_mm", "ci_low_mm", "ci_high_mm", "fraction_improved"):
            learners.loc[column] = sub[column].reindex(learners.columns)
        tables["residual_learners"] = learners

    if LOCO_METHOD in wide:
        loco = _by_catheter(run_rmse, ("PDL", "PDL+GRU", LOCO_METHOD), catheters)
        seeds = run_rmse_by_seed[run_rmse_by_seed["method"] == LOCO_METHOD]
        below = seeds.groupby(fmt.RUN)["rmse_mm"].mean() < 4.0
        below = below.to_frame("below").join(info)
        frac = below.groupby(fmt.CATHETER, sort=False)["below"].mean().reindex(catheters)
        frac["pooled"] = below["below"].mean()
        loco.loc["runs below 4 mm (LOCO, %)"] = 100 * frac
        tables["loco"] = loco

    at5 = cdf[np.isclose(cdf["error_mm"], 5.0)].set_index("method")["fraction"] * 100
    tables["cdf_at_5mm"] = at5.rename("samples below 5 mm (%)").to_frame()

    tables["magnitude"] = (
        magnitude_bins.groupby(["method", "bin_left", "bin_right"], sort=False)["rmse_mm"].median()
        .unstack("method").sort_index()
    )
    tables["time"] = (
        time_bins.groupby(["method", "bin_left", "bin_right"], sort=False)["rmse_mm"].mean()
        .unstack("method").sort_index()
    )
    tables["example"] = _motion_example(result, run_rmse)
    return tables


def _motion_example(result, run_rmse, method="PDL+GRU", seconds=60.0):
    """A 60 s motion segment of the run with the widest measured motion (chosen without looking at errors)."""
    if method not in result.predictions:
        method = "PDL"
    X, y = result.X, result.y
    motion = (X[fmt.PHASE] == fmt.MOTION).to_numpy() & np.isfinite(y).all(axis=1)
    runs = X[fmt.RUN].astype(str).to_numpy()
    extent = pd.DataFrame(y[motion], columns=list("xyz")).groupby(runs[motion], sort=False).agg(np.ptp).sum(axis=1)
    run = extent.idxmax()
    rows = np.flatnonzero(motion & (runs == run))
    t = X[fmt.TIME].to_numpy()[rows]
    t = t - t[0]
    keep = t <= seconds
    seed = next(iter(result.predictions[method]))
    pred = result.predictions[method][seed][rows][keep]
    frame = pd.DataFrame({"t": t[keep]})
    for k, axis in enumerate("xyz"):
        frame[f"p_{axis}"] = y[rows][keep, k]
    for k, axis in enumerate("xyz"):
        frame[f"phat_{axis}"] = pred[:, k]
    rmse = run_rmse[(run_rmse["method"] == method) & (run_rmse[fmt.RUN] == run)]["rmse_mm"]
    frame.attrs.update({"run": run, "method": method, "rmse_mm": float(rmse.iloc[0]), "seed": seed})
    return frame
