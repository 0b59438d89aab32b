"""The nonlinearities of the compiled step, in the network's dtype.

:func:`sigmoid` and :func:`tanh` of one number, float64 or float32: compiled
code evaluates a float32 number in float32 (eight to a vector register)
and a float64 one in float64, each with an exponential of its own that the
compiler vectorises in the loops that call it (no call into a math library,
no conversion between integers and floats):

* float64 (:func:`exp64`): within 1e-15 relative of :func:`numpy.exp`;
* float32 (:func:`exp32`): within 2 units in the last place of float32.

Both reduce ``exp(t) = 2**k exp(r)`` with ``k = round(t / ln 2)``, rounded by
adding and subtracting ``1.5 * 2**p`` (``p`` the bits of the mantissa), which
also leaves ``k`` in the low bits of the sum, from where ``2**k`` is built
(:func:`~skcath._kernel.float_bits`, :func:`~skcath._kernel.with_bits`).
Python runs the same functions on numbers (the numpy engine calls numpy's
own on its vectors instead).
"""

from __future__ import annotations

import math

import numpy as np

from .._kernel import compiled_by_dtype, float_bits, kernel, with_bits

__all__ = ["exp", "exp32", "exp64", "exp_array", "sigmoid", "tanh", "tanh_array"]

# float64: 1 / log(2), log(2) in two parts (the first ends in 21 zero bits, so that
# k * _LN2_HI is exact for the |k| <= 1022 used here), Taylor coefficients 1 / j!,
# 1.5 * 2**52 and its bits
_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_EXP_TAYLOR = tuple(1.0 / math.factorial(j) for j in range(14))
_ROUND64 = 6755399441055744.0
_ROUND64_BITS = int(np.float64(_ROUND64).view(np.int64))

# float32: the same constants (log(2) in a part of 9 bits, exact times |k| <= 127),
# the coefficients of Cephes' expf (minimax on |r| <= ln(2) / 2), 1.5 * 2**23 and its bits
_F = np.float32
_LOG2E32 = _F(1.44269504088896341)
_LN2_HI32 = _F(0.693359375)
_LN2_LO32 = _F(-2.12194440e-4)
_EXPF = tuple(_F(c) for c in (1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3,
                              4.1665795894e-2, 1.6666665459e-1, 5.0000001201e-1))
_ROUND32 = _F(12582912.0)
_ROUND32_BITS = int(_ROUND32.view(np.int32))
_LOW32, _HIGH32, _ONE32, _TWO32 = _F(-87.0), _F(88.0), _F(1.0), _F(2.0)


@kernel
def exp64(x):
    """``exp(x)`` of a float64, ``x`` clipped to [-708, 708] (where it stays normal and finite).

    ``exp(r)`` is its Taylor polynomial of degree 13 (truncation below 1e-17
    relative), evaluated in Estrin's order (pairs of terms, then pairs of
    pairs): a chain of 8 dependent operations where Horner's has 26.
    """
    t = min(max(x, -708.0), 708.0)
    s = t * _LOG2E + _ROUND64
    k = s - _ROUND64
    r = (t - k * _LN2_HI) - k * _LN2_LO
    c = _EXP_TAYLOR
    r2 = r * r
    r4 = r2 * r2
    low = (((c[0] + c[1] * r) + (c[2] + c[3] * r) * r2)
           + ((c[4] + c[5] * r) + (c[6] + c[7] * r) * r2) * r4)
    high = ((c[8] + c[9] * r) + (c[10] + c[11] * r) * r2) + (c[12] + c[13] * r) * r4
    p = low + high * (r4 * r4)
    return p * with_bits((float_bits(s) - _ROUND64_BITS + 1023) << 52, t)


@kernel
def exp32(x):
    """``exp(x)`` of a float32 in float32, ``x`` clipped to [-87, 88] (normal and finite)."""
    t = min(max(x, _LOW32), _HIGH32)
    s = t * _LOG2E32 + _ROUND32
    k = s - _ROUND32
    r = (t - k * _LN2_HI32) - k * _LN2_LO32
    c = _EXPF
    p = ((((c[0] * r + c[1]) * r + c[2]) * r + c[3]) * r + c[4]) * r + c[5]
    p = (p * r * r + r) + _ONE32
    return p * with_bits((float_bits(s) - _ROUND32_BITS + 127) << 23, t)


def _sigmoid64(v):
    return 1.0 / (1.0 + exp64(-v))


def _sigmoid32(v):
    return _ONE32 / (_ONE32 + exp32(-v))


def _tanh64(v):
    return 1.0 - 2.0 / (exp64(2.0 * v) + 1.0)


def _tanh32(v):
    return _ONE32 - _TWO32 / (exp32(_TWO32 * v) + _ONE32)


@compiled_by_dtype(_sigmoid64, _sigmoid32)
def sigmoid(v):
    """``1 / (1 + exp(-v))``, in the precision of ``v`` when compiled (float64 as Python)."""
    return 1.0 / (1.0 + math.exp(-v))


@compiled_by_dtype(_tanh64, _tanh32)
def tanh(v):
    """``tanh(v)`` as ``1 - 2 / (exp(2 v) + 1)``: absolute error ~1e-16 (float64), ~1e-7 (float32).

    In the precision of ``v`` when compiled (float64 as Python).
    """
    return 1.0 - 2.0 / (math.exp(2.0 * v) + 1.0)


@compiled_by_dtype(exp64, exp32)
def exp(v):
    """``exp(v)``: :func:`exp64` or :func:`exp32` by the precision of ``v`` when compiled."""
    return math.exp(v)


@kernel
def exp_array(x):
    """``x[:] = exp(x)`` in place (:func:`exp`)."""
    for i in range(x.shape[0]):
        x[i] = exp(x[i])


@kernel
def tanh_array(y):
    """``y[:] = tanh(y)`` in place (:func:`tanh`)."""
    for i in range(y.shape[0]):
        y[i] = tanh(y[i])
