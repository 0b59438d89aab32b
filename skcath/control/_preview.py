"""Path preview: the commands of the next samples planned, so that a rate-limited motor crosses the play early.

Along a planned path the wanted command of a motor behind a play (or any
rate-independent hysteresis) jumps at every reversal of its effective
angle: the motor crosses the play, ``2 * width`` of travel, while the tip
stands still. At a rate limit of ``R`` degrees per sample that takes
``w / R`` samples for a jump of ``w``; a controller that starts the crossing
only once the target has turned keeps the tip still for all of them after
the reversal. With the targets of the next samples known, :func:`plan`
turns them into the wanted commands of those samples (the hysteresis
inverse applied along their wanted effective angles) and :func:`lead`
picks the command of this sample nearest, in the largest error over the
window, to the commands wanted ahead that the rate limit allows: the
midpoint of their two Lipschitz envelopes. Every jump ahead is then half
made at its reversal: the crossing starts before the target turns, and
the tip's stall is spread about the reversal, where the path turns and a
still tip is nearest it, rather than all after it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["check_upcoming", "lead", "plan"]


def check_upcoming(upcoming, preview):
    """The first ``preview`` rows of ``upcoming`` as floats (k, 3) (mm), or a ``ValueError`` naming it."""
    try:
        ahead = np.asarray(upcoming, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"upcoming must be an array of shape (k, 3), the targets of the next k samples "
                         f"(x, y, z in mm); got {upcoming!r}.") from exc
    if ahead.ndim != 2 or ahead.shape[1] != 3:
        raise ValueError(f"upcoming must have shape (k, 3), the targets of the next k samples (x, y, z in mm); "
                         f"got shape {ahead.shape}.")
    ahead = ahead[:preview]
    if not np.all(np.isfinite(ahead)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(ahead), axis=1))[0])
        raise ValueError(f"upcoming must be finite (x, y, z in mm); row {bad} is {ahead[bad].tolist()}.")
    return ahead


def plan(inverse, z_ahead, z_state, q_previous, project):
    """Wanted commands (deg) of the samples ahead: the hysteresis inverse along their wanted effective angles.

    Parameters
    ----------
    inverse : IdentityInverse, PlayInverse or PIInverse
        The controller's hysteresis inverse (:mod:`skcath.control._hysteresis`).
    z_ahead : ndarray of shape (h, n_motors)
        Wanted effective angles of this sample and of the next ``h - 1`` (deg).
    z_state : ndarray of shape (n_motors,)
        Effective angles the first command moves from (deg).
    q_previous : ndarray of shape (n_motors,)
        The previous command (deg).
    project : callable
        The motor limits: ``project(q) -> q`` (deg).

    Returns
    -------
    u : ndarray of shape (h, n_motors)
        Each sample's command from the previous one's, as if every command
        were issued as wanted, within the motor limits (deg).
    """
    u = np.empty_like(z_ahead)
    pi = inverse.kind == "pi"
    if pi:
        inverse.begin_plan()
    try:
        for s, z in enumerate(z_ahead):
            q_previous = project(inverse.command(project(z), z_state, q_previous))
            u[s] = q_previous
            z_state = inverse.follow(z_state, q_previous)
    finally:
        if pi:
            inverse.end_plan()
    return u


def lead(u, max_step):
    """The command (deg) of this sample nearest the wanted commands ``u`` ahead that the rate limit allows.

    For each motor, with ``R = max_step``: the midpoint of the two
    Lipschitz envelopes of ``u`` at this sample,
    ``(max_s (u[s] - R s) + min_s (u[s] + R s)) / 2`` over ``s = 0 .. h - 1``,
    the command from which every wanted command ahead is reached, at the
    rate, with the least largest error. A jump of ``w`` at sample ``s``
    (a reversal, crossing the play) is started ``w / R`` samples before it,
    at half the rate, half made at ``s`` and finished, at the rate,
    ``w / (2 R)`` samples after it. A path the motor can follow at the rate
    (``|u[s] - u[0]| <= R s``) leaves ``u[0]`` as it is.

    Parameters
    ----------
    u : ndarray of shape (h, n_motors)
        Wanted commands of this sample and the next ``h - 1`` (deg), :func:`plan`.
    max_step : float
        Largest change of a command per sample (deg); inf for no rate limit.

    Returns
    -------
    q : ndarray of shape (n_motors,)
    """
    if len(u) < 2 or not math.isfinite(max_step):
        return u[0].copy()
    reach = max_step * np.arange(len(u))[:, None]
    return 0.5 * (np.max(u - reach, axis=0) + np.min(u + reach, axis=0))
