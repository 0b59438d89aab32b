"""Where the calibration sweep of a run ends, found from the motor angles alone.

A run starts with its calibration sweep: from neutral, the motors move out
along a ray and back to neutral, rest there, and do the same for the next
ray; then the motion follows. :func:`find_sweep_end` finds the end of the
sweep in a recording that does not mark it (no ``phase`` column), for any
number of motors and at any sampling rate, and the readers of
:mod:`skcath.io` use it for ``n_sweep="auto"``.

Algorithm
---------
1. Neutral: the motor angles at rest at the start of the run (the median of
   the samples of its first ``min_rest_s`` seconds), refined in a second
   pass as the mean of the sweep's samples at neutral. ``rho = |q -
   q_neutral|`` (degrees, over all motors). The sweep amplitude ``A`` is
   the largest ``rho`` of the first excursion beyond ``min_amplitude_deg``;
   samples with ``rho <= max(neutral_fraction * A, 4 sigma)`` are at
   neutral (``sigma``: encoder noise estimated from second differences).
2. Excursions: the stretches away from neutral, in time order, except
   those within 4 ``sigma`` of the threshold (noise). Each is a ray while it
   goes out along one direction and straight back: the direction of every
   sample of its far part (``rho`` above half its peak) lies within
   ``max_turn_deg`` of their mean; ``rho`` rises to the peak and falls back
   without turning back by more than a tenth of the peak; the peak is
   within 25 % of ``A`` and the duration within 50 % of the first ray's;
   and the motors rest at neutral for at least ``min_rest_s`` seconds
   before they move again.
3. End: the first excursion that is not a ray starts the motion. The sweep
   ends with the rest before it, at the last sample still at the rest's
   position (the motion leaves neutral gradually); with no such excursion
   the whole recording is the sweep.

These are properties of a sweep (rays of one amplitude and speed, out from
neutral and back, with a rest after each), not of a data set: the motion
that follows, in the benchmark a random walk from target to target, does
not go out and straight back to rest at neutral.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
import pandas as pd
from sklearn.utils._param_validation import Interval, validate_params

from ._format import RUN, TIME
from ._validation import CUT_RUN_HINT, motor_columns, to_array

__all__ = ["N_SWEEP_ATTR", "SweepEnd", "find_sweep_end", "n_sweep_hint", "naming_n_sweep"]

#: Key of ``X.attrs`` under which the readers of :mod:`skcath.io` record the
#: ``n_sweep`` a user gave, as a dict run id -> n_sweep, so that a sweep
#: error can name it (:func:`n_sweep_hint`).
N_SWEEP_ATTR = "n_sweep"

# Far part of an excursion: rho above this fraction of its peak.
_FAR_FRACTION = 0.5
# Rays reach the first ray's amplitude within this relative tolerance, and
# last as long as the first ray within this one.
_AMPLITUDE_TOLERANCE = 0.25
_DURATION_TOLERANCE = 0.5
# Largest turn back of |q - q_neutral| on a ray's way out or back, as a
# fraction of its peak (plus the noise).
_MAX_REVERSAL = 0.1
# Gaps of at most this many samples above the rest's level (noise) do not
# split a rest.
_REST_GAP = 2
# Neutral threshold and the level of the rest, in units of the encoder noise.
_NOISE_SIGMAS = 4.0


@dataclass(frozen=True, eq=False)
class SweepEnd:
    """Where the calibration sweep of one run ends, as found by :func:`find_sweep_end`.

    The arrays are read-only; compare instances field by field.

    Attributes
    ----------
    n_sweep : int
        Number of sweep samples: rows ``0 .. n_sweep - 1`` of the run are the
        sweep, the rest is motion. The value to give ``n_sweep`` of
        :func:`skcath.io.read_recording`.
    time_s : float
        Time ``t`` of the last sweep sample (s).
    directions : ndarray of shape (K, N)
        Unit direction of each ray in the space of the ``N`` motor angles,
        in the order the rays were swept.
    amplitudes : ndarray of shape (K,)
        Largest motor-input magnitude ``rho = |q - q_neutral|`` of each ray
        (degrees).
    bounds : ndarray of shape (K, 2), dtype intp
        First sample and one past the last sample of each ray's excursion
        away from neutral.
    q_neutral : ndarray of shape (N,)
        Motor angles at neutral (degrees): the mean of the sweep's neutral
        samples.
    neutral_threshold : float
        Largest ``rho`` counted as neutral (degrees).
    ended_by : str
        What follows the sweep: the first excursion that is not a ray (its
        samples, and why it is not a ray), or the end of the recording.
    """

    n_sweep: int
    time_s: float
    directions: np.ndarray
    amplitudes: np.ndarray
    bounds: np.ndarray
    q_neutral: np.ndarray
    neutral_threshold: float
    ended_by: str

    @property
    def n_rays(self) -> int:
        """Number of rays ``K`` found in the sweep."""
        return int(self.amplitudes.size)

    @property
    def amplitude(self) -> float:
        """Sweep amplitude: the median of :attr:`amplitudes` (degrees)."""
        return float(np.median(self.amplitudes))

    @property
    def directions_deg(self) -> np.ndarray | None:
        """Ray directions ``psi = atan2(q2 - q2_0, q1 - q1_0)`` in degrees, in sweep order.

        In ``[-180, 180)``, for recordings of one or two motors (one motor:
        0 or -180); None for more motors, where :attr:`directions` gives
        them.
        """
        n_motors = self.directions.shape[1]
        if n_motors > 2:
            return None
        u2 = self.directions[:, 1] if n_motors == 2 else np.zeros(self.n_rays)
        return (np.rad2deg(np.arctan2(u2, self.directions[:, 0])) + 180.0) % 360.0 - 180.0


def _of_run(run) -> str:
    return "" if run is None else f" of run {run!r}"


def _stretches(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and stops (exclusive) of the contiguous True stretches of ``mask``."""
    edges = np.diff(mask.astype(np.int8), prepend=np.int8(0), append=np.int8(0))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _noise_level(q: np.ndarray) -> float:
    """Robust encoder-noise standard deviation (deg) from second differences.

    For white noise of standard deviation ``sigma`` the second difference has
    standard deviation ``sqrt(6) sigma``; the median absolute value (scaled by
    1.4826) ignores the smooth motion that dominates only a minority of steps
    at the usual sampling rates. The largest over the motors (columns).
    """
    if len(q) < 3:
        return 0.0
    d2 = q[2:] - 2.0 * q[1:-1] + q[:-2]
    return float(1.4826 * np.median(np.abs(d2), axis=0).max() / np.sqrt(6.0))


def _run_arrays(X, t, rate_hz, run):
    """Motor angles (n, N), times (n,) and the run id from the arguments."""
    if isinstance(X, pd.DataFrame):
        motors, _ = motor_columns(X)
        if not motors:
            raise ValueError(
                f"X has no motor-angle column q1 .. qN; got the columns {list(X.columns)}."
            )
        if RUN in X.columns:
            ids = pd.unique(X[RUN])
            if len(ids) > 1:
                raise ValueError(
                    f"X holds {len(ids)} runs ({list(ids[:3])}...); find_sweep_end takes the "
                    "rows of one run; select them with X[X['run'] == run_id]."
                )
            if run is None and len(ids) == 1:
                run = ids[0]
        if t is None and rate_hz is None and TIME in X.columns:
            t = X[TIME]
        X = X[list(motors)]
    q = to_array(
        X, f"The motor angles{_of_run(run)} must be a numeric array of shape (n,) or "
        "(n, n_motors) (degrees)", dtype=np.float64,
    )
    if q.ndim == 1:
        q = q[:, None]
    if q.ndim != 2 or q.shape[1] < 1:
        raise ValueError(
            f"The motor angles{_of_run(run)} must have shape (n,) or (n, n_motors) "
            f"(degrees); got shape {q.shape}."
        )
    if len(q) < 3:
        raise ValueError(
            f"The motor angles{_of_run(run)} have {len(q)} sample(s); finding the sweep end "
            "needs at least 3."
        )
    if not np.isfinite(q).all():
        first = int(np.flatnonzero(~np.isfinite(q).all(axis=1))[0])
        raise ValueError(
            f"The motor angles{_of_run(run)} contain non-finite values, first at sample "
            f"{first}; motor angles must be finite."
        )
    return q, _times(t, rate_hz, len(q), run), run


def _times(t, rate_hz, n, run):
    """Sample times (s) from ``t`` or ``rate_hz`` (exactly one of them)."""
    if (t is None) == (rate_hz is None):
        raise ValueError(
            "Give the sample times t (s) or the sampling rate rate_hz (Hz), exactly one of "
            f"them, to find the sweep end{_of_run(run)}; got "
            + ("neither." if t is None else "both.")
        )
    if t is None:
        return np.arange(n) / float(rate_hz)
    t = to_array(t, f"t{_of_run(run)} must be numeric sample times (s)", dtype=np.float64)
    if t.shape != (n,):
        raise ValueError(
            f"t{_of_run(run)} must have shape ({n},), one time (s) per sample; got {t.shape}."
        )
    if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        raise ValueError(f"t{_of_run(run)} must be finite and strictly increasing (s).")
    return t


def _ray_check(k, a, b, d, rho, t, rest_stops, params, first, sigma):
    """Why the excursion ``k`` (samples ``a .. b - 1``) is not a ray, or None if it is one.

    Returns the reason, the unit direction and the peak of the excursion.
    """
    r = rho[a:b]
    peak = float(r.max())
    far = r > _FAR_FRACTION * peak
    u = (d[a:b][far] / r[far, None]).mean(axis=0)
    norm = float(np.linalg.norm(u))
    if norm > 0.0:
        u = u / norm
        cos_dev = np.clip((d[a:b][far] @ u) / r[far], -1.0, 1.0)
        turn = float(np.rad2deg(np.arccos(cos_dev.min())))
    else:  # the far part points every way around neutral
        u, turn = d[a + int(np.argmax(r))] / peak, 180.0
    amplitude, duration = first
    if abs(peak / amplitude - 1.0) > _AMPLITUDE_TOLERANCE:
        return (f"reaches {peak:.1f} deg from neutral against {amplitude:.1f} deg for the "
                f"first ray (rays reach the same amplitude within "
                f"{100 * _AMPLITUDE_TOLERANCE:.0f} %)"), u, peak
    if duration is not None and abs((t[b - 1] - t[a]) / duration - 1.0) > _DURATION_TOLERANCE:
        return (f"lasts {t[b - 1] - t[a]:.1f} s against {duration:.1f} s for the first ray "
                f"(rays are swept at the same speed, durations within "
                f"{100 * _DURATION_TOLERANCE:.0f} %)"), u, peak
    top = int(np.argmax(r))
    reversal = max(float((np.maximum.accumulate(r[:top + 1]) - r[:top + 1]).max()),
                   float((r[top:] - np.minimum.accumulate(r[top:])).max()))
    if reversal > _MAX_REVERSAL * peak + _NOISE_SIGMAS * sigma:
        return (f"goes back and forth: |q - q_neutral| turns back by {reversal:.1f} deg "
                f"(a ray goes out and back, turning once)"), u, peak
    if turn > params["max_turn_deg"]:
        return (f"turns by {turn:.1f} deg far from neutral (a ray keeps one direction "
                f"within max_turn_deg={params['max_turn_deg']:g})"), u, peak
    if b == len(rho):
        return "does not come back to neutral", u, peak
    rest = t[rest_stops[k] - 1] - t[b] if rest_stops[k] > b else 0.0
    if rest < params["min_rest_s"]:
        return (f"comes back to neutral but rests there {rest:.2f} s (a ray ends with a "
                f"rest of at least min_rest_s={params['min_rest_s']:g} s)"), u, peak
    return None, u, peak


def _scan(q, t, q_neutral, params, run):
    """One pass of steps 1-3 from a neutral estimate.

    Returns the number of sweep samples, the rays ``(start, stop, direction,
    peak)``, the neutral threshold (deg) and what follows the sweep.
    """
    d = q - q_neutral
    rho = np.linalg.norm(d, axis=1)
    sigma = _noise_level(q)
    moving = np.flatnonzero(rho > params["min_amplitude_deg"])
    if not moving.size:
        largest = float(rho.max())
        raise ValueError(
            f"The motors do not move at the start{_of_run(run)}: the largest motor-input "
            f"magnitude |q - q_neutral| is {largest:.3g} deg; expected a sweep whose rays reach "
            f"at least min_amplitude_deg={params['min_amplitude_deg']:g} deg."
            + (
                " Motor angles must be in degrees; a largest magnitude of at most 2*pi "
                "suggests radians (convert the motor angles with numpy.rad2deg)."
                if 0.0 < largest <= 2.0 * np.pi
                else ""
            )
        )
    # the first ray: from there until rho is back under half min_amplitude_deg
    back = np.flatnonzero(rho[moving[0]:] <= 0.5 * params["min_amplitude_deg"])
    first_end = len(rho) if not back.size else moving[0] + int(back[0])
    amplitude = float(rho[moving[0]:first_end].max())
    threshold = max(params["neutral_fraction"] * amplitude, _NOISE_SIGMAS * sigma)
    starts, stops = _stretches(rho > threshold)
    if starts.size:  # drop the noise around the neutral threshold
        moved = np.maximum.reduceat(rho, starts) > threshold + _NOISE_SIGMAS * sigma
        starts, stops = starts[moved], stops[moved]
    rest_stops = np.append(starts[1:], len(rho))  # where the rest after each excursion ends
    rays, ended_by, end_at = [], "the end of the recording", None
    for k, (a, b) in enumerate(zip(starts.tolist(), stops.tolist())):
        first = (amplitude, t[rays[0][1] - 1] - t[rays[0][0]] if rays else None)
        reason, u, peak = _ray_check(k, a, b, d, rho, t, rest_stops, params, first, sigma)
        if reason is not None:
            ended_by = (f"the excursion of samples {a}-{b - 1} (t = {t[a]:.1f}-{t[b - 1]:.1f} "
                        f"s), which {reason}")
            end_at = a
            break
        rays.append((a, b, u, peak))
    if not rays:
        raise ValueError(
            f"The start{_of_run(run)} is not a calibration sweep: {ended_by}; expected rays "
            "out from neutral and back, each followed by a rest at neutral of at least "
            f"min_rest_s={params['min_rest_s']:g} s."
        )
    if end_at is None:
        return len(rho), rays, threshold, ended_by
    rest = rays[-1][1], end_at
    min_rest = int(np.count_nonzero(t[rest[0]:rest[1]] - t[rest[0]] < params["min_rest_s"]))
    return _rest_end(q, *rest, min_rest), rays, threshold, ended_by


def _rest_noise(window: np.ndarray) -> float:
    """Encoder-noise standard deviation (deg) of samples at most three quarters in motion.

    As :func:`_noise_level`, from the lower quartile of the absolute second
    differences instead of their median: the quartile of ``|N(0, 6 sigma^2)|``
    is ``0.3186 sqrt(6) sigma``.
    """
    if len(window) < 3:
        return 0.0
    d2 = window[2:] - 2.0 * window[1:-1] + window[:-2]
    return float(np.quantile(np.abs(d2), 0.25, axis=0).max() / (0.3186 * np.sqrt(6.0)))


def _rest_end(q, rest_start, motion_start, min_rest):
    """One past the last sample of the rest before the motion.

    Within ``rest_start .. motion_start - 1`` (the return's end, the rest and
    the start of the motion, all within the neutral threshold), the rest's
    position is the median of the slowest samples (speed within 4 ``sigma``
    of its lower quartile; ``sigma``: the encoder noise of the window), and
    the samples at rest are those whose distance to it is within 4 ``sigma``
    of the slow samples' median distance;
    stretches of them separated by up to two samples join. The rest is the
    last such stretch of at least ``min_rest`` samples (the longest if none
    is that long): the motion leaves it gradually, and may cross neutral
    before it leaves the threshold.
    """
    window = q[rest_start:motion_start]
    sigma = _rest_noise(window)
    # the rest's position: the median of the slowest samples (the rest may be
    # the smaller part of the window when the motion starts with a small step)
    speed = np.linalg.norm(np.gradient(window, axis=0), axis=1) if len(window) > 1 \
        else np.zeros(len(window))
    slow = speed <= np.quantile(speed, 0.25) + _NOISE_SIGMAS * sigma
    dist = np.linalg.norm(window - np.median(window[slow], axis=0), axis=1)
    still = dist <= np.median(dist[slow]) + _NOISE_SIGMAS * sigma
    starts, stops = _stretches(still)
    if not starts.size:
        return rest_start
    keep = np.append(starts[1:] - stops[:-1] > _REST_GAP, True)  # stretches ending a rest
    ends = stops[keep]
    begins = starts[np.append(True, keep[:-1])]
    long = np.flatnonzero(ends - begins >= min_rest)
    pick = long[-1] if long.size else int(np.argmax(ends - begins))
    return rest_start + int(ends[pick])


@validate_params(
    {
        "X": "no_validation",
        "t": "no_validation",
        "rate_hz": [Interval(Real, 0.0, None, closed="neither"), None],
        "run": "no_validation",
        "neutral_fraction": [Interval(Real, 0.0, _FAR_FRACTION, closed="neither")],
        "min_amplitude_deg": [Interval(Real, 0.0, None, closed="neither")],
        "max_turn_deg": [Interval(Real, 0.0, 90.0, closed="neither")],
        "min_rest_s": [Interval(Real, 0.0, None, closed="left")],
        "min_rays": [Interval(Integral, 1, None, closed="left")],
    },
    prefer_skip_nested_validation=True,
)
def find_sweep_end(
    X,
    t=None,
    *,
    rate_hz=None,
    run=None,
    neutral_fraction=0.03,
    min_amplitude_deg=5.0,
    max_turn_deg=10.0,
    min_rest_s=0.5,
    min_rays=2,
) -> SweepEnd:
    """Find where the calibration sweep at the start of a run ends, from its motor angles.

    The sweep is a set of rays: from neutral the motors move out along one
    direction and straight back, then rest at neutral before the next ray.
    The sweep ends where the motors first move otherwise (see
    ``docs/sweep_recording.rst`` for what the robot must run).

    Parameters
    ----------
    X : pandas.DataFrame or array-like of shape (n,) or (n, n_motors)
        The rows of one run in time order: a DataFrame with the motor angles
        ``q1 .. qN`` (and ``t``, used when neither ``t`` nor ``rate_hz`` is
        given), or the motor angles themselves (degrees), any number of
        motors. Never modified.
    t : array-like of shape (n,), default=None
        Sample times (s), strictly increasing.
    rate_hz : float, default=None
        Sampling rate (Hz), for motor angles without times: ``t = i / rate_hz``.
    run : str or int, default=None
        Run id, used in error messages (read from a DataFrame's ``run``
        column when not given).
    neutral_fraction : float, default=0.03
        Samples with ``rho = |q - q_neutral|`` at most this fraction of the
        sweep amplitude are at neutral (never below four times the encoder
        noise estimated from the data).
    min_amplitude_deg : float, default=5.0
        Smallest motor-input magnitude that counts as motion (degrees).
    max_turn_deg : float, default=10.0
        Largest deviation of a ray's far part (``rho`` above half its peak)
        from its mean direction (degrees).
    min_rest_s : float, default=0.5
        Shortest rest at neutral after each ray (s).
    min_rays : int, default=2
        Fewest rays a sweep must have.

    Returns
    -------
    end : SweepEnd
        The number of sweep samples ``n_sweep``, the time of the last sweep
        sample, the rays found (directions, amplitudes, samples), the neutral
        motor angles and what follows the sweep.

    Raises
    ------
    ValueError
        Naming the run, when the motor angles are not finite or not of shape
        (n,) or (n, n_motors), when neither or both of ``t`` and ``rate_hz``
        are given or ``t`` is not strictly increasing, when the motors do not
        move, or when the start of the run is not a sweep: fewer than
        ``min_rays`` rays before the first excursion that is not a ray (the
        message says which excursion and why).

    See Also
    --------
    skcath.sweep.find_rays : the rays of a two-motor sweep, labelled sample by sample.
    skcath.io.read_recording : ``n_sweep="auto"`` finds the sweep of every run.

    Examples
    --------
    >>> from skcath.datasets import make_benchmark
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> run = data.X[data.X["run"] == "C1-S00-R1"]  # doctest: +SKIP
    >>> find_sweep_end(run).n_rays  # doctest: +SKIP
    8
    """
    q, t, run = _run_arrays(X, t, rate_hz, run)
    params = {
        "neutral_fraction": float(neutral_fraction),
        "min_amplitude_deg": float(min_amplitude_deg),
        "max_turn_deg": float(max_turn_deg),
        "min_rest_s": float(min_rest_s),
    }
    q_neutral = np.median(q[t <= t[0] + params["min_rest_s"]], axis=0)
    for _ in range(2):  # the second pass starts from the sweep's own neutral samples
        n_sweep, rays, threshold, ended_by = _scan(q, t, q_neutral, params, run)
        sweep = q[:n_sweep]
        at_rest = np.linalg.norm(sweep - q_neutral, axis=1) <= threshold
        q_neutral = sweep[at_rest].mean(axis=0) if at_rest.any() else q_neutral
    if len(rays) < min_rays:
        raise ValueError(
            f"The start{_of_run(run)} is not a calibration sweep: found {len(rays)} ray(s) "
            f"before {ended_by}; expected at least min_rays={min_rays} rays out from neutral "
            "and back, each followed by a rest at neutral."
        )
    fields = {
        "directions": np.array([u for _, _, u, _ in rays]),
        "amplitudes": np.array([peak for *_, peak in rays]),
        "bounds": np.array([(a, b) for a, b, *_ in rays], dtype=np.intp),
        "q_neutral": np.asarray(q_neutral, dtype=np.float64),
    }
    for array in fields.values():
        array.flags.writeable = False
    return SweepEnd(n_sweep=int(n_sweep), time_s=float(t[n_sweep - 1]),
                    neutral_threshold=float(threshold), ended_by=ended_by, **fields)


def n_sweep_hint(message, n_sweep, q, t, run) -> str:
    """A sweep error's message completed for a sweep cut by a user's ``n_sweep``.

    Parameters
    ----------
    message : str
        The message of the error the sweep rows gave.
    n_sweep : int or None
        The ``n_sweep`` the run was read with, None when its sweep rows came
        from a ``phase`` column or from ``n_sweep="auto"``.
    q : ndarray of shape (n, n_motors)
        Motor angles of all the run's rows, in time order (degrees).
    t : ndarray of shape (n,)
        Their times (s).
    run : str or int
        Run id.

    Returns
    -------
    message : str
        ``message`` unchanged when ``n_sweep`` is None or equals the detected
        sweep length; otherwise, without the hint about cut runs, followed by
        the ``n_sweep`` given and the end :func:`find_sweep_end` finds, or,
        when ``q`` holds only the ``n_sweep`` rows read as the sweep, how to
        find the end in the whole run.
    """
    if n_sweep is None:
        return message
    if len(q) <= n_sweep:  # only the rows read as the sweep, e.g. a sweep given to start
        return (
            f"{message.replace(' ' + CUT_RUN_HINT, '')} The run was read with "
            f"n_sweep={n_sweep} (its first {n_sweep} samples are the sweep), and only those "
            "rows are here, so where its sweep really ends cannot be found from them: find "
            "it in the whole run with skcath.sweep.find_sweep_end, or read the file with "
            "n_sweep='auto'."
        )
    try:
        found = find_sweep_end(q, t, run=run)
    except ValueError as exc:
        return (f"{message} The run was read with n_sweep={n_sweep} (its first {n_sweep} "
                f"samples are the sweep); finding the sweep end from the motor angles "
                f"failed too: {exc}")
    if found.n_sweep == n_sweep:
        return message
    return (
        f"{message.replace(' ' + CUT_RUN_HINT, '')} The run was read with n_sweep={n_sweep} "
        f"(its first {n_sweep} samples are the sweep), but from the motor angles its sweep "
        f"of {found.n_rays} rays ends after {found.n_sweep} samples (t = {found.time_s:.1f} s; "
        f"skcath.sweep.find_sweep_end): read it with n_sweep={found.n_sweep}, or with "
        "n_sweep='auto' to find the sweep of every run."
    )


@contextmanager
def naming_n_sweep(given, q, run):
    """Complete a sweep error raised in the ``with`` block by :func:`n_sweep_hint`.

    Parameters
    ----------
    given : tuple of (int, ndarray of shape (n,)) or None
        The ``n_sweep`` the run was read with and the times of the rows of
        ``q`` (s); None when no ``n_sweep`` was given, and errors pass
        unchanged.
    q : ndarray of shape (n, n_motors)
        Motor angles of the run's rows the block reads, in time order
        (degrees).
    run : str or int
        Run id.

    Raises
    ------
    ValueError
        The block's ValueError, its message completed when ``n_sweep`` may
        be its cause.
    """
    try:
        yield
    except ValueError as exc:
        if given is None:
            raise
        message = n_sweep_hint(str(exc), given[0], q, given[1], run)
        if message == str(exc):
            raise
        raise ValueError(message) from None
