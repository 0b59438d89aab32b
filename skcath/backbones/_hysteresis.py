r"""Hysteresis of the motor transmission identified on a run's own sweep: the play operator.

A tendon drive with slack (backlash) moves the bending section only once the
motor has taken the slack up, and leaves it where it was when the motor
turns back. A symmetric play operator of half-width :math:`w` (deg) models
this for each motor :math:`i` separately: the played angle :math:`z_i`
follows the motor angle :math:`q_i` only when it is more than :math:`w` away,

.. math::

    z_{i,t} = \min\bigl(\max(z_{i,t-1},\; q_{i,t} - w),\; q_{i,t} + w\bigr),
    \qquad z_{i,0} = q_{i,0},

so that :math:`|z_{i,t} - q_{i,t}| \le w` and :math:`z` stays put while the
motor reverses within the play. With :math:`w = 0`, :math:`z = q` exactly.

A backbone with ``hysteresis="play"`` is calibrated on the played sweep
angles and evaluated on the played angles of the whole run; the half-width
of each run is the one whose calibration fits the run's sweep best
(:func:`identify_play_width`). The out-and-back rays of the sweep show the
width of the loop, so the width is identified from the sweep rows alone.
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np
from scipy.optimize import minimize_scalar
from sklearn.utils._param_validation import Interval, validate_params

from .._kernel import compiled, kernel

__all__ = ["identify_play_width", "play_kernel", "play_operator"]

#: Step of the coarse grid of half-widths searched first (deg).
PLAY_GRID_STEP_DEG = 2.0
#: Tolerance of the bounded search that refines the best grid width (deg).
PLAY_XTOL_DEG = 0.1


@kernel
def play_kernel(z, q, width):
    """One step of the symmetric play of one motor: the new played angle (deg).

    ``min(max(z, q - width), q + width)``: the played angle ``z`` follows the
    motor angle ``q`` once it is more than ``width`` away, and stays put
    otherwise. With ``width = 0`` it returns ``q``.

    Parameters
    ----------
    z : float
        Played angle of the previous sample (deg).
    q : float
        Motor angle of this sample (deg).
    width : float
        Half-width of the play (deg), ``>= 0``.

    Returns
    -------
    z : float
        Played angle of this sample (deg).
    """
    return min(max(z, q - width), q + width)


def _play_rows(q1, q2, width, z1, z2):
    """Rows of :func:`play_kernel` for both motors, from ``z = q`` at the first row."""
    a, b = q1[0], q2[0]
    for i in range(len(q1)):
        a = play_kernel(a, q1[i], width)
        b = play_kernel(b, q2[i], width)
        z1[i] = a
        z2[i] = b


@validate_params(
    {"q": ["array-like"], "width": [Interval(Real, 0, None, closed="left")]},
    prefer_skip_nested_validation=True,
)
def play_operator(q, width):
    r"""Motor angles of one run passed through a symmetric play of half-width ``width``.

    For each motor :math:`i`, in time order from :math:`z_{i,0} = q_{i,0}`,

    .. math::

        z_{i,t} = \min\bigl(\max(z_{i,t-1},\; q_{i,t} - w),\; q_{i,t} + w\bigr).

    Every row is stepped by :func:`play_kernel`, in a loop compiled by numba
    where it is available and in Python otherwise. ``width = 0`` returns the
    angles unchanged.

    Parameters
    ----------
    q : array-like of shape (n, 2)
        Motor angles of the rows of one run, in time order (deg); finite.
    width : float
        Half-width ``w`` of the play (deg), finite and ``>= 0``.

    Returns
    -------
    z : ndarray of shape (n, 2)
        Played motor angles (deg), within ``width`` of ``q``.

    Examples
    --------
    >>> from skcath.backbones import play_operator
    >>> play_operator([[0.0, 0.0], [3.0, 1.0], [2.0, -3.0]], 1.5)
    array([[ 0. ,  0. ],
           [ 1.5,  0. ],
           [ 1.5, -1.5]])
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2:
        raise ValueError(f"q must have shape (n, 2) (motor angles q1, q2 in deg); got {q.shape}.")
    if not np.all(np.isfinite(q)):
        raise ValueError("q must be finite (motor angles in deg).")
    width = float(width)
    n = q.shape[0]
    if n == 0:
        return np.empty((0, 2))
    fast = compiled(_play_rows)
    if fast is not None:
        z1, z2 = np.empty(n), np.empty(n)
        fast(np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]), width, z1, z2)
    else:
        z1, z2 = [0.0] * n, [0.0] * n
        _play_rows(q[:, 0].tolist(), q[:, 1].tolist(), width, z1, z2)
    return np.column_stack([z1, z2])


def identify_play_width(sweep_rmse, max_play_deg, grid_rmse=None):
    """The half-width of the play whose calibration fits the sweep best (deg).

    A grid of half-widths from 0 to ``max_play_deg`` in steps of
    :data:`PLAY_GRID_STEP_DEG` (2 deg), then
    :func:`scipy.optimize.minimize_scalar` (``method="bounded"``, tolerance
    :data:`PLAY_XTOL_DEG`, 0.1 deg) between the neighbours of the best grid
    width. The width returned is the best of all those evaluated, so the
    sweep is never fitted worse than without the play (width 0).

    Parameters
    ----------
    sweep_rmse : callable
        ``sweep_rmse(width) -> float``: the RMSE (mm) of the backbone
        calibrated on the sweep angles played with that half-width.
    max_play_deg : float
        Largest half-width searched (deg), > 0.
    grid_rmse : callable, optional
        ``grid_rmse(widths) -> list of float``: the RMSEs (mm) of
        ``sweep_rmse`` for a list of half-widths at once (e.g. all their
        calibrations solved together); it must return exactly the numbers
        of ``sweep_rmse``, so that the width found is the same. It is asked
        for the grid; None means ``sweep_rmse`` on each grid width in turn.

    Returns
    -------
    width : float
        The identified half-width (deg), in ``[0, max_play_deg]``.
    """
    n_cells = max(1, math.ceil(max_play_deg / PLAY_GRID_STEP_DEG - 1e-9))
    grid = np.linspace(0.0, max_play_deg, n_cells + 1)
    widths = [float(w) for w in grid]
    values = list(grid_rmse(widths)) if grid_rmse is not None else [sweep_rmse(w) for w in widths]
    if len(values) != len(widths):
        raise ValueError(f"grid_rmse must return one RMSE (mm) per half-width; got {len(values)} "
                         f"for {len(widths)} half-widths.")
    rmse = dict(zip(widths, values))
    k = int(np.argmin([rmse[float(w)] for w in grid]))
    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, n_cells)])
    result = minimize_scalar(
        sweep_rmse, bounds=(lo, hi), method="bounded", options={"xatol": PLAY_XTOL_DEG}
    )
    rmse[float(result.x)] = float(result.fun)
    return min(rmse, key=lambda w: (rmse[w], w))
