"""Electromagnetic tracking: two noisy 6-DOF sensors in a distorted field.

Aurora-class figures: position jitter 0.1-0.2 mm, orientation jitter
0.1-0.3 deg, a static field distortion of about 0.5-1 mm that varies smoothly
over the working volume (so that the relative error is about 1 mm or less
over 50 mm).
"""

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["DistortionField", "measure_pose", "noisy_pose", "pose_noise"]


class DistortionField:
    """Static, smooth position distortion: a sum of plane waves.

    ``d(p) = sum_k A_k sin(K_k . p + phase_k)`` with wavelengths of 200-500 mm.

    Parameters
    ----------
    random_state : int or numpy.random.Generator
        Source of randomness.
    amplitude_mm : float
        Standard deviation of each wave's amplitude per coordinate (mm).
    n_waves : int
        Number of plane waves.
    """

    def __init__(self, random_state, *, amplitude_mm=0.35, n_waves=3):
        rng = np.random.default_rng(random_state)
        directions = rng.normal(size=(n_waves, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        wavelengths = rng.uniform(200.0, 500.0, size=(n_waves, 1))
        self.wave_vectors = 2 * np.pi * directions / wavelengths
        self.phases = rng.uniform(0, 2 * np.pi, size=n_waves)
        self.amplitudes = rng.normal(0.0, amplitude_mm, size=(n_waves, 3))

    def __call__(self, points):
        """Distortion (mm) at ``points`` of shape (n, 3) in the tracker frame."""
        return np.sin(points @ self.wave_vectors.T + self.phases) @ self.amplitudes


def measure_pose(rng, position, rotation, field, *, position_noise_mm=0.15, orientation_noise_deg=0.2):
    """What an EM sensor reports for a true pose.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    position : ndarray of shape (n, 3)
        True sensor position in the tracker frame (mm).
    rotation : scipy.spatial.transform.Rotation
        True sensor orientation (n rotations).
    field : DistortionField or None
        Static distortion of the tracker's field.
    position_noise_mm : float
        Standard deviation of the position jitter per coordinate (mm).
    orientation_noise_deg : float
        Standard deviation of the orientation jitter per axis (degrees).

    Returns
    -------
    position : ndarray of shape (n, 3)
        Reported position (mm).
    quaternion : ndarray of shape (n, 4)
        Reported orientation, scalar first (w, x, y, z).
    """
    noise = pose_noise(rng, len(position), position_noise_mm, orientation_noise_deg)
    return noisy_pose(position, rotation, field, noise)


def pose_noise(rng, n, position_noise_mm=0.15, orientation_noise_deg=0.2):
    """The jitter of ``n`` poses of :func:`measure_pose`: position (mm) and rotation vector (rad), each (n, 3)."""
    position = rng.normal(0.0, position_noise_mm, size=(n, 3))
    return position, rng.normal(0.0, np.deg2rad(orientation_noise_deg), size=(n, 3))


def noisy_pose(position, rotation, field, noise):
    """What :func:`measure_pose` reports for a true pose, given its jitter ``noise`` (:func:`pose_noise`)."""
    measured = position + noise[0]
    if field is not None:
        measured = measured + field(position)
    jitter = Rotation.from_rotvec(noise[1])
    quat = (rotation * jitter).as_quat()  # x, y, z, w
    return measured, np.roll(quat, 1, axis=1)
