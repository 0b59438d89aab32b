"""Sample rates of runs, and runs brought to a model's rate.

A sequence model counts time in samples: its window, burn-in, sweep blocks
and motor steps ``dq`` mean seconds only at the rate it was fitted at. This
module is the one place where recordings meet a model's rate:

- :func:`run_rates`: the rate of every run, ``1 / median(dt)`` over its rows;
- :func:`training_rate`: the one rate of a model's training runs, refusing
  runs whose rates differ by more than :data:`RATE_TOLERANCE`;
- :func:`model_ticks`: the times at which a model steps through one run;
- :func:`to_model_rate`: the runs of some recordings brought to a model's
  rate, with the interpolation that takes values at the model's ticks back
  to the rows;
- :func:`resample_runs`: every run resampled onto a uniform grid (public, in
  :mod:`skcath.sequences`).

The rule (``docs/residuals.rst``, *Sample rates*): a run whose every time
step is within :data:`RATE_TOLERANCE` of the model's step is taken as it is;
any other run (another rate, uneven or missing samples) is resampled onto
the model's ticks ``t_0 + k / rate_hz`` from its first sample: the numeric
channels are interpolated linearly in time, so a held value stays held and a
slower recording is seen as straight moves between its samples. A tick up
to the last sweep row is a sweep tick, every later tick a motion tick. A run
slower than :data:`MIN_RATE_FRACTION` of the model's rate is refused. Values
computed at the ticks (a residual) are taken back to the run's own rows by
linear interpolation in time between the ticks of the row's phase, and held
at the first or last tick of the phase outside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

import numpy as np
import pandas as pd
from pandas.api import types as pdt
from sklearn.utils._param_validation import Interval, validate_params

from ._format import ID_COLUMNS, MOTION, PHASE, RUN, SWEEP, TIME
from ._medians import group_medians
from ._validation import check_recordings
from ._validation_columns import _column_as_float, factorize_ids

__all__ = [
    "MIN_RATE_FRACTION",
    "RATE_TOLERANCE",
    "TICK_TOLERANCE",
    "ModelRate",
    "model_ticks",
    "resample_runs",
    "run_at_rate",
    "run_rates",
    "to_model_rate",
    "training_rate",
]

#: Largest relative difference between two rates (or between a time step and
#: the model's step) that counts as the same rate: 10 %. Training runs must
#: share one rate within it; at prediction, a run whose every time step is
#: within it of the model's step is taken as it is.
RATE_TOLERANCE = 0.10

#: A run recorded slower than this fraction of the model's rate is refused: a
#: model at 10 Hz takes runs at 2 Hz and faster. Slower runs leave the model
#: mostly interpolated inputs (at 2 Hz, four ticks in five fall between samples).
MIN_RATE_FRACTION = 0.2

#: A sample counts as reaching a tick when it is at most this fraction of the
#: model's step before it, so that rounding of the times never moves a tick.
TICK_TOLERANCE = 1e-6


def _time_steps(X):
    """Run codes, run ids, and the time step of every row to the previous row of its run.

    Returns ``codes`` (n_rows,), ``runs``, ``order`` (rows sorted by run, in
    row order within a run), ``t`` (n_rows,) and ``steps`` (n_rows,), the
    step ending at each row of ``order``'s order (NaN on the first row of a run).
    """
    codes, runs = factorize_ids(X, RUN)
    t = _column_as_float(X, TIME)
    order = np.argsort(codes, kind="stable")
    sorted_t, sorted_codes = t[order], codes[order]
    steps = np.full(len(order), np.nan)
    if len(order) > 1:
        same = sorted_codes[1:] == sorted_codes[:-1]
        steps[1:] = np.where(same, np.diff(sorted_t), np.nan)
    return codes, runs, order, t, steps


def _medians_to_rates(codes, runs, order, steps):
    """The rate of every run (Hz) from the steps of :func:`_time_steps`; NaN for one row."""
    has = np.isfinite(steps)
    if not has.any():
        return np.full(len(runs), np.nan)
    return 1.0 / group_medians(steps[has], codes[order][has], len(runs))


def _listed_rates(runs, rates, picked):
    """``'a' at 10 Hz, 'b' at 40 Hz`` for the runs ``picked``, ten at most."""
    listed = ", ".join(f"{runs[k]!r} at {rates[k]:.4g} Hz" for k in picked[:10])
    return listed + ("" if picked.size <= 10 else f" and {picked.size - 10} more")


def run_rates(X: pd.DataFrame) -> pd.Series:
    """Sample rate of every run (Hz): one over the median time step of its rows.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format; the ``run`` and ``t`` (s) columns are
        read, rows of a run in time order.

    Returns
    -------
    rates : pandas.Series of float
        Indexed by run id, in order of first appearance; NaN for a run of
        one row.
    """
    codes, runs, order, _, steps = _time_steps(X)
    rates = _medians_to_rates(codes, runs, order, steps)
    return pd.Series(rates, index=pd.Index(runs, name=RUN), name="rate_hz")


def training_rate(X: pd.DataFrame, owner: str) -> float | None:
    """The rate of a model's training runs (Hz), checked to be one rate.

    One over the median time step over the rows of all runs. Every run's own
    rate (:func:`run_rates`) must be within :data:`RATE_TOLERANCE` of it.

    Parameters
    ----------
    X : pandas.DataFrame
        Training recordings in the long format (checked).
    owner : str
        Name of the estimator, for the message.

    Returns
    -------
    rate_hz : float or None
        None when no run has two rows (no time step to measure).

    Raises
    ------
    ValueError
        If runs are recorded at rates more than :data:`RATE_TOLERANCE` apart,
        naming them and their rates.
    """
    codes, runs, order, _, steps = _time_steps(X)
    has = np.isfinite(steps)
    if not has.any():
        return None
    rate = 1.0 / float(np.median(steps[has]))
    rates = _medians_to_rates(codes, runs, order, steps)
    off = np.flatnonzero(np.abs(rates / rate - 1.0) > RATE_TOLERANCE)
    if off.size:
        raise ValueError(
            f"{owner} learns time in samples, so its training runs must share one sample "
            f"rate; most rows are at {rate:.4g} Hz, but run(s) {_listed_rates(runs, rates, off)} "
            f"differ by more than {100 * RATE_TOLERANCE:g} % (RATE_TOLERANCE). Resample them "
            "to one rate "
            "first (skcath.sequences.resample_runs), or fit one model per rate."
        )
    return rate


def model_ticks(t0: float, t_end: float, rate_hz: float) -> np.ndarray:
    """Times (s) at which a model at ``rate_hz`` steps through a run: ``t0 + k / rate_hz``.

    From the run's first sample ``t0`` up to its last sample ``t_end``
    (:data:`TICK_TOLERANCE` of a step beyond it included).
    """
    n = int(math.floor((t_end - t0) * rate_hz + TICK_TOLERANCE)) + 1
    return t0 + np.arange(max(n, 1)) / rate_hz


def _is_channel(series: pd.Series) -> bool:
    """Whether a column is a numeric channel, interpolated in time."""
    return pdt.is_numeric_dtype(series.dtype) and not pdt.is_bool_dtype(series.dtype)


def _run_on_ticks(block: pd.DataFrame, t: np.ndarray, rate_hz: float, channels):
    """One run (its rows in time order) on its model ticks; the ticks' phases."""
    sweep = (block[PHASE] == SWEEP).to_numpy() if PHASE in block.columns else None
    ticks = model_ticks(float(t[0]), float(t[-1]), rate_hz)
    out = {}
    for name in block.columns:
        if name in ID_COLUMNS:
            out[name] = np.repeat(block[name].to_numpy()[:1], len(ticks))
        elif name == TIME:
            out[name] = ticks
        elif name in channels:
            values = pd.to_numeric(block[name]).to_numpy(dtype=np.float64)
            out[name] = np.interp(ticks, t, values)
    tick_sweep = np.zeros(len(ticks), dtype=bool)
    if sweep is not None:
        if sweep.any():
            last = float(t[np.flatnonzero(sweep)[-1]])
            tick_sweep = ticks <= last + TICK_TOLERANCE / rate_hz
        out[PHASE] = np.where(tick_sweep, SWEEP, MOTION)
    frame = pd.DataFrame(out, columns=[c for c in block.columns if c in out])
    return frame, tick_sweep


def _back_to_rows(t_rows, row_sweep, ticks, tick_sweep):
    """Tick positions ``lo, hi`` and weight ``w`` of every row, within the ticks of its phase."""
    lo = np.empty(len(t_rows), dtype=np.intp)
    hi = np.empty(len(t_rows), dtype=np.intp)
    w = np.zeros(len(t_rows))
    for phase in (True, False):
        rows = np.flatnonzero(row_sweep == phase)
        if not rows.size:
            continue
        same = np.flatnonzero(tick_sweep == phase)
        if not same.size:  # no tick of this phase: the run's ticks
            same = np.arange(len(ticks))
        at = ticks[same]
        k = np.clip(np.searchsorted(at, t_rows[rows], side="right") - 1, 0, len(at) - 1)
        k1 = np.minimum(k + 1, len(at) - 1)
        span = at[k1] - at[k]
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(span > 0, (t_rows[rows] - at[k]) / span, 0.0)
        lo[rows], hi[rows], w[rows] = same[k], same[k1], np.clip(frac, 0.0, 1.0)
    return lo, hi, w


@dataclass(frozen=True, eq=False)
class ModelRate:
    """Recordings brought to a model's rate, and the way back to their rows.

    Made by :func:`to_model_rate`.

    Attributes
    ----------
    X : pandas.DataFrame
        The recordings at the model's rate: the runs taken as they are, then
        the resampled runs on their ticks (columns: the ids, ``t``,
        ``phase`` and the numeric channels; other columns are dropped).
    lo, hi : ndarray of int, shape (n_rows,)
        Rows of ``X`` between which each row of the original recordings lies.
    weight : ndarray of shape (n_rows,)
        Interpolation weight of ``hi``; 0 for the rows taken as they are.
    resampled : ndarray of object
        Ids of the resampled runs.
    """

    X: pd.DataFrame
    lo: np.ndarray
    hi: np.ndarray
    weight: np.ndarray
    resampled: np.ndarray

    def to_rows(self, values: np.ndarray) -> np.ndarray:
        """Values of the rows of ``X`` (n, ...) taken back to the original rows.

        Linear in time between the two ticks around each row (the row's own
        value where it was taken as it is).
        """
        values = np.asarray(values)
        out = values[self.lo].astype(np.float64, copy=True)
        blend = self.weight > 0
        w = self.weight[blend].reshape((-1,) + (1,) * (values.ndim - 1))
        out[blend] = (1.0 - w) * values[self.lo[blend]] + w * values[self.hi[blend]]
        return out


def _check_not_too_slow(rates, runs, rate_hz, owner):
    """Refuse runs slower than :data:`MIN_RATE_FRACTION` of the model's rate."""
    slow = np.flatnonzero(rates < MIN_RATE_FRACTION * rate_hz)
    if slow.size:
        raise ValueError(
            f"{owner} was fitted at {rate_hz:.4g} Hz and steps at that rate; run(s) "
            f"{_listed_rates(runs, rates, slow)} are recorded slower than "
            f"{MIN_RATE_FRACTION:g} times that rate (MIN_RATE_FRACTION), "
            "where most of what it would see is interpolated between samples. Fit a model "
            "on recordings at their rate."
        )


def to_model_rate(X: pd.DataFrame, rate_hz: float | None, owner: str) -> ModelRate | None:
    """The runs of ``X`` at the rate of a model fitted at ``rate_hz``, or None if all are.

    A run whose every time step is within :data:`RATE_TOLERANCE` of
    ``1 / rate_hz`` is taken as it is; every other run is resampled onto its
    model ticks (see the module's description).

    Parameters
    ----------
    X : pandas.DataFrame
        Checked recordings in the long format.
    rate_hz : float or None
        The model's rate; None (a model that does not know its rate) takes
        every run as it is.
    owner : str
        Name of the model, for the messages.

    Returns
    -------
    ModelRate or None
        None when no run needs resampling: use ``X`` as it is.

    Raises
    ------
    ValueError
        For a run slower than :data:`MIN_RATE_FRACTION` times ``rate_hz``.
    """
    if rate_hz is None or len(X) < 2:
        return None
    return _at_rate(X, *_time_steps(X), rate_hz, owner)


def run_at_rate(X: pd.DataFrame, run, t: np.ndarray, rate_hz: float | None,
                owner: str) -> ModelRate | None:
    """:func:`to_model_rate` of the rows of one run, from their times.

    For the checked rows of a single run in time order (a sweep given to a
    streaming estimator): ``run`` is its id and ``t`` (n_rows,) the times of
    its rows (s), float64, strictly increasing; the rows are not factorized
    or sorted again. Returns what :func:`to_model_rate` returns for ``X``.
    """
    if rate_hz is None or len(X) < 2:
        return None
    steps = np.full(len(t), np.nan)
    steps[1:] = np.diff(t)
    codes = np.zeros(len(t), dtype=np.intp)
    order = np.arange(len(t), dtype=np.intp)
    return _at_rate(X, codes, np.asarray([run], dtype=object), order, t, steps, rate_hz, owner)


def _at_rate(X, codes, runs, order, t, steps, rate_hz, owner):
    """:func:`to_model_rate` from the run codes, ids, order, times and steps of :func:`_time_steps`."""
    sorted_codes = codes[order]
    has = np.isfinite(steps)
    _check_not_too_slow(_medians_to_rates(codes, runs, order, steps), runs, rate_hz, owner)
    off_step = has & (np.abs(np.where(has, steps, 0.0) * rate_hz - 1.0) > RATE_TOLERANCE)
    resample = np.zeros(len(runs), dtype=bool)
    resample[np.unique(sorted_codes[off_step])] = True
    if not resample.any():
        return None
    return _resample(X, codes, runs, order, t, resample, rate_hz)


def _resample(X, codes, runs, order, t, resample, rate_hz):
    """The :class:`ModelRate` of ``X`` with the runs where ``resample`` is True on ticks."""
    channels = {c for c in X.columns if c not in (*ID_COLUMNS, TIME) and _is_channel(X[c])}
    kept = np.flatnonzero(~resample[codes])
    blocks = [X.iloc[kept]] if kept.size or not resample.any() else []
    lo = np.empty(len(X), dtype=np.intp)
    hi = np.empty(len(X), dtype=np.intp)
    weight = np.zeros(len(X))
    lo[kept] = hi[kept] = np.arange(kept.size)
    size = kept.size
    sorted_codes = codes[order]
    bounds = np.searchsorted(sorted_codes, np.arange(len(runs) + 1))
    for k in np.flatnonzero(resample):
        rows = order[bounds[k] : bounds[k + 1]]
        block = X.iloc[rows]
        frame, tick_sweep = _run_on_ticks(block, t[rows], rate_hz, channels)
        row_sweep = (block[PHASE] == SWEEP).to_numpy() if PHASE in X.columns else np.zeros(
            len(rows), dtype=bool
        )
        a, b, w = _back_to_rows(t[rows], row_sweep, frame[TIME].to_numpy(), tick_sweep)
        lo[rows], hi[rows], weight[rows] = size + a, size + b, w
        blocks.append(frame)
        size += len(frame)
    frame = pd.concat(blocks, ignore_index=True)
    return ModelRate(frame, lo, hi, weight, np.asarray(runs[resample], dtype=object))


@validate_params(
    {"X": [pd.DataFrame], "rate_hz": [Interval(Real, 0, None, closed="neither")]},
    prefer_skip_nested_validation=True,
)
def resample_runs(X: pd.DataFrame, rate_hz: float) -> pd.DataFrame:
    """Every run of ``X`` resampled onto a uniform grid at ``rate_hz``.

    Each run is sampled at ``t_0 + k / rate_hz`` from its first sample
    ``t_0`` to its last; the numeric channels are interpolated linearly in
    time (a held value stays held), the ids are kept, a sample up to the
    run's last sweep row is a sweep sample, every later one a motion sample,
    and other columns are dropped. Use it to bring recordings of several
    rates to one before fitting.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format (``t`` in s, rows of a run in time order).
    rate_hz : float
        The rate of the result (Hz), > 0.

    Returns
    -------
    X_resampled : pandas.DataFrame
        The runs in order of first appearance, each on its grid; a new
        index. A sample next to a NaN (the reference columns ``ref_*`` on
        motion rows, a tracker dropout) is NaN. To resample the tip
        positions ``y`` too, put them in columns of ``X`` first.
    """
    if not math.isfinite(rate_hz):
        raise ValueError(f"rate_hz must be a finite number of Hz; got {rate_hz!r}.")
    X, _ = check_recordings(X, columns=(RUN, TIME), require_sweep=False, copy=False)
    codes, runs, order, t, _ = _time_steps(X)
    result = _resample(X, codes, runs, order, t, np.ones(len(runs), dtype=bool), float(rate_hz))
    return result.X

