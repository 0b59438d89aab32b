"""Rays of the initial multidirectional sweep, found from the motor angles alone.

Every recording starts with a calibration sweep: from neutral the two bending
motors move out along a ray of direction ``psi = atan2(q2 - q2_0, q1 - q1_0)``
to a motor-input magnitude ``rho = |q - q_0|`` of about 60 degrees and back to
neutral, once per ray, for ``n_rays`` rays evenly spaced in direction. The
backbones are calibrated per ray, so they need to know which sweep sample
belongs to which ray. :func:`find_rays` recovers this from the motor angles
only (no simulator labels), tolerating a non-zero neutral, encoder noise, an
arbitrary first direction, slightly uneven directions and any ray order;
:func:`check_sweep_references` checks that the EM reference tip positions of a
sweep are usable for the calibration. :func:`find_sweep_end` finds where the
sweep of a run ends, for any number of motors (a recording without a
``phase`` column, ``docs/sweep_recording.rst``). :func:`reduce_sweep` keeps
only some rays or samples of every run's sweep, to study a smaller calibration budget; the
rays of such a sweep are found by passing the spacing of the full layout,
``ray_spacing_deg``, to :func:`find_rays` (and to the backbones).

Algorithm of :func:`find_rays`
------------------------------
1. Neutral: a robust centre (median of the 10 % of samples closest to the
   coordinate-wise median, twice), then the neutral samples are those with
   ``rho <= max(neutral_fraction * max(rho), 4 * sigma)`` (``sigma``: encoder
   noise estimated from second differences), and the neutral position is the
   mean of ``q`` over them, iterated until the neutral set is stable.
2. Excursions: contiguous stretches of non-neutral samples. An excursion whose
   largest ``rho`` is significant (at least ``min_amplitude_deg`` and a quarter
   of the sweep's largest ``rho``) defines a ray candidate whose direction is
   the circular mean of ``psi`` over its far part (``rho`` above half its
   largest ``rho``). An excursion that visits two directions without passing
   through neutral is split at the smallest ``rho`` between them.
3. Rays: candidates whose directions lie within half the nominal spacing
   ``180 / n_rays`` degrees of each other are merged (repeated excursions).
   Samples of small excursions (flicker around the neutral threshold) go to
   the ray closest to their own direction.

An excursion whose far part turns by more than a quarter of the ray spacing
(a move along the rim from one ray to the next) is refused, since its
direction would be a blend of two rays. All steps are vectorised over samples;
the only Python loop is over excursions, so a 4300-sample sweep takes about
1.5 ms.
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
import pandas as pd
from sklearn.utils._param_validation import Interval, validate_params

from ._format import PHASE, SWEEP
from ._runs import run_codes, run_positions
from ._sweep_end import SweepEnd, _noise_level, _stretches, find_sweep_end
from ._validation import CUT_RUN_HINT, check_recordings, check_target, motor_columns, to_array

__all__ = [
    "SweepEnd",
    "SweepRays",
    "check_sweep_references",
    "find_rays",
    "find_sweep_end",
    "reduce_sweep",
]

_TWO_PI = 2.0 * np.pi
# Fraction of the samples, closest to the running centre, used for the robust
# neutral estimate.
_CENTRE_FRACTION = 0.10
# Neutral threshold floor in units of the estimated encoder noise (deg).
_NOISE_FLOOR_SIGMAS = 4.0
# An excursion is a ray candidate when its largest rho reaches this fraction of
# the sweep's largest rho (and min_amplitude_deg).
_SIGNIFICANT_FRACTION = 0.25
# Far part of an excursion: rho above this fraction of the excursion's largest rho.
_FAR_FRACTION = 0.5
# A motor is stuck when its range is below this many degrees, or below this
# fraction of the other motor's range, while the other one moves.
_STUCK_RANGE_DEG = 1.0
_STUCK_RELATIVE = 0.05
# Largest allowed deviation of a far-part sample from its ray's direction, in
# nominal ray spacings (a move along the rim from one ray to the next is refused).
_MAX_SPREAD_SPACINGS = 0.25
# Largest allowed gap between neighbouring ray directions, in nominal spacings.
_MAX_GAP_SPACINGS = 1.5
# References must move by at least this much over the sweep (mm).
_MIN_REFERENCE_RANGE_MM = 1.0


@dataclass(frozen=True, eq=False)
class SweepRays:
    """Rays of one run's calibration sweep, as found by :func:`find_rays`.

    The arrays are read-only; compare instances field by field (``==`` is
    identity, since element-wise array comparison has no single truth value).

    Attributes
    ----------
    labels : ndarray of shape (n,), dtype intp
        Ray index ``0..K-1`` of each sweep sample, indexing :attr:`directions`;
        ``-1`` for the samples at neutral. Every sample away from neutral
        (outward move, dwell at the ray end, return move, and transitions)
        carries the label of a ray.
    directions : ndarray of shape (K,), dtype float64
        Ray directions ``psi_k`` (radians) in ``[-pi, pi)``, sorted ascending:
        ``psi = atan2(q2 - q_neutral[1], q1 - q_neutral[0])``.
    amplitudes : ndarray of shape (K,), dtype float64
        Largest motor-input magnitude ``rho = |q - q_neutral|`` reached on each
        ray (degrees).
    neutral : ndarray of shape (n,), dtype bool
        Samples at neutral, ``rho <=`` :attr:`neutral_threshold`.
    q_neutral : ndarray of shape (2,), dtype float64
        Motor angles ``(q1, q2)`` at neutral: the mean over the neutral
        samples (degrees).
    amplitude : float
        Sweep amplitude: the median of :attr:`amplitudes` (degrees).
    neutral_threshold : float
        Largest ``rho`` counted as neutral (degrees).
    """

    labels: np.ndarray
    directions: np.ndarray
    amplitudes: np.ndarray
    neutral: np.ndarray
    q_neutral: np.ndarray
    amplitude: float
    neutral_threshold: float = 0.0

    @property
    def n_rays(self) -> int:
        """Number of rays ``K``."""
        return int(self.directions.size)

    @property
    def directions_deg(self) -> np.ndarray:
        """Ray directions in degrees, in ``[-180, 180)``, sorted ascending."""
        return np.rad2deg(self.directions)

    def polar(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Motor-input magnitude and direction of ``q`` relative to neutral.

        Parameters
        ----------
        q : array-like of shape (m, 2)
            Motor angles ``(q1, q2)`` (degrees).

        Returns
        -------
        rho : ndarray of shape (m,)
            ``|q - q_neutral|`` (degrees).
        psi : ndarray of shape (m,)
            ``atan2(q2 - q_neutral[1], q1 - q_neutral[0])`` (radians, in
            ``[-pi, pi]``).
        """
        d = np.asarray(q, dtype=np.float64) - self.q_neutral
        return np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def _of_run(run) -> str:
    """`` of run 'X'`` for messages, or an empty string without a run id."""
    return "" if run is None else f" of run {run!r}"


def _cut_hint(run) -> str:
    """How to keep runs whole, for the errors a cut sweep gives; empty without a run id."""
    return "" if run is None else " " + CUT_RUN_HINT


def _in_run(run) -> str:
    """`` in run 'X'`` for messages, or an empty string without a run id."""
    return "" if run is None else f" in run {run!r}"


def _wrap(angle):
    """Wrap angles (radians) into ``[-pi, pi)``."""
    return (np.asarray(angle) + np.pi) % _TWO_PI - np.pi


def _fmt_deg(directions) -> str:
    """Directions (radians) as a readable list of degrees in ``[0, 360)``."""
    deg = np.sort(np.rad2deg(np.asarray(directions)) % 360.0)
    return "[" + ", ".join(f"{d:.1f}" for d in deg) + "]"


def _robust_centre(q: np.ndarray) -> np.ndarray:
    """Approximate neutral: median of the samples closest to the running centre."""
    centre = np.median(q, axis=0)
    k = max(1, int(_CENTRE_FRACTION * len(q)))
    for _ in range(2):
        d = q - centre
        r2 = d[:, 0] ** 2 + d[:, 1] ** 2
        closest = np.argpartition(r2, k - 1)[:k]
        centre = np.median(q[closest], axis=0)
    return centre


def _circular_groups(angles: np.ndarray, tol: float) -> np.ndarray:
    """Group angles (radians) on the circle: neighbours closer than ``tol`` join.

    Returns the group id of every angle, ``0..G-1``.
    """
    m = angles.size
    if m == 0:
        return np.zeros(0, dtype=np.intp)
    order = np.argsort(angles)
    s = angles[order]
    gaps = np.diff(s, append=s[0] + _TWO_PI)  # gap after each sorted angle
    breaks = gaps > tol
    group_sorted = np.concatenate([[0], np.cumsum(breaks[:-1])]).astype(np.intp)
    if breaks.any() and not breaks[-1]:
        # the wrap-around gap is small: the last group continues the first
        group_sorted[group_sorted == group_sorted[-1]] = 0
    _, group_sorted = np.unique(group_sorted, return_inverse=True)
    groups = np.empty(m, dtype=np.intp)
    groups[order] = group_sorted
    return groups


# ---------------------------------------------------------------------------
# find_rays
# ---------------------------------------------------------------------------
def _as_motor_angles(q, run) -> np.ndarray:
    """The sweep motor angles as a float64 array, or a ValueError that says what was expected."""
    return to_array(
        q,
        f"The sweep motor angles{_of_run(run)} must be a numeric array of shape (n, 2) "
        "with columns q1, q2 (degrees)",
        dtype=np.float64,
    )


def _check_motor_angles(arr, run, n_rays, min_samples) -> np.ndarray:
    """Validate the sweep motor angles, a float64 array, and return them."""
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(
            f"The sweep motor angles{_of_run(run)} must have shape (n, 2) with "
            f"columns q1, q2 (degrees); got shape {arr.shape}."
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        cols = [name for j, name in enumerate(("q1", "q2")) if bad[:, j].any()]
        first = int(np.flatnonzero(bad.any(axis=1))[0])
        raise ValueError(
            f"The sweep motor angles{_of_run(run)} contain "
            f"{int(bad.sum())} non-finite value(s) in column(s) {cols}; first at "
            f"sweep sample {first}. Motor angles must be finite."
        )
    n = arr.shape[0]
    if n < min_samples:
        raise ValueError(
            f"The sweep{_of_run(run)} has {n} samples; expected at least "
            f"{min_samples} (n_rays={n_rays} rays out and back from neutral)."
            + _cut_hint(run)
        )
    return arr


def _check_motion(q, rho_max, run, n_rays, min_amplitude_deg) -> None:
    """Raise when the motors do not move or one of them is stuck."""
    if rho_max < min_amplitude_deg:
        raise ValueError(
            f"The motors do not move during the sweep{_of_run(run)}: the largest "
            f"motor-input magnitude |q - q_neutral| is {rho_max:.3g} deg; expected "
            f"rays of at least min_amplitude_deg={min_amplitude_deg:g} deg."
            + (
                " Motor angles must be in degrees; a largest magnitude of at most "
                "2*pi suggests radians (convert q1, q2 with numpy.rad2deg)."
                if 0.0 < rho_max <= _TWO_PI
                else ""
            )
        )
    if n_rays < 3:  # two opposite rays may legitimately use a single motor
        return
    span = np.ptp(q, axis=0)
    for j, name in enumerate(("q1", "q2")):
        other = span[1 - j]
        limit = max(_STUCK_RANGE_DEG, _STUCK_RELATIVE * other)
        if span[j] < limit and other >= min_amplitude_deg:
            raise ValueError(
                f"Motor column {name!r} does not move during the sweep{_of_run(run)}: "
                f"its range is {span[j]:.3g} deg while "
                f"{('q1', 'q2')[1 - j]!r} spans {other:.3g} deg; a sweep of "
                f"{n_rays} rays moves both motors (expected a range of at least "
                f"{limit:.3g} deg). Is the motor or its encoder stuck?"
            )


def _excursion_pieces(rho, ux, uy, neutral, significant, tol):
    """Split the non-neutral stretches into pieces, one per visited direction.

    Returns
    -------
    starts, stops : ndarray of int
        Sample range of each piece.
    is_ray : ndarray of bool
        Whether the piece is a ray candidate (part of a significant excursion).
    csum, ssum : ndarray of float
        Sums of ``cos psi`` and ``sin psi`` over the far part of each candidate
        (``rho`` above half the candidate's largest ``rho``); 0 otherwise.
    spread : ndarray of float
        Largest angular distance (radians) of a far-part sample from the
        candidate's circular-mean direction; 0 for the other pieces.
    """
    seg_starts, seg_stops = _stretches(~neutral)
    starts, stops, is_ray = [], [], []
    for a, b in zip(seg_starts.tolist(), seg_stops.tolist()):
        r = rho[a:b]
        peak = r.max()
        if peak < significant:
            starts.append(a)
            stops.append(b)
            is_ray.append(False)
            continue
        far = r > _FAR_FRACTION * peak
        f_starts, f_stops = _stretches(far)
        bounds = [a]
        if f_starts.size > 1:
            cx = np.add.reduceat(np.where(far, ux[a:b], 0.0), f_starts)
            cy = np.add.reduceat(np.where(far, uy[a:b], 0.0), f_starts)
            angle = np.arctan2(cy, cx)
            # consecutive far stretches pointing the same way stay together; a
            # new direction reached without passing through neutral starts a
            # new piece at the smallest rho between the two far stretches
            group_angle = angle[0]
            gx, gy = cx[0], cy[0]
            for i in range(1, f_starts.size):
                if abs(_wrap(angle[i] - group_angle)) <= tol:
                    gx, gy = gx + cx[i], gy + cy[i]
                else:
                    lo, hi = f_stops[i - 1], f_starts[i]
                    bounds.append(a + lo + int(np.argmin(r[lo:hi])))
                    gx, gy = cx[i], cy[i]
                group_angle = np.arctan2(gy, gx)
        bounds.append(b)
        starts.extend(bounds[:-1])
        stops.extend(bounds[1:])
        is_ray.extend([True] * (len(bounds) - 1))

    starts = np.asarray(starts, dtype=np.intp)
    stops = np.asarray(stops, dtype=np.intp)
    is_ray = np.asarray(is_ray, dtype=bool)
    csum = np.zeros(starts.size)
    ssum = np.zeros(starts.size)
    spread = np.zeros(starts.size)
    for i in np.flatnonzero(is_ray).tolist():
        r = rho[starts[i] : stops[i]]
        far = r > _FAR_FRACTION * r.max()
        fx = ux[starts[i] : stops[i]][far]
        fy = uy[starts[i] : stops[i]][far]
        csum[i], ssum[i] = fx.sum(), fy.sum()
        mean = np.arctan2(ssum[i], csum[i])
        # angular distance of each far sample from the mean direction
        cos_dev = np.clip(fx * np.cos(mean) + fy * np.sin(mean), -1.0, 1.0)
        spread[i] = np.arccos(cos_dev.min())
    return starts, stops, is_ray, csum, ssum, spread


def _ray_spacing(ray_spacing_deg, n_rays: int) -> float:
    """Nominal angle between neighbouring ray directions of the layout (radians)."""
    if ray_spacing_deg is None:
        return _TWO_PI / n_rays
    try:
        spacing_deg = float(ray_spacing_deg)
    except (TypeError, ValueError):
        raise ValueError(
            f"ray_spacing_deg must be a number of degrees or None; got {ray_spacing_deg!r}."
        ) from None
    if not 0.0 < spacing_deg <= 360.0 / n_rays:
        raise ValueError(
            f"ray_spacing_deg must be in (0, 360 / n_rays] = (0, {360.0 / n_rays:g}] "
            f"degrees for n_rays={n_rays} rays; got {ray_spacing_deg!r}."
        )
    return np.deg2rad(spacing_deg)


def _find_neutral(q, run, n_rays, neutral_fraction, min_amplitude_deg):
    """Step 1 of :func:`find_rays`: neutral position and threshold.

    Returns
    -------
    q_neutral : ndarray of shape (2,)
        Motor angles at neutral (degrees).
    d : ndarray of shape (n, 2)
        ``q - q_neutral`` (degrees).
    rho : ndarray of shape (n,)
        ``|q - q_neutral|`` (degrees).
    neutral : ndarray of bool, shape (n,)
        Samples at neutral.
    threshold : float
        Largest ``rho`` counted as neutral (degrees).
    """
    centre = _robust_centre(q)
    d = q - centre
    rho = np.hypot(d[:, 0], d[:, 1])
    rho_max = float(rho.max())
    _check_motion(q, rho_max, run, n_rays, min_amplitude_deg)
    threshold = max(neutral_fraction * rho_max, _NOISE_FLOOR_SIGMAS * _noise_level(q))
    neutral = rho <= threshold
    if not neutral.any():
        raise ValueError(
            f"The sweep{_of_run(run)} never comes back to neutral: no sample lies "
            f"within {threshold:.3g} deg of the estimated neutral motor angles "
            f"{np.round(centre, 2).tolist()}; expected each ray to start and end at neutral."
        )
    for _ in range(5):
        centre = q[neutral].mean(axis=0)
        d = q - centre
        rho = np.hypot(d[:, 0], d[:, 1])
        updated = rho <= threshold
        if np.array_equal(updated, neutral) or not updated.any():
            break
        neutral = updated
    return centre, d, rho, neutral, threshold


def _find_excursions(d, rho, neutral, spacing, min_amplitude_deg, run):
    """Step 2 of :func:`find_rays`: excursions away from neutral and their directions.

    Returns
    -------
    ux, uy : ndarray of shape (n,)
        Unit direction ``(cos psi, sin psi)`` of every sample; 0 at neutral.
    starts, stops, is_ray, csum, ssum : ndarray
        The pieces of :func:`_excursion_pieces`.

    Raises
    ------
    ValueError
        If a ray candidate turns by more than a quarter of the spacing far
        from neutral.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(neutral, 0.0, d[:, 0] / rho)
        uy = np.where(neutral, 0.0, d[:, 1] / rho)
    tol = 0.5 * spacing  # half the nominal spacing
    significant = max(min_amplitude_deg, _SIGNIFICANT_FRACTION * float(rho.max()))
    starts, stops, is_ray, csum, ssum, spread = _excursion_pieces(
        rho, ux, uy, neutral, significant, tol
    )
    max_spread = _MAX_SPREAD_SPACINGS * spacing
    if spread.max(initial=0.0) > max_spread:
        i = int(np.argmax(spread))
        raise ValueError(
            f"The sweep{_of_run(run)} changes direction far from neutral within "
            f"one excursion (sweep samples {int(starts[i])}-{int(stops[i]) - 1}): "
            f"its direction psi deviates by up to {np.rad2deg(spread[i]):.1f} deg "
            f"from its mean; expected out-and-back moves along rays from neutral, "
            f"each within {np.rad2deg(max_spread):.1f} deg of one direction at "
            f"rho above half its peak." + _cut_hint(run)
        )
    return ux, uy, (starts, stops, is_ray, csum, ssum)


def _merge_rays(is_ray, csum, ssum, spacing):
    """Step 3 of :func:`find_rays`: merge candidates pointing the same way into rays.

    Returns
    -------
    directions : ndarray of shape (K,)
        Ray directions (radians) in ``[-pi, pi)``, sorted ascending.
    piece_label : ndarray of int, shape (n_pieces,)
        Ray of every piece that is a ray candidate, -1 for the others.
    """
    cand = np.flatnonzero(is_ray)
    cand_dir = np.arctan2(ssum[cand], csum[cand])
    groups = _circular_groups(cand_dir, 0.5 * spacing)
    n_found = int(groups.max()) + 1 if groups.size else 0
    gx = np.bincount(groups, weights=csum[cand], minlength=n_found)
    gy = np.bincount(groups, weights=ssum[cand], minlength=n_found)
    group_dir = _wrap(np.arctan2(gy, gx))
    order = np.argsort(group_dir)
    rank = np.empty(n_found, dtype=np.intp)
    rank[order] = np.arange(n_found)
    piece_label = np.full(is_ray.size, -1, dtype=np.intp)
    piece_label[cand] = rank[groups]
    return group_dir[order], piece_label


def _check_layout(directions, n_candidates, n_rays, spacing, ray_spacing_deg, run):
    """Raise unless ``n_rays`` rays were found with no gap too wide between them."""
    n_found = directions.size
    layout = (
        f"spaced {360.0 / n_rays:g} deg apart"
        if ray_spacing_deg is None
        else f"from a layout spaced {np.rad2deg(spacing):g} deg apart"
    )
    if n_found != n_rays:
        what = "Rays missing" if n_found < n_rays else "Too many rays"
        raise ValueError(
            f"{what} in the sweep{_of_run(run)}: found {n_found} distinct "
            f"ray(s) at directions {_fmt_deg(directions)} deg (from "
            f"{n_candidates} excursion(s) away from neutral); expected "
            f"n_rays={n_rays} rays {layout}." + _cut_hint(run)
        )
    gaps = np.diff(directions, append=directions[0] + _TWO_PI)
    if ray_spacing_deg is None:
        max_gap = _MAX_GAP_SPACINGS * _TWO_PI / n_rays
    else:  # the rays left when the others of the layout are side by side, and slack
        max_gap = _TWO_PI - (n_rays - 1) * spacing + (_MAX_GAP_SPACINGS - 1.0) * spacing
    if gaps.max() > max_gap:
        i = int(np.argmax(gaps))
        a = np.rad2deg(directions[i]) % 360.0
        b = np.rad2deg(directions[(i + 1) % n_found]) % 360.0
        raise ValueError(
            f"Rays missing in the sweep{_of_run(run)}: a gap of "
            f"{np.rad2deg(gaps[i]):.1f} deg between the rays at {a:.1f} and "
            f"{b:.1f} deg (directions found: {_fmt_deg(directions)} deg); expected "
            f"{n_rays} rays {layout}, with no gap above "
            f"{np.rad2deg(max_gap):.1f} deg." + _cut_hint(run)
        )


def _label_samples(starts, stops, piece_label, neutral, ux, uy, directions):
    """Ray of every sample: ray candidates by excursion, small excursions by direction.

    Returns
    -------
    labels : ndarray of int, shape (n,)
        Ray index of every sample, -1 at neutral.
    """
    labels = np.full(neutral.size, -1, dtype=np.intp)
    lengths = stops - starts
    idx = np.repeat(starts - np.cumsum(np.concatenate([[0], lengths[:-1]])), lengths)
    idx += np.arange(lengths.sum())
    labels[idx] = np.repeat(piece_label, lengths)
    loose = np.flatnonzero((labels < 0) & ~neutral)
    if loose.size:
        psi = np.arctan2(uy[loose], ux[loose])
        dist = np.abs(_wrap(psi[:, None] - directions[None, :]))
        labels[loose] = np.argmin(dist, axis=1)
    return labels


@validate_params(
    {
        "q": "no_validation",
        "n_rays": [Interval(Integral, 2, None, closed="left")],
        "run": "no_validation",
        "neutral_fraction": [Interval(Real, 0.0, _FAR_FRACTION, closed="neither")],
        "min_amplitude_deg": [Interval(Real, 0.0, None, closed="neither")],
        "min_samples": [Interval(Integral, 1, None, closed="left"), None],
        "ray_spacing_deg": "no_validation",
    },
    prefer_skip_nested_validation=True,
)
def find_rays(
    q,
    *,
    n_rays: int = 8,
    run=None,
    neutral_fraction: float = 0.03,
    min_amplitude_deg: float = 5.0,
    min_samples: int | None = None,
    ray_spacing_deg: float | None = None,
) -> SweepRays:
    """Find the rays of a calibration sweep from its motor angles.

    Parameters
    ----------
    q : array-like of shape (n, 2)
        Motor angles ``(q1, q2)`` (degrees) of the sweep rows of one run, in
        time order. Never modified.
    n_rays : int, default 8
        Number of rays the protocol sweeps, evenly spaced by ``360 / n_rays``
        degrees.
    run : str or None, default None
        Run id, used in error messages only.
    neutral_fraction : float, default 0.03
        Samples with ``rho = |q - q_neutral|`` at most this fraction of the
        largest ``rho`` of the sweep are at neutral (the threshold never drops
        below four times the encoder noise estimated from the data).
    min_amplitude_deg : float, default 5.0
        Smallest motor-input magnitude (degrees) that counts as motion; an
        excursion must reach it (and a quarter of the sweep's largest ``rho``)
        to define a ray.
    min_samples : int or None, default None
        Fewest sweep samples accepted; None means ``10 * n_rays``.
    ray_spacing_deg : float or None, default None
        Nominal angle between neighbouring directions of the sweep layout
        (degrees). None means ``360 / n_rays``: the rays are evenly spaced
        around the circle. Give the spacing of the full layout for a sweep
        that keeps only some of its rays (:func:`reduce_sweep`), e.g. 45 for
        4 of 8 rays; it must be at most ``360 / n_rays``. Candidates within
        half the spacing are merged, and the largest allowed gap between
        neighbouring directions is ``360 - (n_rays - 1) * spacing`` plus half
        a spacing, which is ``1.5 * 360 / n_rays`` for the default.

    Returns
    -------
    rays : SweepRays
        Labels, sorted directions (radians), amplitudes (degrees), neutral
        mask and neutral motor angles (degrees) of the sweep.

    Raises
    ------
    sklearn.utils._param_validation.InvalidParameterError
        When ``n_rays`` is not an integer of at least 2, ``neutral_fraction``
        not in ``(0, 0.5)``, ``min_amplitude_deg`` not positive or
        ``min_samples`` not a positive integer or None.
    ValueError
        Naming the run, when ``q`` is not of shape (n, 2) or not finite, when
        the sweep has fewer than ``min_samples`` samples, when the motors do
        not move (largest ``rho`` below ``min_amplitude_deg``; when it is at
        most ``2 * pi`` the message points to angles in radians), when one motor
        column (``q1`` or ``q2``) is stuck while the other moves, when fewer or
        more distinct rays than ``n_rays`` are found, when two neighbouring
        ray directions are more than ``1.5 * 360 / n_rays`` degrees apart (a
        ray is missing; see ``ray_spacing_deg`` for reduced sweeps), or when
        an excursion changes direction far from neutral by more than a
        quarter of the spacing, ``90 / n_rays`` degrees by default (a move
        along the rim between rays instead of out and back).

    Notes
    -----
    Only the motor angles are used. The neutral position is estimated from the
    data, so a rig whose neutral is not at ``q = 0`` works; the first ray's
    direction and the order of the rays are arbitrary. Repeated excursions in
    the same direction (within ``180 / n_rays`` degrees) form one ray. The
    cost is linear in ``n`` with a Python loop over excursions only.

    Examples
    --------
    >>> from skcath.datasets._protocol import sweep_trajectory
    >>> rays = find_rays(sweep_trajectory(), run="demo")
    >>> rays.n_rays, round(rays.amplitude, 1)
    (8, 60.0)
    """
    return _find_rays(
        _as_motor_angles(q, run), n_rays=n_rays, run=run, neutral_fraction=neutral_fraction,
        min_amplitude_deg=min_amplitude_deg, min_samples=min_samples,
        ray_spacing_deg=ray_spacing_deg,
    )


def _find_rays(q, *, n_rays, run=None, neutral_fraction=0.03, min_amplitude_deg=5.0,
               min_samples=None, ray_spacing_deg=None) -> SweepRays:
    """:func:`find_rays` of motor angles that are a float64 ndarray already, parameters valid.

    For the checked sweep rows of a run (a backbone's calibration): the
    angles are not converted again; their shape, values and number are
    checked as by :func:`find_rays`.
    """
    spacing = _ray_spacing(ray_spacing_deg, n_rays)
    if min_samples is None:
        min_samples = 10 * n_rays
    q = _check_motor_angles(q, run, n_rays, int(min_samples))

    # 1. neutral position and threshold
    q_neutral, d, rho, neutral, threshold = _find_neutral(
        q, run, n_rays, neutral_fraction, min_amplitude_deg
    )
    # 2. excursions and their directions
    ux, uy, (starts, stops, is_ray, csum, ssum) = _find_excursions(
        d, rho, neutral, spacing, min_amplitude_deg, run
    )
    # 3. merge candidates pointing the same way into rays
    directions, piece_label = _merge_rays(is_ray, csum, ssum, spacing)
    _check_layout(directions, int(is_ray.sum()), n_rays, spacing, ray_spacing_deg, run)
    labels = _label_samples(starts, stops, piece_label, neutral, ux, uy, directions)

    amplitudes = np.zeros(directions.size)
    on_ray = labels >= 0
    np.maximum.at(amplitudes, labels[on_ray], rho[on_ray])
    for array in (labels, directions, amplitudes, neutral, q_neutral):
        array.flags.writeable = False
    return SweepRays(
        labels=labels,
        directions=directions,
        amplitudes=amplitudes,
        neutral=neutral,
        q_neutral=q_neutral,
        amplitude=float(np.median(amplitudes)),
        neutral_threshold=float(threshold),
    )


# ---------------------------------------------------------------------------
# check_sweep_references
# ---------------------------------------------------------------------------
@validate_params(
    {
        "ref": "no_validation",
        "rays": "no_validation",
        "run": "no_validation",
        "min_fraction": [Interval(Real, 0.0, 1.0, closed="both")],
    },
    prefer_skip_nested_validation=True,
)
def check_sweep_references(ref, rays: SweepRays, *, run=None, min_fraction: float = 0.5) -> None:
    """Check that the EM reference tip positions of a sweep can calibrate a backbone.

    Parameters
    ----------
    ref : array-like of shape (n, 3)
        Reference tip positions in the base frame (mm) of the sweep samples
        passed to :func:`find_rays`, in the same order. NaN marks a tracker
        dropout.
    rays : SweepRays
        The rays of the same sweep, from :func:`find_rays`.
    run : str or None, default None
        Run id, used in error messages only.
    min_fraction : float, default 0.5
        Smallest fraction of each ray's samples that must have a finite
        reference.

    Raises
    ------
    TypeError
        When ``rays`` is not a :class:`SweepRays`.
    sklearn.utils._param_validation.InvalidParameterError
        When ``min_fraction`` is not in ``[0, 1]``.
    ValueError
        Naming the run, when ``ref`` does not have shape ``(n, 3)`` matching
        ``rays``, when fewer than ``min_fraction`` of a ray's samples have a
        finite reference (the message names the ray direction in degrees),
        when no neutral sample has a finite reference, or when the references
        do not move (peak-to-peak below 1 mm in every coordinate over the
        sweep; the message points to positions in metres).

    Notes
    -----
    A row counts as finite when all three coordinates are finite. ``ref`` is
    never modified.
    """
    if not isinstance(rays, SweepRays):
        raise TypeError(
            f"rays must be the SweepRays returned by find_rays; got "
            f"{type(rays).__module__}.{type(rays).__qualname__}."
        )
    ref = to_array(
        ref,
        f"The sweep references{_of_run(run)} must be numeric of shape (n, 3) "
        "(ref_x, ref_y, ref_z in mm)",
        dtype=np.float64,
    )
    _check_sweep_references(ref, rays, run=run, min_fraction=min_fraction)


def _check_sweep_references(ref, rays, *, run=None, min_fraction=0.5) -> None:
    """:func:`check_sweep_references` of references that are a float64 ndarray already.

    For the checked sweep rows of a run: ``rays`` is the :class:`SweepRays`
    of :func:`find_rays` and ``min_fraction`` valid; the shape and values
    of ``ref`` are checked as by :func:`check_sweep_references`.
    """
    n = rays.labels.size
    if ref.shape != (n, 3):
        raise ValueError(
            f"The sweep references{_of_run(run)} must have shape ({n}, 3), one "
            f"(ref_x, ref_y, ref_z) row (mm) per sweep sample; got shape {ref.shape}."
        )
    finite = np.isfinite(ref).all(axis=1)

    k = rays.n_rays
    on_ray = rays.labels >= 0
    total = np.bincount(rays.labels[on_ray], minlength=k)
    good = np.bincount(rays.labels[on_ray & finite], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.where(total > 0, good / np.maximum(total, 1), 0.0)
    poor = np.flatnonzero(fraction < min_fraction)
    if poor.size:
        deg = np.rad2deg(rays.directions) % 360.0
        listed = "; ".join(
            f"ray {int(i)} at {deg[i]:.1f} deg: {int(good[i])} of {int(total[i])} "
            f"({100.0 * fraction[i]:.0f} %)"
            for i in poor
        )
        raise ValueError(
            f"Too few finite reference tip positions{_in_run(run)} on "
            f"{poor.size} ray(s) of the sweep ({listed}); expected at least "
            f"{100.0 * min_fraction:.0f} % of each ray's samples to have finite "
            f"ref_x, ref_y, ref_z (EM tracker dropouts?)."
        )
    n_neutral = int(rays.neutral.sum())
    if not (finite & rays.neutral).any():
        raise ValueError(
            f"No neutral sample of the sweep{_of_run(run)} has a finite reference "
            f"tip position ({n_neutral} neutral sample(s), all NaN); expected at "
            "least one to locate the neutral tip."
        )
    span = np.ptp(ref[finite], axis=0)
    if span.max() < _MIN_REFERENCE_RANGE_MM:
        raise ValueError(
            f"The reference tip positions{_in_run(run)} do not move during the "
            f"sweep: their range is {np.array2string(span, precision=3)} mm in "
            f"(ref_x, ref_y, ref_z); expected at least "
            f"{_MIN_REFERENCE_RANGE_MM:g} mm while the motors sweep "
            f"{rays.amplitude:.1f} deg. Is the EM tip sensor attached and read? "
            "Positions must be in mm; if they are in metres, multiply every position "
            "by 1000: the references and the target alike (read_recording: "
            "scale={...: 1000.0} for each position column the file has, ref_x/y/z, "
            "p_x/y/z or tip_px.../base_px...)."
        )


# ---------------------------------------------------------------------------
# reduce_sweep
# ---------------------------------------------------------------------------
def _kept_rays(directions: np.ndarray, n_rays: int) -> np.ndarray:
    """Indices of the ``n_rays`` rays kept out of ``directions`` (radians, sorted).

    The reference ray is the one closest to ``psi = 0`` (the positive ``q1``
    direction). With ``n_rays >= 3`` the targets are the reference direction
    plus multiples of ``360 / n_rays`` degrees; with ``n_rays == 2`` they are
    the reference direction and the one 90 degrees on, so that both motors
    move. Each target takes the nearest ray not taken yet, in target order.
    """
    first = directions[np.argmin(np.abs(_wrap(directions)))]
    step = np.pi / 2.0 if n_rays == 2 else _TWO_PI / n_rays
    free = np.ones(directions.size, dtype=bool)
    kept = []
    for j in range(n_rays):
        dist = np.abs(_wrap(directions - (first + j * step)))
        dist[~free] = np.inf
        k = int(np.argmin(dist))
        free[k] = False
        kept.append(k)
    return np.sort(np.asarray(kept, dtype=np.intp))


def _ray_blocks(rays: SweepRays, q: np.ndarray) -> np.ndarray:
    """Ray block of every sweep sample: the ray whose excursion it follows, or -1.

    A block runs from the first sample of a ray's excursion (where it leaves
    neutral) to the sample before the next ray's excursion, so it holds the
    outward move, the dwell at the ray end, the return and the neutral dwell
    that follows. Samples before the first excursion (the neutral start) get
    -1. Only the far part of an excursion (``rho`` above half its ray's
    amplitude) decides its ray, so that flicker around the neutral threshold
    does not start a block.
    """
    labels = rays.labels
    on_ray = labels >= 0
    rho, _ = rays.polar(q)
    far = on_ray & (rho > _FAR_FRACTION * rays.amplitudes[np.where(on_ray, labels, 0)])
    marker = np.where(far, labels, -1)
    starts, stops = _stretches(~rays.neutral)
    for a, b in zip(starts.tolist(), stops.tolist()):
        first = np.flatnonzero(far[a:b])
        if first.size:  # the excursion starts its ray's block where it leaves neutral
            marker[a] = labels[a + first[0]]
    last = np.maximum.accumulate(np.where(marker >= 0, np.arange(labels.size), -1))
    return np.where(last >= 0, marker[np.maximum(last, 0)], -1)


def reduce_sweep(X, y=None, *, n_rays=None, stride=1, n_rays_swept=8):
    """Reduce the calibration sweep of every run to fewer rays and fewer samples.

    The cost of a calibration is the time the sweep takes. This function
    emulates a smaller calibration budget on recordings made with the full
    sweep: in each run, the sweep keeps only the samples of some of its rays
    and, optionally, every ``stride``-th sample; the motion rows are left
    untouched, so errors on them compare directly with those of the full
    sweep.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format (``docs/data_format.rst``). Every run
        starts with a sweep of ``n_rays_swept`` rays. Never modified.
    y : array-like of shape (n_samples, 3), optional
        Tip positions (mm) aligned with the rows of ``X``; when given, the
        rows kept are returned too.
    n_rays : int or None, default None
        Rays kept per run, from 2 to ``n_rays_swept``; None keeps them all.
        The kept rays are spread as evenly as the swept layout allows: the
        ray closest to the positive ``q1`` direction (``psi = 0``) is kept,
        and the others are those nearest to ``360 / n_rays`` degree steps from
        it (for 4 of 8 rays every other ray; for 6 of 8, two opposite rays
        dropped; for 3 of 8, rays at about 0, 135 and 225 degrees). Two rays
        are a special case: the ray at ``psi = 0`` and the one 90 degrees on
        (one per motor), since two opposite rays move the motors along a
        single line and leave the effect of the other motor direction
        unobserved. A ray is kept with everything from where it leaves
        neutral to where the next ray leaves neutral, so the neutral dwell
        after a dropped ray goes with it (the hysteresis offset it carries
        belongs to that ray).
    stride : int, default 1
        Keep every ``stride``-th sample of the sweep (counted from its first
        sample, which is kept), as if the sweep had been recorded at
        ``1 / stride`` of the sampling rate.
    n_rays_swept : int, default 8
        Number of rays of the recorded sweeps, evenly spaced by
        ``360 / n_rays_swept`` degrees; the rays are found with
        :func:`find_rays` from the motor angles.

    Returns
    -------
    X_reduced : pandas.DataFrame
        A copy of the rows of ``X`` that are kept, with their index labels,
        columns and dtypes; the ``t`` values are the original ones, so the
        reduced sweep has gaps in time where rays were dropped.
    y_reduced : ndarray or pandas object of shape (n_kept, 3)
        Only if ``y`` is given: its rows kept, of the same type as ``y``.

    Raises
    ------
    ValueError
        When ``X`` or ``y`` do not follow the recording format, when
        ``n_rays`` is not an integer from 2 to ``n_rays_swept``, when
        ``stride`` is not a positive integer, or, when rays are dropped,
        when the ``n_rays_swept`` rays of a run's sweep cannot be found (the
        message of :func:`find_rays` names the run).

    See Also
    --------
    find_rays : the rays of a sweep.
    skcath.backbones.PDLBackbone : calibrate on the reduced sweep with
        ``n_rays=n_rays`` and ``ray_spacing_deg=360 / n_rays_swept``.

    Notes
    -----
    The learned residuals also read the sweep: their context encoder takes
    the sweep samples and their sweep frame
    (:func:`skcath.frames.sweep_frame`) is fitted on them. Two rays are
    enough for neither the backbones (which need at least 3) nor the sweep
    frame, whose quadratic fit is singular when the sweep lies on two lines
    through neutral.

    Examples
    --------
    >>> from skcath.datasets import make_benchmark
    >>> from skcath.sweep import reduce_sweep
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> X4, y4 = reduce_sweep(data.X, data.y, n_rays=4, stride=2)  # doctest: +SKIP
    """
    if isinstance(n_rays_swept, bool) or not isinstance(n_rays_swept, Integral) or n_rays_swept < 2:
        raise ValueError(f"n_rays_swept must be an integer of at least 2; got {n_rays_swept!r}.")
    n_rays_swept = int(n_rays_swept)
    if n_rays is not None and (
        isinstance(n_rays, bool)
        or not isinstance(n_rays, Integral)
        or not 2 <= n_rays <= n_rays_swept
    ):
        raise ValueError(
            f"n_rays must be None or an integer from 2 to n_rays_swept={n_rays_swept} (the rays "
            f"of the recorded sweep); got {n_rays!r}."
        )
    if isinstance(stride, bool) or not isinstance(stride, Integral) or stride < 1:
        raise ValueError(f"stride must be a positive integer (keep every stride-th sweep sample); "
                         f"got {stride!r}.")
    checked, _ = check_recordings(X)
    if y is not None:
        check_target(y, len(X))
    n_keep = n_rays_swept if n_rays is None else int(n_rays)

    sweep = (checked[PHASE] == SWEEP).to_numpy()
    q = checked[list(motor_columns(checked)[0])].to_numpy()
    keep = np.ones(len(checked), dtype=bool)
    _, runs = run_codes(checked)
    for run, pos in zip(runs, run_positions(checked, rows=sweep)):
        drop = np.arange(pos.size) % stride != 0
        if n_keep < n_rays_swept:
            rays = find_rays(q[pos], n_rays=n_rays_swept, run=run)
            blocks = _ray_blocks(rays, q[pos])
            kept = _kept_rays(rays.directions, n_keep)
            drop |= (blocks >= 0) & ~np.isin(blocks, kept)
        keep[pos[drop]] = False

    rows = np.flatnonzero(keep)
    X_reduced = X.iloc[rows].copy()
    if y is None:
        return X_reduced
    if isinstance(y, (pd.DataFrame, pd.Series)):
        return X_reduced, y.iloc[rows].copy()
    return X_reduced, np.array(np.asarray(y)[rows], copy=True)
