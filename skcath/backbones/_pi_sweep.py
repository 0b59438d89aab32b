r"""Prandtl-Ishlinskii hysteresis identified on a run's sweep by the backbone's own calibration.

The geometric backbones (PCC, PDL) judge a hysteresis by one number: the
sweep RMSE of their calibration on the effective sweep angles (``rmse_mm``
of ``calibrate``), the objective the play's half-width is chosen by. The
identification here minimises that same number over the hysteresis
parameters, the backbone recalibrated at every trial (variable
projection: hysteresis outer, calibration inner), so the hysteresis and
the backbone are identified together and judged as they are used. For PDL
this matters: its calibration fits every ray on its own rows, while its
tips between rays are interpolated, and a hysteresis fitted on the
interpolated tips with the rays' coefficients fixed does not lower the
rays' own RMSE.

The sweep's 8 out-and-back rays show the width of the loop and how sharply
the tip turns at a reversal, so two parameters are identified:

- the **loop half-width** :math:`L` (deg): the lag of the effective angle
  behind the motor angle after a long travel;
- the **softness** :math:`s \in [0, 1]`: the share of the lag taken by
  plays of the nonzero thresholds :math:`g_1, g_2` of the grid (the
  tip turns gradually after a reversal) rather than by the dead band (the
  tip stops for :math:`2 d` of motor travel, then follows at once).

The model is a dead band :math:`d = L - s\,\bar g` with weights
:math:`w = (1 - s, s/2, s/2, 0)` on the thresholds of
:data:`~skcath.backbones._pi.PI_GRID_FRACTIONS`, where :math:`\bar g =
(g_1 + g_2)/2`, so that :math:`d + \sum_k w_k g_k = L` for every
:math:`s`; :math:`s` is bounded so that :math:`d \ge 0`. :math:`s = 0` is
the play of half-width :math:`L`. Neither creep nor an asymmetry of the
dead band is identified: the sweep's short dwells do not separate creep
from the shape of the loop, and its rays leave and return to neutral
angles found from the motor angles, with which a shift of the dead band is
confounded.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from ._pi import PI_GRID_FRACTIONS, ROWS_PER_PARAMETER, PrandtlIshlinskii, _fallback, _n_shown

__all__ = ["SWEEP_PI_PARAMETERS", "identify_sweep_pi", "soft_play", "strided_reference"]

#: Largest number of sweep rows with a reference read by each trial calibration (evenly strided).
MAX_SEARCH_ROWS = 1000
#: Parameters identified on the sweep: loop half-width and softness.
SWEEP_PI_PARAMETERS = 2
#: Tolerance of the bounded search of the softness (fraction of the lag).
SOFTNESS_XTOL = 0.1
#: Step of the first grid of loop half-widths (deg), tolerance of their bounded searches (deg)
#: and half-range of the search of the half-width at the found softness (deg).
WIDTH_GRID_STEP_DEG = 4.0
WIDTH_XTOL_DEG = 0.25
WIDTH_RANGE_DEG = 1.0


def soft_play(width, softness, max_play_deg, n_motors=2):
    r"""The PI of loop half-width ``width`` (deg) and softness ``softness`` in [0, 1].

    A dead band :math:`d = L - s\,\bar g` and weights ``(1 - s, s/2, s/2,
    0)`` on the thresholds ``max_play_deg * PI_GRID_FRACTIONS``, with
    :math:`\bar g` the mean of the two middle thresholds (module
    docstring); ``softness = 0`` is the play of half-width ``width``.

    Parameters
    ----------
    width : float
        Loop half-width :math:`L` (deg), ``>= 0``.
    softness : float
        Share :math:`s` of the lag taken by the nonzero thresholds, in
        ``[0, min(1, width / g_bar)]``.
    max_play_deg : float
        Largest threshold of the grid (deg), > 0.
    n_motors : int
        Number of motors.

    Returns
    -------
    model : PrandtlIshlinskii
    """
    grid = np.asarray(PI_GRID_FRACTIONS) * max_play_deg
    g_bar = 0.5 * (grid[1] + grid[2])
    if not (0.0 <= softness <= 1.0 and softness * g_bar <= width * (1.0 + 1e-12)):
        raise ValueError(f"softness must be in [0, min(1, width / {g_bar:.4g})]; got "
                         f"softness={softness}, width={width} (deg).")
    weights = np.array([1.0 - softness, 0.5 * softness, 0.5 * softness, 0.0])
    return PrandtlIshlinskii(grid, weights, dead_band=max(width - softness * g_bar, 0.0),
                             asymmetry=np.zeros(n_motors))


def strided_reference(target, max_rows=MAX_SEARCH_ROWS):
    """A copy of ``target`` (n, 3) with NaN on all but at most ``max_rows`` evenly strided finite rows."""
    finite = np.flatnonzero(np.isfinite(target).all(axis=1))
    keep = finite[:: max(1, -(-finite.size // max_rows))]
    out = np.full_like(target, np.nan, dtype=float)
    out[keep] = target[keep]
    return out


def _best_width(rmse, lo, hi, grid=False, many=None):
    """The half-width (deg) in ``[lo, hi]`` of the lowest ``rmse(width)``, by a bounded search.

    With ``grid``, a grid of step :data:`WIDTH_GRID_STEP_DEG` first, the
    search then between the neighbours of its best width; ``many(widths)``
    gives the grid's RMSEs at once (the numbers of ``rmse``), None means
    ``rmse`` on each grid width in turn.
    """
    seen = {}

    def f(w):
        w = float(min(max(w, lo), hi))
        seen[w] = rmse(w)
        return seen[w]

    if grid:
        n_cells = max(1, math.ceil((hi - lo) / WIDTH_GRID_STEP_DEG - 1e-9))
        widths = np.linspace(lo, hi, n_cells + 1)
        if many is None:
            values = [f(w) for w in widths]
        else:
            clamped = [float(min(max(w, lo), hi)) for w in widths]
            values = many(clamped)
            seen.update(zip(clamped, values))
        k = int(np.argmin(values))
        lo, hi = float(widths[max(k - 1, 0)]), float(widths[min(k + 1, n_cells)])
    minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": WIDTH_XTOL_DEG})
    return min(seen, key=lambda w: (seen[w], w))


def _plays_at_once(fits, problem, search_many, max_play_deg, n_motors):
    """``plays(widths)``: the RMSEs (mm) of the plays (softness 0) of ``widths``, judged at once.

    The trials not yet in ``fits`` (keyed ``(width, softness)``, as in
    :func:`identify_sweep_pi`) are calibrated by one ``search_many`` call
    and recorded there.
    """

    def plays(widths):
        keys = [(w, 0.0) for w in widths if (w, 0.0) not in fits]
        models = [soft_play(w, s, max_play_deg, n_motors) for w, s in keys]
        found = search_many([problem.effective(model) for model in models]) if keys else []
        for key, model, fit in zip(keys, models, found):
            fits[key] = (model, *fit)
        return [fits[(w, 0.0)][2]["rmse_mm"] for w in widths]

    return plays


def identify_sweep_pi(problem, *, max_play_deg, n_motors, where="the rows", search=None,
                      search_many=None):
    """Identify the loop half-width and softness of the PI by the backbone's sweep RMSE.

    ``problem`` (:class:`~skcath.backbones._pi.SweepProblem`) holds the
    sweep's motor angles and times, its reference tips and the backbone's
    ``calibrate``. Every trial hysteresis is judged by ``rmse_mm`` of
    ``search`` (a calibration on some of the rows, e.g. on the references of
    :func:`strided_reference`; default ``problem.calibrate``) on its
    effective sweep angles:

    1. the loop half-width of the play (softness 0): a grid of step
       :data:`WIDTH_GRID_STEP_DEG` in ``[0, max_play_deg]``, then a bounded
       scalar search (:func:`scipy.optimize.minimize_scalar`, tolerance
       :data:`WIDTH_XTOL_DEG`) between the neighbours of the best;
    2. the softness at that half-width, by a bounded scalar search
       (tolerance :data:`SOFTNESS_XTOL`);
    3. the half-width at that softness, within :data:`WIDTH_RANGE_DEG` of
       the play's (tolerance :data:`WIDTH_XTOL_DEG`).

    The backbone is then calibrated on all the rows (``problem.calibrate``)
    with the trial of the lowest RMSE, which is kept if it beats
    no hysteresis by the Bayesian information criterion
    (``n log(SSE_0 / SSE) > p log n``, ``n`` the residuals, ``p = 2``),
    else no hysteresis: noise is never fitted. Flat or short sweeps fall
    back to no hysteresis with a warning naming ``where``.

    Parameters
    ----------
    problem : SweepProblem
        The sweep's ``segments`` (motor angles in deg, times in s),
        ``target`` (reference tips, mm) and ``calibrate``.
    max_play_deg : float
        Largest threshold of the grid and largest half-width searched (deg).
    n_motors : int
        Number of motors.
    where : str
        Names the rows in the warning of a fallback (e.g. ``"run 'R1'"``).
    search : callable, optional
        ``search(z) -> (params, info)`` with ``info["rmse_mm"]``: the
        calibration that judges the trials; None means ``problem.calibrate``.
    search_many : callable, optional
        ``search_many(zs) -> list of (params, info)``: ``search`` on a list
        of effective sweep angles at once, with exactly its numbers (e.g.
        all the calibrations solved together); it is asked for the first
        grid. None means ``search`` on each in turn.

    Returns
    -------
    model : PrandtlIshlinskii
        The hysteresis (the identity where none was identified).
    params, info
        The backbone's calibration on the effective sweep angles.
    """
    grid = np.asarray(PI_GRID_FRACTIONS) * max_play_deg
    g_bar = 0.5 * (grid[1] + grid[2])
    identity = PrandtlIshlinskii.identity(grid, n_motors=n_motors)
    none = (identity, *problem.calibrate(problem.effective(identity)))
    n_finite = int(np.isfinite(problem.target).all(axis=1).sum())
    if not _n_shown(problem, grid, where):
        return none
    if n_finite < ROWS_PER_PARAMETER * SWEEP_PI_PARAMETERS:
        _fallback(where, f"{n_finite} rows with a finite reference are too few to identify "
                         f"{SWEEP_PI_PARAMETERS} parameters (at least "
                         f"{ROWS_PER_PARAMETER * SWEEP_PI_PARAMETERS})")
        return none
    search = search or problem.calibrate
    fits = {}

    def rmse(width, softness):
        key = (float(width), float(softness))
        if key not in fits:
            model = soft_play(key[0], key[1], max_play_deg, n_motors)
            fits[key] = (model, *search(problem.effective(model)))
        return fits[key][2]["rmse_mm"]

    many = None if search_many is None else _plays_at_once(fits, problem, search_many, max_play_deg, n_motors)
    width = _best_width(lambda w: rmse(w, 0.0), 0.0, max_play_deg, grid=True, many=many)
    top = min(1.0, width / g_bar)
    if top > 0:
        minimize_scalar(lambda s: rmse(width, min(s, top)), bounds=(0.0, top),
                        method="bounded", options={"xatol": SOFTNESS_XTOL})
        softness = min((k for k in fits if k[0] == width), key=lambda k: fits[k][2]["rmse_mm"])[1]
        lo = max(softness * g_bar, width - WIDTH_RANGE_DEG)
        hi = min(max_play_deg, width + WIDTH_RANGE_DEG)
        if hi > lo:
            _best_width(lambda w: rmse(w, softness), lo, hi)
    model = fits[min(fits, key=lambda k: fits[k][2]["rmse_mm"])][0]
    best = (model, *problem.calibrate(problem.effective(model)))
    n_obs = 3 * n_finite
    rmse0, rmse1 = none[2]["rmse_mm"], best[2]["rmse_mm"]
    if rmse0 == 0 or (rmse1 > 0 and n_obs * 2.0 * math.log(rmse0 / rmse1)
                      <= SWEEP_PI_PARAMETERS * math.log(n_obs)):
        return none
    return best
