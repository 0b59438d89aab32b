"""Motor trajectories of the recording protocol: an 8-ray sweep, then a random walk.

All angles are motor angles in degrees, or the commands of an instrument
whose motors follow them (:mod:`skcath.datasets._tendons`): one coordinate
for one motor, two (a bend vector) otherwise. A trajectory is a :class:`Trajectory`:
pieces (moves and holds) whose durations are whole samples at the protocol's
rate ``rate_hz``; it is a function of time, so it can be sampled at that rate
or at any other (:meth:`Trajectory.sample`) and stays the same motion.
"""

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Trajectory",
    "min_jerk",
    "protocol_trajectory",
    "sweep_trajectory",
    "random_walk_trajectory",
    "run_protocol",
    "resweep_trajectory",
]

#: A sample counts as inside a piece when at most this fraction of a
#: protocol sample beyond its end, so that rounding of the times never moves
#: a sample to another piece.
_POSITION_TOLERANCE = 1e-9


def _min_jerk_at(tau):
    """``10 tau^3 - 15 tau^4 + 6 tau^5``: the minimum-jerk profile at ``tau`` in [0, 1]."""
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def _constant_speed_at(tau, ramp_fraction=0.1):
    """The trapezoidal velocity profile at ``tau`` in [0, 1] (see :func:`constant_speed`)."""
    a = ramp_fraction
    v_max = 1.0 / (1.0 - a)
    return np.where(
        tau < a,
        0.5 * v_max * tau**2 / a,
        np.where(tau > 1 - a, 1.0 - 0.5 * v_max * (1.0 - tau) ** 2 / a, v_max * (tau - 0.5 * a)),
    )


@dataclass(frozen=True)
class _Piece:
    """``n`` protocol samples from ``start`` to ``stop`` along ``profile`` (None: hold ``stop``)."""

    n: int
    start: np.ndarray
    stop: np.ndarray
    profile: object = None


@dataclass(frozen=True)
class Trajectory:
    """A motor trajectory of pieces of whole samples at ``rate_hz``, sampled at any rate.

    Piece ``k`` covers the protocol samples ``N_k .. N_k + n_k - 1``; between
    the last sample of the previous piece (position ``N_k - 1``) and its own
    last sample it moves from its start to its stop along its profile
    (minimum jerk or constant speed) or holds its stop. Sampling at another
    rate evaluates the same pieces at the times ``m / sample_rate``.

    Attributes
    ----------
    pieces : tuple
        The pieces, in time order.
    rate_hz : float
        Rate of the protocol's samples (Hz).
    n_sweep : int
        Protocol samples of the sweep at the start (0: no sweep).
    """

    pieces: tuple
    rate_hz: float
    n_sweep: int = 0

    @property
    def n_samples(self):
        """Number of protocol samples."""
        return int(sum(p.n for p in self.pieces))

    def _positions(self, sample_rate_hz):
        """Protocol-sample positions ``m rate_hz / sample_rate_hz`` of the samples at a rate."""
        last = (self.n_samples - 1) * sample_rate_hz / self.rate_hz
        m = np.arange(int(np.floor(last + _POSITION_TOLERANCE)) + 1)
        return m * self.rate_hz / sample_rate_hz

    def sample(self, sample_rate_hz=None):
        """The motor angles at ``sample_rate_hz`` (default: the protocol's rate).

        Returns
        -------
        q : ndarray of shape (n, n_dims)
            Motor angles (degrees) at ``t = m / sample_rate_hz``, ``m = 0 ..
            n - 1``, up to the time of the last protocol sample. At the
            protocol's own rate, exactly its samples.
        n_sweep : int
            Samples of the sweep: those up to its last protocol sample.
        """
        rate = self.rate_hz if sample_rate_hz is None else float(sample_rate_hz)
        s = self._positions(rate)
        ends = np.cumsum([p.n for p in self.pieces]) - 1  # last sample of every piece
        piece = np.searchsorted(ends, s - _POSITION_TOLERANCE, side="left")
        q = np.empty((len(s), len(self.pieces[0].stop)))
        for k, p in enumerate(self.pieces):
            rows = np.flatnonzero(piece == k)
            if not rows.size:
                continue
            if p.profile is None:
                q[rows] = p.stop
                continue
            tau = (s[rows] - (ends[k] - p.n)) / p.n
            q[rows] = p.start + (p.stop - p.start) * p.profile(tau)[:, None]
        n_sweep = int(np.count_nonzero(s <= self.n_sweep - 1 + _POSITION_TOLERANCE))
        return q, n_sweep


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
    return _min_jerk_at(np.arange(1, n + 1) / n)


def _move(start, stop, n, profile=None):
    """Samples of a move between two points (start excluded), minimum jerk by default."""
    s = (min_jerk(n) if profile is None else profile(n))[:, None]
    return start + (stop - start) * s


def constant_speed(n, ramp_fraction=0.1):
    """Trapezoidal velocity profile from 0 to 1 in ``n`` samples (start excluded).

    Constant speed except for linear acceleration and deceleration ramps
    over ``ramp_fraction`` of the move at each end; the last value is 1.
    """
    return _constant_speed_at(np.arange(1, n + 1) / n, ramp_fraction)


def _sweep_pieces(amplitude_deg, speed_deg_s, dwell_out_s, dwell_in_s, rest_s, n_rays,
                  first_direction_deg, rate_hz, n_dims=2):
    """The pieces of :func:`sweep_trajectory`, durations in samples at ``rate_hz``.

    In one dimension (``n_dims=1``) a ray's direction keeps its cosine: the
    rays at 0 and 180 degrees go out to both signs.
    """
    n_move = max(1, int(round(amplitude_deg / speed_deg_s * rate_hz)))
    origin = np.zeros(n_dims)
    pieces = [_Piece(max(1, int(round(rest_s * rate_hz))), origin, origin)]
    for k in range(n_rays):
        psi = np.deg2rad(first_direction_deg + 360.0 * k / n_rays)
        end = amplitude_deg * np.array([np.cos(psi), np.sin(psi)])[:n_dims]
        pieces += [
            _Piece(n_move, origin, end, _constant_speed_at),
            _Piece(int(round(dwell_out_s * rate_hz)), end, end),
            _Piece(n_move, end, origin, _constant_speed_at),
            _Piece(int(round(dwell_in_s * rate_hz)), origin, origin),
        ]
    return [p for p in pieces if p.n > 0]


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
    pieces = _sweep_pieces(amplitude_deg, speed_deg_s, dwell_out_s, dwell_in_s, rest_s,
                           n_rays, first_direction_deg, rate_hz)
    return Trajectory(tuple(pieces), float(rate_hz)).sample()[0]


def _reflect_into_disk(q, radius):
    """Reflect points whose magnitude exceeds ``radius`` back into the disk."""
    r = np.linalg.norm(q)
    if r <= radius:
        return q
    r_new = abs(2.0 * radius - r) % (2.0 * radius)
    r_new = min(r_new, radius)
    return q * (r_new / r)


def _walk_pieces(rng, n_samples, n_steps, step_std_deg, radius_deg, start):
    """The pieces of :func:`random_walk_trajectory` (the same draws)."""
    if n_samples < n_steps:
        raise ValueError(f"n_samples={n_samples} must be >= n_steps={n_steps}.")
    durations = rng.uniform(1.0, 2.6, size=n_steps)
    bounds = np.round(np.cumsum(durations) / durations.sum() * n_samples).astype(int)
    lengths = np.diff(np.concatenate([[0], bounds]))
    if np.any(lengths < 1):  # pathological draws: fall back to equal steps
        lengths = np.full(n_steps, n_samples // n_steps)
        lengths[: n_samples - lengths.sum()] += 1
    q = np.asarray(start, dtype=float)
    pieces = []
    for n in lengths:
        target = _reflect_into_disk(q + rng.normal(0.0, step_std_deg, size=q.shape), radius_deg)
        pieces.append(_Piece(int(n), q, target, _min_jerk_at))
        q = target
    return pieces


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
    pieces = _walk_pieces(rng, n_samples, n_steps, step_std_deg, radius_deg, start)
    # one sample per protocol sample: the rate does not matter
    return Trajectory(tuple(pieces), 1.0).sample()[0]


def protocol_trajectory(rng, *, rate_hz=10.0, n_samples_range=(6000, 6300), amplitude_deg=60.0,
                        n_rays=8, n_dims=2):
    """The trajectory of one run, the 8-ray sweep then a 100-step random walk, as pieces.

    Draws what :func:`run_protocol` draws; its durations are whole samples at
    ``rate_hz``, and :meth:`Trajectory.sample` samples it at any rate.

    ``n_rays`` and ``n_dims`` give the sweep and the walk of other
    instruments (:mod:`skcath.datasets._tendons`): ``n_rays`` evenly spaced
    rays from direction 0, and a walk in an interval (``n_dims=1``) or a
    disk (2). ``n_samples_range`` is the length of a run with the 8-ray
    sweep: the walk has the length it has after that sweep, so a sweep of
    fewer rays gives a shorter run with the same walk.

    Returns
    -------
    trajectory : Trajectory
        With ``n_sweep``, the sweep's samples at ``rate_hz``.
    """
    speed = 2.4 * (1.0 + rng.uniform(-0.03, 0.03))
    full = _sweep_pieces(amplitude_deg, speed, 0.0, 2.5, 3.0, 8, 0.0, rate_hz)
    sweep = full if (n_rays, n_dims) == (8, 2) else _sweep_pieces(
        amplitude_deg, speed, 0.0, 2.5, 3.0, n_rays, 0.0, rate_hz, n_dims
    )
    n_full = sum(p.n for p in full)
    n_total = int(rng.integers(n_samples_range[0], n_samples_range[1] + 1))
    n_motion = n_total - n_full
    if n_motion < 1000:
        raise ValueError(
            f"n_samples_range={n_samples_range} leaves {n_motion} motion samples after a "
            f"{n_full}-sample sweep; expected at least 1000."
        )
    walk = _walk_pieces(rng, n_motion, 100, 22.0, amplitude_deg, np.zeros(n_dims))
    return Trajectory(tuple(sweep + walk), float(rate_hz), sum(p.n for p in sweep))


def run_protocol(rng, *, rate_hz=10.0, n_samples_range=(6000, 6300), amplitude_deg=60.0,
                 sample_rate_hz=None):
    """Motor trajectory of one run: the 8-ray sweep, then a 100-step random walk.

    The sweep speed varies by a few percent from run to run; the total length
    is drawn uniformly in ``n_samples_range`` and the random walk fills the rest.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    rate_hz : float
        Rate of the protocol (Hz): the durations of its moves are whole
        samples at this rate.
    n_samples_range : tuple of int
        Inclusive range of the total number of samples of the run at ``rate_hz``.
    amplitude_deg : float
        Sweep amplitude and random-walk radius (degrees).
    sample_rate_hz : float or None
        Rate at which the trajectory is sampled (Hz); None samples it at
        ``rate_hz``. The same draws give the same motion at every rate.

    Returns
    -------
    q : ndarray of shape (n, 2)
        Motor angles (degrees).
    n_sweep : int
        Number of sweep samples at the start of ``q``.
    """
    trajectory = protocol_trajectory(
        rng, rate_hz=rate_hz, n_samples_range=n_samples_range, amplitude_deg=amplitude_deg
    )
    return trajectory.sample(sample_rate_hz)


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
