"""Input features of the residual learners (paper eqs. "features" and "context").

Pure numpy functions: per-step motion features ``x = [q, dq, tau, b]``
(width ``3N + 3`` for ``N`` motors, ``2N + 3`` without torques), sweep
features ``s = [q, tau]`` pooled over blocks of a fixed length, featurewise
normalisation statistics, and the training windows cut from the motion
sequences. Nothing here depends on torch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import _format as fmt
from .._runs import run_codes, run_differences
from .._validation import motor_columns
from ..backbones import BACKBONE_COLUMNS

__all__ = [
    "DELTA_COLUMNS",
    "delta_names",
    "Standardizer",
    "cut_windows",
    "feature_frame",
    "pool_sweep",
    "step_feature_names",
    "sweep_feature_names",
    "weighted_mean_std",
]

#: Names of the per-sample motor-angle differences of the default two motors
#: (degrees per sample); :func:`delta_names` gives them for ``N`` motors.
DELTA_COLUMNS = ("dq1", "dq2")


def delta_names(n_motors: int = 2) -> tuple[str, ...]:
    """Names of the per-sample motor-angle differences: ``("dq1", ..., "dqN")``."""
    return tuple(f"d{name}" for name in fmt.motor_names(n_motors))


def step_feature_names(use_torque: bool = True, n_motors: int = 2) -> tuple[str, ...]:
    """Names of the per-step features ``x_t``, in the order the network sees them.

    ``[q1 .. qN, dq1 .. dqN, tau1 .. tauN, b_x, b_y, b_z]``: ``3N + 3``
    features, ``2N + 3`` without the torques (``use_torque`` False); for the
    default two motors ``[q1, q2, dq1, dq2, tau1, tau2, b_x, b_y, b_z]`` (9).
    """
    torque = fmt.torque_names(n_motors) if use_torque else ()
    return (*fmt.motor_names(n_motors), *delta_names(n_motors), *torque, *BACKBONE_COLUMNS)


def sweep_feature_names(use_torque: bool = True, n_motors: int = 2) -> tuple[str, ...]:
    """Names of the sweep features ``s_k``: the motor angles, then the torques when used.

    ``[q1 .. qN, tau1 .. tauN]``, or ``[q1 .. qN]`` without torques.
    """
    torque = fmt.torque_names(n_motors) if use_torque else ()
    return (*fmt.motor_names(n_motors), *torque)


def weighted_mean_std(values: np.ndarray, sample_weight=None):
    """Mean and standard deviation of the rows of ``values`` (n_rows, n_features).

    Weighted by ``sample_weight`` (n_rows,), positive, when it is given:
    ``sum w v / sum w`` and the square root of ``sum w (v - mean)^2 / sum w``.
    """
    if sample_weight is None:
        return values.mean(axis=0), values.std(axis=0)
    w = np.asarray(sample_weight, dtype=np.float64)
    mean = np.average(values, axis=0, weights=w)
    return mean, np.sqrt(np.average((values - mean) ** 2, axis=0, weights=w))


@dataclass(frozen=True)
class Standardizer:
    """Featurewise mean and standard deviation, ``(v - mean) / scale``.

    Attributes
    ----------
    mean : ndarray of shape (n_features,)
    scale : ndarray of shape (n_features,)
        Standard deviation, floored at ``1e-6`` times the largest one (and at
        ``1e-12``) so that a constant feature maps to 0 instead of dividing by 0.
    """

    mean: np.ndarray
    scale: np.ndarray

    @classmethod
    def fit(cls, values: np.ndarray, sample_weight=None) -> "Standardizer":
        """Statistics of the rows of ``values`` (n_rows, n_features); NaN rows are ignored.

        With ``sample_weight`` (n_rows,), non-negative, the mean and the
        standard deviation are weighted; a row of weight 0 counts as if it
        were not there.
        """
        values = np.asarray(values, dtype=np.float64)
        finite = np.isfinite(values).all(axis=1)
        if sample_weight is not None:
            sample_weight = np.asarray(sample_weight, dtype=np.float64)
            finite &= sample_weight > 0
        if not finite.any():
            raise ValueError("Cannot compute normalisation statistics: no finite row.")
        mean, std = weighted_mean_std(
            values[finite], None if sample_weight is None else sample_weight[finite]
        )
        floor = max(1e-12, 1e-6 * float(std.max()))
        return cls(mean=mean, scale=np.maximum(std, floor))

    def transform(self, values: np.ndarray) -> np.ndarray:
        """Normalised copy of ``values`` (any leading shape, last axis features)."""
        return (values - self.mean.astype(values.dtype)) / self.scale.astype(values.dtype)


def pool_sweep(values: np.ndarray, lengths: np.ndarray, stride: int, pooling: str = "mean"):
    """Shorten padded sweep sequences by ``stride`` for the context encoder.

    ``pooling="mean"`` averages every block of ``stride`` consecutive samples
    (the last block of a run averages the samples it has), which keeps the
    slow shape of the sweep and divides the variance of white measurement
    noise (torque quantisation and sensor noise) by ``stride``;
    ``pooling="subsample"`` keeps the first sample of every block.

    Parameters
    ----------
    values : ndarray of shape (n_runs, L, n_features)
        Sweep features, padded after each run's length.
    lengths : ndarray of int, shape (n_runs,)
        Valid samples of every run.
    stride : int
        Block length (samples), at least 1.
    pooling : {"mean", "subsample"}, default="mean"
        How a block becomes one step.

    Returns
    -------
    pooled : ndarray of shape (n_runs, ceil(L / stride), n_features)
        One step per block, zero after each run's last block.
    n_steps : ndarray of int, shape (n_runs,)
        ``ceil(lengths / stride)``, the valid steps of every run.
    """
    values = np.asarray(values)
    lengths = np.asarray(lengths, dtype=np.int64)
    n_runs, length, n_features = values.shape
    n_blocks = -(-length // stride)
    n_steps = -(-lengths // stride)
    if pooling == "subsample":
        pooled = values[:, ::stride].copy()
    elif pooling == "mean":
        padded = np.zeros((n_runs, n_blocks * stride, n_features), dtype=np.float64)
        padded[:, :length] = values
        valid = np.arange(n_blocks * stride)[None, :] < lengths[:, None]
        padded[~valid] = 0.0
        total = padded.reshape(n_runs, n_blocks, stride, n_features).sum(axis=2)
        count = valid.reshape(n_runs, n_blocks, stride).sum(axis=2)
        pooled = (total / np.maximum(count, 1)[..., None]).astype(values.dtype, copy=False)
    else:
        raise ValueError(f"pooling must be 'mean' or 'subsample'; got {pooling!r}.")
    pooled[np.arange(n_blocks)[None, :] >= n_steps[:, None]] = 0.0
    return pooled, n_steps


def cut_windows(lengths: np.ndarray, window: int | None, step: int | None = None):
    """Start of every training window of the motion sequences.

    Each run's motion sequence of length ``n`` is tiled by windows of
    ``window`` steps placed every ``step`` steps from step 0; the last window
    is aligned to the end of the run so that every step is covered. A run
    shorter than ``window`` gives one window holding the whole run (padded by
    the caller).

    Parameters
    ----------
    lengths : ndarray of int, shape (n_runs,)
        Motion length of every run (steps).
    window : int or None
        Window length (steps); None means one window per run of the longest
        run's length (whole sequences).
    step : int, optional
        Distance between window starts; defaults to ``window`` (no overlap).

    Returns
    -------
    run_index : ndarray of int, shape (n_windows,)
        Run of every window.
    start : ndarray of int, shape (n_windows,)
        First motion step of every window.
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    if window is None:
        keep = np.flatnonzero(lengths > 0)
        return keep, np.zeros(keep.size, dtype=np.int64)
    step = window if step is None else step
    runs, starts = [], []
    for k, n in enumerate(lengths):
        if n <= 0:
            continue
        last = max(int(n) - window, 0)
        s = np.arange(0, last + 1, step, dtype=np.int64)
        if s[-1] != last:
            s = np.append(s, last)
        runs.append(np.full(s.size, k, dtype=np.int64))
        starts.append(s)
    if not runs:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(runs), np.concatenate(starts)


def feature_frame(X: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    """Recordings with the ``dq1 .. dqN`` columns added, plus run codes and ids.

    ``X`` must be a checked long-format frame with the backbone columns. The
    motor-angle differences ``dq_t = q_t - q_{t-1}`` (degrees per sample) are
    taken within each run and are 0 on its first row; the first motion row
    differs from the last sweep row, so the motion sequence starts with the
    true step.
    """
    codes, runs = run_codes(X)
    motors, torques = motor_columns(X)
    q = X[list(motors)].to_numpy(dtype=np.float64)
    dq = run_differences(q, codes, len(runs))
    keep = [*fmt.ID_COLUMNS, fmt.TIME, fmt.PHASE]
    keep = [c for c in keep if c in X.columns]
    F = X[keep].copy()
    for name in (*motors, *torques, *BACKBONE_COLUMNS):
        F[name] = X[name].to_numpy(dtype=np.float64)
    for j, name in enumerate(delta_names(len(motors))):
        F[name] = dq[:, j]
    return F, codes, runs
