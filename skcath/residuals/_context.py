"""The sweep context of the residual learners: a run's sweep pooled, normalised and encoded."""

from __future__ import annotations

import numpy as np
import torch

from ._features import pool_sweep, sweep_feature_names
from ._modules import on_cpu
from ._time_scales import fitted_sweep_stride

__all__ = ["context_input", "encode_sweeps", "sweep_context"]


def _sweep_pooling(learner):
    """``sweep_pooling`` of a learner; those pickled before the parameter existed subsampled."""
    return getattr(learner, "sweep_pooling", "subsample")


def context_input(learner, values, lengths, dtype=np.float32):
    """Normalised sweep pooled over blocks of ``sweep_stride_``, and its valid lengths.

    ``values`` of shape (n_runs, n_steps, n_features) holds the zero-padded
    sweep features of the runs (those of
    :func:`~skcath.residuals.sweep_feature_names`), ``lengths`` their
    numbers of samples; ``dtype`` is the precision of the result.
    """
    pooling = _sweep_pooling(learner)
    stride = fitted_sweep_stride(learner)
    pooled, lengths = pool_sweep(values, lengths, stride, pooling)
    values = learner.s_scaler_.transform(pooled).astype(dtype)
    valid = np.arange(values.shape[1])[None, :] < lengths[:, None]
    values[~valid] = 0.0
    return values, np.maximum(lengths, 1).astype(np.int64)


def encode_sweeps(learner, values, lengths, dtype):
    """Sweep context ``z`` of every run, shape (n_runs, context_size), float64.

    ``values`` and ``lengths`` as for :func:`context_input`; the fitted
    learner's encoder runs on the CPU in ``dtype`` (a CPU copy of it when
    the network is elsewhere or in the other precision).
    """
    torch_dtype = torch.float64 if dtype == np.float64 else torch.float32
    encoder = on_cpu(learner.module_.encoder, torch_dtype)
    values, lengths = context_input(learner, values, lengths, dtype)
    with torch.no_grad():
        z = encoder(torch.from_numpy(values), torch.from_numpy(lengths))
    return z.detach().cpu().to(torch.float64).numpy()


def sweep_context(learner, X, n_motors, dtype):
    """Sweep context ``z`` of one run (context_size,), from its checked sweep rows.

    ``X`` holds the sweep rows of one run at the learner's rate, with float64
    channels (checked recordings, or those resampled to the rate), of
    ``n_motors`` motors, those of the learner; what
    ``learner.encode_context`` computes for that run, without checking or
    resampling the rows again. ``dtype`` is the encoder's precision.
    """
    names = sweep_feature_names(learner.use_torque, n_motors)
    values = np.ascontiguousarray(X[list(names)].to_numpy(dtype=np.float64))[None]
    lengths = np.array([values.shape[1]], dtype=np.int64)
    return encode_sweeps(learner, values, lengths, np.dtype(dtype))[0]
