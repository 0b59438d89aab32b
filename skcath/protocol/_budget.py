"""Reduced calibration budget: tip error against the size of each run's sweep.

:func:`run_calibration_budget` calibrates the backbones, and applies a
PDL+GRU residual trained on full sweeps, on sweeps reduced by
:func:`skcath.sweep.reduce_sweep` to fewer rays or to every ``stride``-th
sample, and scores every budget on the unchanged motion rows;
:func:`format_budget_report`, :func:`write_budget_results` and
:func:`plot_calibration_budget` print, save and draw the result.
``python -m skcath calibration-budget`` runs them all; see
``docs/studies/calibration_budget.rst``.
"""

from __future__ import annotations

import os
import time
from numbers import Integral, Real
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.utils import Bunch
from sklearn.utils._param_validation import Interval, validate_params

from .. import _format as fmt
from .._validation import check_recordings
from ..metrics import per_run_rmse
from ..model_selection import exclusion_set
from ..sweep import reduce_sweep
from ._figure_tools import _new_figure
from ._methods import METHODS, backbone_method, methods_with_role
from ._protocol import (
    calibrate_backbones,
    finetune_models,
    learner_input,
    pretrain_models,
    protocol_folds,
)
from ._schedule import SCHEDULE_CONSTRAINT, get_schedule

__all__ = [
    "BUDGET_FILES",
    "BUDGET_METHODS",
    "format_budget_report",
    "plot_calibration_budget",
    "run_calibration_budget",
    "write_budget_results",
]

#: Methods scored at every budget: the two backbones and the GRU residual on PDL.
BUDGET_METHODS = methods_with_role("budget")

#: Learned method of the experiment, trained on full sweeps.
(_VARIANT,) = (name for name in BUDGET_METHODS if METHODS[name].learner is not None)
#: The backbone methods of the budget.
_BACKBONES = tuple(name for name in BUDGET_METHODS if METHODS[name].learner is None)

#: File names written by :func:`write_budget_results`.
BUDGET_FILES = {
    "summary": "calibration_budget.csv",
    "run_rmse": "calibration_budget_runs.csv",
    "figure": "calibration_budget.png",
}


def _check_levels(values, name, low, high=None, why=""):
    """Validated tuple of distinct integers in ``[low, high]``, in the given order.

    ``why`` ends the error message's statement of what is expected.
    """
    values = (values,) if isinstance(values, Integral) else tuple(values)
    bad = [
        v for v in values
        if isinstance(v, bool) or not isinstance(v, Integral) or v < low or (high is not None and v > high)
    ]
    if not values or bad:
        upper = "" if high is None else f" to {high}"
        raise ValueError(f"{name} must hold integers from {low}{upper}{why}; got {values!r}.")
    return tuple(dict.fromkeys(int(v) for v in values))


def _budgets(rays, strides, n_rays_swept):
    """(n_rays, stride) pairs after checking the arguments: the full sweep, fewer rays, then
    sparser samples."""
    if isinstance(n_rays_swept, bool) or not isinstance(n_rays_swept, Integral) or n_rays_swept < 3:
        raise ValueError(f"n_rays_swept must be an integer of at least 3; got {n_rays_swept!r}.")
    rays = _check_levels(
        rays, "rays", 3, int(n_rays_swept),
        f" (the backbones need at least 3 rays; a sweep of n_rays_swept={n_rays_swept} has no more)",
    )
    strides = _check_levels(strides, "strides", 1)
    pairs = [(int(n_rays_swept), 1)]
    pairs += [(n, 1) for n in sorted(rays, reverse=True)]
    pairs += [(int(n_rays_swept), s) for s in sorted(strides)]
    return list(dict.fromkeys(pairs))


def _sweep_size(X, stride):
    """Sweep samples and sweep duration (s) of every run of ``X``.

    The duration counts ``stride`` sample periods per kept sample, the
    period being the median time step of the motion rows of the run.
    """
    sweep = X[fmt.PHASE].to_numpy() == fmt.SWEEP
    runs = X[fmt.RUN].to_numpy()
    n = pd.Series(sweep).groupby(runs, sort=False).sum()
    motion = X.loc[~sweep, [fmt.RUN, fmt.TIME]]
    period = motion.groupby(fmt.RUN, observed=True, sort=False)[fmt.TIME].apply(
        lambda t: float(np.median(np.diff(t.to_numpy()))) if len(t) > 1 else np.nan
    )
    period.index = period.index.astype(str)
    n.index = n.index.astype(str)
    return n.astype(int), n * stride * period.reindex(n.index)


@validate_params(
    {
        "X": "no_validation",
        "y": ["array-like", None],
        "rays": "no_validation",
        "strides": "no_validation",
        "n_rays_swept": "no_validation",
        "learned": ["boolean"],
        "schedule": SCHEDULE_CONSTRAINT,
        "catheters": "no_validation",
        "exclude_settings": "no_validation",
        "n_jobs": [Integral, None],
        "verbose": ["verbose"],
    },
    prefer_skip_nested_validation=False,
)
def run_calibration_budget(
    X,
    y,
    *,
    rays=(8, 6, 4, 3),
    strides=(5, 20, 50),
    n_rays_swept=8,
    learned=True,
    schedule="quick",
    catheters=None,
    exclude_settings=None,
    n_jobs=1,
    verbose=False,
):
    """Tip error of the backbones and of PDL+GRU against the calibration budget.

    Budgets are the full sweep (``n_rays_swept`` rays, every sample), each
    number of rays in ``rays`` (every sample) and each stride in ``strides``
    (all rays), made by :func:`skcath.sweep.reduce_sweep` on every evaluated
    run. For each budget, PCC and PDL are calibrated on the reduced sweep of
    every run and scored on its motion rows, which no budget changes.

    With ``learned``, PDL+GRU is trained as in :func:`run_protocol` under
    ``schedule``, on full sweeps only: for every evaluated catheter and seed
    a model is pretrained on the other catheters and fine-tuned, for every
    fold of a setting-held-out split within the catheter, on the fold's
    training runs. Each fold's test runs are then predicted once per budget:
    their PDL backbone is calibrated on the reduced sweep, and the context
    encoder and the sweep frame read the reduced sweep. Two-ray budgets are
    refused, since neither the backbones nor the sweep frame can use them.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format (``docs/data_format.rst``); every run
        starts with a sweep of ``n_rays_swept`` evenly spaced rays. With
        ``learned``, at least two catheters.
    y : array-like of shape (n_samples, 3)
        Measured tip positions in the base frame (mm).
    rays : iterable of int, default=(8, 6, 4, 3)
        Numbers of rays kept, from 3 to ``n_rays_swept``.
    strides : iterable of int, default=(5, 20, 50)
        Strides of the sweep samples kept, with all rays (positive).
    n_rays_swept : int, default=8
        Rays of the recorded sweeps.
    learned : bool, default=True
        Also train and score PDL+GRU; False scores the backbones only.
    schedule : {"quick", "full"} or Schedule, default="quick"
        Seeds, folds, epochs and model size of PDL+GRU (:class:`Schedule`).
    catheters : iterable of str, default=None
        Catheters evaluated; None evaluates all. The others still serve for
        pretraining.
    exclude_settings : str or iterable of str, default=None
        Settings never evaluated (the straight reference ``S00`` of the
        built-in benchmark, in the protocol); still used for training.
    n_jobs : int, default=1
        Runs calibrated and models trained in parallel (joblib); each model
        uses one torch thread.
    verbose : bool, default=False
        Show progress bars on standard error.

    Returns
    -------
    result : sklearn.utils.Bunch
        ``summary``: DataFrame with one row per budget and columns
        ``n_rays``, ``stride``, ``sweep_samples`` and ``sweep_s`` (median
        per run; sweep duration in s), then the mean per-run RMSE (mm) of
        each method in :data:`BUDGET_METHODS` (PDL+GRU averaged over seeds;
        absent without ``learned``). ``run_rmse``: one row per budget,
        method, seed and evaluated run (``n_rays``, ``stride``, ``method``,
        ``seed``, ``catheter``, ``setting``, ``run``, ``rmse_mm``; ``seed``
        is -1 for the backbones). ``schedule`` (None without ``learned``),
        ``catheters``, ``exclude_settings`` and ``elapsed`` (wall time, s).

    Raises
    ------
    ValueError
        On malformed recordings, on ``rays`` outside ``[3, n_rays_swept]``,
        on non-positive strides, on unknown catheters, or when a sweep's rays
        cannot be found (the message names the run).
    """
    start = time.perf_counter()
    budgets = _budgets(rays, strides, n_rays_swept)
    exclude = tuple(sorted(exclusion_set(exclude_settings)))
    X, y = check_recordings(X, y)
    if y is None:
        raise ValueError("y (the measured tip positions, mm) is required to score the budgets.")
    X = X.reset_index(drop=True)
    y = np.asarray(y, dtype=float)
    tested, evaluated = _evaluated_runs(X, catheters, exclude)
    schedule = _learned_schedule(X, schedule) if learned else None

    X_eval, y_eval = X[evaluated].reset_index(drop=True), y[evaluated]
    reduced, records, summary = _backbone_budgets(X_eval, y_eval, budgets, n_rays_swept, n_jobs)
    if learned:
        records += _learned_records(
            X, y, budgets, reduced, schedule, exclude, tested, n_jobs, verbose, n_rays_swept,
        )
    run_rmse = _run_rmse_table(records, X_eval)
    return Bunch(
        summary=_summary_table(summary, run_rmse),
        run_rmse=run_rmse,
        schedule=schedule,
        catheters=tuple(tested),
        exclude_settings=exclude,
        elapsed=time.perf_counter() - start,
    )


def _evaluated_runs(X, catheters, exclude):
    """The catheters evaluated and the mask of their rows outside the excluded settings."""
    catheter_ids = X[fmt.CATHETER].astype(str).to_numpy()
    available = list(pd.unique(catheter_ids))
    if catheters is None:
        tested = available
    else:
        tested = [str(c) for c in ([catheters] if isinstance(catheters, str) else catheters)]
        if not tested or set(tested) - set(available):
            raise ValueError(
                f"catheters must name catheters of X's 'catheter' column {available}; "
                f"got {tested!r}."
            )
    evaluated = np.isin(catheter_ids, tested) & ~np.isin(X[fmt.SETTING].astype(str).to_numpy(), exclude)
    if not evaluated.any():
        raise ValueError(
            f"no run is left to evaluate: catheters {tested} have only the "
            f"excluded settings {list(exclude)}."
        )
    return tested, evaluated


def _learned_schedule(X, schedule):
    """The schedule of the learned method, after checking that X has catheters to pretrain on."""
    schedule = get_schedule(schedule)
    available = list(pd.unique(X[fmt.CATHETER].astype(str)))
    if len(available) < 2:
        raise ValueError(
            f"{_VARIANT} is pretrained on the other catheters, so X needs recordings of at "
            f"least two catheters in its 'catheter' column; got {available} (or pass "
            "learned=False)."
        )
    return schedule


def _backbone_budgets(X_eval, y_eval, budgets, n_rays_swept, n_jobs):
    """The learner input of every budget, the backbones' per-run RMSE and the sweep sizes.

    Returns the list of (learner input, targets) of every budget, the records
    (n_rays, stride, method, seed, per-run RMSE) of the backbones, seed -1,
    and one summary row per budget.
    """
    spacing = 360.0 / n_rays_swept
    reduced, records, summary = [], [], []
    for n_rays, stride in budgets:
        X_b, y_b = reduce_sweep(X_eval, y_eval, n_rays=n_rays, stride=stride, n_rays_swept=n_rays_swept)
        X_b = X_b.reset_index(drop=True)
        inputs, predictions = calibrate_backbones(
            X_b, methods=_BACKBONES, n_rays=n_rays, ray_spacing_deg=spacing, n_jobs=n_jobs
        )
        Xt = inputs[backbone_method(_VARIANT)]
        for method, pred in predictions.items():
            records.append((n_rays, stride, method, -1, per_run_rmse(y_b, pred, X_b)))
        samples, seconds = _sweep_size(X_b, stride)
        summary.append({"n_rays": n_rays, "stride": stride, "sweep_samples": float(samples.median()),
                        "sweep_s": float(seconds.median())})
        reduced.append((Xt, y_b))
    return reduced, records, summary


def _run_rmse_table(records, X_eval):
    """One row per budget, method, seed and evaluated run."""
    run_info = X_eval[[fmt.RUN, fmt.CATHETER, fmt.SETTING]].astype(str).drop_duplicates(fmt.RUN)
    run_info = run_info.set_index(fmt.RUN)
    frames = []
    for n_rays, stride, method, seed, per_run in records:
        frame = per_run.rename("rmse_mm").rename_axis(fmt.RUN).reset_index()
        frame[fmt.RUN] = frame[fmt.RUN].astype(str)
        frame = frame.join(run_info, on=fmt.RUN)
        frames.append(frame.assign(n_rays=n_rays, stride=stride, method=method, seed=seed))
    return pd.concat(frames, ignore_index=True)[
        ["n_rays", "stride", "method", "seed", fmt.CATHETER, fmt.SETTING, fmt.RUN, "rmse_mm"]
    ]


def _summary_table(summary, run_rmse):
    """Sweep size and mean per-run RMSE of every method (averaged over seeds) per budget."""
    means = (
        run_rmse.groupby(["n_rays", "stride", "method", "seed"], sort=False)["rmse_mm"].mean()
        .groupby(["n_rays", "stride", "method"], sort=False).mean()
        .unstack("method")
    )
    table = pd.DataFrame(summary).set_index(["n_rays", "stride"])
    return table.join(means[[m for m in BUDGET_METHODS if m in means.columns]]).reset_index()


def _learned_records(
    X, y, budgets, reduced, schedule, exclude, catheters, n_jobs, verbose, n_rays_swept
):
    """Per-run RMSE of the learned method trained on full sweeps, for every budget and seed.

    The models are pretrained and fine-tuned as in the protocol
    (:func:`pretrain_models`, :func:`finetune_models`); each fine-tuned model
    predicts its fold's test runs once per budget, from the reduced sweeps.
    """
    Xb = learner_input(X, n_rays=n_rays_swept, n_jobs=n_jobs)
    folds = protocol_folds(X, schedule, exclude_settings=exclude, catheters=catheters)
    stage = dict(variants=(_VARIANT,), n_jobs=n_jobs, verbose=verbose)
    pretrained = pretrain_models(Xb, y, folds.loco, schedule, **stage)

    run_ids = X[fmt.RUN].astype(str).to_numpy()
    budget_runs = [Xt[fmt.RUN].astype(str).to_numpy() for Xt, _ in reduced]

    def budget_rows(fold):
        """Rows of every budget's frame that belong to the fold's test runs."""
        test_runs = np.unique(run_ids[fold.test])
        return [np.isin(runs, test_runs) for runs in budget_runs]

    def tests(fold):
        return [Xt[rows] for (Xt, _), rows in zip(reduced, budget_rows(fold))]

    finetuned = finetune_models(Xb, y, folds.within, schedule, pretrained.models, tests=tests, **stage)
    predictions = {
        seed: [np.full((len(Xt), 3), np.nan) for Xt, _ in reduced] for seed in schedule.seeds
    }
    for (_, seed, number), preds in finetuned.predictions.items():
        for b, (rows, pred) in enumerate(zip(budget_rows(folds.within[number]), preds)):
            predictions[seed][b][rows] = pred
    records = []
    for seed in schedule.seeds:
        for (n_rays, stride), (Xt, y_b), pred in zip(budgets, reduced, predictions[seed]):
            if not np.isfinite(pred).all():
                raise RuntimeError(f"{_VARIANT}: some evaluated rows got no prediction (seed {seed}).")
            records.append((n_rays, stride, _VARIANT, seed, per_run_rmse(y_b, pred, Xt)))
    return records


@validate_params({"result": [Bunch]}, prefer_skip_nested_validation=True)
def format_budget_report(result):
    """The budget table as text, with a header naming the runs and the schedule.

    Parameters
    ----------
    result : sklearn.utils.Bunch
        Output of :func:`run_calibration_budget`.

    Returns
    -------
    text : str
    """
    table = result.summary.copy()
    methods = [m for m in BUDGET_METHODS if m in table.columns]
    table = table.rename(columns={"n_rays": "rays", "sweep_samples": "sweep samples",
                                  "sweep_s": "sweep (s)"})
    n_runs = result.run_rmse[fmt.RUN].nunique()
    schedule = "backbones only" if result.schedule is None else (
        f"{_VARIANT} schedule {result.schedule.name!r}, seeds {list(result.schedule.seeds)}"
    )
    lines = [
        "Calibration budget: mean per-run RMSE (mm) on the motion rows",
        f"{n_runs} runs of catheters {', '.join(result.catheters)}"
        + (f", settings {', '.join(result.exclude_settings)} excluded" if result.exclude_settings else "")
        + f"; {schedule}; {result.elapsed:.0f} s",
        "sweep samples and sweep (s): median per run; stride s keeps every s-th sweep sample",
        "",
        table.to_string(
            index=False,
            formatters={
                "sweep samples": "{:.0f}".format,
                "sweep (s)": "{:.0f}".format,
                **{m: "{:.2f}".format for m in methods},
            },
        ),
    ]
    return "\n".join(lines)


@validate_params({"summary": [pd.DataFrame]}, prefer_skip_nested_validation=True)
def plot_calibration_budget(summary):
    """Error against the number of rays and against the sweep stride.

    Parameters
    ----------
    summary : pandas.DataFrame
        The ``summary`` of :func:`run_calibration_budget`: columns
        ``n_rays``, ``stride`` and one column of mean per-run RMSE (mm) per
        method of :data:`BUDGET_METHODS`.

    Returns
    -------
    figure : matplotlib.figure.Figure
        Left: error against the rays kept (stride 1); right: error against
        the stride (all rays, logarithmic axis).

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    """
    methods = [m for m in BUDGET_METHODS if m in summary.columns]
    full = int(summary["n_rays"].max())
    by_rays = summary[summary["stride"] == 1].sort_values("n_rays")
    by_stride = summary[summary["n_rays"] == full].sort_values("stride")
    figure = _new_figure((9.0, 3.8))
    left, right = figure.subplots(1, 2, sharey=True)
    for method in methods:
        style = {"color": METHODS[method].colour, "marker": "o", "label": method}
        left.plot(by_rays["n_rays"], by_rays[method], **style)
        right.plot(by_stride["stride"], by_stride[method], **style)
    left.set_xticks(by_rays["n_rays"].tolist())
    left.set_xlabel("rays in the sweep (every sample)")
    left.set_ylabel("mean per-run RMSE (mm)")
    left.set_title("Fewer rays")
    right.set_xscale("log")
    right.set_xticks(by_stride["stride"].tolist())
    right.set_xticklabels([str(s) for s in by_stride["stride"]])
    right.minorticks_off()
    right.set_xlabel(f"stride of the sweep samples ({full} rays)")
    right.set_title("Fewer sweep samples")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    left.set_ylim(bottom=0.0)
    left.legend(loc="lower left")
    return figure


@validate_params(
    {
        "result": [Bunch],
        "out_dir": [str, os.PathLike],
        "figure": ["boolean"],
        "dpi": [Interval(Real, 0, None, closed="neither")],
    },
    prefer_skip_nested_validation=True,
)
def write_budget_results(result, out_dir, *, figure=True, dpi=150):
    """Write the budget tables as CSV and, optionally, the figure as PNG.

    Parameters
    ----------
    result : sklearn.utils.Bunch
        Output of :func:`run_calibration_budget`.
    out_dir : str or path-like
        Folder (created if missing).
    figure : bool, default=True
        Also draw ``calibration_budget.png`` (needs matplotlib:
        ``pip install "skcath[plot]"``).
    dpi : float, default=150
        Resolution of the PNG file (dots per inch).

    Returns
    -------
    paths : list of pathlib.Path
        The files written (:data:`BUDGET_FILES`).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / BUDGET_FILES["summary"], out / BUDGET_FILES["run_rmse"]]
    result.summary.to_csv(paths[0], index=False, float_format="%.6g")
    result.run_rmse.to_csv(paths[1], index=False, float_format="%.6g")
    if figure:
        path = out / BUDGET_FILES["figure"]
        plot_calibration_budget(result.summary).savefig(path, dpi=dpi)
        paths.append(path)
    return paths
