"""The streaming step, written once for both engines.

:func:`step` does a whole step of :meth:`~skcath.online.OnlineEstimator.step`
after the input checks: the play in front of the backbone
(:func:`~skcath.backbones.play_kernel`, for a backbone with
``hysteresis="play"``) or the Prandtl-Ishlinskii hysteresis
(:func:`~skcath.online._pi_stream.pi_angles`, ``hysteresis="pi"``), the backbone's nominal tip for the played motor
angles (its tip kernel, :func:`~skcath.backbones.pcc_kernel`,
:func:`~skcath.backbones.pdl_kernel` or
:func:`~skcath.backbones.polynomial_kernel`), the step features
``[q1 .. qN, dq1 .. dqN, (tau1 .. tauN,) b_x, b_y, b_z]``, the residual network (GRU
layers then the tanh head, or the MLP), the clip and the addition of the
nominal tip. It reads the run's packed arrays by the names of
:mod:`skcath.online._layout`.

The numpy engine runs :func:`step` as Python; the numba engine compiles the
same function (:mod:`skcath.online._jit`). They differ only in the few vector
primitives the step calls, each declared with :func:`skcath._kernel.compiled_as`:
Python runs one or a few numpy calls on the preallocated vectors (the fixed
cost of a numpy call is what a step pays), compiled code runs loops that
the compiler vectorises, allocate nothing, and evaluate the nonlinearities
in place in the network's dtype, with exponentials of their own
(:mod:`skcath.online._nonlinear`). The GRU's gate equations, the feature
assembly and the clip are written here only.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import expit

from .._kernel import compiled_as, fma, kernel
from ..backbones import (
    PCCParams,
    PDLParams,
    PolynomialParams,
    pcc_kernel,
    pdl_kernel,
    play_kernel,
    polynomial_kernel,
)
from ._layout import (
    BACKBONE_PCC,
    BACKBONE_PDL,
    BACKBONE_POLYNOMIAL,
    F_CLIP,
    F_LIMIT2,
    F_NOMINAL,
    F_PLAY_WIDTH,
    GRU_CAND,
    GRU_GATES,
    GRU_N_IN,
    GRU_RECORD,
    GRU_VECTOR,
    HEAD_DST,
    HEAD_MATRIX,
    HEAD_RECORD,
    HEAD_SRC,
    HEAD_TANH,
    M_ANGLES,
    M_BACKBONE,
    M_CAND,
    M_FUSED,
    M_GATES,
    M_HEADER,
    M_HIDDEN,
    M_LAST,
    M_N_CHANNELS,
    M_N_GRU,
    M_N_HEAD,
    M_N_MOTORS,
    M_NEUTRAL,
    M_PLAY,
    M_RESIDUAL,
    M_RESULT,
    M_TMP,
    M_USE_TORQUE,
    M_X,
    MAT_A_AT,
    MAT_A_W32,
    MAT_B_AT,
    MAT_B_W32,
    MAT_COLS,
    MAT_ROWS,
    MAT_SPLIT,
    RESIDUAL_GRU,
    RESIDUAL_NONE,
)
from ._nonlinear import sigmoid, tanh
from ._pi_stream import pi_angles

__all__ = ["BackboneStep", "step"]

# ---------------------------------------------------------------------------
# compiled loops
# ---------------------------------------------------------------------------
@kernel
def _matrix(w, at, rows, cols, y, accumulate):
    """The column-major matrix (rows, cols) at ``w[at:]``, a (cols, rows) view.

    Zeroes ``y`` first unless ``accumulate``.
    """
    if not accumulate:
        y[:] = 0
    return w[at : at + rows * cols].reshape((cols, rows))


@kernel
def _eight(x, j):
    """``x[j] .. x[j + 7]``: the inputs of a pass over eight columns."""
    return x[j], x[j + 1], x[j + 2], x[j + 3], x[j + 4], x[j + 5], x[j + 6], x[j + 7]


@kernel
def _matvec(w, at, rows, cols, x, y, accumulate):
    """``y (+)= M @ x`` for the column-major ``M`` (rows, cols) at ``w[at:]``.

    Eight (then four, then one) columns per pass over ``y``, so that the
    inner loop vectorises without the compiler reordering any sum. ``w`` may
    be float32 while ``x`` and ``y`` are float64: the products are then
    float64.
    """
    M = _matrix(w, at, rows, cols, y, accumulate)
    j = 0
    while j + 8 <= cols:
        v0, v1, v2, v3, v4, v5, v6, v7 = _eight(x, j)
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


@kernel
def _matvec_fused(w, at, rows, cols, x, y, accumulate):
    """:func:`_matvec` with fused multiply-adds (:func:`~skcath._kernel.fma`), column after column.

    Each product is added to ``y[i]`` with one rounding: half the
    arithmetic of :func:`_matvec`, which rounds every product and sum.
    Eight (then one) columns per pass over ``y``.
    """
    M = _matrix(w, at, rows, cols, y, accumulate)
    j = 0
    while j + 8 <= cols:
        v0, v1, v2, v3, v4, v5, v6, v7 = _eight(x, j)
        for i in range(rows):
            a = fma(M[j + 3, i], v3, fma(M[j + 2, i], v2, fma(M[j + 1, i], v1,
                                                               fma(M[j, i], v0, y[i]))))
            y[i] = fma(M[j + 7, i], v7, fma(M[j + 6, i], v6, fma(M[j + 5, i], v5,
                                                                  fma(M[j + 4, i], v4, a))))
        j += 8
    while j < cols:
        v0 = x[j]
        for i in range(rows):
            y[i] = fma(M[j, i], v0, y[i])
        j += 1


@kernel
def _block(in_w32, at, w, w32, rows, cols, x, y, accumulate, fused):
    """:func:`_matvec` (:func:`_matvec_fused` if ``fused``) of a block in ``w32`` or ``w``."""
    if fused and in_w32:
        _matvec_fused(w32, at, rows, cols, x, y, accumulate)
    elif fused:
        _matvec_fused(w, at, rows, cols, x, y, accumulate)
    elif in_w32:
        _matvec(w32, at, rows, cols, x, y, accumulate)
    else:
        _matvec(w, at, rows, cols, x, y, accumulate)


def _matvec_compiled(meta, r, w, w32, x, y):
    rows, cols, split = meta[r + MAT_ROWS], meta[r + MAT_COLS], meta[r + MAT_SPLIT]
    fused = meta[M_FUSED]
    _block(meta[r + MAT_A_W32], meta[r + MAT_A_AT], w, w32, rows, split, x[:split], y, False,
           fused)
    if split < cols:
        _block(meta[r + MAT_B_W32], meta[r + MAT_B_AT], w, w32, rows, cols - split, x[split:], y,
               True, fused)


def _gru_vectors_sliced(meta, buf, rec):
    H = meta[M_HIDDEN]
    n_in = meta[rec + GRU_N_IN]
    at = meta[rec + GRU_VECTOR]
    v = buf[at : at + n_in + 1 + H]
    g = buf[meta[M_GATES] : meta[M_GATES] + 3 * H]
    return (v, v[:n_in], v[: n_in + 1], v[n_in + 1 :], g, g[: 2 * H], g[:H], g[H : 2 * H],
            g[2 * H :], buf[meta[M_CAND] : meta[M_CAND] + H], buf[meta[M_TMP] : meta[M_TMP] + H])


def _head_vectors_sliced(meta, buf, rec):
    src, dst = meta[rec + HEAD_SRC], meta[rec + HEAD_DST]
    return (buf[src : src + meta[rec + HEAD_MATRIX + MAT_COLS]],
            buf[dst : dst + meta[rec + HEAD_MATRIX + MAT_ROWS]])


def _gates_compiled(rz, r_pre, z_pre):
    for i in range(rz.shape[0]):
        rz[i] = sigmoid(rz[i])
    return r_pre, z_pre


def _tanh_of_sum_compiled(a, r, b):
    for i in range(a.shape[0]):
        a[i] = tanh(a[i] + r[i] * b[i])
    return a


def _blend_compiled(h, z, n, tmp):
    for i in range(h.shape[0]):
        h[i] = n[i] + z[i] * (h[i] - n[i])


def _accepted_compiled(meta, f, sample):
    for k in range(meta[M_N_CHANNELS]):
        if not math.isfinite(sample[k]):
            return False
    at = meta[M_NEUTRAL]
    total = 0.0
    for j in range(meta[M_N_MOTORS]):
        d = sample[j] - f[at + j]
        total += d * d
    return total <= f[F_LIMIT2]


def _tanh_inplace_compiled(y):
    for i in range(y.shape[0]):
        y[i] = tanh(y[i])


# ---------------------------------------------------------------------------
# vector primitives: numpy in Python, the loops above when compiled
# ---------------------------------------------------------------------------
@compiled_as(_matvec_compiled)
def matvec(meta, r, w, w32, x, y):
    """``y = M @ x`` for the matrix of record ``meta[r:]`` (``MAT_*``)."""
    np.dot(w[meta[r + MAT_A_AT]], x, y)


@compiled_as(_gru_vectors_sliced)
def gru_vectors(meta, buf, rec):
    """The vectors of the GRU layer of record ``meta[rec:]``, views of ``buf``.

    ``v = [x; 1; h]``, ``x``, ``[x; 1]``, ``h``; the gates' pre-activations
    ``g`` (3H), its parts for ``r`` and ``z`` together, for ``r``, for ``z``
    and ``W_hn h + b_hn``; ``W_in x + b_in``; a scratch vector. Compiled
    code slices them out of ``buf``; Python reads them from ``meta.views``,
    sliced once by the numpy engine (:class:`~skcath.online._fast.NumpyStep`).
    """
    return meta.views[rec]


@compiled_as(_head_vectors_sliced)
def head_vectors(meta, buf, rec):
    """The input ``[1; a]`` and the output of the head layer of record ``meta[rec:]``.

    Views of ``buf``, sliced as :func:`gru_vectors` says.
    """
    return meta.views[rec]


@compiled_as(_gates_compiled)
def gates(rz, r_pre, z_pre):
    """The reset and update gates ``sigmoid(rz)`` in place, ``rz`` holding both pre-activations.

    ``r_pre``, ``z_pre`` are the two halves of ``rz``: returns them, which
    then hold ``r`` and ``z``.
    """
    expit(rz, rz)
    return r_pre, z_pre


@compiled_as(_tanh_of_sum_compiled)
def tanh_of_sum(a, r, b):
    """``tanh(a + r * b)`` into ``a``, which it returns (Python overwrites ``b`` too)."""
    np.multiply(r, b, b)
    np.add(a, b, a)
    np.tanh(a, a)
    return a


@compiled_as(_blend_compiled)
def blend(h, z, n, tmp):
    """``h = n + z (h - n)`` in place; ``tmp`` is scratch of the size of ``h`` (Python only)."""
    np.subtract(h, n, tmp)
    np.multiply(z, tmp, tmp)
    np.add(n, tmp, h)


@compiled_as(_tanh_inplace_compiled)
def tanh_inplace(y):
    """``y = tanh(y)``."""
    np.tanh(y, y)


@compiled_as(_accepted_compiled)
def accepted(meta, f, sample):
    """Whether ``step`` takes the sample: every channel finite, the motor angles in range.

    In range: the squared distance of the motor angles from the neutral
    angles (``meta[M_NEUTRAL]``), summed motor by motor, is at most
    ``f[F_LIMIT2]``. Python reads the neutral angles and the limit from
    ``meta.neutral`` and ``meta.limit2``, set by the numpy engine, and tests
    the channels with their sum, which is not finite where a channel is not
    (nor where finite channels overflow it: a sample then refused is
    accepted on the caller's second look).
    """
    total = sum(sample)
    if not total - total == 0.0:
        return False
    total = 0.0
    for v, neutral in zip(sample, meta.neutral):
        d = v - neutral
        total += d * d
    return total <= meta.limit2


# ---------------------------------------------------------------------------
# the step
# ---------------------------------------------------------------------------
@kernel
def _gru(meta, f, w, w32, buf):
    """All GRU layers, from the features in the first layer's ``[x; 1; h]``.

    Per layer, as :class:`torch.nn.GRU` (gate order r, z, n):

    .. math::

        r = \\sigma(W_{ir} x + b_{ir} + W_{hr} h + b_{hr}),\\;
        z = \\sigma(W_{iz} x + b_{iz} + W_{hz} h + b_{hz}),\\;
        n = \\tanh(W_{in} x + b_{in} + r \\odot (W_{hn} h + b_{hn})),\\;
        h' = n + z \\odot (h - n).

    One product of the gates' matrix with ``[x; 1; h]`` gives the
    pre-activations of ``r``, ``z`` and ``W_hn h + b_hn``, one of the
    candidate's matrix with ``[x; 1]`` gives ``W_in x + b_in``.
    """
    below = buf
    for k in range(meta[M_N_GRU]):
        rec = M_HEADER + GRU_RECORD * k
        v, x, x1, h, g, rz, r_pre, z_pre, hn, cand, tmp = gru_vectors(meta, buf, rec)
        if k > 0:  # the input is the hidden state of the layer below
            x[:] = below
        matvec(meta, rec + GRU_GATES, w, w32, v, g)
        matvec(meta, rec + GRU_CAND, w, w32, x1, cand)
        r, z = gates(rz, r_pre, z_pre)
        n = tanh_of_sum(cand, r, hn)
        blend(h, z, n, tmp)
        below = h


@kernel
def _head(meta, f, w, w32, buf):
    """Dense tanh layers and the output layer, each on a vector ``[1; a]``."""
    first = M_HEADER + GRU_RECORD * meta[M_N_GRU]
    for k in range(meta[M_N_HEAD]):
        rec = first + HEAD_RECORD * k
        x, y = head_vectors(meta, buf, rec)
        matvec(meta, rec + HEAD_MATRIX, w, w32, x, y)
        if meta[rec + HEAD_TANH]:
            tanh_inplace(y)


@kernel
def _nominal_tip(meta, f, theta):
    """The backbone's tip ``(x, y, z)`` (mm) for the motor angles at ``f[meta[M_ANGLES]:]``."""
    at = meta[M_ANGLES]
    kind = meta[M_BACKBONE]
    if kind == BACKBONE_PCC:
        return pcc_kernel(theta, float(f[at]), float(f[at + 1]))
    if kind == BACKBONE_PDL:
        return pdl_kernel(theta, float(f[at]), float(f[at + 1]))
    return polynomial_kernel(theta, f[at : at + meta[M_N_MOTORS]])


def step(meta, f, theta, w, w32, buf, out, sample, check):
    """One whole step: the tip (mm, base frame) for a sample, into ``out``.

    Parameters
    ----------
    meta, f, theta, w, w32, buf : arrays
        The packed arrays of the run (:class:`~skcath.online._layout.PackedStep`).
    out : ndarray of shape (3,), float64
        Receives the tip (mm).
    sample : tuple of float
        The motor angles ``q1 .. qN`` (deg), finite and in range, then the
        drive torques ``tau1 .. tauN`` (finite) when the recordings have
        them. The backbone reads the angles played (a half-width of 0
        leaves them as they are, and the play is skipped), or with the
        Prandtl-Ishlinskii hysteresis its effective angles
        (:func:`~skcath.online._pi_stream.pi_angles`, the creep stepped by
        ``f[F_DT]``); the step features read them as they are.
    check : bool
        Whether to check the sample first (:func:`accepted`): a sample that
        fails changes nothing (neither ``out`` nor the state of the run).
        Without the check the sample must be one that passes.

    Returns
    -------
    stepped : bool
        False where the check refused the sample, else True.
    """
    if check and not accepted(meta, f, sample):
        return False
    n = meta[M_N_MOTORS]
    last = meta[M_LAST]
    angles = meta[M_ANGLES]
    width = f[F_PLAY_WIDTH]
    if width > 0.0:
        played = meta[M_PLAY]
        for j in range(n):
            f[played + j] = play_kernel(f[played + j], sample[j], width)
            f[angles + j] = f[played + j]
    elif width < 0.0:  # the Prandtl-Ishlinskii hysteresis (PI_FLAG)
        pi_angles(meta, f, sample)
    else:
        for j in range(n):
            f[angles + j] = sample[j]
    bx, by, bz = _nominal_tip(meta, f, theta)
    f[F_NOMINAL] = bx
    f[F_NOMINAL + 1] = by
    f[F_NOMINAL + 2] = bz
    kind = meta[M_RESIDUAL]
    if kind != RESIDUAL_NONE:
        x = meta[M_X]
        for j in range(n):
            buf[x + j] = sample[j]
            buf[x + n + j] = sample[j] - f[last + j]
        x += 2 * n
        if meta[M_USE_TORQUE]:
            for j in range(n):
                buf[x + j] = sample[n + j]
            x += n
        buf[x] = bx
        buf[x + 1] = by
        buf[x + 2] = bz
    for k in range(meta[M_N_CHANNELS]):
        f[last + k] = sample[k]
    if kind == RESIDUAL_NONE:
        out[0] = bx
        out[1] = by
        out[2] = bz
        return True
    if kind == RESIDUAL_GRU:
        _gru(meta, f, w, w32, buf)
    _head(meta, f, w, w32, buf)
    e = meta[M_RESULT]
    c = float(f[F_CLIP])
    out[0] = min(max(float(buf[e]), -c), c) + bx
    out[1] = min(max(float(buf[e + 1]), -c), c) + by
    out[2] = min(max(float(buf[e + 2]), -c), c) + bz
    return True


class BackboneStep:
    """A run's backbone in the step: its tip kernel, its calibration packed for it, its play.

    Parameters
    ----------
    params : PCCParams, PDLParams or PolynomialParams
        Calibrated parameters of the run.
    play_width : float, default=0.0
        Half-width of the play in front of the backbone (deg); 0 without
        hysteresis.
    play_start : tuple of float, default=None
        Played motor angles of the last sweep sample (deg), one per motor,
        where the play starts the motion; unused with a half-width of 0.
        None means zeros.
    pi : PIStep or None, default=None
        The Prandtl-Ishlinskii hysteresis in front of the backbone
        (:class:`~skcath.online._pi_stream.PIStep`), in place of the play;
        None without it.

    Attributes
    ----------
    code : int
        ``meta[M_BACKBONE]`` of this backbone.
    n_motors : int
        Number of motors the backbone reads: 2 for PCC and PDL.
    theta : ndarray
        The packed parameters (``params.pack()``).
    play_width, play_start, pi
        As given.
    """

    def __init__(self, params, play_width=0.0, play_start=None, pi=None):
        if isinstance(params, PCCParams):
            self.code, self._kernel, self.n_motors = BACKBONE_PCC, pcc_kernel, 2
        elif isinstance(params, PDLParams):
            self.code, self._kernel, self.n_motors = BACKBONE_PDL, pdl_kernel, 2
        elif isinstance(params, PolynomialParams):
            self.code, self._kernel = BACKBONE_POLYNOMIAL, None
            self.n_motors = params.n_motors
        else:
            raise TypeError(f"Unsupported backbone parameters {type(params).__name__}.")
        self.play_width = float(play_width)
        if play_start is None:
            play_start = (0.0,) * self.n_motors
        self.play_start = tuple(float(v) for v in play_start)
        self.pi = pi
        self.params = params
        self.theta = params.pack()
        self._theta = self.theta.tolist()

    def __call__(self, *q):
        """Tip ``(x, y, z)`` in the base frame (mm) for the motor angles (deg), as Python."""
        if self._kernel is None:
            return polynomial_kernel(self._theta, q)
        return self._kernel(self._theta, *q)
