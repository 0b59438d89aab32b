"""The Prandtl-Ishlinskii hysteresis of a started estimator as torch operations, for the exported step.

:class:`PIGraph` mirrors :func:`~skcath.online._pi_stream.pi_angles` (one
:func:`~skcath.backbones.pi_step` per motor) on a row of motor angles, all
motors and plays at once: the dead band, the plays, their weighted sum, the
creep stepped by the input ``dt`` (s) and the effective angle. Its state,
``K + 2`` values per motor (dead band output, the ``K`` plays, the creep; deg),
is a part of the exported step's ``state``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["PIGraph"]


def _const(values):
    return torch.as_tensor(np.asarray(values, dtype=np.float64))


class PIGraph(nn.Module):
    """The PI of a :class:`~skcath.online._pi_stream.PIStep`: ``(q, state, dt) -> (v, state_out)``.

    ``q`` (1, N) motor angles (deg), ``state`` (1, N (K + 2)), ``dt`` (1,)
    time since the previous sample (s); ``v`` (1, N) effective angles (deg).
    """

    def __init__(self, pi):
        super().__init__()
        theta = pi.theta
        k = int(theta[0])
        self.n_motors = pi.bands.size // 2
        self.k = k
        self.kappa, self.tau = float(theta[1]), float(theta[2])
        self.register_buffer("g", _const(theta[3 : 3 + k]))
        self.register_buffer("w", _const(theta[3 + k : 3 + 2 * k]))
        self.register_buffer("up", _const(pi.bands[: self.n_motors][None]))
        self.register_buffer("down", _const(pi.bands[self.n_motors :][None]))

    def forward(self, q, state, dt):
        n, k = self.n_motors, self.k
        s = state.reshape(1, n, k + 2)
        b = torch.minimum(torch.maximum(s[:, :, 0], q - self.up), q + self.down)
        bk = b.unsqueeze(2)
        z = torch.minimum(torch.maximum(s[:, :, 1 : k + 1], bk - self.g), bk + self.g)
        y = (z * self.w).sum(dim=2)
        c = s[:, :, k + 1]
        c = c + (y - c) * (1.0 - torch.exp(-dt.unsqueeze(1) / self.tau))
        v = (y - self.kappa * c) / (1.0 - self.kappa)
        return v, torch.cat([bk, z, c.unsqueeze(2)], dim=2).reshape(1, n * (k + 2))
