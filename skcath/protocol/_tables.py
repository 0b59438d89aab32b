"""Tables of the protocol's results, computed from held-out predictions.

Learned methods are evaluated per seed and their errors averaged over the
seeds (per run, per CDF point, per run-bin), as in the paper.
"""

from __future__ import annotations

from numbers import Integral

import numpy as np
import pandas as pd
from sklearn.utils import Bunch
from sklearn.utils._param_validation import Interval, validate_params

from .. import _format as fmt
from ..metrics import (
    error_cdf,
    paired_reduction,
    per_run_rmse,
    rmse_by_motor_magnitude,
    rmse_over_time,
)
from ._methods import (
    ADAPTED_METHOD,
    COMPARISONS,
    LOCO_METHOD,
    LOCO_METHODS,
    MAIN_METHODS,
    PROPOSED_METHOD,
    TORQUE_CONTEXT,
    backbone_method,
    comparison_label,
    methods_with_role,
)

__all__ = ["compute_tables"]

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


#: Per-seed tables averaged over the seeds: key -> (columns averaged over, value averaged).
_SEED_MEANS = {
    "runs": ([fmt.RUN], "rmse_mm"),
    "cdf": (["error_mm"], "fraction"),
    "magnitude": ([fmt.RUN, "bin_left", "bin_right"], "rmse_mm"),
    "time": ([fmt.RUN, "bin_left", "bin_right"], "rmse_mm"),
}


def _seed_tables(y, pred, X):
    """Per-run RMSE, error CDF and run-bin RMSE (motor magnitude, motion time) of one prediction."""
    rmse = per_run_rmse(y, pred, X).rename("rmse_mm").reset_index()
    rmse[fmt.RUN] = rmse[fmt.RUN].astype(str)
    cdf = error_cdf(y, pred, X, CDF_GRID)
    cdf = pd.DataFrame({"error_mm": cdf.index.to_numpy(), "fraction": cdf.to_numpy()})
    tables = {"runs": rmse, "cdf": cdf}
    binned = (("magnitude", rmse_by_motor_magnitude(y, pred, X)), ("time", rmse_over_time(y, pred, X)))
    for key, table in binned:
        table = table.copy()
        table[fmt.RUN] = table[fmt.RUN].astype(str)
        tables[key] = table[[fmt.RUN, "bin_left", "bin_right", "rmse_mm"]]
    return tables


def _method_tables(method, by_seed, y, X, info):
    """One method's tables averaged over its seeds, and its per-run RMSE of every seed (``by_seed``)."""
    per_seed = {seed: _seed_tables(y, pred, X) for seed, pred in by_seed.items()}
    tables = {
        key: _seed_mean([seeds[key] for seeds in per_seed.values()], keys, value)
        for key, (keys, value) in _SEED_MEANS.items()
    }
    tables["runs"] = tables["runs"].join(info, on=fmt.RUN)
    tables = {key: table.assign(method=method) for key, table in tables.items()}
    tables["by_seed"] = pd.concat(
        [seeds["runs"].assign(method=method, seed=seed) for seed, seeds in per_seed.items()],
        ignore_index=True,
    )
    return tables


def _long_tables(result, info):
    """The long tables of every method: one row per run (and seed, bin, CDF point)."""
    frames = {key: [] for key in (*_SEED_MEANS, "by_seed")}
    for method, by_seed in result.predictions.items():
        for key, table in _method_tables(method, by_seed, result.y, result.X, info).items():
            frames[key].append(table)
    joined = {key: pd.concat(tables, ignore_index=True) for key, tables in frames.items()}
    bins = ["method", fmt.RUN, "bin_left", "bin_right", "rmse_mm"]
    return {
        "run_rmse": joined["runs"][["method", fmt.CATHETER, fmt.SETTING, fmt.RUN, "rmse_mm"]],
        "run_rmse_by_seed": joined["by_seed"].join(info, on=fmt.RUN)[
            ["method", "seed", fmt.CATHETER, fmt.SETTING, fmt.RUN, "rmse_mm"]],
        "cdf": joined["cdf"][["method", "error_mm", "fraction"]],
        "magnitude_bins": joined["magnitude"][bins],
        "time_bins": _covered_bins(joined["time"][bins], len(info)),
    }


def _torque_context_table(run_rmse, catheters):
    """Table II, indexed by (torque, context); None without an ablated variant."""
    table = _by_catheter(run_rmse, TORQUE_CONTEXT.values(), catheters)
    if len(table) <= 1:  # an ablation table needs at least one ablated variant
        return None
    names = {method: inputs for inputs, method in TORQUE_CONTEXT.items()}
    table.index = pd.MultiIndex.from_tuples([names[m] for m in table.index], names=["torque", "context"])
    return table


def _paired_table(run_rmse, info, catheters, n_bootstrap, random_state):
    """Paired reductions of every comparison whose two methods were run, per catheter and pooled."""
    wide = run_rmse.pivot(index=fmt.RUN, columns="method", values="rmse_mm")
    clusters = info[fmt.CATHETER] + "/" + info[fmt.SETTING]
    rows = []
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
            rows.append({
                "comparison": label, "baseline": base, "candidate": cand, "scope": scope,
                "reduction_mm": res.reduction_mm, "ci_low_mm": res.ci_low_mm, "ci_high_mm": res.ci_high_mm,
                "reduction_pct": res.reduction_pct, "fraction_improved": res.fraction_improved,
                "n_runs": res.n_runs,
            })
    return pd.DataFrame(rows)


def _residual_learners_table(run_rmse, paired, catheters):
    """The residual learners' RMSE and their paired reduction; None unless both were run."""
    learners = methods_with_role("residual_learners")
    if not set(learners) <= set(run_rmse["method"]):
        return None
    table = _by_catheter(run_rmse, learners, catheters)
    sub = paired[paired["comparison"] == comparison_label(*learners)].set_index("scope")
    for column in ("reduction_mm", "ci_low_mm", "ci_high_mm", "fraction_improved"):
        table.loc[column] = sub[column].reindex(table.columns)
    return table


def _loco_table(run_rmse, run_rmse_by_seed, info, catheters):
    """Catheter held out against setting held out, with the runs below 4 mm; None without LOCO."""
    if LOCO_METHOD not in set(run_rmse["method"]):
        return None
    table = _by_catheter(run_rmse, methods_with_role("loco"), catheters)
    seeds = run_rmse_by_seed[run_rmse_by_seed["method"] == LOCO_METHOD]
    below = seeds.groupby(fmt.RUN)["rmse_mm"].mean() < 4.0
    below = below.to_frame("below").join(info)
    frac = below.groupby(fmt.CATHETER, sort=False)["below"].mean().reindex(catheters)
    frac["pooled"] = below["below"].mean()
    table.loc["runs below 4 mm (LOCO, %)"] = 100 * frac
    return table


def adaptation_ratios():
    """The ratios of the sweep-adaptation table: label -> (numerator, denominator) methods.

    The adapted method within the catheter against the backbone the paper's
    method corrects, and the adapted method with the catheter held out
    against the paper's method within the catheter (the error a new catheter
    gets from its sweep alone, against a model trained on that catheter).
    """
    if ADAPTED_METHOD is None:
        return {}
    (adapted_loco,) = (name for name, v in LOCO_METHODS.items() if v == ADAPTED_METHOD)
    base = backbone_method(PROPOSED_METHOD)
    return {
        f"{ADAPTED_METHOD} / {base}": (ADAPTED_METHOD, base),
        f"{adapted_loco} / {PROPOSED_METHOD}": (adapted_loco, PROPOSED_METHOD),
    }


def _adaptation_table(run_rmse, catheters):
    """The methods with and without sweep adaptation and their ratios; None unless both ran."""
    ratios = adaptation_ratios()
    needed = {name for pair in ratios.values() for name in pair}
    if not ratios or not needed <= set(run_rmse["method"]):
        return None
    table = _by_catheter(run_rmse, methods_with_role("adaptation"), catheters)
    for label, (numerator, denominator) in ratios.items():
        table.loc[f"ratio {label}"] = table.loc[numerator] / table.loc[denominator]
    return table


@validate_params(
    {
        "result": [Bunch],
        "n_bootstrap": [Interval(Integral, 1, None, closed="left")],
        "random_state": ["random_state"],
    },
    prefer_skip_nested_validation=True,
)
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
        (PDL+MLP vs PDL+GRU), ``loco`` (catheter held out), ``adaptation``
        (PDL and PDL+GRU without and with sweep adaptation, within the
        catheter and held out, with the ratios of :func:`adaptation_ratios`),
        ``cdf_at_5mm`` (%),
        ``magnitude`` (median run-bin RMSE per 10 deg bin), ``time`` (mean
        run-bin RMSE per 10 s bin), ``paired`` (paired reductions with 95 %
        setting-cluster intervals), and the long tables the figures use:
        ``run_rmse``, ``run_rmse_by_seed``, ``cdf``, ``magnitude_bins``,
        ``time_bins``, ``example``.
    """
    info = _run_info(result.X)
    catheters = list(pd.unique(info[fmt.CATHETER]))
    long = _long_tables(result, info)
    run_rmse = long["run_rmse"]
    tables = {"table_1": _by_catheter(run_rmse, MAIN_METHODS, catheters), **long}
    paired = _paired_table(run_rmse, info, catheters, n_bootstrap, random_state)
    optional = {
        "table_2": _torque_context_table(run_rmse, catheters),
        "paired": paired,
        "residual_learners": _residual_learners_table(run_rmse, paired, catheters),
        "loco": _loco_table(run_rmse, long["run_rmse_by_seed"], info, catheters),
        "adaptation": _adaptation_table(run_rmse, catheters),
    }
    tables.update({key: table for key, table in optional.items() if table is not None})

    cdf = long["cdf"]
    at5 = cdf[np.isclose(cdf["error_mm"], 5.0)].set_index("method")["fraction"] * 100
    tables["cdf_at_5mm"] = at5.rename("samples below 5 mm (%)").to_frame()
    for key, bins, statistic in (("magnitude", "magnitude_bins", "median"), ("time", "time_bins", "mean")):
        grouped = long[bins].groupby(["method", "bin_left", "bin_right"], sort=False)["rmse_mm"]
        tables[key] = getattr(grouped, statistic)().unstack("method").sort_index()
    tables["example"] = _motion_example(result, run_rmse)
    return tables


def _motion_example(result, run_rmse, seconds=60.0):
    """A 60 s motion segment of the run with the widest measured motion (chosen without looking at errors).

    The estimate shown is that of the first method of the ``example`` role
    that was run.
    """
    method = next(m for m in methods_with_role("example") if m in result.predictions)
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
