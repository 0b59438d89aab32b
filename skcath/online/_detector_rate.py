"""The rate check of :class:`~skcath.online.ShaftChangeDetector`: its CUSUM counts samples.

The detector's statistic adds one term per sample, so its ``threshold``
(standard deviations times samples) and ``drift`` (per sample) mean another
detection delay and false-alarm rate in seconds at another rate; their
defaults were chosen at 10 Hz. ``warm_up_s`` and ``alarm_time_`` are in
seconds through ``rate_hz``, the rate the caller declares.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from .. import _format as fmt
from .._rate import RATE_TOLERANCE
from ..exceptions import SampleRateWarning

__all__ = ["DEFAULTS_RATE_HZ", "check_detector_rate"]

#: The rate (Hz) at which the detector's default ``threshold`` and ``drift``
#: were chosen (catheter C1 of the simulated benchmark).
DEFAULTS_RATE_HZ = 10.0

#: The per-sample parameters and their defaults.
_PER_SAMPLE = {"threshold": 130.0, "drift": 1.5}


def _sweep_rate(sweep: pd.DataFrame) -> float | None:
    """One over the median time step of the sweep's ``t`` column (Hz), or None."""
    if fmt.TIME not in sweep.columns or len(sweep) < 2:
        return None
    t = pd.to_numeric(sweep[fmt.TIME], errors="coerce").to_numpy(dtype=np.float64)
    steps = np.diff(t)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return 1.0 / float(np.median(steps)) if steps.size else None


def _off(rate: float, reference: float) -> bool:
    return abs(rate / reference - 1.0) > RATE_TOLERANCE


def check_detector_rate(detector, sweep: pd.DataFrame) -> None:
    """Warn where the detector's samples are not at the rate its parameters assume.

    Parameters
    ----------
    detector : ShaftChangeDetector
        Its ``rate_hz``, ``threshold`` and ``drift`` are read.
    sweep : pandas.DataFrame
        The sweep rows given to ``start``; their times ``t`` (s), if present,
        give the rate of the samples.

    Warns
    -----
    SampleRateWarning
        When the sweep's rate is more than 10 % from ``rate_hz``; and when
        ``threshold`` or ``drift`` keeps its default at a rate (the sweep's,
        else ``rate_hz``) more than 10 % from :data:`DEFAULTS_RATE_HZ`.
    """
    name = type(detector).__name__
    rate = float(detector.rate_hz)
    measured = _sweep_rate(sweep)
    if measured is not None and _off(measured, rate):
        warnings.warn(
            f"{name} has rate_hz={detector.rate_hz!r}, but the sweep's times are at "
            f"{measured:.4g} Hz; warm_up_s and alarm_time_ count samples at rate_hz. Pass "
            f"rate_hz={measured:.4g}.",
            SampleRateWarning,
            stacklevel=4,
        )
        rate = measured
    kept = [k for k, v in _PER_SAMPLE.items() if getattr(detector, k) == v]
    if kept and _off(rate, DEFAULTS_RATE_HZ):
        listed = " and ".join(f"{k}={_PER_SAMPLE[k]!r}" for k in kept)
        warnings.warn(
            f"{name} adds one CUSUM term per sample, and its default {listed} "
            f"{'were' if len(kept) > 1 else 'was'} chosen at {DEFAULTS_RATE_HZ:g} Hz; at "
            f"{rate:.4g} Hz an alarm needs {DEFAULTS_RATE_HZ / rate:.3g} times the time and "
            "false alarms come at another rate. Choose them at this rate "
            "(benchmarks/bench_shaft_change.py), or resample the signals to 10 Hz "
            "(skcath.sequences.resample_runs).",
            SampleRateWarning,
            stacklevel=4,
        )
