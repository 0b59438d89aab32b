"""The sweep given to a streaming estimator, checked once and carried as arrays.

:func:`check_sweep` reads the sweep rows of one run through
:func:`skcath.check_recordings` once and keeps what the rest of
:meth:`~skcath.online.OnlineEstimator.start` needs as arrays: the run id,
the motor and torque columns, the times, motor angles and torques. The
backbone is calibrated on them (:func:`calibrate`), the sweep is brought to
the residual's rate from its times (:func:`skcath._rate.run_at_rate`), and
the sweep frame and context are computed from the arrays
(:func:`skcath.frames._sweep_frame`,
:func:`skcath.residuals._context.sweep_context`): the rows are checked,
factorized and sorted once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import _format as fmt
from .._sweep_end import N_SWEEP_ATTR
from .._validation import check_recordings, motor_columns
from ._pi_stream import calibrate_pi

__all__ = ["CheckedSweep", "calibrate", "check_sweep"]


@dataclass(frozen=True, eq=False)
class CheckedSweep:
    """The checked sweep rows of one run and their arrays.

    Attributes
    ----------
    X : pandas.DataFrame
        The rows as :func:`skcath.check_recordings` returns them (numeric
        channels float64).
    run : object
        The run id.
    motors, torques : tuple of str
        The motor and torque columns (:func:`skcath.motor_columns`).
    t : ndarray of shape (n,)
        Times of the rows (s), strictly increasing.
    q : ndarray of shape (n, n_motors)
        Motor angles (deg).
    tau : ndarray of shape (n, n_torques)
        Drive torques (N mm); no column without torques.
    """

    X: pd.DataFrame
    run: object
    motors: tuple
    torques: tuple
    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray

    @property
    def channels(self):
        """The motor columns, then the torque columns."""
        return (*self.motors, *self.torques)


def check_sweep(sweep, columns="auto"):
    """The :class:`CheckedSweep` of the sweep rows of exactly one run, with the columns ``columns``.

    Raises
    ------
    ValueError
        If the rows fail :func:`skcath.check_recordings`, hold several runs
        or rows of another phase than ``"sweep"``.
    """
    X, _ = check_recordings(sweep, columns=columns)
    motors, torques = motor_columns(X)
    # the run ids as skcath.factorize_ids gives them; check_recordings has checked them
    runs = np.asarray(pd.factorize(X[fmt.RUN], sort=False)[1], dtype=object)
    if len(runs) != 1:
        raise ValueError(
            f"sweep must hold the sweep rows of exactly one run; got {len(runs)} runs "
            f"({', '.join(map(repr, list(runs)[:5]))})."
        )
    n_motion = int((X[fmt.PHASE] != fmt.SWEEP).sum())
    if n_motion:
        raise ValueError(
            f"sweep must hold only rows with {fmt.PHASE!r} == {fmt.SWEEP!r}; got "
            f"{n_motion} {fmt.MOTION!r} row(s) of run {runs[0]!r}. Pass "
            f"X[X[{fmt.PHASE!r}] == {fmt.SWEEP!r}]."
        )
    return CheckedSweep(
        X=X, run=runs[0], motors=motors, torques=torques,
        t=X[fmt.TIME].to_numpy(dtype=np.float64),
        q=X[list(motors)].to_numpy(dtype=np.float64),
        tau=X[list(torques)].to_numpy(dtype=np.float64),
    )


def calibrate(backbone, sweep):
    """The backbone calibrated on a :class:`CheckedSweep`, as its ``calibrate`` does for the run.

    Returns the run's parameters, the nominal tip of every sweep row (n, 3)
    (mm) and the half-width of the play (deg, 0 without hysteresis), or with
    ``hysteresis="pi"`` the run's :class:`~skcath.backbones.PrandtlIshlinskii`
    (:func:`~skcath.online._pi_stream.calibrate_pi`).
    """
    if getattr(backbone, "hysteresis", None) == "pi":
        return calibrate_pi(backbone, sweep)
    given = sweep.X.attrs.get(N_SWEEP_ATTR, {})
    ref = np.ascontiguousarray(sweep.X[list(fmt.REFERENCE_COLUMNS)].to_numpy(dtype=np.float64))
    tip, params, width = backbone._calibrate_sweep(
        sweep.run, sweep.motors, np.ascontiguousarray(sweep.q), ref,
        (given[sweep.run], sweep.t) if sweep.run in given else None,
    )
    nominal = np.empty((len(sweep.q), 3))  # the rows' array, as calibrate returns it
    nominal[:] = tip
    return params, nominal, float(width)
