"""Validated, read-only parameter arrays shared by the backbone parameter classes."""

import numpy as np


def frozen_array(value, shape, name):
    """Read-only float64 copy of ``value`` with the given ``shape``.

    Raises
    ------
    ValueError
        If the shape differs or a value is not finite; the message names ``name``.
    """
    arr = np.array(value, dtype=float, copy=True)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}; got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite; got {arr.tolist()}.")
    arr.setflags(write=False)
    return arr
