"""Run the evaluation protocol: backbones, pretraining, fine-tuning, predictions.

:func:`run_protocol` is the whole protocol. Its steps are public, so that
other experiments on the protocol's models (the calibration budget) train
them the same way: :func:`calibrate_backbones` calibrates the backbones on
every run's sweep, :func:`learner_input` gives the residual learners' input,
:func:`protocol_folds` splits the recordings by catheter and by setting,
:func:`pretrain_models` pretrains the learned methods on the other catheters
and :func:`finetune_models` fine-tunes them within each catheter.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Mapping
from numbers import Integral
from typing import NamedTuple

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.frozen import FrozenEstimator
from sklearn.utils import Bunch
from sklearn.utils._param_validation import validate_params
from tqdm.auto import tqdm

from .. import _format as fmt
from .._validation import check_recordings, check_target
from ..backbones import BACKBONE_COLUMNS
from ..model_selection import (
    LeaveOneCatheterOut,
    LeaveOneSettingOut,
    SettingGroupKFold,
    exclusion_set,
)
from ._methods import (
    ADAPTED_BACKBONE,
    BACKBONE_METHODS,
    BACKBONES,
    LOCO_METHODS,
    METHODS,
    _adapted,
    backbone_method,
    make_learner,
)
from ._schedule import SCHEDULE_CONSTRAINT, get_schedule

__all__ = [
    "Fold",
    "LEARNER_COLUMNS",
    "calibrate_backbones",
    "finetune_models",
    "learner_input",
    "pretrain_models",
    "protocol_folds",
    "run_protocol",
]

#: Columns the residual learners need (the recording format plus the backbone output).
LEARNER_COLUMNS = (*fmt.REQUIRED_COLUMNS, *BACKBONE_COLUMNS)

#: The backbone the learned methods correct (the ``backbone`` of every learned method).
(_LEARNER_BACKBONE,) = {method.backbone for method in METHODS.values() if method.learner is not None}


class Fold(NamedTuple):
    """One split of the protocol: the catheter tested, and training and test row positions."""

    catheter: str
    train: np.ndarray
    test: np.ndarray


def _make_learner(variant, seed, params):
    """A fresh residual learner of ``variant`` (one torch thread: tasks run in parallel)."""
    return make_learner(variant, random_state=seed, n_threads=1, **params)


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


def learner_input(X, *, adapt=False, **backbone_params):
    """The input of the residual learners: the recordings and the nominal tip of their backbone.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format (``docs/data_format.rst``).
    adapt : bool, default=False
        The backbone of the adapted methods (:data:`ADAPTED_BACKBONE`: the
        hysteresis of each run identified on its own tracked sweep) instead
        of the paper's.
    **backbone_params
        Parameters of the backbone (``n_rays``, ``ray_spacing_deg``,
        ``n_jobs``, ...), calibrated on each run's own sweep.

    Returns
    -------
    X_learner : pandas.DataFrame
        The columns of :data:`LEARNER_COLUMNS`, one row per row of ``X``;
        the backbone columns hold the nominal tip (mm) of the backbone the
        learned methods correct (PDL).
    """
    params = {**(ADAPTED_BACKBONE if adapt else {}), **backbone_params}
    backbone = BACKBONES[_LEARNER_BACKBONE](**params)
    return backbone.fit(X).transform(X)[list(LEARNER_COLUMNS)]


def calibrate_backbones(X, *, methods=None, **backbone_params):
    """Calibrate backbones on each run's own sweep.

    Parameters
    ----------
    X : pandas.DataFrame
        The recordings.
    methods : iterable of str, default=None
        Backbone methods of :data:`METHODS` to calibrate; None calibrates
        every one (:data:`BACKBONE_METHODS`).
    **backbone_params
        Parameters given to every backbone, as in :func:`learner_input`.

    Returns
    -------
    inputs : dict of str to pandas.DataFrame
        The input of the residual learners (:func:`learner_input`) for every
        calibrated backbone method that learned methods correct, by its name
        (``"PDL"``, ``"PDL+adapt"``).
    predictions : dict of str to ndarray of shape (n_samples, 3)
        Nominal tip (mm) of every calibrated backbone method.
    """
    methods = BACKBONE_METHODS if methods is None else tuple(methods)
    inputs, predictions = {}, {}
    for name in methods:
        spec = METHODS[name]
        if spec.backbone == _LEARNER_BACKBONE:
            inputs[name] = learner_input(X, adapt=spec.adapt, **backbone_params)
            predictions[name] = inputs[name][list(BACKBONE_COLUMNS)].to_numpy()
        else:
            backbone = BACKBONES[spec.backbone](**spec.backbone_params, **backbone_params)
            predictions[name] = backbone.fit(X).predict(X)
    return inputs, predictions


@validate_params(
    {
        "X": "no_validation",
        "schedule": SCHEDULE_CONSTRAINT,
        "exclude_settings": "no_validation",
        "catheters": ["array-like", None],
    },
    prefer_skip_nested_validation=True,
)
def protocol_folds(X, schedule, *, exclude_settings=None, catheters=None):
    """The protocol's catheter-held-out and setting-held-out folds.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format, rows in the order the folds index.
    schedule : {"full", "quick"} or Schedule
        Its ``n_setting_folds`` chooses the setting-held-out splitter.
    exclude_settings : str or iterable of str, default=None
        Settings never tested (kept for training).
    catheters : iterable of str, default=None
        Catheters tested; None tests all.

    Returns
    -------
    folds : sklearn.utils.Bunch
        ``loco``: one :class:`Fold` per tested catheter, trained on the other
        catheters (:class:`~skcath.model_selection.LeaveOneCatheterOut`);
        ``within``: the folds of each tested catheter's settings
        (:class:`~skcath.model_selection.LeaveOneSettingOut`, or
        :class:`~skcath.model_selection.SettingGroupKFold` with the
        schedule's ``n_setting_folds``).
    """
    schedule = get_schedule(schedule)
    exclude = tuple(sorted(exclusion_set(exclude_settings)))
    if schedule.n_setting_folds is None:
        within = LeaveOneSettingOut(exclude_settings=exclude)
    else:
        within = SettingGroupKFold(n_splits=schedule.n_setting_folds, exclude_settings=exclude)
    catheter_ids = X[fmt.CATHETER].astype(str).to_numpy()

    def folds(splitter):
        out = [Fold(str(catheter_ids[test[0]]), train, test) for train, test in splitter.split(X)]
        return [fold for fold in out if catheters is None or fold.catheter in catheters]

    return Bunch(loco=folds(LeaveOneCatheterOut(exclude_settings=exclude)), within=folds(within))


def _timing(stage, key, seconds):
    return {"stage": stage, "variant": key["variant"], "seed": key["seed"],
            "catheter": key["catheter"], "seconds": seconds}


def _continued_params(schedule, continue_from):
    """``params(variant, seed, catheter)``: a pretraining's learner parameters.

    A model with a start in ``continue_from`` continues it with the
    schedule's ``adapt_pretrain_params``; any other starts afresh with its
    ``pretrain_params``.
    """
    fresh = {**schedule.model_params, **schedule.pretrain_params}
    starts = {} if continue_from is None else dict(continue_from)
    if starts and schedule.adapt_pretrain_params is None:
        raise ValueError(
            f"continue_from was given, but schedule {schedule.name!r} has no "
            "adapt_pretrain_params to continue the models with; set it (a dict of "
            "learner parameters) or pretrain from scratch without continue_from."
        )

    def params(variant, seed, catheter):
        start = starts.get((variant, seed, catheter))
        if start is None:
            return fresh
        return {**schedule.model_params, **schedule.adapt_pretrain_params,
                "pretrained": FrozenEstimator(start)}

    return params


#: Parameters shared by pretrain_models and finetune_models.
_STAGE_PARAMETERS = {
    "X": [pd.DataFrame],
    "y": ["array-like"],
    "folds": ["array-like"],
    "schedule": SCHEDULE_CONSTRAINT,
    "variants": ["array-like", None],
    "n_jobs": [Integral, None],
    "verbose": ["verbose"],
}


@validate_params(
    {**_STAGE_PARAMETERS, "predict": ["array-like"], "continue_from": [Mapping, None]},
    prefer_skip_nested_validation=False,
)
def pretrain_models(
    X, y, folds, schedule, *, variants=None, predict=(), continue_from=None, n_jobs=1, verbose=False
):
    """Pretrain every learned method and seed on the other catheters.

    Parameters
    ----------
    X : pandas.DataFrame
        Input of the residual learners (:func:`calibrate_backbones`).
    y : array-like of shape (n_samples, 3)
        Measured tip positions (mm), rows of ``X``.
    folds : list of Fold
        Catheter-held-out folds (``loco`` of :func:`protocol_folds`).
    schedule : {"full", "quick"} or Schedule
        Seeds, model and pretraining parameters.
    variants : iterable of str, default=None
        Learned methods to pretrain; None pretrains the schedule's variants.
    predict : iterable of str, default=()
        Variants whose pretrained models also predict their fold's test rows.
    continue_from : mapping, default=None
        Fitted models keyed by (variant, seed, catheter) of the models
        trained here: each of these continues its model's network and
        normalisation statistics with the schedule's
        ``adapt_pretrain_params`` instead of starting afresh with its
        ``pretrain_params`` (:func:`run_protocol` gives the adapted methods
        the pretrained models of their methods without adaptation).
    n_jobs : int, default=1
        Models trained in parallel (joblib); each uses one torch thread.
    verbose : bool, default=False
        Show a progress bar on standard error.

    Returns
    -------
    result : sklearn.utils.Bunch
        ``models`` and, for the variants of ``predict``, ``predictions``
        (ndarray of the fold's test rows, mm), both keyed by (variant, seed,
        catheter); ``timings``, one dict per model (``stage``, ``variant``,
        ``seed``, ``catheter``, ``seconds``), in the order the models finished.
    """
    schedule = get_schedule(schedule)
    variants = schedule.variants if variants is None else tuple(variants)
    y = check_target(y, len(X))
    continued = _continued_params(schedule, continue_from)

    def tasks():
        for fold in folds:
            for variant in variants:
                for seed in schedule.seeds:
                    key = {"variant": variant, "seed": seed, "catheter": fold.catheter, "test": fold.test}
                    X_tests = [X.iloc[fold.test]] if variant in predict else []
                    params = continued(variant, seed, fold.catheter)
                    yield delayed(_pretrain)(key, params, X.iloc[fold.train], y[fold.train], X_tests)

    out = Bunch(models={}, predictions={}, timings=[])
    n_tasks = len(folds) * len(variants) * len(schedule.seeds)
    for key, model, preds, seconds in _run_tasks(tasks(), n_tasks, n_jobs, "pretraining", verbose):
        name = (key["variant"], key["seed"], key["catheter"])
        out.models[name] = model
        if preds:
            out.predictions[name] = preds[0]
        out.timings.append(_timing("pretrain", key, seconds))
    return out


@validate_params(
    {**_STAGE_PARAMETERS, "pretrained": [Mapping], "tests": [callable, None]},
    prefer_skip_nested_validation=False,
)
def finetune_models(
    X, y, folds, schedule, pretrained, *, variants=None, tests=None, n_jobs=1, verbose=False
):
    """Fine-tune the pretrained models on each fold's training runs and predict its test runs.

    Parameters
    ----------
    X, y : pandas.DataFrame, array-like of shape (n_samples, 3)
        Input of the residual learners and measured tip positions (mm), as
        in :func:`pretrain_models`.
    folds : list of Fold
        Setting-held-out folds (``within`` of :func:`protocol_folds`).
    schedule : {"full", "quick"} or Schedule
        Seeds, model and fine-tuning parameters.
    pretrained : mapping
        Pretrained model of every (variant, seed, catheter), the ``models`` of
        :func:`pretrain_models`; a fold's models are those of its catheter.
    variants : iterable of str, default=None
        Learned methods to fine-tune; None fine-tunes the schedule's variants.
    tests : callable, default=None
        ``tests(fold)`` gives the list of frames a fold's models predict; by
        default its test rows of ``X``.
    n_jobs : int, default=1
        Models trained in parallel, as in :func:`pretrain_models`.
    verbose : bool, default=False
        Show a progress bar on standard error.

    Returns
    -------
    result : sklearn.utils.Bunch
        ``predictions``: the list of predictions (mm), one per frame of
        ``tests(fold)``, keyed by (variant, seed, fold number); ``timings``
        as in :func:`pretrain_models`.
    """
    schedule = get_schedule(schedule)
    variants = schedule.variants if variants is None else tuple(variants)
    params = {**schedule.model_params, **schedule.finetune_params}
    y = check_target(y, len(X))

    def tasks():
        for number, fold in enumerate(folds):
            X_tests = [X.iloc[fold.test]] if tests is None else tests(fold)
            for variant in variants:
                for seed in schedule.seeds:
                    key = {"variant": variant, "seed": seed, "catheter": fold.catheter,
                           "fold": number}
                    yield delayed(_finetune)(
                        key, params, pretrained[variant, seed, fold.catheter],
                        X.iloc[fold.train], y[fold.train], X_tests,
                    )

    out = Bunch(predictions={}, timings=[])
    n_tasks = len(folds) * len(variants) * len(schedule.seeds)
    for key, _, preds, seconds in _run_tasks(tasks(), n_tasks, n_jobs, "fine-tuning", verbose):
        out.predictions[key["variant"], key["seed"], key["fold"]] = preds
        out.timings.append(_timing("fine-tune", key, seconds))
    return out


def _check_protocol_input(X, y, exclude_settings):
    """Checked recordings (index reset), float targets and the sorted excluded settings."""
    exclude = tuple(sorted(exclusion_set(exclude_settings)))
    X, y = check_recordings(X, y)
    if y is None:
        raise ValueError("y (the measured tip positions, mm) is required to run the protocol.")
    catheters = pd.unique(X[fmt.CATHETER].astype(str))
    if len(catheters) < 2:
        raise ValueError(
            "the protocol pretrains on the other catheters, so X needs recordings of at least "
            f"two catheters in its 'catheter' column; got {list(catheters)}."
        )
    return X.reset_index(drop=True), np.asarray(y, dtype=float), exclude


def _evaluated(predictions, rows):
    """Every method's predictions on the evaluated rows, checked to be complete."""
    out = {}
    for method, by_seed in predictions.items():
        out[method] = {seed: values[rows] for seed, values in by_seed.items()}
        missing = [seed for seed, values in out[method].items() if not np.isfinite(values).all()]
        if missing:  # every evaluated row must have been a test row of exactly the expected folds
            raise RuntimeError(f"{method}: some evaluated rows got no prediction (seeds {missing}).")
    return out


def _adapted_starts(group, models, inputs, y, folds, schedule, stage, timings):
    """The models the adapted variants of ``group`` continue, by key; None if they start afresh.

    With the schedule's ``adapt_pretrain_params``, each adapted variant
    continues the pretrained model of its method without adaptation, found
    in ``models`` or pretrained here first (its timings join ``timings``).
    """
    plain = {v: _adapted(v, adapt=False) for v in group if METHODS[v].adapt}
    if schedule.adapt_pretrain_params is None or not plain:
        return None
    for variant in sorted(set(plain.values()) - {key[0] for key in models}):
        extra = pretrain_models(inputs[backbone_method(variant)], y, folds, schedule,
                                variants=(variant,), **stage)
        models.update(extra.models)
        timings.extend(extra.timings)
    return {(v, seed, fold.catheter): models[p, seed, fold.catheter]
            for v, p in plain.items() for seed in schedule.seeds for fold in folds}


@validate_params(
    {
        "X": "no_validation",
        "y": ["array-like", None],
        "schedule": SCHEDULE_CONSTRAINT,
        "exclude_settings": "no_validation",
        "n_jobs": [Integral, None],
        "verbose": ["verbose"],
    },
    prefer_skip_nested_validation=False,
)
def run_protocol(X, y, *, schedule="full", exclude_settings=None, n_jobs=1, verbose=False):
    """Run the paper's evaluation protocol on a set of recordings.

    For every catheter ``c`` and seed, each learned method (``PDL+GRU``, its
    ablations and ``PDL+MLP``, see :data:`VARIANTS`) is

    1. **pretrained** on all recordings of the other catheters; applied as
       is to ``c``, this model gives the leave-one-catheter-out result;
    2. **fine-tuned** from that model, for every fold of a setting-held-out
       split within ``c``, on the fold's training runs (``c``'s other
       settings), and evaluated on the fold's held-out runs.

    A sweep-adapted method (``adapt=True``) under a schedule with
    ``adapt_pretrain_params`` (``FULL``) is pretrained by continuing the
    pretrained model of its method without adaptation, same seed and
    catheters, which is pretrained first if it is not among the variants.

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
    X, y, exclude = _check_protocol_input(X, y, exclude_settings)
    start = time.perf_counter()
    folds = protocol_folds(X, schedule, exclude_settings=exclude)
    evaluated = np.zeros(len(X), dtype=bool)
    for fold in folds.loco:
        evaluated[fold.test] = True
    rows = np.flatnonzero(evaluated)

    variants = tuple(schedule.variants)
    backbones = [
        name for name in BACKBONE_METHODS
        if not METHODS[name].adapt or any(METHODS[v].adapt for v in variants)
    ]
    if verbose:
        tqdm.write(f"calibrating the {', '.join(backbones)} backbones on every run's sweep ...",
                   file=sys.stderr)
    inputs, backbone_predictions = calibrate_backbones(X, methods=backbones, n_jobs=n_jobs)
    loco = {name: variant for name, variant in LOCO_METHODS.items() if variant in variants}
    # every method and seed gets its slot now, in a fixed order, because the
    # tasks finish in whatever order the workers complete them
    predictions = {name: {None: values} for name, values in backbone_predictions.items()}
    for method in (*variants, *loco):
        predictions[method] = {seed: np.full((len(X), 3), np.nan) for seed in schedule.seeds}

    stage = dict(n_jobs=n_jobs, verbose=verbose)
    tested = {fold.catheter: fold.test for fold in folds.loco}
    timings, models = [], {}
    for backbone, X_learner in inputs.items():
        # the learned methods on this backbone's nominal tip
        group = tuple(v for v in variants if backbone_method(v) == backbone)
        if not group:
            continue
        predict = tuple(v for v in loco.values() if v in group)
        starts = _adapted_starts(group, models, inputs, y, folds.loco, schedule, stage, timings)
        pretrained = pretrain_models(X_learner, y, folds.loco, schedule, variants=group,
                                     predict=predict, continue_from=starts, **stage)
        models.update(pretrained.models)
        by_variant = {variant: name for name, variant in loco.items()}
        for (variant, seed, catheter), values in pretrained.predictions.items():
            predictions[by_variant[variant]][seed][tested[catheter]] = values
        finetuned = finetune_models(X_learner, y, folds.within, schedule, pretrained.models,
                                    variants=group, **stage)
        for (variant, seed, number), values in finetuned.predictions.items():
            predictions[variant][seed][folds.within[number].test] = values[0]
        timings += pretrained.timings + finetuned.timings

    return Bunch(
        X=X.iloc[rows].reset_index(drop=True),
        y=y[rows],
        predictions=_evaluated(predictions, rows),
        schedule=schedule,
        exclude_settings=exclude,
        timings=pd.DataFrame(timings),
        elapsed=time.perf_counter() - start,
    )
