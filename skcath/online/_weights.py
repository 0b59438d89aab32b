"""Per-run weights of a fitted residual network, with the run's constants folded in.

Everything that is constant within a run is folded into the first layer's
weights: the feature normalisation ``(x - mean) / scale``, the rotation of
the nominal tip into the sweep frame (``frame="sweep"``) and the context
contribution ``W_z z`` (which becomes part of the bias). The output layer
likewise absorbs ``sigma_e`` and the rotation back to the base frame, so the
folded network reads the raw features ``[q1 .. qN, dq1 .. dqN, (tau1 ..
tauN,) b_x, b_y, b_z]`` and returns the residual in the base frame (mm) before clipping.
Both streaming engines pack these weights (:mod:`skcath.online._layout`).
"""

from __future__ import annotations

import hashlib
from typing import NamedTuple

import numpy as np
import torch

from ..residuals import GRUResidualModule
from ..residuals._time_scales import fitted_sweep_stride

__all__ = [
    "StepWeights",
    "fitted_fingerprint",
    "fold_input_layer",
    "fold_output_layer",
    "step_weights",
]


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


class StepWeights(NamedTuple):
    """Folded float64 weights of one run's residual network.

    Attributes
    ----------
    gru : list of (W_ih, W_hh, b_ih, b_hh)
        The GRU layers in PyTorch's layout (gate order r, z, n), the first
        layer's input weights and bias on the raw step features; empty for
        the MLP.
    head : list of (W, b)
        The dense layers after the GRU (or the whole MLP): tanh layers, then
        the output layer, which returns the residual in the base frame.
    """

    gru: list
    head: list


def _numpy(t):
    return t.detach().cpu().to(torch.float64).numpy()


def step_weights(residual, rotation, z):
    """The folded weights of a fitted residual learner for one run.

    Parameters
    ----------
    residual : MLPResidual or GRUResidual
        Fitted learner.
    rotation : ndarray of shape (3, 3) or None
        ``R_SB`` of the run (``frame="sweep"``), or None.
    z : ndarray or None
        Context of the run.

    Returns
    -------
    weights : StepWeights
    """
    module = residual.module_
    scaler = residual.x_scaler_
    gru = []
    if isinstance(module, GRUResidualModule):
        for k in range(module.gru.num_layers):
            W_ih, W_hh, b_ih, b_hh = (
                _numpy(getattr(module.gru, f"{name}_l{k}"))
                for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")
            )
            if k == 0:
                W_ih, b_ih = fold_input_layer(W_ih, b_ih, scaler.mean, scaler.scale, rotation, z)
            gru.append((W_ih, W_hh, b_ih, b_hh))
        dense = module.head
    else:
        dense = module.mlp
    head = [(_numpy(m.weight), _numpy(m.bias)) for m in dense if isinstance(m, torch.nn.Linear)]
    if not gru:
        head[0] = fold_input_layer(*head[0], scaler.mean, scaler.scale, rotation, z)
    head[-1] = fold_output_layer(*head[-1], residual.sigma_e_, rotation)
    return StepWeights(gru, head)


def fitted_fingerprint(backbone, residual):
    """A digest of what a streaming estimator reads from a fitted pipeline.

    The backbone's class and parameters and, for a learned residual, its
    network's weights (``module_.state_dict()``), normalisation statistics,
    ``sigma_e_`` and the parameters that shape the step. It changes when the
    pipeline is refit (unless to the same weights) or its parameters are
    set, and survives pickling. Hashing the weights of the default GRU takes
    well under a millisecond.

    Parameters
    ----------
    backbone : PCCBackbone or PDLBackbone
    residual : MLPResidual, GRUResidual or None

    Returns
    -------
    digest : str
    """
    h = hashlib.blake2b(digest_size=16)
    h.update(repr((type(backbone).__name__, sorted(backbone.get_params().items()))).encode())
    if residual is None:
        return h.hexdigest()
    keys = (residual.frame, residual.clip, residual.use_torque, residual.use_context,
            fitted_sweep_stride(residual), getattr(residual, "sweep_pooling", None))
    h.update(repr((type(residual).__name__, keys)).encode())
    for name, tensor in residual.module_.state_dict().items():
        h.update(name.encode())
        h.update(tensor.detach().cpu().numpy().tobytes())
    for scaler in (residual.x_scaler_, residual.s_scaler_):
        if scaler is None:  # no sweep statistic: fitted on runs without a sweep
            h.update(b"none")
            continue
        h.update(np.ascontiguousarray(scaler.mean, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(scaler.scale, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(residual.sigma_e_, dtype=np.float64).tobytes())
    return h.hexdigest()
