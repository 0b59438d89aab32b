"""One motor sample given to a streaming step: what counts as a number.

The streaming estimator and the shaft-change detector take one sample
``(q1, q2, tau1, tau2)`` per call. Both accept the same values: real numbers
(``int``, ``float``, numpy integer and floating scalars, any other
:class:`numbers.Real`), never ``bool``, strings, bytes, :class:`decimal.Decimal`
or complex numbers, which ``float()`` would silently turn into a number or
which carry a meaning other than a measurement.
"""

from __future__ import annotations

from numbers import Real

import numpy as np

__all__ = ["CHANNELS", "as_real", "real_sample"]

#: Names of the four channels of a sample, in the order the steps take them.
CHANNELS = ("q1", "q2", "tau1", "tau2")

# The usual types of a real number, recognised without the slower check of
# the abstract base class.
_REAL_TYPES = frozenset(
    {float, int, np.float64, np.float32, np.float16, np.int64, np.int32, np.int16, np.int8}
)


def as_real(value, name: str) -> float:
    """``value`` as a float if it is a real number, else a ``TypeError`` naming ``name``.

    Parameters
    ----------
    value : object
        One channel of a sample.
    name : str
        Its name, for the message (``"q1"``, ``"tau2"``, ...).

    Returns
    -------
    value : float
        The number; not checked for being finite.
    """
    kind = type(value)
    if kind in _REAL_TYPES or (isinstance(value, Real) and kind is not bool):
        return float(value)
    raise TypeError(
        f"step takes four numbers, q1, q2 (deg), tau1, tau2: {name} must be a real number "
        f"(int, float or a numpy real scalar), not {value!r} of type {kind.__name__}. "
        "Convert text to numbers where it is read."
    )


def real_sample(q1, q2, tau1, tau2) -> tuple[float, float, float, float]:
    """The four channels of a sample as floats, checked with :func:`as_real`."""
    # the usual types, without a call per channel
    if (type(q1) in _REAL_TYPES and type(q2) in _REAL_TYPES
            and type(tau1) in _REAL_TYPES and type(tau2) in _REAL_TYPES):
        return float(q1), float(q2), float(tau1), float(tau2)
    return (as_real(q1, "q1"), as_real(q2, "q2"), as_real(tau1, "tau1"), as_real(tau2, "tau2"))
