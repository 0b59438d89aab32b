"""Motor trajectories of the recording protocol: an 8-ray sweep, then a random walk.

All angles are motor angles in degrees; trajectories are sampled at ``rate_hz``.
"""

import numpy as np

__all__ = [
    "min_jerk",
    "sweep_trajectory",
    "random_walk_trajectory",
    "run_protocol",
    "resweep_trajectory",
]


def min_jerk(n):
    """Minimum-jerk profile from 0 to 1 in ``n`` samples, excluding the start.

    Parameters
    ----------
    n : int
        Number of samples of the move (>= 1).

    Returns
    -------
    s : ndarray of shape (n,)
        ``10 tau^3 - 15 tau^4 + 6 tau^5`` at ``tau = k / n``, ``k = 1..n``;
        the last value is exactly 1.
    """
    tau = np.arange(1, n + 1) / n
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def _move(start, stop, n, profile=None):
    """Samples of a move between two points (start excluded), minimum jerk by default."""
    s = (min_jerk(n) if profile is None else profile(n))[:, None]
    return start + (stop - start) * s


def constant_speed(n, ramp_fraction=0.1):
    """Trapezoidal velocity profile from 0 to 1 in ``n`` samples (start excluded).

    Constant speed except for linear acceleration and deceleration ramps
    over ``ramp_fraction`` of the move at each end; the last value is 1.
    """
    tau = np.arange(1, n + 1) / n
    a = ramp_fraction
    v_max = 1.0 / (1.0 - a)
    s = np.where(
        tau < a,
        0.5 * v_max * tau**2 / a,
        np.where(tau > 1 - a, 1.0 - 0.5 * v_max * (1.0 - tau) ** 2 / a, v_max * (tau - 0.5 * a)),
    )
    return s


def sweep_trajectory(
    *,
    amplitude_deg=60.0,
    speed_deg_s=2.4,
    dwell_out_s=0.0,
    dwell_in_s=2.5,
    rest_s=3.0,
    n_rays=8,
    first_direction_deg=0.0,
    rate_hz=10.0,
):
    """Outward-and-return sweep along ``n_rays`` evenly spaced motor directions.

    Each ray starts at neutral (``q = 0``), moves out to ``amplitude_deg``
    along direction ``psi_k = first_direction_deg + 360 k / n_rays`` (in the
    ``(q1, q2)`` plane), dwells, returns to neutral and dwells again.

    Parameters
    ----------
    amplitude_deg : float
        Motor-input magnitude ``rho = |q|`` at the end of each ray (degrees).
    speed_deg_s : float
        Mean speed of each outward or return move (degrees per second).
    dwell_out_s, dwell_in_s, rest_s : float
        Pauses at the ray end, at neutral after each ray, and before the first
        ray (seconds).
    n_rays : int
        Number of rays.
    first_direction_deg : float
        Direction of the first ray (degrees).
    rate_hz : float
        Sampling rate (Hz).

    Returns
    -------
    q : ndarray of shape (n, 2)
        Motor angles (degrees).
    """
    n_move = max(1, int(round(amplitude_deg / speed_deg_s * rate_hz)))
    parts = [np.zeros((max(1, int(round(rest_s * rate_hz))), 2))]
    origin = np.zeros(2)
    for k in range(n_rays):
        psi = np.deg2rad(first_direction_deg + 360.0 * k / n_rays)
        end = amplitude_deg * np.array([np.cos(psi), np.sin(psi)])
        parts.append(_move(origin, end, n_move, constant_speed))
        parts.append(np.repeat(end[None], int(round(dwell_out_s * rate_hz)), axis=0))
        parts.append(_move(end, origin, n_move, constant_speed))
        parts.append(np.zeros((int(round(dwell_in_s * rate_hz)), 2)))
    return np.concatenate(parts)


def _reflect_into_disk(q, radius):
    """Reflect points whose magnitude exceeds ``radius`` back into the disk."""
    r = np.linalg.norm(q)
    if r <= radius:
        return q
    r_new = abs(2.0 * radius - r) % (2.0 * radius)
    r_new = min(r_new, radius)
    return q * (r_new / r)


def random_walk_trajectory(
    rng,
    n_samples,
    *,
    n_steps=100,
    step_std_deg=22.0,
    radius_deg=60.0,
    start=(0.0, 0.0),
):
    """Random walk of both motors inside a disk of motor-input magnitudes.

    Each of the ``n_steps`` steps draws a new target ``q_k + N(0, step_std^2 I)``,
    reflected into ``|q| <= radius_deg``, and moves there with a minimum-jerk
    profile. Step durations are random and add up to ``n_samples`` samples.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    n_samples : int
        Total number of samples (>= n_steps).
    n_steps : int
        Number of random-walk steps.
    step_std_deg : float
        Standard deviation of each step per motor (degrees).
    radius_deg : float
        Largest motor-input magnitude ``|q|`` (degrees).
    start : array-like of shape (2,)
        Starting motor angles (degrees).

    Returns
    -------
    q : ndarray of shape (n_samples, 2)
        Motor angles (degrees).
    """
    if n_samples < n_steps:
        raise ValueError(f"n_samples={n_samples} must be >= n_steps={n_steps}.")
    durations = rng.uniform(1.0, 2.6, size=n_steps)
    bounds = np.round(np.cumsum(durations) / durations.sum() * n_samples).astype(int)
    lengths = np.diff(np.concatenate([[0], bounds]))
    if np.any(lengths < 1):  # pathological draws: fall back to equal steps
        lengths = np.full(n_steps, n_samples // n_steps)
        lengths[: n_samples - lengths.sum()] += 1
    q = np.asarray(start, dtype=float)
    parts = []
    for n in lengths:
        target = _reflect_into_disk(q + rng.normal(0.0, step_std_deg, size=2), radius_deg)
        parts.append(_move(q, target, int(n)))
        q = target
    return np.concatenate(parts)


def run_protocol(rng, *, rate_hz=10.0, n_samples_range=(6000, 6300), amplitude_deg=60.0):
    """Motor trajectory of one run: the 8-ray sweep, then a 100-step random walk.

    The sweep speed varies by a few percent from run to run; the total length
    is drawn uniformly in ``n_samples_range`` and the random walk fills the rest.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    rate_hz : float
        Sampling rate (Hz).
    n_samples_range : tuple of int
        Inclusive range of the total number of samples of the run.
    amplitude_deg : float
        Sweep amplitude and random-walk radius (degrees).

    Returns
    -------
    q : ndarray of shape (n, 2)
        Motor angles (degrees).
    n_sweep : int
        Number of sweep samples at the start of ``q``.
    """
    speed = 2.4 * (1.0 + rng.uniform(-0.03, 0.03))
    q_sweep = sweep_trajectory(amplitude_deg=amplitude_deg, speed_deg_s=speed, rate_hz=rate_hz)
    n_total = int(rng.integers(n_samples_range[0], n_samples_range[1] + 1))
    n_motion = n_total - len(q_sweep)
    if n_motion < 1000:
        raise ValueError(
            f"n_samples_range={n_samples_range} leaves {n_motion} motion samples after a "
            f"{len(q_sweep)}-sample sweep; expected at least 1000."
        )
    q_motion = random_walk_trajectory(rng, n_motion, radius_deg=amplitude_deg)
    return np.concatenate([q_sweep, q_motion]), len(q_sweep)


def resweep_trajectory(q, n_sweep, change_index, *, rate_hz=10.0, speed_deg_s=2.4, return_s=2.0):
    """Motor trajectory of a run after a shaft change with a re-sweep.

    When the shaft is repositioned at sample ``change_index``, the motors
    return from where they stand to neutral at the sweep's mean speed
    (trapezoidal velocity profile), perform the run's own sweep
    ``q[:n_sweep]`` again, move back with one minimum-jerk move of
    ``return_s`` seconds to where they stood, and go on with the rest of the
    run's random walk, ``q[change_index:]``.

    Parameters
    ----------
    q : ndarray of shape (n, 2)
        Motor angles of the run (degrees): its sweep, then its random walk.
    n_sweep : int
        Number of sweep samples at the start of ``q``.
    change_index : int
        First sample in the new shaft setting, ``n_sweep < change_index < n``.
    rate_hz : float
        Sampling rate (Hz).
    speed_deg_s : float
        Mean speed of the return to neutral (degrees per second).
    return_s : float
        Duration of the move from neutral back into the random walk (s).

    Returns
    -------
    q_after : ndarray of shape (m, 2)
        Motor angles from ``change_index`` on (degrees): the return to
        neutral, the sweep, the move back and the rest of the walk.
    n_home : int
        Number of samples of the return to neutral at the start of
        ``q_after``; the sweep follows them.
    """
    stop = np.asarray(q[change_index - 1], dtype=float)
    n_home = max(1, int(round(np.hypot(*stop) / speed_deg_s * rate_hz)))
    home = _move(stop, np.zeros(2), n_home, constant_speed)
    back = _move(np.zeros(2), stop, max(1, int(round(return_s * rate_hz))))
    return np.concatenate([home, q[:n_sweep], back, q[change_index:]]), n_home
