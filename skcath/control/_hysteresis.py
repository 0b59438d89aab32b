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

    Parameters
    ----------
    width : float
        Half-width of the play (deg), ``>= 0``.
    """

    kind = "play"

    def __init__(self, width):
        self.width = float(width)

    def command(self, z_wanted, z_state, q_previous):
        """Motor command (deg) that plays the effective angles to ``z_wanted``; as :meth:`IdentityInverse.command`."""
        z = np.asarray(z_wanted, dtype=float)
        w = self.width
        # within TOL_DEG of the played angle counts as there: rounding does not flip the side
        up, down = z > z_state + TOL_DEG, z < z_state - TOL_DEG
        return np.where(up, z + w, np.where(down, z - w, np.clip(q_previous, z - w, z + w)))


#: The inverse of each kind of hysteresis: ``kind -> factory(estimator)``, for a started
#: :class:`~skcath.online.OnlineEstimator`.
INVERSES = {
    "none": lambda est: IdentityInverse(),
    "play": lambda est: PlayInverse(est.play_width_),
}


def hysteresis_inverse(estimator):
    """The inverse of the hysteresis in front of a started estimator's backbone.

    Parameters
    ----------
    estimator : OnlineEstimator
        Started.

    Returns
    -------
    inverse : IdentityInverse or PlayInverse
        ``PlayInverse`` for a play of positive half-width, else ``IdentityInverse``.
    """
    kind = "play" if getattr(estimator, "play_width_", 0.0) > 0.0 else "none"
    return INVERSES[kind](estimator)
