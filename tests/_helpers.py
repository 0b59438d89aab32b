"""Builders shared by several test modules: tiny estimators, schedules and data.

Imported as ``from _helpers import ...`` (pytest puts the ``tests`` folder on
``sys.path``, as it holds no ``__init__.py``).
"""

import functools

import numpy as np
import pandas as pd

from skcath import motor_columns
from skcath.datasets import make_benchmark
from skcath.protocol import Schedule
from skcath.residuals import GRUResidual


def tiny_residual(Est, *, max_epochs=2, **params):
    """A residual learner small enough to train in well under a second.

    Parameters
    ----------
    Est : {GRUResidual, MLPResidual}
        The residual learner class.
    max_epochs : int, default=2
        Training epochs.
    **params
        Other estimator parameters; they override the tiny defaults.

    Returns
    -------
    est : Est
        Unfitted, single-threaded, seeded with ``random_state=0`` unless given.
    """
    base = dict(
        max_epochs=max_epochs,
        batch_size=16,
        window_s=5.0,
        burn_in_s=1.0,
        sweep_stride_s=5.0,
        n_threads=1,
        random_state=0,
        module__hidden_size=8,
        module__encoder_hidden_size=8,
        module__context_size=4,
    )
    if Est is GRUResidual:
        base["module__head_hidden_size"] = 8
    base.update(params)
    return Est(**base)


def tiny_schedule(*, seeds, variants):
    """A protocol schedule of two setting folds, small networks and one epoch per stage.

    Parameters
    ----------
    seeds : tuple of int
        Seeds of the learned models.
    variants : tuple of str
        Learned methods run (names of ``skcath.protocol.VARIANTS``).

    Returns
    -------
    schedule : skcath.protocol.Schedule
        Named ``"tiny"``.
    """
    return Schedule(
        name="tiny",
        seeds=seeds,
        n_setting_folds=2,
        variants=variants,
        model_params={"module__hidden_size": 8, "window_step_s": 20.0},
        pretrain_params={"max_epochs": 1},
        finetune_params={"max_epochs": 1},
    )


def benchmark_settings(settings):
    """Recordings of the default benchmark (two catheters, one run each) of ``settings``.

    Parameters
    ----------
    settings : sequence of str
        Shaft settings kept, e.g. ``("S00", "S01")``.

    Returns
    -------
    X : pandas.DataFrame
        The kept rows, index ``0 .. n-1``.
    y : ndarray of shape (n_rows, 3)
        Their tip positions (mm, float).
    """
    bench = make_benchmark(n_catheters=2, n_runs=1)
    keep = bench.X["setting"].astype(str).isin(settings).to_numpy()
    return bench.X[keep].reset_index(drop=True), np.asarray(bench.y, dtype=float)[keep]


@functools.lru_cache(maxsize=None)
def _instrument_benchmark(n_motors):
    """The one-catheter benchmark (one run per setting) of the instrument of ``n_motors`` motors."""
    return make_benchmark(n_catheters=1, n_runs=1, n_motors=n_motors)


def instrument(n_motors, settings, n_motion=None, *, torques=True):
    """Recordings of the simulated instrument of ``n_motors`` motors (one catheter).

    Parameters
    ----------
    n_motors : {1, 2, 3}
        Motors of the instrument (``make_benchmark(n_motors=...)``): one
        tendon pair in one plane, the benchmark's two pairs, or three
        tendons at 120 degrees.
    settings : sequence of str
        Shaft settings kept, one run each, e.g. ``("S02", "S09")``.
    n_motion : int or None, default=None
        Motion rows kept at the start of each run's motion (all sweep rows
        are kept); None keeps all.
    torques : bool, default=True
        Keep the torque columns ``tau1 .. tauN``; False drops them.

    Returns
    -------
    X : pandas.DataFrame
        The kept rows in the long format, index ``0 .. n-1``.
    y : ndarray of shape (n_rows, 3)
        Their tip positions (mm, float).
    """
    bench = _instrument_benchmark(n_motors)
    X = bench.X
    keep = X["setting"].astype(str).isin(settings).to_numpy()
    if n_motion is not None:
        motion = (X["phase"] == "motion").to_numpy()
        rank = pd.Series(motion).groupby(X["run"].astype(str).to_numpy()).cumsum().to_numpy()
        keep = keep & (~motion | (rank <= n_motion))
    X = X[keep].reset_index(drop=True)
    if not torques:
        X = X.drop(columns=list(motor_columns(X)[1]))
    return X, np.asarray(bench.y, dtype=float)[keep]


def pi_pipelines(backbone_name, kind, n_motors, n_motion):
    """A pipeline of a backbone with ``hysteresis="pi"`` fitted on S02, its float64 copy, and a S05 run.

    ``backbone_name`` is ``"pcc"``, ``"pdl"`` or ``"polynomial"``; ``kind`` is
    ``"gru"``, ``"mlp"`` or ``"none"``. Returns ``pipe, pipe64, run, motion``
    (``motion``: the boolean mask of the run's motion rows).
    """
    import copy

    from sklearn.pipeline import Pipeline

    from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
    from skcath.residuals import MLPResidual, NoResidual

    backbones = {"pcc": PCCBackbone, "pdl": PDLBackbone, "polynomial": PolynomialBackbone}
    residuals = {"gru": GRUResidual, "mlp": MLPResidual, "none": NoResidual}
    train, y = instrument(n_motors, ["S02"], 200)
    run, _ = instrument(n_motors, ["S05"], n_motion)
    backbone = backbones[backbone_name](hysteresis="pi").fit(train, y)
    Est = residuals[kind]
    residual = Est() if Est is NoResidual else tiny_residual(Est, max_epochs=1)
    pipe = Pipeline([("backbone", backbone),
                     ("residual", residual.fit(backbone.transform(train), y))])
    pipe64 = copy.deepcopy(pipe)
    if hasattr(pipe64["residual"], "module_"):
        pipe64["residual"].module_.double()
    return pipe, pipe64, run, (run["phase"] == "motion").to_numpy()
