"""Time scales of the residual learners: seconds, turned into samples at the fitted rate.

A residual learner steps its network once per sample at the rate of its
training runs (``rate_hz_``), so its windows, burn-in, window starts and sweep
blocks are counts of samples inside it. Its parameters give them in seconds
(``window_s``, ``burn_in_s``, ``window_step_s``, ``sweep_stride_s``), so that
the defaults mean the same physical time at any rate; ``fit`` turns each into
the nearest whole number of samples at the fitted rate,
``round(seconds * rate_hz_)`` (20.0 s at 10 Hz: 200 samples, exactly), and
keeps the counts as the fitted attributes ``window_``, ``window_step_``,
``burn_in_`` and ``sweep_stride_``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._rate import to_model_rate

__all__ = [
    "REFERENCE_RATE_HZ",
    "RENAMED",
    "TimeScales",
    "at_model_rate",
    "check_renamed",
    "fitted_sweep_stride",
    "time_scales",
    "to_samples",
]

#: The rate (Hz) at which the learners' defaults were chosen (the simulated
#: benchmark's rate), and at which a learner whose training runs give no rate
#: (no run of two rows) counts its time scales.
REFERENCE_RATE_HZ = 10.0

#: The parameters that counted samples, and their names in seconds.
RENAMED = {
    "window": "window_s",
    "window_step": "window_step_s",
    "burn_in": "burn_in_s",
    "sweep_stride": "sweep_stride_s",
}


def check_renamed(owner: str, params, error=TypeError) -> None:
    """Raise ``error`` for a time scale given by its former name in samples.

    Parameters
    ----------
    owner : str
        Name of the estimator, for the message.
    params : iterable of str
        The names of the parameters given.
    error : type of Exception, default=TypeError
        ``TypeError`` from ``__init__`` (an unexpected argument), ``ValueError``
        from ``set_params`` (an invalid parameter, as scikit-learn raises).
    """
    old = [name for name in params if name in RENAMED]
    if not old:
        return
    hints = "; ".join(
        f"{name} -> {RENAMED[name]} (e.g. {RENAMED[name]}={_EXAMPLES[name]!r} "
        f"for {name}={_EXAMPLES[name] * REFERENCE_RATE_HZ:g} at {REFERENCE_RATE_HZ:g} Hz)"
        for name in old
    )
    raise error(
        f"{owner} does not take {', '.join(repr(n) for n in old)} (samples): its time "
        f"scales are given in seconds, and fit turns them into samples at the rate of the "
        f"training runs. Use {hints}."
    )


#: Example values (s) of the messages: the defaults of GRUResidual.
_EXAMPLES = {"window": 20.0, "window_step": 20.0, "burn_in": 5.0, "sweep_stride": 4.0}


def to_samples(seconds: float, rate_hz: float) -> int:
    """The nearest whole number of samples in ``seconds`` at ``rate_hz``.

    ``round(seconds * rate_hz)``, Python's rounding (a tie goes to the even
    count); exact where the product is a whole number, e.g. 20.0 s at 10 Hz
    is 200 samples.
    """
    return int(round(float(seconds) * float(rate_hz)))


@dataclass(frozen=True)
class TimeScales:
    """A learner's time scales in samples at one rate.

    Attributes
    ----------
    rate_hz : float
        The rate they count samples at (Hz).
    window : int or None
        Length of the training windows; None for whole sequences.
    window_step : int or None
        Distance between window starts; None with ``window`` None.
    burn_in : int
        Leading steps of a window inside a run left out of the loss.
    sweep_stride : int
        Sweep samples per step of the context encoder.
    """

    rate_hz: float
    window: int | None
    window_step: int | None
    burn_in: int
    sweep_stride: int


def _too_short(name, seconds, count, minimum, rate_hz, what):
    """The message of a time scale whose count of samples is below its minimum."""
    return (
        f"{name}={seconds!r} s is {count} sample(s) at the fitted rate of {rate_hz:.4g} Hz; "
        f"{what} needs at least {minimum} (at least {minimum / rate_hz:.4g} s at this "
        f"rate). Give a longer {name}."
    )


def time_scales(learner, rate_hz: float | None) -> TimeScales:
    """The time scales of ``learner`` in samples at ``rate_hz``, checked.

    Parameters
    ----------
    learner : GRUResidual or MLPResidual
        Its ``window_s``, ``window_step_s``, ``burn_in_s`` and
        ``sweep_stride_s`` (s) are read.
    rate_hz : float or None
        The fitted rate; None counts at :data:`REFERENCE_RATE_HZ`.

    Returns
    -------
    TimeScales

    Raises
    ------
    ValueError
        If a time scale is fewer samples at ``rate_hz`` than it needs (a
        window of 2 samples, a window step and a sweep block of 1), or if
        the burn-in is not shorter than the window or the window step
        longer than it, in samples; the message names the parameter in
        seconds.
    """
    rate = REFERENCE_RATE_HZ if rate_hz is None else float(rate_hz)
    window = None if learner.window_s is None else to_samples(learner.window_s, rate)
    burn_in = to_samples(learner.burn_in_s, rate)
    stride = to_samples(learner.sweep_stride_s, rate)
    if window is not None and window < 2:
        raise ValueError(_too_short("window_s", learner.window_s, window, 2, rate,
                                    "a training window"))
    if stride < 1:
        raise ValueError(_too_short("sweep_stride_s", learner.sweep_stride_s, stride, 1, rate,
                                    "a step of the context encoder"))
    if window is not None and burn_in >= window:
        raise ValueError(
            f"burn_in_s must be shorter than window_s in samples at the fitted rate of "
            f"{rate:.4g} Hz; burn_in_s={learner.burn_in_s!r} s is {burn_in} samples, "
            f"window_s={learner.window_s!r} s is {window}."
        )
    step = None
    if learner.window_step_s is not None:
        step = to_samples(learner.window_step_s, rate)
        if step < 1:
            raise ValueError(_too_short("window_step_s", learner.window_step_s, step, 1, rate,
                                        "the distance between window starts"))
        if window is None or step > window:
            raise ValueError(
                "window_step_s must be at most window_s so that the windows cover every "
                f"motion step; at the fitted rate of {rate:.4g} Hz, window_step_s="
                f"{learner.window_step_s!r} s is {step} samples and window_s="
                f"{learner.window_s!r} s is {window if window is None else f'{window} samples'}."
            )
    elif window is not None:
        step = max(window - burn_in, 1)
    return TimeScales(rate, window, step, burn_in, stride)


def fitted_sweep_stride(learner) -> int:
    """Sweep samples per context-encoder step of a fitted learner.

    ``sweep_stride_``; a learner pickled when the parameter counted samples
    holds the count in ``sweep_stride``.
    """
    stride = getattr(learner, "sweep_stride_", None)
    if stride is None:
        stride = learner.__dict__["sweep_stride"]
    return int(stride)


def at_model_rate(X, y, sample_weight, rate_hz, owner):
    """Training recordings, targets and weights brought to a learner's ``rate_hz``.

    None keeps them as they are. Otherwise (the learners' default is 10 Hz)
    every run not at ``rate_hz`` within ``RATE_TOLERANCE`` is
    resampled onto its ticks at ``rate_hz`` as ``predict`` does
    (:func:`skcath._rate.to_model_rate`): the channels, the backbone's tip,
    the measured tip ``y`` and the weights are interpolated linearly in time
    (a tip next to a tracker dropout is NaN, and left out of the loss).

    Returns
    -------
    X, y, sample_weight
        New objects where a run was resampled; the inputs are not modified.
    """
    if rate_hz is None:
        return X, y, sample_weight
    extra = {f"__tip{k}": y[:, k] for k in range(y.shape[1])}
    if sample_weight is not None:
        extra["__weight"] = sample_weight
    try:
        at_rate = to_model_rate(X.assign(**extra), float(rate_hz), owner)
    except ValueError as exc:
        raise ValueError(
            f"{owner}(rate_hz={rate_hz:g}) steps its network at {rate_hz:g} Hz and brings the "
            f"training runs to that rate: {exc} Pass rate_hz=None to step at the training "
            "runs' own rate, or a lower rate_hz."
        ) from None
    if at_rate is None:
        return X, y, sample_weight
    Z = at_rate.X
    tips = Z[[f"__tip{k}" for k in range(y.shape[1])]].to_numpy(dtype=np.float64)
    weight = None if sample_weight is None else Z["__weight"].to_numpy(dtype=np.float64)
    return Z.drop(columns=list(extra)), tips, weight
