"""Inverses of the transmission's hysteresis: the motor command that gives a wanted effective angle.

A backbone with ``hysteresis="play"`` or ``"pi"`` reads the effective angles
``z`` (the motor angles ``q`` played, :func:`~skcath.backbones.play_operator`,
or through the Prandtl-Ishlinskii model, :class:`~skcath.backbones.PrandtlIshlinskii`)
rather than the motor angles. The controllers solve for the
effective angles that put the model's tip on the target, then ask the
inverse of the hysteresis for the command that moves the transmission
there from its present state. Each inverse is a small object with one
method, :meth:`command`, picked for a started estimator by
:func:`hysteresis_inverse` from :data:`INVERSES`; another hysteresis model
plugs in by adding its inverse there.
"""

from __future__ import annotations

import numpy as np

from .._kernel import kernel
from ..backbones._pi import pi_inverse_step, pi_step

__all__ = ["INVERSES", "IdentityInverse", "PIInverse", "PlayInverse", "hysteresis_inverse", "pi_command",
           "pi_link"]

#: A wanted effective angle this close to the present one (deg) needs no motion.
TOL_DEG = 1e-6


class IdentityInverse:
    """No hysteresis: the command is the wanted effective angle."""

    kind = "none"

    def command(self, z_wanted, z_state, q_previous):
        """Motor command (deg) that brings the effective angles to ``z_wanted`` (deg).

        Parameters
        ----------
        z_wanted : ndarray of shape (n_motors,)
            Wanted effective angles (deg).
        z_state : ndarray of shape (n_motors,)
            Effective angles of the last step (deg).
        q_previous : ndarray of shape (n_motors,)
            Previous command (deg).

        Returns
        -------
        q : ndarray of shape (n_motors,)
        """
        return np.array(z_wanted, dtype=float)

    def follow(self, z_state, q):
        """Effective angles (deg) after command ``q`` from ``z_state``; for :func:`~skcath.control._preview.plan`."""
        return np.array(q, dtype=float)


class PlayInverse:
    """Inverse of the symmetric play of half-width ``width`` (deg).

    The played angle follows the motor only once the motor is ``width`` away
    from it, so to move the played angle to ``z`` the motor goes to
    ``z + width`` when ``z`` lies above the present played angle and to
    ``z - width`` when below; a motor whose played angle is already where it
    is wanted (within :data:`TOL_DEG`) keeps its command, brought within
    ``width`` of ``z``.

    A reversal (a wanted angle on the other side of the played angle than
    the motor, which last pushed it) crosses the whole play, ``2 * width``
    of motor travel; with ``dead_band > 0`` a reversal smaller than
    ``dead_band`` is not made (the command is kept, brought within
    ``width`` of ``z``), so that a wanted angle that jitters about the
    played one does not swing the motor across the play at every sample.
    Motion in the direction the motor pushes is always followed.

    Parameters
    ----------
    width : float
        Half-width of the play (deg), ``>= 0``.
    dead_band : float, default=0.0
        Smallest reversal of the played angle that is made (deg), ``>= 0``.
    """

    kind = "play"

    def __init__(self, width, dead_band=0.0):
        self.width = float(width)
        self.dead_band = float(dead_band)

    def command(self, z_wanted, z_state, q_previous):
        """Motor command (deg) that plays the effective angles to ``z_wanted``; as :meth:`IdentityInverse.command`."""
        w = self.width
        band = max(self.dead_band, TOL_DEG)
        q = []
        # per motor on floats: a few motors, where numpy's calls would cost more than the arithmetic
        for zj, sj, qj in zip(np.asarray(z_wanted, dtype=float).tolist(), np.asarray(z_state).tolist(),
                              np.asarray(q_previous).tolist()):
            # the side the motor pushes from needs no reversal; the other needs dead_band
            # (within TOL_DEG of the played angle counts as there: rounding does not flip the side)
            tol_up, tol_down = (TOL_DEG, band) if qj >= sj else (band, TOL_DEG)
            if zj > sj + tol_up:
                q.append(zj + w)
            elif zj < sj - tol_down:
                q.append(zj - w)
            else:
                q.append(min(max(qj, zj - w), zj + w))
        return np.array(q)

    def follow(self, z_state, q):
        """Played angles (deg) after command ``q`` from ``z_state``; as :meth:`IdentityInverse.follow`."""
        return np.minimum(np.maximum(z_state, q - self.width), q + self.width)


def pi_link(model):
    """What :func:`pi_command` reads of the forward PI ``model`` to set its inverse's state (flat array).

    ``[K, M, a_0..a_{M-1}, w_0..w_{M-1}]``: the number of plays, and the
    ``M`` plays of positive weight (their indices and weights), as
    :meth:`~skcath.backbones.PrandtlIshlinskii.inverse_terms` reads them.
    """
    active = np.flatnonzero(model.weights > 0)
    return np.concatenate([[model.thresholds.size, active.size], active, model.weights[active]])


@kernel
def pi_command(link, theta, forward, at, scratch, v, q_previous, v_state, dt, up, down, dead_band):
    """The motor command (deg) of one motor that brings its PI's effective angle to ``v`` (deg).

    The inverse's state is set from the forward state ``forward[at:at + K + 2]``
    (dead band ``b``, plays ``z_k``, creep ``c``; deg) and the previous
    command ``q_previous``: the same creep; the dead band's output at the
    first play of positive weight, ``b' = z_f``; inverse play ``j`` at
    ``W_j z_j + sum_{i > j} w_i z_i`` (over the plays of positive weight,
    ``W_j = sum_{i <= j} w_i``), where the inverse plays stand after the
    forward ones' history. One :func:`~skcath.backbones.pi_inverse_step` from there by
    ``dt`` (s) gives the command, whose forward step from the same state is ``v``.

    A reversal (``v`` on the other side of the present effective angle
    ``v_state`` than the command, which last pushed it) smaller than
    ``dead_band`` (deg) is not made: the previous command is kept.
    ``theta``, ``up``, ``down``: :meth:`~skcath.backbones.PrandtlIshlinskii.pack_inverse`;
    ``link``: :func:`pi_link`; ``scratch`` holds ``K' + 3`` floats.
    """
    if dead_band > 0.0:
        if q_previous >= v_state:
            if v_state - dead_band < v < v_state:
                return q_previous
        elif v_state < v < v_state + dead_band:
            return q_previous
    k, m = int(link[0]), int(link[1])
    weights = 2 + m
    scratch[0] = forward[at + 1 + k]
    for j in range(m):  # z'_j = W_j z_j + sum_{i > j} w_i z_i
        total = 0.0
        for i in range(m):
            zi = forward[at + 1 + int(link[2 + max(i, j)])]
            total += link[weights + i] * zi
        scratch[1 + j] = total
    z_first = forward[at + 1 + int(link[2])]
    scratch[1 + m] = z_first
    scratch[2 + m] = q_previous
    return pi_inverse_step(theta, scratch, 0, v, dt, up, down)


class PIInverse:
    """Inverse of a backbone's Prandtl-Ishlinskii hysteresis (:class:`~skcath.backbones.PrandtlIshlinskii`).

    Every command steps the PI's inverse once from the state the stream's
    forward PI is in (:func:`pi_command`): the forward step of the command
    from that state gives the wanted effective angle (up to rounding), its
    dead band, plays and creep included. The creep is stepped by the
    stream's time step of the next sample.

    With ``dead_band > 0`` a reversal of the wanted effective angle smaller
    than ``dead_band`` keeps the previous command, as the play's inverse
    (:class:`PlayInverse`) keeps it within the play.

    Parameters
    ----------
    model : PrandtlIshlinskii
        The run's hysteresis (``OnlineEstimator.hysteresis_``).
    state : ndarray of shape (n_motors * (K + 2),)
        The forward state, read at every command (``hysteresis_state_``, a
        view of the stream's state; deg).
    dt : ndarray of shape (1,)
        The time step (s) the stream's creep reads at the next sample, read at every command.
    dead_band : float, default=0.0
        Smallest reversal of an effective angle that is made (deg), ``>= 0``.
    """

    kind = "pi"

    def __init__(self, model, state, dt, dead_band=0.0):
        self.model = model
        self.state = state
        self.dt = dt
        self.dead_band = float(dead_band)
        self.theta, self.up, self.down = model.pack_inverse()
        self.link = pi_link(model)
        self._forward_theta = model.pack()
        self._forward_bands = model._bands()

    def begin_plan(self):
        """Start a plan of commands ahead: the forward state copied, the stream's own left as it is."""
        self._saved, self.state = self.state, np.array(self.state, dtype=float)

    def end_plan(self):
        """Read the stream's forward state again, as before :meth:`begin_plan`."""
        self.state = self._saved

    def follow(self, z_state, q):
        """Effective angles (deg) after command ``q``, the forward state (a plan's copy) stepped in place."""
        size, dt = self.model.thresholds.size + 2, float(self.dt[0])
        up, down = self._forward_bands
        return np.array([pi_step(self._forward_theta, self.state, j * size, float(qj), dt, up[j], down[j])
                         for j, qj in enumerate(np.asarray(q, dtype=float).tolist())])

    def command(self, z_wanted, z_state, q_previous):
        """Motor command (deg) that brings the effective angles to ``z_wanted``; as :meth:`IdentityInverse.command`."""
        size, dt = self.model.thresholds.size + 2, float(self.dt[0])
        scratch = np.empty(int(self.theta[0]) + 3)
        return np.array([
            pi_command(self.link, self.theta, self.state, j * size, scratch, float(v), float(q), float(s), dt,
                       self.up[j], self.down[j], self.dead_band)
            for j, (v, q, s) in enumerate(zip(np.asarray(z_wanted, dtype=float).tolist(),
                                              np.asarray(q_previous).tolist(), np.asarray(z_state).tolist()))
        ])


#: The inverse of each kind of hysteresis: ``kind -> factory(estimator)``, for a started
#: :class:`~skcath.online.OnlineEstimator`.
INVERSES = {
    "none": lambda est: IdentityInverse(),
    "play": lambda est: PlayInverse(est.play_width_),
    "pi": lambda est: PIInverse(est.hysteresis_, est.hysteresis_state_, est._dt),
}


def hysteresis_inverse(estimator, dead_band=0.0):
    """The inverse of the hysteresis in front of a started estimator's backbone.

    Parameters
    ----------
    estimator : OnlineEstimator
        Started.
    dead_band : float, default=0.0
        Smallest reversal of an effective angle that is made (deg); for the play and the PI.

    Returns
    -------
    inverse : IdentityInverse, PlayInverse or PIInverse
        ``PIInverse`` for a backbone with ``hysteresis="pi"`` (``hysteresis_``
        set), ``PlayInverse`` for a play of positive half-width, else ``IdentityInverse``.
    """
    if getattr(estimator, "hysteresis_", None) is not None:
        kind = "pi"
    else:
        kind = "play" if getattr(estimator, "play_width_", 0.0) > 0.0 else "none"
    inverse = INVERSES[kind](estimator)
    if kind != "none":
        inverse.dead_band = float(dead_band)
    return inverse
