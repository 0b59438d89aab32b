"""Inverses of the transmission's hysteresis: the motor command that gives a wanted effective angle.

A backbone with ``hysteresis="play"`` reads the played motor angles (the
effective angles ``z``) rather than the motor angles ``q``
(:func:`~skcath.backbones.play_operator`). The controllers solve for the
effective angles that put the model's tip on the target, then ask the
inverse of the hysteresis for the command that moves the transmission
there from its present state. Each inverse is a small object with one
method, :meth:`command`, picked for a started estimator by
:func:`hysteresis_inverse` from :data:`INVERSES`; another hysteresis model
plugs in by adding its inverse there.
"""

from __future__ import annotations

import numpy as np

__all__ = ["INVERSES", "IdentityInverse", "PlayInverse", "hysteresis_inverse"]

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


#: The inverse of each kind of hysteresis: ``kind -> factory(estimator)``, for a started
#: :class:`~skcath.online.OnlineEstimator`.
INVERSES = {
    "none": lambda est: IdentityInverse(),
    "play": lambda est: PlayInverse(est.play_width_),
}


def hysteresis_inverse(estimator, dead_band=0.0):
    """The inverse of the hysteresis in front of a started estimator's backbone.

    Parameters
    ----------
    estimator : OnlineEstimator
        Started.
    dead_band : float, default=0.0
        Smallest reversal of a played angle that is made (deg); for the play only.

    Returns
    -------
    inverse : IdentityInverse or PlayInverse
        ``PlayInverse`` for a play of positive half-width, else ``IdentityInverse``.
    """
    kind = "play" if getattr(estimator, "play_width_", 0.0) > 0.0 else "none"
    inverse = INVERSES[kind](estimator)
    if kind == "play":
        inverse.dead_band = float(dead_band)
    return inverse
