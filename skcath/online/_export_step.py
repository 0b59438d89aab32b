"""Export of a started estimator's whole step as one ONNX or TorchScript graph.

The graph does what :meth:`OnlineEstimator.step` does after its input
checks (:func:`skcath.online._kernels.step`), in float64, from the arrays
the estimator took from the pipeline at ``start``: the play or the
Prandtl-Ishlinskii hysteresis in front of the backbone, the backbone's tip for the run's calibration, the step features,
the residual network with the run's sweep frame and context folded into its
first and last layers, the clip and the addition of the nominal tip. Each
part is a small torch module mirroring one function of the numpy step;
:func:`export_step` traces their composition.

What the step carries from one sample to the next is one float64 vector,
``state``: the previous motor angles, the played angles (with a play), the
state of the Prandtl-Ishlinskii hysteresis (with ``hysteresis="pi"``, whose
creep reads one more input, ``dt``, the time since the previous sample) and
the GRU's hidden states. The graph also returns whether ``step`` would
accept the sample (finite, within the sweep's range of motor angles).
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings

import numpy as np
import torch
from torch import nn

from ..backbones._pcc import (
    _N_TERMS,
    _SERIES_MAX,
    PCC_C,
    PCC_F_SERIES,
    PCC_LR,
    PCC_Q0,
    PCC_S_M,
    PCC_S_SERIES,
    PCC_U0,
)
from ..backbones._pdl import (
    _N_COEF,
    _TWO_PI,
    PDL_BASIS,
    PDL_BIG_P,
    PDL_FIRST,
    PDL_N_RAYS,
    PDL_P0,
    PDL_Q_NEUTRAL,
    PDL_RHO0,
    _ray_blocks,
)
from ._export_pi import PIGraph
from ._layout import BACKBONE_PCC, BACKBONE_PDL

__all__ = ["STEP_FORMATS", "export_step", "step_io", "step_state"]

STEP_FORMATS = ("onnx", "torchscript")
_F64 = torch.float64
#: Newton steps that refine the float32 ``atan2`` (ONNX Runtime has no float64
#: ``Atan``): each squares the relative error, 1e-7 -> 1e-14 -> rounding.
_ATAN2_NEWTON = 2


def _const(values):
    return torch.as_tensor(np.asarray(values, dtype=np.float64))


def atan2(y, x):
    """``atan2(y, x)`` in float64 from a float32 first guess and Newton steps on ``x sin - y cos``.

    The result may differ from the principal value by a multiple of ``2 pi``
    (the callers reduce it modulo ``2 pi``); 0 where ``x = y = 0``.
    """
    a = torch.atan2(y.to(torch.float32), x.to(torch.float32)).to(_F64)
    for _ in range(_ATAN2_NEWTON):
        s, c = torch.sin(a), torch.cos(a)
        a = a - (x * s - y * c) / (x * c + y * s)
    return torch.where(x * x + y * y > 0.0, a, torch.zeros_like(a))


class PCCTip(nn.Module):
    """:func:`~skcath.backbones.pcc_kernel` on a row ``q`` (1, 2): the tip (1, 3), mm."""

    def __init__(self, theta):
        super().__init__()
        t = np.asarray(theta, dtype=np.float64)
        self.register_buffer("q0", _const(t[PCC_Q0 : PCC_Q0 + 2]))
        self.s_m = float(t[PCC_S_M])
        self.register_buffer("C", _const(t[PCC_C : PCC_C + 4].reshape(2, 2)))
        self.register_buffer("u0", _const(t[PCC_U0 : PCC_U0 + 2]))
        self.register_buffer("LR", _const(t[PCC_LR : PCC_LR + 9].reshape(3, 3)))
        self.f_series = [float(v) for v in t[PCC_F_SERIES : PCC_F_SERIES + _N_TERMS]]
        self.s_series = [float(v) for v in t[PCC_S_SERIES : PCC_S_SERIES + _N_TERMS]]

    def forward(self, q):
        v = (q - self.q0) / self.s_m
        u1 = v[:, 0:1] * self.C[0, 0] + v[:, 1:2] * self.C[0, 1] + self.u0[0]
        u2 = v[:, 0:1] * self.C[1, 0] + v[:, 1:2] * self.C[1, 1] + self.u0[1]
        x = u1 * u1 + u2 * u2
        f, s = torch.full_like(x, self.f_series[0]), torch.full_like(x, self.s_series[0])
        for k in range(1, _N_TERMS):  # Taylor series in x = alpha^2
            f = f * x + self.f_series[k]
            s = s * x + self.s_series[k]
        a = torch.sqrt(x)
        series = x < _SERIES_MAX
        f = torch.where(series, f, 2.0 * torch.sin(0.5 * a) ** 2 / x)
        s = torch.where(series, s, torch.sin(a) / a)
        h = torch.cat([u1 * f, u2 * f, s], dim=1)
        return h @ self.LR.transpose(0, 1)


def pdl_section(gamma, dist, phi, big_p):
    """:func:`~skcath.backbones._pdl.pdl_section` on tensors: ``c1, c2, c3`` (mm)."""
    h = 0.5 * gamma
    ch, sh = torch.cos(h), torch.sin(h)
    disc = dist * dist - (big_p * sh) ** 2
    s = torch.sign(disc) * torch.sqrt(torch.abs(disc))
    across = (big_p * ch + s) * sh
    return across * torch.cos(phi), across * torch.sin(phi), s * ch - big_p * sh * sh


class PDLTip(nn.Module):
    """:func:`~skcath.backbones.pdl_kernel` on a row ``q`` (1, 2): the tip (1, 3), mm."""

    def __init__(self, theta):
        super().__init__()
        t = np.asarray(theta, dtype=np.float64)
        n = int(t[PDL_N_RAYS])
        relative, span, lower, upper = _ray_blocks(n)
        self.n_rays = n
        self.register_buffer("q_neutral", _const(t[PDL_Q_NEUTRAL : PDL_Q_NEUTRAL + 2]))
        self.first, self.rho0, self.big_p = (float(t[i]) for i in (PDL_FIRST, PDL_RHO0, PDL_BIG_P))
        self.register_buffer("relative", _const(t[relative : relative + n]))
        self.register_buffer("span", _const(t[span : span + n]))
        self.register_buffer("lower", _const(t[lower : lower + _N_COEF * n].reshape(n, _N_COEF)))
        self.register_buffer("upper", _const(t[upper : upper + _N_COEF * n].reshape(n, _N_COEF)))
        self.register_buffer("p0", _const(t[PDL_P0 : PDL_P0 + 3]))
        self.register_buffer("basis", _const(t[PDL_BASIS : PDL_BASIS + 9].reshape(3, 3)))

    def forward(self, q):
        v = q - self.q_neutral
        v1, v2 = v[:, 0], v[:, 1]
        rho = torch.sqrt(v1 * v1 + v2 * v2)
        offset = torch.remainder(atan2(v2, v1) - self.first, _TWO_PI)
        # bisect_right over the rays' directions, less one: the ray at or before the direction
        k = (self.relative <= offset.unsqueeze(1)).sum(dim=1) - 1
        k = torch.clamp(k, 0, self.n_rays - 1)
        w = torch.clamp((offset - self.relative[k]) / self.span[k], 0.0, 1.0).unsqueeze(1)
        c = (1.0 - w) * self.lower[k] + w * self.upper[k]  # (1, 6): the interpolated coefficients
        gamma = rho * (c[:, 0] + c[:, 1] * rho)
        dist = rho * (c[:, 2] + c[:, 3] * rho)
        phi = c[:, 4] + c[:, 5] * (rho - self.rho0)
        c1, c2, c3 = pdl_section(gamma, dist, phi, self.big_p)
        return self.p0 + torch.stack([c1, c2, c3], dim=1) @ self.basis


class PolynomialTip(nn.Module):
    """:func:`~skcath.backbones.polynomial_kernel` on a row ``q`` (1, N): the tip (1, 3), mm."""

    def __init__(self, theta):
        super().__init__()
        t = np.asarray(theta, dtype=np.float64)
        n, m = int(t[0]), int(t[1])
        at_powers = 2 + 2 * n
        at_coef = at_powers + m * n
        self.register_buffer("center", _const(t[2 : 2 + n]))
        self.register_buffer("scale", _const(t[2 + n : 2 + 2 * n]))
        self.register_buffer("powers", _const(t[at_powers:at_coef].reshape(m, n)))
        self.register_buffer("coef", _const(t[at_coef : at_coef + 3 * m].reshape(m, 3)))
        self.register_buffer("intercept", _const(t[at_coef + 3 * m : at_coef + 3 * m + 3]))

    def forward(self, q):
        u = (q - self.center) / self.scale
        terms = torch.prod(u.unsqueeze(1) ** self.powers, dim=2)  # (1, m)
        return self.intercept + terms @ self.coef


def backbone_tip(backbone):
    """The tip module of a :class:`~skcath.online._kernels.BackboneStep`."""
    if backbone.code == BACKBONE_PCC:
        return PCCTip(backbone.theta)
    if backbone.code == BACKBONE_PDL:
        return PDLTip(backbone.theta)
    return PolynomialTip(backbone.theta)


class Network(nn.Module):
    """The folded residual network (:class:`~skcath.online._weights.StepWeights`) on raw features.

    GRU layers (gate order r, z, n, as :class:`torch.nn.GRU`), then the dense
    layers (tanh, then the output layer), or the MLP alone; returns the
    residual in the base frame (mm) before the clip, and the new hidden
    states ``(n_layers, H)``.
    """

    def __init__(self, weights):
        super().__init__()
        self.n_gru = len(weights.gru)
        self.n_head = len(weights.head)
        for k, (W_ih, W_hh, b_ih, b_hh) in enumerate(weights.gru):
            for name, value in (("W_ih", W_ih), ("W_hh", W_hh), ("b_ih", b_ih), ("b_hh", b_hh)):
                self.register_buffer(f"{name}{k}", _const(value))
        for k, (W, b) in enumerate(weights.head):
            self.register_buffer(f"W{k}", _const(W))
            self.register_buffer(f"b{k}", _const(b))
        self.hidden_size = weights.gru[0][1].shape[1] if weights.gru else 0

    def _gru(self, k, x, h):
        gi = x @ getattr(self, f"W_ih{k}").transpose(0, 1) + getattr(self, f"b_ih{k}")
        gh = h @ getattr(self, f"W_hh{k}").transpose(0, 1) + getattr(self, f"b_hh{k}")
        H = self.hidden_size
        r = torch.sigmoid(gi[:, :H] + gh[:, :H])
        z = torch.sigmoid(gi[:, H : 2 * H] + gh[:, H : 2 * H])
        n = torch.tanh(gi[:, 2 * H :] + r * gh[:, 2 * H :])
        return n + z * (h - n)

    def forward(self, x, hidden):
        new = []
        for k in range(self.n_gru):
            x = self._gru(k, x, hidden[:, k * self.hidden_size : (k + 1) * self.hidden_size])
            new.append(x)
        for k in range(self.n_head):
            x = x @ getattr(self, f"W{k}").transpose(0, 1) + getattr(self, f"b{k}")
            if k < self.n_head - 1:
                x = torch.tanh(x)
        return x, new


def _layout(est):
    """``(name, size)`` of the parts of the state vector, in order; the motors ``N``."""
    backbone = est._backbone
    weights, _, _ = est._step_inputs
    n = backbone.n_motors
    parts = [("previous_angles", n)]
    if backbone.play_width > 0.0:
        parts.append(("played_angles", n))
    if backbone.pi is not None:
        parts.append(("hysteresis_state", backbone.pi.start.size))
    if weights is not None and weights.gru:
        H = weights.gru[0][1].shape[1]
        parts += [(f"hidden_{k}", H) for k in range(len(weights.gru))]
    return parts, n


def step_state(est):
    """The estimator's current stream state in the layout of the exported step's ``state``.

    Right after ``start`` or ``reset`` this is the state that ``reset=True``
    makes the graph use; after some steps it is the state to feed the graph
    to continue the stream where the estimator is.

    Parameters
    ----------
    est : OnlineEstimator
        A started estimator.

    Returns
    -------
    state : ndarray of shape (1, state_size), float64
        ``[previous motor angles (N, deg), played angles (N, deg; with
        hysteresis="play" only), state of the Prandtl-Ishlinskii hysteresis
        (N (K + 2), deg; with hysteresis="pi" only: per motor the dead band's
        output, the K plays and the creep), hidden state of each GRU layer
        (H each)]``.
    """
    est._check_started()
    parts, n = _layout(est)
    values = [np.asarray(est._last[:n], dtype=np.float64)]
    if any(name == "played_angles" for name, _ in parts):
        values.append(np.asarray(est.play_state_, dtype=np.float64))
    if est._pi is not None:
        values.append(np.asarray(est.hysteresis_state_, dtype=np.float64))
    values += [np.asarray(h, dtype=np.float64) for h in est._packed.hidden]
    return np.concatenate(values)[None]


class WholeStep(nn.Module):
    """One whole step of a started estimator: ``(sample, state, reset) -> (tip, state_out, valid)``.

    See :func:`export_step` for the inputs and outputs.
    """

    def __init__(self, est):
        super().__init__()
        backbone = est._backbone
        weights, clip, use_torque = est._step_inputs
        parts, self.n_motors = _layout(est)
        self.play = backbone.play_width > 0.0
        self.play_width = float(backbone.play_width)
        self.use_torque = bool(use_torque) and weights is not None
        self.pi = None if backbone.pi is None else PIGraph(backbone.pi)
        self.tip = backbone_tip(backbone)
        self.network = None if weights is None else Network(weights)
        self.clip = None if math.isinf(clip) else float(clip)
        n = self.n_motors
        initial = [np.asarray(est._last_sweep[:n], dtype=np.float64)]
        if self.play:
            initial.append(np.asarray(backbone.play_start, dtype=np.float64))
        if self.pi is not None:
            initial.append(backbone.pi.start)
        initial += [np.zeros(size) for name, size in parts if name.startswith("hidden")]
        self.register_buffer("initial", _const(np.concatenate(initial)[None]))
        self.register_buffer("q_neutral", _const(est._qn))
        self.limit2 = float(est._limit2)
        self.eval()

    def forward(self, sample, state, reset, dt=None):
        n = self.n_motors
        state = torch.where(reset.unsqueeze(1), self.initial, state)
        q = sample[:, :n]
        previous = state[:, :n]
        at = n
        angles = q
        new_state = [q]
        if self.play:  # play_kernel: min(max(z, q - w), q + w)
            played = torch.minimum(torch.maximum(state[:, n : 2 * n], q - self.play_width),
                                   q + self.play_width)
            angles, at = played, 2 * n
            new_state.append(played)
        if self.pi is not None:  # pi_angles, the creep stepped by dt
            size = self.pi.n_motors * (self.pi.k + 2)
            angles, pi_state = self.pi(q, state[:, at : at + size], dt)
            at += size
            new_state.append(pi_state)
        nominal = self.tip(angles)
        tip = nominal
        if self.network is not None:
            x = [q, q - previous]
            if self.use_torque:
                x.append(sample[:, n : 2 * n])
            e, hidden = self.network(torch.cat([*x, nominal], dim=1), state[:, at:])
            if self.clip is not None:
                e = torch.clamp(e, -self.clip, self.clip)
            tip = nominal + e
            new_state += hidden
        d = q - self.q_neutral
        valid = torch.isfinite(sample).all(dim=1) & ((d * d).sum(dim=1) <= self.limit2)
        # a sample step would reject leaves the state as it was and gives a NaN tip
        keep = valid.unsqueeze(1)
        tip = torch.where(keep, tip, torch.full_like(tip, math.nan))
        return tip, torch.where(keep, torch.cat(new_state, dim=1), state), valid


def step_io(est):
    """Names and shapes of the inputs and outputs of the exported whole step.

    Parameters
    ----------
    est : OnlineEstimator
        A started estimator.

    Returns
    -------
    inputs : dict
        Name -> shape, in the order the graph takes them: ``sample``
        ``(1, n_channels)`` (float64, the channels of ``channels_``),
        ``state`` ``(1, state_size)`` (float64), ``reset`` ``(1,)`` (bool),
        and with ``hysteresis="pi"`` ``dt`` ``(1,)`` (float64, the time since
        the previous sample, s, which the hysteresis's creep reads).
    outputs : dict
        ``tip`` ``(1, 3)`` (float64, mm), ``state_out`` ``(1, state_size)``
        (float64), ``valid`` ``(1,)`` (bool).
    """
    est._check_started()
    parts, _ = _layout(est)
    size = sum(s for _, s in parts)
    inputs = {"sample": (1, len(est.channels_)), "state": (1, size), "reset": (1,)}
    if est._pi is not None:
        inputs["dt"] = (1,)
    outputs = {"tip": (1, 3), "state_out": (1, size), "valid": (1,)}
    return inputs, outputs


def step_metadata(est):
    """What a caller needs to know about the exported step, as strings (the model's metadata)."""
    parts, n = _layout(est)
    pi = {} if est._pi is None else {"skcath.dt_s": json.dumps(est._pi.period)}
    return {**pi,
        "skcath.channels": json.dumps(list(est.channels_)),
        "skcath.n_motors": str(n),
        "skcath.state_layout": json.dumps([[name, size] for name, size in parts]),
        "skcath.rate_hz": json.dumps(getattr(est, "rate_hz_", None)),
        "skcath.q_neutral": json.dumps([float(v) for v in est._qn]),
        # null for q_margin=None: JSON has no infinity
        "skcath.q_limit": json.dumps(None if math.isinf(est.q_limit_) else float(est.q_limit_)),
    }


def export_step(est, path, format="onnx"):
    """Write the whole step of a started estimator (see :func:`skcath.online.export`)."""
    if format not in STEP_FORMATS:
        raise ValueError(f"format must be one of {list(STEP_FORMATS)}; got {format!r}.")
    est._check_started()
    est._warn_if_pipeline_changed("was exported")
    inputs, outputs = step_io(est)
    model = WholeStep(est)
    examples = (
        torch.as_tensor(np.array([est._last_sweep], dtype=np.float64)),
        model.initial.clone(),
        torch.tensor([True]),
    )
    if model.pi is not None:
        examples += (torch.tensor([est._pi.period], dtype=_F64),)
    path = os.fspath(path)
    metadata = step_metadata(est)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", (DeprecationWarning, torch.jit.TracerWarning))
        if format == "torchscript":
            traced = torch.jit.trace(model, examples)
            torch.jit.save(traced, path, _extra_files={"skcath.json": json.dumps(metadata)})
            return path
        buffer = io.BytesIO()
        torch.onnx.export(model, examples, buffer, input_names=list(inputs),
                          output_names=list(outputs), opset_version=17, dynamo=False)
    import onnx

    # The graph just exported, parsed from memory: no file is read back.
    graph = onnx.ModelProto.FromString(buffer.getvalue())
    for key, value in metadata.items():
        graph.metadata_props.add(key=key, value=value)
    onnx.save(graph, path)
    return path
