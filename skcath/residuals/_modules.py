"""Torch modules of the residual learners: sweep context encoder, GRU and MLP cores, loss.

All modules work on normalised inputs and return the normalised residual
``F`` (paper eq. "head" before the rescaling by ``sigma_e``); the estimators
in :mod:`skcath.residuals._estimators` do the normalisation, the rescaling and
the clipping.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

__all__ = [
    "GRUResidualModule",
    "MLPResidualModule",
    "MaskedNormalizedMSE",
    "SweepEncoder",
    "on_cpu",
]


def on_cpu(module: nn.Module, dtype: torch.dtype) -> nn.Module:
    """``module`` itself if its parameters are CPU tensors of ``dtype``, else such a copy.

    What the streaming estimator and the export read a network through, so
    that a network trained on a GPU (or converted to another precision) is
    evaluated on the CPU without changing the fitted estimator.
    """
    if all(p.device.type == "cpu" and p.dtype == dtype for p in module.parameters()):
        return module
    return copy.deepcopy(module).to(device="cpu", dtype=dtype)


class SweepEncoder(nn.Module):
    """Context encoder ``z = Enc(s_bar)`` (paper eq. "context").

    A GRU reads the normalised, subsampled sweep sequence; the mean of its
    outputs over the valid steps and its output at the last valid step are
    mapped by a linear layer and ``tanh`` to the context ``z``.

    Parameters
    ----------
    n_inputs : int
        Sweep features per step (4 with torques, 2 without).
    hidden_size : int
        Hidden size of the encoder GRU.
    context_size : int
        Length of ``z``.
    """

    def __init__(self, n_inputs: int, hidden_size: int = 32, context_size: int = 16):
        super().__init__()
        self.gru = nn.GRU(n_inputs, hidden_size, batch_first=True)
        self.out = nn.Linear(2 * hidden_size, context_size)

    def forward(self, sweep: torch.Tensor, sweep_length: torch.Tensor) -> torch.Tensor:
        """Context of every sequence.

        Parameters
        ----------
        sweep : Tensor of shape (batch, L, n_inputs)
            Normalised sweep features, zero-padded after ``sweep_length`` steps.
        sweep_length : Tensor of int, shape (batch,)
            Number of valid steps (at least 1).

        Returns
        -------
        z : Tensor of shape (batch, context_size)
        """
        out, _ = self.gru(sweep)
        steps = torch.arange(sweep.shape[1], device=sweep.device)
        valid = (steps[None, :] < sweep_length[:, None]).to(out.dtype)
        n = valid.sum(dim=1, keepdim=True).clamp_min(1.0)
        mean = (out * valid[..., None]).sum(dim=1) / n
        last_index = (sweep_length.long() - 1).clamp_min(0)
        last = out[torch.arange(out.shape[0], device=out.device), last_index]
        return torch.tanh(self.out(torch.cat([mean, last], dim=1)))


def _head(n_inputs: int, hidden_size: int) -> nn.Sequential:
    """Nonlinear output head ``H``: linear, tanh, linear to the 3 coordinates."""
    return nn.Sequential(nn.Linear(n_inputs, hidden_size), nn.Tanh(), nn.Linear(hidden_size, 3))


class _ContextMixin(nn.Module):
    """Optional context encoder and the concatenation ``v = [x; z]``."""

    def _init_context(self, n_sweep_features, use_context, encoder_hidden_size, context_size):
        self.use_context = bool(use_context)
        self.encoder = (
            SweepEncoder(n_sweep_features, encoder_hidden_size, context_size)
            if self.use_context
            else None
        )
        return context_size if self.use_context else 0

    def _with_context(self, features, sweep, sweep_length):
        if self.encoder is None:
            return features
        if sweep is None or sweep_length is None:
            raise ValueError("This module uses the sweep context: pass sweep and sweep_length.")
        z = self.encoder(sweep, sweep_length)
        z = z[:, None, :].expand(-1, features.shape[1], -1)
        return torch.cat([features, z], dim=2)


def _layer_cell(gru, k):
    """A :class:`torch.nn.GRUCell` whose parameters are those of layer ``k`` of ``gru``."""
    cell = nn.GRUCell(gru.input_size if k == 0 else gru.hidden_size, gru.hidden_size,
                      device="meta")
    for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"):
        setattr(cell, name, getattr(gru, f"{name}_l{k}"))
    return cell


class GRUResidualModule(_ContextMixin):
    """GRU residual core: ``h_t = GRU([x_t; z], h_{t-1})``, ``F_t = H(h_t)``.

    Parameters
    ----------
    n_features : int
        Per-step features ``x_t`` (9, or 7 without torques); set by the estimator.
    n_sweep_features : int
        Sweep features ``s_k`` (4, or 2 without torques); set by the estimator.
    hidden_size : int, default=128
        Hidden size of the recurrent core.
    num_layers : int, default=1
        Stacked GRU layers.
    context_size : int, default=16
        Length of the sweep context ``z``.
    encoder_hidden_size : int, default=32
        Hidden size of the context encoder GRU.
    head_hidden_size : int, default=64
        Width of the output head.
    dropout : float, default=0.0
        Dropout between stacked GRU layers.
    use_context : bool, default=True
        Encode the sweep; without it ``v = x``.
    """

    def __init__(
        self,
        n_features: int = 9,
        n_sweep_features: int = 4,
        hidden_size: int = 128,
        num_layers: int = 1,
        context_size: int = 16,
        encoder_hidden_size: int = 32,
        head_hidden_size: int = 64,
        dropout: float = 0.0,
        use_context: bool = True,
    ):
        super().__init__()
        n_context = self._init_context(
            n_sweep_features, use_context, encoder_hidden_size, context_size
        )
        self.gru = nn.GRU(
            n_features + n_context,
            hidden_size,
            num_layers=num_layers,
            batch_first=True,
            dropout=dropout if num_layers > 1 else 0.0,
        )
        self.head = _head(hidden_size, head_hidden_size)

    def forward(self, features, sweep=None, sweep_length=None, hidden=None):
        """Normalised residual of every step.

        Parameters
        ----------
        features : Tensor of shape (batch, T, n_features)
            Normalised per-step features.
        sweep, sweep_length : Tensor
            See :class:`SweepEncoder`; ignored without context.
        hidden : Tensor of shape (num_layers, batch, hidden_size), optional
            Initial hidden state; zeros (the start of a motion sequence) if None.

        Returns
        -------
        F : Tensor of shape (batch, T, 3)
        """
        v = self._with_context(features, sweep, sweep_length)
        h, _ = self.gru(v, hidden)
        return self.head(h)

    def step(self, v, hidden=None):
        """One time step: the normalised residual and the next hidden state.

        The GRU layers are evaluated as :class:`torch.nn.GRUCell` steps whose
        parameters are those of :attr:`gru` itself (the same tensors, not
        copies; the cells are not submodules, so ``state_dict`` does not
        change), which gives what :meth:`forward` gives at that step. A
        traced step is written with elementary operations (no ONNX ``GRU``
        node).

        Parameters
        ----------
        v : Tensor of shape (batch, n_features + context_size)
            Normalised step features ``x_bar`` followed by the context ``z``
            (only ``x_bar`` without context), as the GRU reads them.
        hidden : Tensor of shape (num_layers, batch, hidden_size), optional
            Hidden state before the step; zeros (the start of a motion
            sequence) if None.

        Returns
        -------
        F : Tensor of shape (batch, 3)
        hidden : Tensor of shape (num_layers, batch, hidden_size)
        """
        gru = self.gru
        if hidden is None:
            hidden = v.new_zeros((gru.num_layers, v.shape[0], gru.hidden_size))
        states = []
        for k in range(gru.num_layers):
            v = _layer_cell(gru, k)(v, hidden[k])
            states.append(v)
        return self.head(v), torch.stack(states)


class MLPResidualModule(_ContextMixin):
    """Per-step MLP residual core: ``F_t = MLP([x_t; z])`` (no recurrence).

    Parameters
    ----------
    n_features, n_sweep_features : int
        Set by the estimator, as for :class:`GRUResidualModule`.
    hidden_size : int, default=128
        Width of the hidden layers.
    num_layers : int, default=2
        Number of hidden layers (tanh).
    context_size, encoder_hidden_size, use_context
        As for :class:`GRUResidualModule`.
    dropout : float, default=0.0
        Dropout after every hidden layer.
    """

    def __init__(
        self,
        n_features: int = 9,
        n_sweep_features: int = 4,
        hidden_size: int = 128,
        num_layers: int = 2,
        context_size: int = 16,
        encoder_hidden_size: int = 32,
        dropout: float = 0.0,
        use_context: bool = True,
    ):
        super().__init__()
        n_context = self._init_context(
            n_sweep_features, use_context, encoder_hidden_size, context_size
        )
        layers, width = [], n_features + n_context
        for _ in range(num_layers):
            layers += [nn.Linear(width, hidden_size), nn.Tanh()]
            if dropout:
                layers.append(nn.Dropout(dropout))
            width = hidden_size
        layers.append(nn.Linear(width, 3))
        self.mlp = nn.Sequential(*layers)

    def forward(self, features, sweep=None, sweep_length=None):
        """Normalised residual of every step, shape (batch, T, 3)."""
        return self.mlp(self._with_context(features, sweep, sweep_length))

    def step(self, v, hidden=None):
        """One time step: the normalised residual, and ``hidden`` passed through (no state).

        Parameters
        ----------
        v : Tensor of shape (batch, n_features + context_size)
            Normalised step features followed by the context ``z``.
        hidden : None
            The MLP has no state.

        Returns
        -------
        F : Tensor of shape (batch, 3)
        hidden : None
        """
        return self.mlp(v), hidden


class MaskedNormalizedMSE(nn.Module):
    """Masked normalised-residual loss (paper eq. "loss").

    ``L = sum_{j,t} m_{j,t} ||F_{j,t} - e_{j,t} / sigma_e||^2 / (3 sum m_{j,t})``;
    the target passed in is already ``e / sigma_e``. The mask ``m`` is 1 on
    the steps that count and 0 elsewhere, or, with sample weights, the weight
    of each step (0 where it does not count): the loss is then the weighted
    mean, and a step of weight 0 contributes no gradient.
    """

    def forward(self, prediction, target, mask):
        """Loss of a batch; ``mask`` (batch, T) holds the non-negative weight of every step."""
        mask = mask.to(prediction.dtype)
        squared = ((prediction - target) ** 2).sum(dim=2)
        total = mask.sum()
        # a batch without a step that counts has loss 0 (and no gradient)
        return (squared * mask).sum() / (3.0 * torch.where(total > 0, total, 1.0))
