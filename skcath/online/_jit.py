"""Compiled stepping kernel of the streaming estimator (numba).

One call of :func:`step_kernel` does a whole step of
:meth:`~skcath.online.OnlineEstimator.step` after the input checks: the
backbone's nominal tip for ``(q1, q2)``, the step features, the residual
network (GRU layers then the tanh head, or the MLP), the clip and the
addition of the nominal tip. :class:`JitStep` takes the calibrated backbone
and the folded weights from the numpy kernels of :mod:`skcath.online._fast`,
so both engines evaluate the same equations with the same numbers. They
differ in rounding only: the order of the additions inside a matrix-vector
product, and the nonlinearities, which the compiled kernel evaluates in
float64 whatever the network's dtype, with an exponential of its own that
the compiler vectorises (:func:`_exp`, within 1e-15 relative of ``np.exp``).

The kernel works on five flat arrays made once per run, so that a step
allocates no arrays and crosses from Python to compiled code once:

* ``meta`` (int64): sizes, and offsets into the other arrays (``_M_*``);
* ``f`` (float64): the nominal tip of the last step ``f[0:3]``, the last
  accepted sample ``f[3:7]`` (q1, q2, tau1, tau2), the clip ``f[7]``, the
  backbone's parameters, then scratch space for the nonlinearities;
* ``w`` (the network's dtype) and ``w32`` (float32): the weight matrices,
  column-major, one after the other; ``w32`` holds those that float32
  represents exactly (see :class:`_Weights`);
* ``buf`` (the network's dtype): the per-layer vectors ``[x; 1; h]`` that
  hold the GRU's hidden states, the gates, the head's vectors ``[1; a]``,
  and the residual (3,).

numba is an optional dependency (``pip install "skcath[fast]"``); this module
is imported only when the numba engine is selected.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from ..backbones._pcc import _SERIES_MAX
from ..backbones._pdl import _TWO_PI
from ._fast import GRUStep, MLPStep, PCCStep, PDLStep, pdl_section

__all__ = ["JitStep", "step_kernel"]

# --- meta: fixed header -----------------------------------------------------
_M_BACKBONE = 0  # 0: PCC, 1: PDL
_M_RESIDUAL = 1  # 0: none, 1: GRU, 2: MLP
_M_USE_TORQUE = 2
_M_X = 3  # offset in buf of the raw step features
_M_N_GRU = 4  # GRU layers
_M_HIDDEN = 5  # GRU hidden size H
_M_GATES = 6  # offset in buf of the pre-activations (3H,)
_M_CAND = 7  # offset in buf of W_in x + b_in (H,)
_M_N_HEAD = 8  # dense layers of the head (hidden ones and the output)
_M_RESULT = 9  # offset in buf of the residual (3,)
_M_N_BACKBONE = 10  # PCC: series terms; PDL: rays
_M_SCRATCH = 11  # offset in f of the float64 scratch (n,), then int64 scratch (n,)
_M_N_SCRATCH = 12  # its length n
_M_HEADER = 13
# per GRU layer: n_in, offset in buf of [x; 1; h], then for each of M_x (3H, n_in + 1),
# M_h (3H, H) and N (H, n_in + 1): 1 if in w32 else 0, offset
_GRU_RECORD = 8
# per head layer: rows, cols, 1 if in w32 else 0, offset, input offset, output offset,
# tanh (1/0)
_HEAD_RECORD = 7

# --- f: fixed header --------------------------------------------------------
_F_NOMINAL = 0
_F_LAST = 3
_F_CLIP = 7
_F_BACKBONE = 8

# exp: 1 / log(2), log(2) in two parts (the first ends in 21 zero bits, so that
# k * _LN2_HI is exact for the |k| <= 1022 used here), Taylor coefficients 1 / j!
_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_EXP_TAYLOR = tuple(1.0 / math.factorial(j) for j in range(14))


# ---------------------------------------------------------------------------
# compiled parts
# ---------------------------------------------------------------------------
# cache: compiled once per machine; error_model="numpy": no division checks
# (no division in the kernel can have a zero divisor)
_njit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_njit
def _pcc_tip(f, n_terms, q1, q2):
    """As :meth:`PCCStep.__call__`, parameters read from ``f``."""
    o = _F_BACKBONE
    v1 = (q1 - f[o]) / f[o + 2]
    v2 = (q2 - f[o + 1]) / f[o + 2]
    u1 = v1 * f[o + 3] + v2 * f[o + 4] + f[o + 7]
    u2 = v1 * f[o + 5] + v2 * f[o + 6] + f[o + 8]
    x = u1 * u1 + u2 * u2
    if x < f[o + 18]:
        fs = o + 19
        ss = fs + n_terms
        fv, sv = f[fs], f[ss]
        for k in range(1, n_terms):
            fv = fv * x + f[fs + k]
            sv = sv * x + f[ss + k]
    else:
        a = math.sqrt(x)
        fv = 2.0 * math.sin(0.5 * a) ** 2 / x
        sv = math.sin(a) / a
    h1, h2 = u1 * fv, u2 * fv
    R = o + 9
    return (
        f[R] * h1 + f[R + 1] * h2 + f[R + 2] * sv,
        f[R + 3] * h1 + f[R + 4] * h2 + f[R + 5] * sv,
        f[R + 6] * h1 + f[R + 7] * h2 + f[R + 8] * sv,
    )


_pdl_section = _njit(pdl_section)


@_njit
def _pdl_tip(f, n_rays, q1, q2):
    """As :meth:`PDLStep.__call__`, parameters read from ``f``.

    The interpolation between rays repeats :class:`~skcath.online._fast.PDLStep`
    with the parameters read from ``f``; the section's geometry is the same
    function, :func:`~skcath.online._fast.pdl_section`, compiled. The same
    order of operations keeps the two engines equal to rounding
    (``tests/test_online_jit.py`` compares them).
    """
    o = _F_BACKBONE
    v1 = q1 - f[o]
    v2 = q2 - f[o + 1]
    rho = math.hypot(v1, v2)
    offset = (math.atan2(v2, v1) - f[o + 2]) % f[o + 3]
    rel = o + 18
    # bisect_right on the ray directions relative to the first one
    lo, hi = 0, n_rays
    while lo < hi:
        mid = (lo + hi) // 2
        if offset < f[rel + mid]:
            hi = mid
        else:
            lo = mid + 1
    lower = min(max(lo - 1, 0), n_rays - 1)
    w = (offset - f[rel + lower]) / f[rel + n_rays + lower]
    w = min(max(w, 0.0), 1.0)
    a = rel + 2 * n_rays + 6 * lower
    b = rel + 8 * n_rays + 6 * lower
    wl = 1.0 - w
    gamma = rho * ((wl * f[a] + w * f[b]) + (wl * f[a + 1] + w * f[b + 1]) * rho)
    dist = rho * ((wl * f[a + 2] + w * f[b + 2]) + (wl * f[a + 3] + w * f[b + 3]) * rho)
    phi = (wl * f[a + 4] + w * f[b + 4]) + (wl * f[a + 5] + w * f[b + 5]) * (rho - f[o + 4])
    c1, c2, c3 = _pdl_section(gamma, dist, phi, f[o + 5])
    p, B = o + 6, o + 9
    return (
        f[p] + c1 * f[B] + c2 * f[B + 3] + c3 * f[B + 6],
        f[p + 1] + c1 * f[B + 1] + c2 * f[B + 4] + c3 * f[B + 7],
        f[p + 2] + c1 * f[B + 2] + c2 * f[B + 5] + c3 * f[B + 8],
    )


@_njit
def _matvec(w, at, rows, cols, x, y, accumulate):
    """``y (+)= M @ x`` for the column-major ``M`` (rows, cols) at ``w[at:]``.

    Eight (then four, then one) columns per pass over ``y``, so that the
    inner loop vectorises without the compiler reordering any sum. ``w`` may
    be float32 while ``x`` and ``y`` are float64: the products are then
    float64.
    """
    M = w[at : at + rows * cols].reshape((cols, rows))
    if not accumulate:
        y[:] = 0
    j = 0
    while j + 8 <= cols:
        v0, v1, v2, v3 = x[j], x[j + 1], x[j + 2], x[j + 3]
        v4, v5, v6, v7 = x[j + 4], x[j + 5], x[j + 6], x[j + 7]
        for i in range(rows):
            y[i] += (((M[j, i] * v0 + M[j + 1, i] * v1) + (M[j + 2, i] * v2 + M[j + 3, i] * v3))
                     + ((M[j + 4, i] * v4 + M[j + 5, i] * v5)
                        + (M[j + 6, i] * v6 + M[j + 7, i] * v7)))
        j += 8
    while j + 4 <= cols:
        v0, v1, v2, v3 = x[j], x[j + 1], x[j + 2], x[j + 3]
        for i in range(rows):
            y[i] += (M[j, i] * v0 + M[j + 1, i] * v1) + (M[j + 2, i] * v2 + M[j + 3, i] * v3)
        j += 4
    while j < cols:
        v0 = x[j]
        for i in range(rows):
            y[i] += M[j, i] * v0
        j += 1


@_njit
def _product(meta, r, w, w32, rows, cols, x, y, accumulate):
    """:func:`_matvec` for the matrix of record ``meta[r:r+2]`` (in ``w32`` or ``w``, offset)."""
    if meta[r]:
        _matvec(w32, meta[r + 1], rows, cols, x, y, accumulate)
    else:
        _matvec(w, meta[r + 1], rows, cols, x, y, accumulate)


@_njit
def _exp(x, bits):
    """``x[:] = exp(x)`` (float64), in two loops that the compiler vectorises.

    ``exp(t) = 2**k exp(r)`` with ``k = round(t / ln 2)`` and ``|r| <= ln(2) / 2``
    (``ln 2`` split in two parts so that ``k ln 2`` is exact); ``exp(r)`` is its
    Taylor polynomial of degree 13 (truncation below 1e-17 relative), ``2**k``
    is built from its bits in ``bits`` (int64 scratch of the same length).
    Arguments are clipped to [-708, 708], where ``exp`` stays normal and finite.
    """
    for i in range(x.shape[0]):
        t = min(max(x[i], -708.0), 708.0)
        k = math.floor(t * _LOG2E + 0.5)
        r = (t - k * _LN2_HI) - k * _LN2_LO
        c = _EXP_TAYLOR
        x[i] = ((((((((((((c[13] * r + c[12]) * r + c[11]) * r + c[10]) * r + c[9]) * r
                        + c[8]) * r + c[7]) * r + c[6]) * r + c[5]) * r + c[4]) * r + c[3]) * r
                  + c[2]) * r + c[1]) * r + c[0]
        bits[i] = (np.int64(k) + 1023) << 52
    scale = bits.view(np.float64)
    for i in range(x.shape[0]):
        x[i] *= scale[i]


@_njit
def _tanh(y, bits):
    """``y[:] = tanh(y)`` (float64) as ``1 - 2 / (exp(2 y) + 1)``: absolute error ~1e-16."""
    for i in range(y.shape[0]):
        y[i] = 2.0 * y[i]
    _exp(y, bits)
    for i in range(y.shape[0]):
        y[i] = 1.0 - 2.0 / (y[i] + 1.0)


@_njit
def _gru(meta, f, w, w32, buf):
    """All GRU layers, from the features in the first layer's ``[x; 1; h]``.

    The gates follow :class:`~skcath.online._fast.GRUStep`; the
    nonlinearities are evaluated in float64 (the scratch of ``f``).
    """
    H = meta[_M_HIDDEN]
    g = buf[meta[_M_GATES] : meta[_M_GATES] + 3 * H]
    cand = buf[meta[_M_CAND] : meta[_M_CAND] + H]
    s = meta[_M_SCRATCH]
    t = f[s : s + 3 * H]
    bits = f[s + 3 * H : s + 6 * H].view(np.int64)
    below = buf[:0]
    for k in range(meta[_M_N_GRU]):
        r = _M_HEADER + _GRU_RECORD * k
        n_in, at = meta[r], meta[r + 1]
        v = buf[at : at + n_in + 1 + H]
        x1, h = v[: n_in + 1], v[n_in + 1 :]
        if k > 0:  # the input is the hidden state of the layer below
            v[:H] = below
        _product(meta, r + 2, w, w32, 3 * H, n_in + 1, x1, g, False)
        _product(meta, r + 4, w, w32, 3 * H, H, h, g, True)
        _product(meta, r + 6, w, w32, H, n_in + 1, x1, cand, False)
        # reset and update gates: expit(g) = 1 / (1 + exp(-g))
        for i in range(2 * H):
            t[i] = -g[i]
        _exp(t[: 2 * H], bits[: 2 * H])
        for i in range(2 * H):
            t[i] = 1.0 / (1.0 + t[i])
        # candidate n = tanh(W_in x + b_in + r * (W_hn h + b_hn)), then h' = n + z (h - n)
        for i in range(H):
            t[2 * H + i] = cand[i] + t[i] * g[2 * H + i]
        _tanh(t[2 * H :], bits[2 * H :])
        for i in range(H):
            n = t[2 * H + i]
            h[i] = n + t[H + i] * (h[i] - n)
        below = h


@_njit
def _head(meta, f, w, w32, buf):
    """Dense tanh layers and the output layer, each on a vector ``[1; a]``."""
    first = _M_HEADER + _GRU_RECORD * meta[_M_N_GRU]
    s = meta[_M_SCRATCH]
    n = meta[_M_N_SCRATCH]
    t = f[s : s + n]
    bits = f[s + n : s + 2 * n].view(np.int64)
    for k in range(meta[_M_N_HEAD]):
        r = first + _HEAD_RECORD * k
        rows, cols, src, dst = meta[r], meta[r + 1], meta[r + 4], meta[r + 5]
        y = buf[dst : dst + rows]
        _product(meta, r + 2, w, w32, rows, cols, buf[src : src + cols], y, False)
        if meta[r + 6]:
            for i in range(rows):
                t[i] = y[i]
            _tanh(t[:rows], bits[:rows])
            for i in range(rows):
                y[i] = t[i]


@_njit
def step_kernel(meta, f, w, w32, buf, out, q1, q2, tau1, tau2):
    """One whole step: tip (mm, base frame) for an accepted sample, into ``out``.

    Parameters
    ----------
    meta, f, w, w32, buf : ndarray
        The arrays of a :class:`JitStep` (see the module's description).
    out : ndarray of shape (3,), float64
        Receives the tip (mm).
    q1, q2 : float
        Motor angles (deg), finite and in range.
    tau1, tau2 : float
        Drive torques, finite.
    """
    if meta[_M_BACKBONE] == 0:
        bx, by, bz = _pcc_tip(f, meta[_M_N_BACKBONE], q1, q2)
    else:
        bx, by, bz = _pdl_tip(f, meta[_M_N_BACKBONE], q1, q2)
    f[_F_NOMINAL] = bx
    f[_F_NOMINAL + 1] = by
    f[_F_NOMINAL + 2] = bz
    dq1 = q1 - f[_F_LAST]
    dq2 = q2 - f[_F_LAST + 1]
    f[_F_LAST] = q1
    f[_F_LAST + 1] = q2
    f[_F_LAST + 2] = tau1
    f[_F_LAST + 3] = tau2
    kind = meta[_M_RESIDUAL]
    if kind == 0:
        out[0] = bx
        out[1] = by
        out[2] = bz
        return
    x = meta[_M_X]
    buf[x] = q1
    buf[x + 1] = q2
    buf[x + 2] = dq1
    buf[x + 3] = dq2
    if meta[_M_USE_TORQUE]:
        buf[x + 4] = tau1
        buf[x + 5] = tau2
        x += 2
    buf[x + 4] = bx
    buf[x + 5] = by
    buf[x + 6] = bz
    if kind == 1:
        _gru(meta, f, w, w32, buf)
    _head(meta, f, w, w32, buf)
    e = meta[_M_RESULT]
    c = f[_F_CLIP]
    out[0] = min(max(float(buf[e]), -c), c) + bx
    out[1] = min(max(float(buf[e + 1]), -c), c) + by
    out[2] = min(max(float(buf[e + 2]), -c), c) + bz


# ---------------------------------------------------------------------------
# packing
# ---------------------------------------------------------------------------
def _backbone_values(backbone):
    """``(kind, integer, parameters)`` of a numpy backbone kernel for ``f``."""
    if isinstance(backbone, PCCStep):
        n_terms = len(backbone.f_series)
        values = [*backbone.q0, backbone.S_m, *backbone.C, *backbone.u0, *backbone.LR,
                  _SERIES_MAX, *backbone.f_series, *backbone.s_series]
        return 0, n_terms, values
    if isinstance(backbone, PDLStep):
        values = [*backbone.qn, backbone.d0, _TWO_PI, backbone.rho0, backbone.big_p,
                  *backbone.p0, *backbone.basis, *backbone.relative, *backbone.span]
        for rows in (backbone.lower_coef, backbone.upper_coef):
            for row in rows:
                values.extend(row)
        return 1, backbone.n_rays, values
    raise TypeError(f"Unsupported backbone kernel {type(backbone).__name__}.")


class _Arena:
    """A flat array built piece by piece, handing out offsets."""

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self.parts, self.size = [], 0

    def add(self, values):
        """Append ``values`` (column-major when 2-D); their offset."""
        at = self.size
        values = np.asarray(values).ravel(order="F").astype(self.dtype)
        self.parts.append(values)
        self.size += values.size
        return at

    def array(self):
        if not self.parts:
            return np.zeros(1, dtype=self.dtype)
        return np.concatenate(self.parts)


class _Weights:
    """The weight matrices of a network: ``w`` in its dtype, ``w32`` in float32.

    A matrix goes to ``w32`` when float32 holds its values exactly (weights
    the fitting left untouched, in float32): a float64 step then reads half
    the bytes and still multiplies exactly these values in float64. The
    matrices that absorbed the folded constants go to ``w``.
    """

    def __init__(self, dtype):
        self.w, self.w32 = _Arena(dtype), _Arena(np.float32)

    def add(self, M):
        """Store ``M``; ``(1 if in w32 else 0, offset)``."""
        M = np.asarray(M)
        if np.array_equal(M.astype(np.float32), M):
            return 1, self.w32.add(M)
        return 0, self.w.add(M)


class JitStep:
    """The compiled step of one run, packed from the numpy kernels.

    Parameters
    ----------
    backbone : PCCStep or PDLStep
        Numpy kernel of the calibrated backbone.
    residual : GRUStep, MLPStep or None
        Numpy kernel of the residual network (its folded weights and dtype
        are used), or None for the backbone alone.
    clip : float
        Bound of each residual coordinate (mm); inf for none.
    use_torque : bool
        Whether the step features hold the torques.

    Attributes
    ----------
    nominal : ndarray of shape (3,)
        Nominal tip of the last step (mm); a view, updated by each step.
    last : ndarray of shape (4,)
        Last accepted sample ``(q1, q2, tau1, tau2)``; a view.
    compile_seconds : float
        Time taken to compile the kernel for these arrays, or to load it
        from numba's cache (s).
    """

    def __init__(self, backbone, residual, clip, use_torque):
        kind, n_backbone, values = _backbone_values(backbone)
        f = np.zeros(_F_BACKBONE + len(values))
        f[_F_CLIP] = clip
        f[_F_BACKBONE:] = values
        dtype = np.float64 if residual is None else residual.dtype
        weights, vectors = _Weights(dtype), _Arena(dtype)
        gru, head, hidden = [], [], []
        x_at = result = gates = cand = H = 0
        if isinstance(residual, GRUStep):
            H = residual.hidden_size
            for M, N, v, _, _ in residual._layers:
                n_in = N.shape[1] - 1
                at = vectors.add(v)  # [x; 1; h], the 1 already set
                gru.append((n_in, at, *weights.add(M[:, : n_in + 1]),
                            *weights.add(M[:, n_in + 1 :]), *weights.add(N)))
                hidden.append((at + n_in + 1, H))
            x_at = gru[0][1]
            src = gru[-1][1] + gru[-1][0]  # [1; h] of the last layer
            gates = vectors.add(np.zeros(3 * H))
            cand = vectors.add(np.zeros(H))
            mats = residual.head.mats
        elif isinstance(residual, MLPStep):
            src = vectors.add(residual._vec)  # [1; x]
            x_at = src + 1
            mats = residual.head.mats
        elif residual is None:
            mats = []
        else:
            raise TypeError(f"Unsupported residual kernel {type(residual).__name__}.")
        for k, M in enumerate(mats):
            rows, cols = M.shape
            if k < len(mats) - 1:  # hidden layer: tanh, output [1; a]
                dst = vectors.add(np.r_[1.0, np.zeros(rows)])
                head.append((rows, cols, *weights.add(M), src, dst + 1, 1))
                src = dst
            else:
                result = vectors.add(np.zeros(rows))
                head.append((rows, cols, *weights.add(M), src, result, 0))
        n_scratch = max([3 * H] + [rows for rows, *_ in head])
        scratch = f.size
        f = np.concatenate([f, np.zeros(2 * n_scratch)])
        records = [v for record in gru + head for v in record]
        meta = np.zeros(_M_HEADER + len(records), dtype=np.int64)
        meta[_M_BACKBONE] = kind
        meta[_M_RESIDUAL] = 0 if residual is None else 1 if gru else 2
        meta[_M_USE_TORQUE] = bool(use_torque)
        meta[_M_X] = x_at
        meta[_M_N_GRU] = len(gru)
        meta[_M_HIDDEN] = H
        meta[_M_GATES] = gates
        meta[_M_CAND] = cand
        meta[_M_N_HEAD] = len(head)
        meta[_M_RESULT] = result
        meta[_M_N_BACKBONE] = n_backbone
        meta[_M_SCRATCH] = scratch
        meta[_M_N_SCRATCH] = n_scratch
        meta[_M_HEADER:] = records
        self.meta = meta
        self.f = f
        self.w = weights.w.array()
        self.w32 = weights.w32.array()
        self.buf = vectors.array()
        self.dtype = np.dtype(dtype)
        self._hidden = [self.buf[at : at + n] for at, n in hidden]
        self.nominal = f[_F_NOMINAL : _F_NOMINAL + 3]
        self.last = f[_F_LAST : _F_LAST + 4]
        self.compile_seconds = _compile(self.meta, self.f, self.w, self.w32, self.buf)

    def reset(self, last_sample):
        """Zero hidden state; ``last_sample`` becomes the previous sample."""
        for h in self._hidden:
            h[:] = 0.0
        self.last[:] = last_sample

    def __call__(self, q1, q2, tau1, tau2, out):
        """Step with an accepted sample; the tip (mm) is written into ``out``."""
        step_kernel(self.meta, self.f, self.w, self.w32, self.buf, out, q1, q2, tau1, tau2)


def _compile(*arrays):
    """Compile (or load from numba's cache) the kernel for these arrays; seconds taken.

    Done when the run starts, so that the first step does not pay for it.
    """
    t0 = time.perf_counter()
    if not numba.config.DISABLE_JIT:  # else the kernel runs as Python code
        sig = tuple(numba.typeof(a) for a in (*arrays, np.empty(3))) + (numba.float64,) * 4
        step_kernel.compile(sig)
    return time.perf_counter() - t0
