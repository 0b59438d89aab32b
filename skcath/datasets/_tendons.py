"""Tendon layouts of the simulated instruments: one, two or three motors.

The bending section bends along a bend vector of two components (its two
*bending inputs*, :mod:`skcath.datasets._kinematics`); the motors pull
tendons that produce them. A layout says which tendons each motor pulls and
how their inputs add up to the two bending inputs:

* **one motor**: one antagonistic tendon pair in one bending plane; the
  second bending input stays at rest and the section cannot leave the plane;
* **two motors** (the benchmark): two antagonistic pairs at 90 degrees, one
  per bending input;
* **three motors**: three single tendons at 120 degrees, one motor each. The
  bending inputs are the fixed linear map ``(2/3) sum_i e_i (cos a_i, sin a_i)``
  of the three tendon inputs ``e_i`` at azimuths ``a_i`` (tendons that
  shorten by ``e cos(psi - a_i)`` bend the section by ``e`` towards
  ``psi``).

The protocol draws its motor trajectory in a *command* space (the motor
angle of one motor, or the two bending directions of the section), and the
layout turns it into the angles of its motors (:meth:`TendonLayout.motor_angles`).
"""

from dataclasses import dataclass
from numbers import Integral

import numpy as np
from sklearn.utils._param_validation import Options

__all__ = ["MOTOR_COUNTS", "RELEASE_RATIO", "MotorCount", "TendonLayout", "tendon_layout"]

#: Numbers of motors of the simulated instruments.
MOTOR_COUNTS = (1, 2, 3)

#: Share of its geometric displacement that a released tendon of a
#: three-tendon instrument is paid out: the controller lets out a little less
#: than the geometry asks, so that the released tendons stay taut.
RELEASE_RATIO = 0.75


class MotorCount(Options):
    """Parameter constraint: a number of motors of :data:`MOTOR_COUNTS`, booleans excluded."""

    def __init__(self):
        super().__init__(Integral, set(MOTOR_COUNTS))

    def is_satisfied_by(self, val):
        return not isinstance(val, (bool, np.bool_)) and super().is_satisfied_by(val)

    def __str__(self):
        return f"an int among {{{', '.join(map(str, MOTOR_COUNTS))}}}"


@dataclass(frozen=True)
class TendonLayout:
    """The tendons of an instrument with ``n_motors`` motors.

    Attributes
    ----------
    n_motors : int
        Number of motors.
    azimuths : ndarray of shape (n_motors, 2)
        Azimuth (rad) of the tendon pulled by a positive / negative input of
        each motor; a single tendon is the same one for both signs.
    bend_map : ndarray of shape (2, n_motors)
        The two bending inputs from the inputs of the motors' tendons.
    command_map : ndarray of shape (n_motors, n_commands)
        Motor angles from the protocol's command (``n_commands`` is 1 for
        one motor, else 2: the bend vector the user commands).
    single_tendons : bool
        Whether each motor pulls a single tendon (three motors) rather than
        an antagonistic pair.
    sweep_rays : int
        Rays of the calibration sweep, evenly spaced in the command space
        from direction 0.
    """

    n_motors: int
    azimuths: np.ndarray
    bend_map: np.ndarray
    command_map: np.ndarray
    single_tendons: bool
    sweep_rays: int

    @property
    def planar(self):
        """Whether the section bends in one plane only (one motor)."""
        return self.n_motors == 1

    @property
    def n_commands(self):
        """Dimension of the protocol's command space."""
        return self.command_map.shape[1]

    @property
    def directions(self):
        """Unit vectors of shape (n_motors, 2) of the tendon pulled by each motor's positive input."""
        a = self.azimuths[:, 0]
        return np.column_stack([np.cos(a), np.sin(a)]) if self.n_motors == 3 else self.bend_map.T

    def motor_angles(self, command):
        """Motor angles (deg) of shape (n, n_motors) from a command of shape (n, n_commands).

        A three-tendon instrument pulls the tendons towards the commanded
        bend by ``|c| cos(psi - a_i)`` and pays the others out by
        :data:`RELEASE_RATIO` of the same.
        """
        q = np.asarray(command, dtype=float) @ self.command_map.T
        if self.single_tendons:
            q = np.where(q < 0.0, RELEASE_RATIO * q, q)
        return q

    def bending_inputs(self, x):
        """The two bending inputs of shape (..., 2) from per-motor inputs of shape (..., n_motors)."""
        return x @ self.bend_map.T

    def per_motor(self, vector):
        """The component of a bend-plane vector of shape (2,) along each motor's tendon, shape (n_motors,)."""
        return self.directions @ np.asarray(vector, dtype=float)


def _three_tendons():
    azimuth = np.deg2rad([0.0, 120.0, 240.0])
    directions = np.column_stack([np.cos(azimuth), np.sin(azimuth)])
    return TendonLayout(3, np.column_stack([azimuth, azimuth]), (2.0 / 3.0) * directions.T,
                        directions, True, 6)


def tendon_layout(n_motors):
    """The tendon layout of the simulated instrument with ``n_motors`` motors.

    Parameters
    ----------
    n_motors : {1, 2, 3}
        Number of motors.

    Returns
    -------
    layout : TendonLayout
        One pair in one plane (1), two pairs at 90 degrees (2), three single
        tendons at 120 degrees (3).

    Raises
    ------
    ValueError
        For another number of motors.
    """
    if isinstance(n_motors, (bool, np.bool_)) or n_motors not in MOTOR_COUNTS:
        raise ValueError(f"n_motors must be one of {MOTOR_COUNTS}; got {n_motors!r}.")
    if n_motors == 3:
        return _three_tendons()
    # antagonistic pairs: axis 1 bends towards +x, axis 2 towards +y (exact
    # zeros and ones, so that the two-motor maps are identities)
    axes = np.eye(2)[:n_motors]
    azimuths = np.array([[0.0, np.pi], [np.pi / 2, 3 * np.pi / 2]])[:n_motors]
    return TendonLayout(
        int(n_motors), azimuths, axes.T, np.eye(n_motors), False, 8 if n_motors == 2 else 2
    )
