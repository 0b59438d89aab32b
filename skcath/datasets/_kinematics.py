"""Bending-section kinematics that deviate from constant curvature.

The bending section is two circular sub-arcs in one bend plane followed by a
rigid transducer tip. The proximal sub-arc spans a fraction ``f`` of the
length ``L`` but takes a share ``s(a)`` of the total bend ``a`` that changes
with ``a`` (uneven curvature: ``s = f`` would be constant curvature). The
bend magnitude saturates near its mechanical limit and the bend plane twists
as the section bends. Coordinates: z along the base axis, bend plane at
azimuth ``delta`` about z; lengths in mm, angles in radians.
"""

import numpy as np

__all__ = ["versine_ratio", "sine_ratio", "bend_from_inputs", "tip_position", "tip_rotvec"]

def versine_ratio(a):
    """``(1 - cos a) / a``, written as ``(a / 2) sinc^2(a / 2)``: exact near 0, 0 at 0."""
    a = np.asarray(a, dtype=float)
    return 0.5 * a * np.sinc(a / (2.0 * np.pi)) ** 2


def sine_ratio(a):
    """``sin a / a`` (``numpy.sinc`` of ``a / pi``): 1 at 0, no division."""
    return np.sinc(np.asarray(a, dtype=float) / np.pi)


def bend_from_inputs(theta, *, rest, max_bend, twist):
    """Bend magnitude and plane azimuth from the two axis bend components.

    Parameters
    ----------
    theta : ndarray of shape (n, 2)
        Bend components produced by the two tendon pairs (rad).
    rest : ndarray of shape (2,) or (n, 2)
        Resting curvature of the section, as a bend vector (rad).
    max_bend : float
        Mechanical limit of the bend magnitude (rad):
        ``a = max_bend * tanh(|theta + rest| / max_bend)``.
    twist : float
        Twist of the bend plane per radian of bend (rad/rad).

    Returns
    -------
    a : ndarray of shape (n,)
        Bend magnitude (rad).
    delta : ndarray of shape (n,)
        Bend-plane azimuth about the base axis (rad).
    """
    vec = theta + rest
    linear = np.hypot(vec[:, 0], vec[:, 1])
    a = max_bend * np.tanh(linear / max_bend)
    delta = np.arctan2(vec[:, 1], vec[:, 0]) + twist * a
    return a, delta


def tip_position(a, delta, *, length, tip_length, split_fraction, split_share):
    """Tip position of two sub-arcs and a rigid tip (mm, kinematic base frame).

    Parameters
    ----------
    a : ndarray of shape (n,)
        Total bend (rad).
    delta : ndarray of shape (n,)
        Bend-plane azimuth (rad).
    length : float
        Length of the bending section (mm).
    tip_length : float
        Length of the rigid tip beyond the bending section (mm).
    split_fraction : float
        Fraction ``f`` of ``length`` in the proximal sub-arc.
    split_share : ndarray of shape (n,)
        Share ``s`` of the bend taken by the proximal sub-arc.

    Returns
    -------
    p : ndarray of shape (n, 3)
        Tip position (mm).
    """
    a1 = split_share * a
    a2 = a - a1
    l1 = split_fraction * length
    l2 = length - l1
    x1, z1 = l1 * versine_ratio(a1), l1 * sine_ratio(a1)
    dx2, dz2 = l2 * versine_ratio(a2), l2 * sine_ratio(a2)
    c1, s1 = np.cos(a1), np.sin(a1)
    lateral = x1 + dx2 * c1 + dz2 * s1 + tip_length * np.sin(a)
    axial = z1 - dx2 * s1 + dz2 * c1 + tip_length * np.cos(a)
    return np.column_stack([lateral * np.cos(delta), lateral * np.sin(delta), axial])


def tip_rotvec(a, delta):
    """Rotation vector of the tip frame: bend ``a`` about ``(-sin delta, cos delta, 0)``."""
    return np.column_stack([-np.sin(delta) * a, np.cos(delta) * a, np.zeros_like(a)])
