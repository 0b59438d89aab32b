"""Run the evaluation protocol: backbones, pretraining, fine-tuning, predictions."""

from __future__ import annotations

import sys
import time

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.frozen import FrozenEstimator
from sklearn.utils import Bunch
from tqdm.auto import tqdm

from .. import _format as fmt
from .._validation import check_recordings
from ..backbones import BACKBONE_COLUMNS, PCCBackbone, PDLBackbone
from ..model_selection import LeaveOneCatheterOut, LeaveOneSettingOut, SettingGroupKFold
from ..model_selection._split import _exclusion_set
from ..residuals import GRUResidual, MLPResidual
from ._schedule import VARIANTS, get_schedule

__all__ = ["run_protocol"]

#: The learned method whose pretrained models are reported as leave-one-catheter-out.
LOCO_VARIANT = "PDL+GRU"

#: Name of the leave-one-catheter-out results among the methods.
LOCO_METHOD = f"{LOCO_VARIANT} (LOCO)"

#: Columns the residual learners need (the recording format plus the backbone output).
_LEARNER_COLUMNS = (*fmt.REQUIRED_COLUMNS, *BACKBONE_COLUMNS)


def _make_learner(variant, seed, params):
    """A fresh residual learner of ``variant`` (one torch thread: tasks run in parallel)."""
    learner, use_torque, use_context = VARIANTS[variant]
    cls = GRUResidual if learner == "gru" else MLPResidual
    return cls(use_torque=use_torque, use_context=use_context, random_state=seed, n_threads=1, **params)


def _pretrain(key, params, X_train, y_train, X_tests):
    """Pretrain on the other catheters; predict each frame of ``X_tests``.

    ``X_tests`` holds the held-out catheter (LOCO) or nothing. Returns the
    key, the model, the list of predictions and the wall time (s).
    """
    start = time.perf_counter()
    model = _make_learner(key["variant"], key["seed"], params).fit(X_train, y_train)
    preds = [model.predict(X) for X in X_tests]
    return key, model, preds, time.perf_counter() - start


def _finetune(key, params, pretrained, X_train, y_train, X_tests):
    """Fine-tune a pretrained model on a fold's training runs; predict each frame of ``X_tests``.

    ``X_tests`` holds the fold's test runs, once or in several versions (one
    per calibration budget). Returns the key, None (the model stays in the
    worker), the list of predictions and the wall time (s).
    """
    start = time.perf_counter()
    params = {**params, "pretrained": FrozenEstimator(pretrained)}
    model = _make_learner(key["variant"], key["seed"], params).fit(X_train, y_train)
    preds = [model.predict(X) for X in X_tests]
    return key, None, preds, time.perf_counter() - start


def _run_tasks(tasks, n_tasks, n_jobs, desc, verbose):
    """Run delayed tasks with joblib, with a progress bar over finished tasks.

    ``tasks`` is a generator, so that each task's training data is sliced only
    when the task is dispatched; ``max_nbytes=None`` sends the slices to the
    workers by pickling instead of memory-mapping them, because joblib keeps
    every memory-mapped argument until the whole batch of tasks ends, which
    would hold hundreds of training sets in memory at once. Results come in
    the order the tasks finish; a joblib backend that cannot stream results
    (Ray's) returns them all at the end instead, which changes nothing
    downstream (every result carries its key) but the progress bar.
    """
    try:
        parallel = Parallel(n_jobs=n_jobs, return_as="generator_unordered", max_nbytes=None)
    except ValueError:  # the active backend cannot return results as they finish
        parallel = Parallel(n_jobs=n_jobs, return_as="list", max_nbytes=None)
    results = parallel(tasks)
    bar = tqdm(total=n_tasks, desc=desc, unit="model", disable=not verbose, dynamic_ncols=True)
    out = []
    with bar:
        for result in results:
            out.append(result)
            bar.update()
    return out


def run_protocol(X, y, *, schedule="full", exclude_settings=None, n_jobs=1, verbose=False):
    """Run the paper's evaluation protocol on a set of recordings.

    For every catheter ``c`` and seed, each learned method (``PDL+GRU``, its
    ablations and ``PDL+MLP``, see :data:`VARIANTS`) is

    1. **pretrained** on all recordings of the other catheters; applied as
       is to ``c``, this model gives the leave-one-catheter-out result;
    2. **fine-tuned** from that model, for every fold of a setting-held-out
       split within ``c``, on the fold's training runs (``c``'s other
       settings), and evaluated on the fold's held-out runs.

    The held-out runs contribute only their initial sweeps, which calibrate
    the per-run backbones (PCC and PDL, fitted on each run's own sweep) and
    feed the context encoder. Feature and target normalisation come from the
    pretraining data. Settings in ``exclude_settings`` (the straight
    reference in the paper) are used for training but never evaluated.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format (``docs/data_format.rst``) with at
        least two catheters.
    y : array-like of shape (n_samples, 3)
        Measured tip positions in the base frame (mm).
    schedule : {"full", "quick"} or Schedule, default="full"
        Seeds, folds, epochs and model size (:class:`Schedule`).
    exclude_settings : str or iterable of str, default=None
        Settings never evaluated (kept for training).
    n_jobs : int, default=1
        Models trained in parallel (joblib); each uses one torch thread.
    verbose : bool, default=False
        Show progress bars on standard error.

    Returns
    -------
    result : sklearn.utils.Bunch
        ``X`` and ``y`` of the evaluated rows (every row of the evaluated
        runs), ``predictions`` (method -> {seed: ndarray (n_rows, 3)} in mm;
        the backbones have the single key None), ``schedule``,
        ``exclude_settings``, ``timings`` (DataFrame of the wall time of every
        trained model, s) and ``elapsed`` (total wall time, s).
    """
    schedule = get_schedule(schedule)
    exclude = tuple(sorted(_exclusion_set(exclude_settings)))
    X, y = check_recordings(X, y)
    if y is None:
        raise ValueError("y (the measured tip positions, mm) is required to run the protocol.")
    catheters = pd.unique(X[fmt.CATHETER].astype(str))
    if len(catheters) < 2:
        raise ValueError(
            "the protocol pretrains on the other catheters, so X needs recordings of at least "
            f"two catheters in its 'catheter' column; got {list(catheters)}."
        )
    start = time.perf_counter()
    X = X.reset_index(drop=True)
    y = np.asarray(y, dtype=float)

    loco = LeaveOneCatheterOut(exclude_settings=exclude)
    if schedule.n_setting_folds is None:
        within = LeaveOneSettingOut(exclude_settings=exclude)
    else:
        within = SettingGroupKFold(n_splits=schedule.n_setting_folds, exclude_settings=exclude)
    loco_folds = list(loco.split(X))
    within_folds = list(within.split(X))
    evaluated = np.zeros(len(X), dtype=bool)
    for _, test in loco_folds:
        evaluated[test] = True

    if verbose:
        tqdm.write("calibrating the PCC and PDL backbones on every run's sweep ...", file=sys.stderr)
    Xb = PDLBackbone(n_jobs=n_jobs).fit(X).transform(X)[list(_LEARNER_COLUMNS)]
    pdl = Xb[list(BACKBONE_COLUMNS)].to_numpy()
    pcc = PCCBackbone(n_jobs=n_jobs).fit(X).predict(X)

    pre_params = {**schedule.model_params, **schedule.pretrain_params}
    fine_params = {**schedule.model_params, **schedule.finetune_params}
    def pretrain_tasks():
        for train, test in loco_folds:
            catheter = str(X[fmt.CATHETER].iloc[test[0]])
            for variant in schedule.variants:
                for seed in schedule.seeds:
                    key = {"variant": variant, "seed": seed, "catheter": catheter, "test": test}
                    X_tests = [Xb.iloc[test]] if variant == LOCO_VARIANT else []
                    yield delayed(_pretrain)(key, pre_params, Xb.iloc[train], y[train], X_tests)

    n_models = len(schedule.variants) * len(schedule.seeds)
    pretrained = {}
    # every method and seed gets its slot now, in a fixed order, because the
    # tasks finish in whatever order the workers complete them
    learned = [*schedule.variants]
    if LOCO_VARIANT in schedule.variants:
        learned.append(LOCO_METHOD)
    predictions = {"PCC": {None: pcc}, "PDL": {None: pdl}}
    for method in learned:
        predictions[method] = {seed: np.full((len(X), 3), np.nan) for seed in schedule.seeds}

    def store(method, seed, rows, values):
        predictions[method][seed][rows] = values

    timings = []
    for key, model, preds, seconds in _run_tasks(
        pretrain_tasks(), n_models * len(loco_folds), n_jobs, "pretraining", verbose
    ):
        pretrained[key["variant"], key["seed"], key["catheter"]] = model
        if key["variant"] == LOCO_VARIANT:
            store(LOCO_METHOD, key["seed"], key["test"], preds[0])
        timings.append({"stage": "pretrain", "variant": key["variant"], "seed": key["seed"],
                        "catheter": key["catheter"], "seconds": seconds})

    def finetune_tasks():
        for fold, (train, test) in enumerate(within_folds):
            catheter = str(X[fmt.CATHETER].iloc[test[0]])
            for variant in schedule.variants:
                for seed in schedule.seeds:
                    key = {"variant": variant, "seed": seed, "catheter": catheter, "fold": fold,
                           "test": test}
                    yield delayed(_finetune)(
                        key, fine_params, pretrained[variant, seed, catheter],
                        Xb.iloc[train], y[train], [Xb.iloc[test]],
                    )

    for key, _, preds, seconds in _run_tasks(
        finetune_tasks(), n_models * len(within_folds), n_jobs, "fine-tuning", verbose
    ):
        store(key["variant"], key["seed"], key["test"], preds[0])
        timings.append({"stage": "fine-tune", "variant": key["variant"], "seed": key["seed"],
                        "catheter": key["catheter"], "seconds": seconds})

    rows = np.flatnonzero(evaluated)
    out = {}
    for method, by_seed in predictions.items():
        out[method] = {seed: values[rows] for seed, values in by_seed.items()}
        missing = [seed for seed, values in out[method].items() if not np.isfinite(values).all()]
        if missing:  # every evaluated row must have been a test row of exactly the expected folds
            raise RuntimeError(f"{method}: some evaluated rows got no prediction (seeds {missing}).")
    return Bunch(
        X=X.iloc[rows].reset_index(drop=True),
        y=y[rows],
        predictions=out,
        schedule=schedule,
        exclude_settings=exclude,
        timings=pd.DataFrame(timings),
        elapsed=time.perf_counter() - start,
    )
