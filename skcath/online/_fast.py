"""Numpy stepping kernels of the streaming estimator (no torch on the step path).

Two kinds of kernels, both built once per calibrated run and then called
once per motor sample:

* backbone kernels (:class:`PCCStep`, :class:`PDLStep`) evaluate the
  calibrated backbone for one sample ``(q1, q2)`` with scalar ``math``
  operations, in the same order as :func:`~skcath.backbones.pcc_tip` and
  :func:`~skcath.backbones.pdl_tip`;
* residual kernels (:class:`GRUStep`, :class:`MLPStep`) run one step of the
  residual network on preallocated buffers (every numpy call writes with
  an output argument), so that a steady-state loop allocates no arrays.

Everything that is constant within a run is folded into the first layer's
weights when the kernel is built: the feature normalisation
``(x - mean) / scale``, the rotation of the nominal tip into the sweep frame
(``frame="sweep"``) and the context contribution ``W_z z`` (which becomes
part of the bias). The output layer likewise absorbs ``sigma_e`` and the
rotation back to the base frame, so one step reads the raw features
``[q1, q2, dq1, dq2, (tau1, tau2,) b_x, b_y, b_z]`` and returns the residual
in the base frame (mm) before clipping.
"""

from __future__ import annotations

import bisect
import math

import numpy as np
from scipy.special import expit

from ..backbones import PCCParams, PDLParams
from ..backbones._pcc import _N_TERMS, _SERIES_MAX, _TABLE
from ..backbones._pdl import _PHI0, _TWO_PI, _unwrap_rays, _winding

__all__ = ["GRUStep", "MLPStep", "PCCStep", "PDLStep", "fold_input_layer", "fold_output_layer"]


# ---------------------------------------------------------------------------
# backbones
# ---------------------------------------------------------------------------
class PCCStep:
    """Nominal tip of a calibrated PCC backbone for one motor sample.

    Parameters
    ----------
    params : PCCParams
        Calibrated parameters of the run.
    """

    def __init__(self, params: PCCParams):
        self.q0 = tuple(float(v) for v in params.q0)
        self.S_m = float(params.S_m)
        self.C = tuple(float(v) for v in params.C.ravel())
        self.u0 = tuple(float(v) for v in params.u0)
        # L R_g, row-major: the tip is L R_g h
        self.LR = tuple(float(v) for v in (params.L * params.R_g).ravel())
        self.f_series = tuple(float(v) for v in _TABLE[0, ::-1])  # highest power first
        self.s_series = tuple(float(v) for v in _TABLE[1, ::-1])

    def __call__(self, q1: float, q2: float) -> tuple[float, float, float]:
        """Tip ``(x, y, z)`` in the base frame (mm) for the motor angles (deg)."""
        v1 = (q1 - self.q0[0]) / self.S_m
        v2 = (q2 - self.q0[1]) / self.S_m
        C = self.C
        u1 = v1 * C[0] + v2 * C[1] + self.u0[0]
        u2 = v1 * C[2] + v2 * C[3] + self.u0[1]
        x = u1 * u1 + u2 * u2
        if x < _SERIES_MAX:
            fs, ss = self.f_series, self.s_series
            f, s = fs[0], ss[0]
            for k in range(1, _N_TERMS):
                f = f * x + fs[k]
                s = s * x + ss[k]
        else:
            a = math.sqrt(x)
            f = 2.0 * math.sin(0.5 * a) ** 2 / x
            s = math.sin(a) / a
        h1, h2 = u1 * f, u2 * f
        R = self.LR
        return (
            R[0] * h1 + R[1] * h2 + R[2] * s,
            R[3] * h1 + R[4] * h2 + R[5] * s,
            R[6] * h1 + R[7] * h2 + R[8] * s,
        )


def pdl_section(gamma, dist, phi, big_p):
    """Tip coordinates along the PDL basis from one ray's interpolated section.

    Scalar, pure and free of numpy, so that the compiled engine compiles this
    same function (``skcath.online._jit``) and both engines round alike.

    Parameters
    ----------
    gamma : float
        Bend angle of the section (rad).
    dist : float
        Chord length from the base to the tip (mm).
    phi : float
        Bend-plane angle about the basis' third axis (rad).
    big_p : float
        Norm of the straight tip position ``|p0|`` (mm).

    Returns
    -------
    c1, c2, c3 : float
        Coordinates along the three basis vectors (mm), before adding ``p0``.
    """
    h = 0.5 * gamma
    ch, sh = math.cos(h), math.sin(h)
    disc = dist * dist - (big_p * sh) ** 2
    s = math.copysign(math.sqrt(abs(disc)), disc) if disc != 0.0 else 0.0
    across = (big_p * ch + s) * sh
    return across * math.cos(phi), across * math.sin(phi), s * ch - big_p * sh * sh


class PDLStep:
    """Nominal tip of a calibrated PDL backbone for one motor sample.

    The PDL backbone is a function of the current motor angles only (no state
    carried along the run), so every sample is evaluated on its own.

    Parameters
    ----------
    params : PDLParams
        Calibrated parameters of the run.
    """

    def __init__(self, params: PDLParams):
        directions = np.asarray(params.directions, dtype=float)
        coef = np.array(params.coef, dtype=float, copy=True)
        coef[:, _PHI0] = _unwrap_rays(coef[:, _PHI0], wrap_first=False)
        n_rays = len(directions)
        upper = coef[(np.arange(n_rays) + 1) % n_rays].copy()
        upper[-1, _PHI0] += _winding(coef[:, _PHI0])
        self.n_rays = n_rays
        self.d0 = float(directions[0])
        self.relative = [float(v) for v in directions - directions[0]]
        self.span = [float(v) for v in np.diff(np.append(directions, directions[0] + _TWO_PI))]
        self.lower_coef = [tuple(float(v) for v in row) for row in coef]
        self.upper_coef = [tuple(float(v) for v in row) for row in upper]
        self.qn = tuple(float(v) for v in params.q_neutral)
        self.rho0 = float(params.rho0)
        self.p0 = tuple(float(v) for v in params.p0)
        self.big_p = float(np.linalg.norm(params.p0))
        self.basis = tuple(float(v) for v in params.basis.ravel())

    def __call__(self, q1: float, q2: float) -> tuple[float, float, float]:
        """Tip ``(x, y, z)`` in the base frame (mm) for the motor angles (deg)."""
        v1 = q1 - self.qn[0]
        v2 = q2 - self.qn[1]
        rho = math.hypot(v1, v2)
        offset = (math.atan2(v2, v1) - self.d0) % _TWO_PI
        lower = bisect.bisect_right(self.relative, offset) - 1
        lower = min(max(lower, 0), self.n_rays - 1)
        w = (offset - self.relative[lower]) / self.span[lower]
        w = min(max(w, 0.0), 1.0)
        a, b = self.lower_coef[lower], self.upper_coef[lower]
        wl = 1.0 - w
        gamma = rho * ((wl * a[0] + w * b[0]) + (wl * a[1] + w * b[1]) * rho)
        dist = rho * ((wl * a[2] + w * b[2]) + (wl * a[3] + w * b[3]) * rho)
        phi = (wl * a[4] + w * b[4]) + (wl * a[5] + w * b[5]) * (rho - self.rho0)
        c1, c2, c3 = pdl_section(gamma, dist, phi, self.big_p)
        B, p0 = self.basis, self.p0
        return (
            p0[0] + c1 * B[0] + c2 * B[3] + c3 * B[6],
            p0[1] + c1 * B[1] + c2 * B[4] + c3 * B[7],
            p0[2] + c1 * B[2] + c2 * B[5] + c3 * B[8],
        )


# ---------------------------------------------------------------------------
# folding of the constant parts into the weights
# ---------------------------------------------------------------------------
def fold_input_layer(W, b, mean, scale, rotation, z):
    """First-layer weights on the raw step features, with constants folded in.

    The layer computes ``W [x_bar; z] + b`` with the normalised features
    ``x_bar = (x' - mean) / scale`` and ``x'`` the raw features whose last
    three entries (the nominal tip) are rotated into the network's frame.

    Parameters
    ----------
    W : ndarray of shape (m, n_features + n_context)
        Weights on ``[x_bar; z]`` (float64).
    b : ndarray of shape (m,)
        Bias.
    mean, scale : ndarray of shape (n_features,)
        Normalisation statistics of the step features.
    rotation : ndarray of shape (3, 3) or None
        ``R_SB`` that rotates the nominal tip into the sweep frame, or None.
    z : ndarray of shape (n_context,) or None
        Context of the run, or None without context.

    Returns
    -------
    W_raw : ndarray of shape (m, n_features)
        Weights on the raw features ``[..., b_x, b_y, b_z]`` (base frame).
    b_raw : ndarray of shape (m,)
        Bias including ``-W mean / scale`` and ``W_z z``.
    """
    n = mean.shape[0]
    Wx = W[:, :n] / scale[None, :]
    b_raw = b - Wx @ mean
    if z is not None:
        b_raw = b_raw + W[:, n:] @ z
    if rotation is not None:
        Wx = Wx.copy()
        Wx[:, n - 3 :] = Wx[:, n - 3 :] @ rotation
    return Wx, b_raw


def fold_output_layer(W, b, sigma_e, rotation):
    """Output-layer weights that return the residual in the base frame (mm).

    ``e = R^T (sigma_e * (W a + b))`` with ``R = R_SB`` (or the identity).

    Returns
    -------
    W_out : ndarray of shape (3, m)
    b_out : ndarray of shape (3,)
    """
    W = sigma_e[:, None] * W
    b = sigma_e * b
    if rotation is not None:
        W = rotation.T @ W
        b = rotation.T @ b
    return W, b


# ---------------------------------------------------------------------------
# residual networks
# ---------------------------------------------------------------------------
class GRUStep:
    """One step of the GRU residual on preallocated buffers.

    Per layer the update gate ``z``, reset gate ``r`` and candidate ``n``
    follow :class:`torch.nn.GRU`:

    .. math::

        r = \\sigma(W_{ir} v + b_{ir} + W_{hr} h + b_{hr}),\\;
        z = \\sigma(W_{iz} v + b_{iz} + W_{hz} h + b_{hz}),\\;
        n = \\tanh(W_{in} v + b_{in} + r \\odot (W_{hn} h + b_{hn})),\\;
        h' = n + z \\odot (h - n).

    Per layer the vector ``v = [x; 1; h]`` (input, a constant 1 that
    carries the biases, hidden state) is multiplied by one matrix for the
    pre-activations of ``r``, ``z`` and ``W_hn h + b_hn``, and its leading
    part ``[x; 1]`` by a second one for ``W_in x + b_in``; no product
    involves a block of zeros larger than ``H x n_in``.

    Parameters
    ----------
    layers : list of (W_ih, W_hh, b_ih, b_hh)
        Weights of every layer as float64 arrays in PyTorch's layout (gate
        order r, z, n); the first layer's ``W_ih`` and ``b_ih`` act on the
        raw step features (see :func:`fold_input_layer`).
    head : list of (W, b)
        The output head, hidden layers with tanh then the output layer (see
        :func:`fold_output_layer`).
    dtype : numpy dtype
        Arithmetic precision of the step.

    Attributes
    ----------
    input : ndarray of shape (n_features,)
        Write the raw step features here before calling.
    output : ndarray of shape (3,), float64
        The residual of the last call (mm, base frame, not clipped).
    """

    def __init__(self, layers, head, dtype):
        self.dtype = np.dtype(dtype)
        H = layers[0][1].shape[1]
        self.hidden_size = H
        self.n_features = layers[0][0].shape[1]
        self._layers = []
        self.hidden = []
        for W_ih, W_hh, b_ih, b_hh in layers:
            n_in = W_ih.shape[1]
            M = np.zeros((3 * H, n_in + 1 + H))
            M[: 2 * H, :n_in] = W_ih[: 2 * H]
            M[: 2 * H, n_in] = b_ih[: 2 * H] + b_hh[: 2 * H]
            M[: 2 * H, n_in + 1 :] = W_hh[: 2 * H]
            M[2 * H :, n_in] = b_hh[2 * H :]
            M[2 * H :, n_in + 1 :] = W_hh[2 * H :]
            N = np.column_stack([W_ih[2 * H :], b_ih[2 * H :]])
            v = np.zeros(n_in + 1 + H, dtype=self.dtype)
            v[n_in] = 1.0
            h = v[n_in + 1 :]
            self.hidden.append(h)
            # column-major: for these small shapes OpenBLAS's matrix-vector
            # product ran faster on them than on row-major copies
            self._layers.append((
                np.asfortranarray(M, dtype=self.dtype),
                np.asfortranarray(N, dtype=self.dtype),
                v, v[: n_in + 1], h,
            ))
        g = np.empty(3 * H, dtype=self.dtype)
        self._gates = (g, g[: 2 * H], g[:H], g[H : 2 * H], g[2 * H :])
        self._n = np.empty(H, dtype=self.dtype)
        self._tmp = np.empty(H, dtype=self.dtype)
        self.head = _Head(head, H, self.dtype)
        v_last = self._layers[-1][2]
        self._head_input = v_last[-H - 1 :]  # [1; h] of the last layer
        self.input = self._layers[0][2][: self.n_features]
        self.output = self.head.output

    def reset(self):
        """Zero hidden state (the start of a motion sequence)."""
        for h in self.hidden:
            h[:] = 0.0

    def __call__(self):
        """Advance one step from :attr:`input`; the residual is in :attr:`output`."""
        g, rz, r, z, hn = self._gates
        n, tmp = self._n, self._tmp
        dot, multiply, add, subtract, tanh = np.dot, np.multiply, np.add, np.subtract, np.tanh
        layers = self._layers
        last = len(layers) - 1
        for k, (M, N, v, x1, h) in enumerate(layers):
            dot(M, v, g)
            dot(N, x1, n)
            expit(rz, rz)
            multiply(r, hn, hn)
            add(n, hn, n)
            tanh(n, n)
            subtract(h, n, tmp)
            multiply(z, tmp, tmp)
            add(n, tmp, h)
            if k < last:
                layers[k + 1][2][: self.hidden_size] = h
        self.head(self._head_input)


class MLPStep:
    """One step of the MLP residual on preallocated buffers.

    Parameters
    ----------
    layers : list of (W, b)
        Hidden layers (tanh) then the output layer, float64; the first acts
        on the raw step features (:func:`fold_input_layer`) and the last
        returns the residual in the base frame (:func:`fold_output_layer`).
    dtype : numpy dtype
        Arithmetic precision of the step.

    Attributes
    ----------
    input, output : ndarray
        As for :class:`GRUStep`.
    """

    def __init__(self, layers, dtype):
        self.dtype = np.dtype(dtype)
        self.n_features = layers[0][0].shape[1]
        v = np.zeros(self.n_features + 1, dtype=self.dtype)
        v[0] = 1.0
        self._vec = v
        self.input = v[1:]
        self.head = _Head(layers, self.n_features, self.dtype)
        self.output = self.head.output

    def reset(self):
        """Nothing to reset: the MLP has no state."""

    def __call__(self):
        """Residual of the features in :attr:`input`, written into :attr:`output`."""
        self.head(self._vec)


class _Head:
    """Dense tanh layers and a linear output, each acting on ``[1; a]``.

    The output (3,) is always float64: the last product writes into it
    directly in float64, or is copied there from a float32 buffer.
    """

    def __init__(self, layers, n_in, dtype):
        self.mats, self.bufs = [], []
        width = n_in
        for W, b in layers:
            if W.shape[1] != width:
                raise ValueError(f"Layer expects {W.shape[1]} inputs, got {width}.")
            # column-major, as in GRUStep
            self.mats.append(np.asfortranarray(np.column_stack([b, W]), dtype=dtype))
            width = W.shape[0]
            buf = np.empty(width + 1, dtype=dtype)
            buf[0] = 1.0
            self.bufs.append(buf)
        self.output = np.zeros(3)
        self._direct = np.dtype(dtype) == np.float64
        self._last = self.output if self._direct else self.bufs[-1][1:]
        self._hidden = [(M, buf, buf[1:]) for M, buf in zip(self.mats[:-1], self.bufs[:-1])]

    def __call__(self, v):
        """Evaluate on ``v = [1; a]``; the result is in :attr:`output`."""
        for M, buf, a in self._hidden:
            np.dot(M, v, a)
            np.tanh(a, a)
            v = buf
        np.dot(self.mats[-1], v, self._last)
        if not self._direct:
            self.output[:] = self._last
