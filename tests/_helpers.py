"""Builders shared by several test modules: tiny estimators, schedules and data.

Imported as ``from _helpers import ...`` (pytest puts the ``tests`` folder on
``sys.path``, as it holds no ``__init__.py``).
"""

import numpy as np

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
        window=50,
        burn_in=10,
        sweep_stride=50,
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
        model_params={"module__hidden_size": 8, "window_step": 200},
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


def with_motors(X, n_motors, *, torques=True, random_state=0):
    """Recordings of the default two-motor benchmark turned into ``n_motors`` motors.

    One motor keeps ``q1`` (and ``tau1``); three motors add ``q3 = (q1 - q2) / 2``
    plus noise (0.5 deg) and ``tau3 = (tau1 + tau2) / 2`` plus noise (0.1),
    deterministic for a ``random_state``, so that every motor moves and none
    is a linear function of the others. Stands in for simulated one- and
    three-motor instruments.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings with ``q1, q2, tau1, tau2``; never modified.
    n_motors : {1, 2, 3}
        Motors of the result.
    torques : bool, default=True
        Keep the torque columns; False drops them all.
    random_state : int, default=0
        Seed of the noise of the third motor.

    Returns
    -------
    X : pandas.DataFrame
        A new frame with the columns ``q1 .. qN`` (and ``tau1 .. tauN``) in
        place of the two motors', in the format's order.
    """
    rng = np.random.default_rng(random_state)
    out = X.copy()
    if n_motors == 3:
        n = len(out)
        out["q3"] = 0.5 * (out["q1"] - out["q2"]) + rng.normal(0.0, 0.5, n)
        out["tau3"] = 0.5 * (out["tau1"] + out["tau2"]) + rng.normal(0.0, 0.1, n)
    elif n_motors == 1:
        out = out.drop(columns=["q2", "tau2"])
    motors, torque_columns = motor_columns(out)
    if not torques:
        out = out.drop(columns=list(torque_columns))
        torque_columns = ()
    first = [c for c in out.columns if c not in (*motors, *torque_columns)]
    at = first.index("phase") + 1
    return out[[*first[:at], *motors, *torque_columns, *first[at:]]]
