"""Motor limits, rate limits and the inputs of a controller's step: checked, never exceeded."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .._format import REFERENCE_COLUMNS, TIME

__all__ = ["MotorLimits", "UnreachableTargetWarning", "check_target", "read_obs"]

#: Names of the tracker's tip in an observation, then their names in the recording format.
TRACKER_KEYS = ("x", "y", "z")


class UnreachableTargetWarning(UserWarning):
    """A target lies farther than ``reach_tol_mm`` from every tip the model reaches within the motor limits.

    The controller steers to the nearest reachable tip instead
    (``aimed_`` of the controller).
    """


class MotorLimits:
    """The motor angles a controller may command: a box, within the estimator's accepted disk.

    Parameters
    ----------
    low, high : ndarray of shape (n_motors,)
        Bounds of each motor angle (deg).
    neutral : ndarray of shape (n_motors,)
        Neutral motor angles of the sweep (deg).
    radius : float
        Largest distance of the motor angles from ``neutral`` (deg); inf for none.
    """

    def __init__(self, low, high, neutral, radius):
        self.low, self.high = np.asarray(low, float), np.asarray(high, float)
        self.neutral, self.radius = np.asarray(neutral, float), float(radius)
        self._bounds = tuple(zip(self.low.tolist(), self.high.tolist(), self.neutral.tolist()))

    def project(self, q):
        """``q`` (deg) brought into the box, then radially into the disk."""
        # on floats: a few motors, where numpy's calls would cost more than the arithmetic
        v = [min(max(x, lo), hi) for x, (lo, hi, _) in zip(np.asarray(q, dtype=float).tolist(), self._bounds)]
        d = [x - c for x, (_, _, c) in zip(v, self._bounds)]
        r = math.sqrt(sum(x * x for x in d))
        if r > self.radius:
            v = [c + x * (self.radius / r) for x, (_, _, c) in zip(d, self._bounds)]
        return np.array(v)

    def contains(self, q, tol=1e-9):
        """Whether ``q`` (deg) is within the limits."""
        d = q - self.neutral
        return bool(np.all(q >= self.low - tol) and np.all(q <= self.high + tol)
                    and float(d @ d) <= (self.radius + tol) ** 2)


def rate_limited(q, q_previous, max_step):
    """``q`` moved from ``q_previous`` by at most ``max_step`` (deg) on every motor.

    The move is scaled as a whole, so that its direction is kept. Returns the
    command and whether it was limited.
    """
    step = q - q_previous
    largest = float(np.max(np.abs(step)))
    if largest <= max_step:
        return q, False
    return q_previous + step * (max_step / largest), True


def check_target(target):
    """``target`` as a float array of shape (3,) (mm), or a ``ValueError`` naming it."""
    try:
        t = np.asarray(target, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"target must be 3 numbers, the tip's x, y, z in mm; got {target!r}.") from exc
    if t.shape != (3,):
        raise ValueError(f"target must have shape (3,) (x, y, z in mm in the base frame); got shape {t.shape}.")
    if not all(math.isfinite(v) for v in t.tolist()):
        raise ValueError(f"target must be finite (x, y, z in mm); got {t.tolist()}.")
    return t


def _tracker(obs):
    """The tracker's tip of a mapping observation, or None where it has none."""
    for keys in (TRACKER_KEYS, REFERENCE_COLUMNS):
        if all(k in obs for k in keys):
            return keys, np.array([float(obs[k]) for k in keys])
    return None, None


def read_obs(obs, channels, need_tracker):
    """The sample, its time and the tracker's tip of one observation.

    Parameters
    ----------
    obs : mapping, pandas.Series or sequence of float
        A mapping (or Series) with the channels, ``t`` and ``x, y, z`` (or
        ``ref_x, ref_y, ref_z``) when the tracker is on; or the channels'
        values in order, followed by the tracker's ``x, y, z`` when it is needed.
    channels : tuple of str
        The channels of a sample (``q1 .. qN``, then ``tau1 .. tauN``).
    need_tracker : bool
        Whether the tracker's tip is needed.

    Returns
    -------
    sample : tuple of float
    t : float or None
    tip : ndarray of shape (3,) or None
    """
    if isinstance(obs, Mapping) or hasattr(obs, "keys"):
        missing = [c for c in channels if c not in obs]
        if missing:
            raise ValueError(f"obs lacks the channel(s) {', '.join(missing)}; it must have {', '.join(channels)}.")
        sample = tuple(float(obs[c]) for c in channels)
        t = float(obs[TIME]) if TIME in obs else None
        names, tip = _tracker(obs)
        if need_tracker and tip is None:
            raise ValueError(
                "close_on='tracker' needs the tracker's tip in obs: keys x, y, z (mm); got "
                f"{', '.join(map(str, list(obs.keys())))}."
            )
    else:
        values = tuple(float(v) for v in obs)
        n = len(channels)
        if len(values) != n + 3 * need_tracker:
            extra = " then the tracker's x, y, z (mm)" if need_tracker else ""
            raise ValueError(f"obs must hold {n + 3 * need_tracker} numbers, {', '.join(channels)}{extra}; "
                             f"got {len(values)}.")
        sample, t, names = values[:n], None, TRACKER_KEYS
        tip = np.array(values[n:]) if need_tracker else None
    bad = [c for c, v in zip(channels, sample) if not math.isfinite(v)]
    if t is not None and not math.isfinite(t):
        bad.append(TIME)
    if need_tracker:
        bad += [k for k, v in zip(names, tip) if not math.isfinite(v)]
    if bad:
        raise ValueError(f"obs has non-finite value(s) for {', '.join(bad)}; a controller steps on finite samples "
                         "only (skip the sample, or hold the last command).")
    return sample, t, (tip if need_tracker else None)
