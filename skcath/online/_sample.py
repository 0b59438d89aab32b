"""One motor sample given to a streaming step: what counts as a number.

The streaming estimator and the shaft-change detector take one sample per
call: ``(q1, q2, tau1, tau2)`` for the default catheter, ``(q1 .. qN, tau1 ..
tauN)`` (or the angles alone, without torques) for ``N`` motors. Both accept the same values: real numbers
(``int``, ``float``, numpy integer and floating scalars, any other
:class:`numbers.Real`), never ``bool``, strings, bytes, :class:`decimal.Decimal`
or complex numbers, which ``float()`` would silently turn into a number or
which carry a meaning other than a measurement.
"""

from __future__ import annotations

from numbers import Real

import numpy as np

from .._format import MOTOR_PREFIX, channel_index

__all__ = ["CHANNELS", "as_real", "real_sample"]

#: Names of the four channels of a sample of the default catheter, in the
#: order the steps take them.
CHANNELS = ("q1", "q2", "tau1", "tau2")

# The usual types of a real number, recognised without the slower check of
# the abstract base class.
_REAL_TYPES = frozenset(
    {float, int, np.float64, np.float32, np.float16, np.int64, np.int32, np.int16, np.int8}
)


_WORDS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")


def _expected(names):
    """``"four numbers, q1, q2 (deg), tau1, tau2"``: what a step takes, for messages."""
    count = _WORDS[len(names)] if len(names) < len(_WORDS) else str(len(names))
    motors = [n for n in names if (channel_index(n) or ("",))[0] == MOTOR_PREFIX]
    listed = [*motors[:-1], f"{motors[-1]} (deg)", *names[len(motors):]] if motors else names
    return f"{count} number{'s' if len(names) != 1 else ''}, {', '.join(listed)}"


def as_real(value, name: str, names=CHANNELS) -> float:
    """``value`` as a float if it is a real number, else a ``TypeError`` naming ``name``.

    Parameters
    ----------
    value : object
        One channel of a sample.
    name : str
        Its name, for the message (``"q1"``, ``"tau2"``, ...).
    names : tuple of str, default=CHANNELS
        The channels of a sample, for the message.

    Returns
    -------
    value : float
        The number; not checked for being finite.
    """
    kind = type(value)
    if kind in _REAL_TYPES or (isinstance(value, Real) and kind is not bool):
        return float(value)
    raise TypeError(
        f"step takes {_expected(names)}: {name} must be a real number "
        f"(int, float or a numpy real scalar), not {value!r} of type {kind.__name__}. "
        "Convert text to numbers where it is read."
    )


def real_sample(sample, names=CHANNELS) -> tuple[float, ...]:
    """The channels of a sample as floats, checked with :func:`as_real`.

    Parameters
    ----------
    sample : tuple
        The values given to a step, one per channel.
    names : tuple of str, default=CHANNELS
        The channels: the motor angles ``q1 .. qN``, then the torques
        ``tau1 .. tauN`` when the recordings have them.

    Returns
    -------
    sample : tuple of float

    Raises
    ------
    TypeError
        If the number of values is not that of ``names``, or a value is not
        a real number.
    """
    if len(sample) != len(names):
        raise TypeError(
            f"step takes {_expected(names)}, one per channel of the recordings; got "
            f"{len(sample)} value(s)."
        )
    # the usual types, without a call per channel
    if all(type(v) in _REAL_TYPES for v in sample):
        return tuple(float(v) for v in sample)
    return tuple(as_real(v, name, names) for v, name in zip(sample, names))
