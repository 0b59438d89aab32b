"""Export of a streaming step as ONNX or TorchScript.

Given a started :class:`OnlineEstimator`, :func:`export` writes its whole
step (:mod:`skcath.online._export_step`). Given a fitted pipeline, the
exported graph is one step of the residual learner of a fitted pipeline,
from the raw step features to the clipped residual in the base frame. The
normalisation statistics, ``sigma_e`` and the clip bound are constants of the
graph; what depends on the run (the sweep frame ``R_SB`` and the context
``z``, both computed once per run by :meth:`OnlineEstimator.start`) and the
recurrent state are inputs. The backbone is not part of the graph: evaluate
it (e.g. with ``OnlineEstimator``'s calibration, ``backbone_params_``) and
add its nominal tip to the residual.
"""

from __future__ import annotations

import copy
import os

import torch
from torch import nn

from ..residuals import GRUResidualModule
from ._estimator import OnlineEstimator
from ._export_step import export_step, step_io
from ._pipeline import check_online_pipeline

__all__ = ["export", "export_io"]

FORMATS = ("onnx", "torchscript")


class _StepGraph(nn.Module):
    """One step of a fitted residual learner on raw features (see :func:`export`).

    The network's own ``step`` (:meth:`GRUResidualModule.step`,
    :meth:`MLPResidualModule.step`) on a CPU copy of the module in ``dtype``
    (whatever the ``device`` it was trained on), between the normalisation,
    the rotations, ``sigma_e`` and the clip.
    """

    def __init__(self, residual, dtype):
        super().__init__()
        self.module = copy.deepcopy(residual.module_)
        self.rotate = residual.frame == "sweep"
        self.use_context = residual.use_context
        as_tensor = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
        self.register_buffer("mean", as_tensor(residual.x_scaler_.mean))
        self.register_buffer("scale", as_tensor(residual.x_scaler_.scale))
        self.register_buffer("sigma_e", as_tensor(residual.sigma_e_))
        clip = float("inf") if residual.clip is None else float(residual.clip)
        self.register_buffer("clip", as_tensor(clip))
        self.to(device="cpu", dtype=dtype).eval()

    def _features(self, features, rotation):
        if not self.rotate:
            return (features - self.mean) / self.scale
        b = features[:, -3:] @ rotation.transpose(0, 1)  # R_SB b, as rows
        x = torch.cat([features[:, :-3], b], dim=1)
        return (x - self.mean) / self.scale

    def _residual(self, f, rotation):
        e = f * self.sigma_e
        if self.rotate:
            e = e @ rotation  # R_SB^T e, as rows
        return torch.maximum(torch.minimum(e, self.clip), -self.clip)

    def step(self, features, rotation, context, hidden):
        v = self._features(features, rotation)
        if self.use_context:
            v = torch.cat([v, context], dim=1)
        F, hidden = self.module.step(v, hidden)
        return self._residual(F, rotation), hidden


def _wrapper(graph, names):
    """A module whose ``forward`` takes exactly the inputs in ``names``."""
    has_rotation = "rotation" in names
    has_context = "context" in names
    has_hidden = "hidden" in names

    class Step(nn.Module):
        def __init__(self):
            super().__init__()
            self.graph = graph

        def forward(self, *inputs):
            values = dict(zip(names, inputs))
            out = self.graph.step(
                values["features"],
                values["rotation"] if has_rotation else None,
                values["context"] if has_context else None,
                values["hidden"] if has_hidden else None,
            )
            return out if has_hidden else out[0]

    return Step()


def export_io(pipeline):
    """Names and shapes of the inputs and outputs of the exported step graph.

    Parameters
    ----------
    pipeline : OnlineEstimator or sklearn.pipeline.Pipeline
        A started :class:`OnlineEstimator` (its whole step), or a fitted
        pipeline with an :class:`~skcath.residuals.MLPResidual` or
        :class:`~skcath.residuals.GRUResidual` as last step (its network).

    Returns
    -------
    inputs : dict
        Name -> shape, in the order the graph takes them. For an
        estimator: ``sample`` ``(1, n_channels)``, ``state`` ``(1,
        state_size)``, ``reset`` ``(1,)``, and ``dt`` ``(1,)`` with
        ``hysteresis="pi"`` (see :func:`export`). For a
        pipeline: ``features``
        ``(1, n_features)`` (``3N + 3`` for ``N`` motors, ``2N + 3`` without
        torques); ``rotation`` ``(3, 3)`` (``frame="sweep"``
        only); ``context`` ``(1, context_size)`` (``use_context=True`` only);
        ``hidden`` ``(num_layers, 1, hidden_size)`` (GRU only).
    outputs : dict
        For an estimator: ``tip`` ``(1, 3)``, ``state_out`` ``(1,
        state_size)``, ``valid`` ``(1,)``. For a pipeline: ``residual``
        ``(1, 3)``, and ``hidden_out`` for the GRU.
    """
    if isinstance(pipeline, OnlineEstimator):
        return step_io(pipeline)
    _, residual = check_online_pipeline(pipeline)
    if residual is None:
        raise ValueError(
            "pipeline has no learned residual (a backbone alone or with NoResidual): "
            "there is no network to export; the backbone runs as is."
        )
    module = residual.module_
    n_features = residual.x_scaler_.mean.shape[0]
    inputs = {"features": (1, n_features)}
    if residual.frame == "sweep":
        inputs["rotation"] = (3, 3)
    if residual.use_context:
        inputs["context"] = (1, module.encoder.out.out_features)
    outputs = {"residual": (1, 3)}
    if isinstance(module, GRUResidualModule):
        shape = (module.gru.num_layers, 1, module.gru.hidden_size)
        inputs["hidden"] = shape
        outputs["hidden_out"] = shape
    return inputs, outputs


def export(pipeline, path, format="onnx", *, dtype=None):
    """Write one streaming step to a file: an estimator's whole step, or a pipeline's network.

    **A started** :class:`OnlineEstimator` (``export(est, path)``): the
    whole step, in float64, with the run's calibration, play or PI, sweep frame,
    context and clip taken from ``start`` and written into the graph. The
    graph does what ``est.step`` does for an accepted sample, at the model's
    rate (one model step per call):

    ``(sample, state, reset) -> (tip, state_out, valid)``

    ``sample`` (1, n_channels) float64 holds the channels of ``channels_``
    (motor angles ``q1 .. qN``, deg, then the torques ``tau1 .. tauN`` when
    the recordings have them); ``state`` (1, state_size) float64 is what the
    step carries (the previous motor angles, the played angles with
    ``hysteresis="play"``, the Prandtl-Ishlinskii hysteresis's state with
    ``hysteresis="pi"``, the GRU's hidden states); with ``reset`` (1,)
    bool set, the graph ignores ``state`` and starts from the state right
    after ``start`` (as ``est.reset()``). With ``hysteresis="pi"`` a fourth
    input, ``dt`` (1,) float64, is the time since the previous sample (s),
    which the hysteresis's creep reads: ``(sample, state, reset, dt)``. ``tip`` (1, 3) float64 is the
    tip in the base frame (mm); ``state_out`` is the state to pass back
    with the next sample; ``valid`` (1,) bool says whether ``step`` would
    accept the sample (all channels finite, motor angles within
    ``q_limit_`` of ``q_neutral_``): where it is False, ``state_out`` is
    ``state`` unchanged and ``tip`` is NaN.
    :func:`~skcath.online.step_state` gives an estimator's current state in
    this layout; the model's metadata (``skcath.state_layout``, ...) describe it.

    **A fitted pipeline** (``export(pipe, path)``): one step of its
    residual network, from the raw step features of one motor sample to the
    residual (mm, base frame, clipped), for a GRU also the hidden state to
    the next one:

    ``(features, [rotation], [context], [hidden]) -> (residual, [hidden_out])``

    ``features`` are ``[q1, q2, dq1, dq2, tau1, tau2, b_x, b_y, b_z]``, for
    ``N`` motors ``[q1 .. qN, dq1 .. dqN, tau1 .. tauN, b_x, b_y, b_z]``
    (without the torques if the learner has ``use_torque=False``): motor
    angles (deg), their differences to the previous sample (deg; for the
    first motion sample, to the last sweep sample), drive torques and the
    backbone's nominal tip in the base frame (mm). ``rotation`` is the run's
    ``R_SB`` and ``context`` its sweep context ``z``
    (``OnlineEstimator.rotation_`` and ``.context_`` after ``start``);
    ``hidden`` starts at zeros for every motion sequence. The tip is the
    nominal tip plus ``residual``. The backbone is not part of this graph.

    :func:`export_io` gives the shapes of either graph.

    Parameters
    ----------
    pipeline : OnlineEstimator or sklearn.pipeline.Pipeline
        A started estimator (any backbone, with or without a residual
        network), or a fitted pipeline whose last step is an
        :class:`~skcath.residuals.MLPResidual` or
        :class:`~skcath.residuals.GRUResidual`.
    path : str or os.PathLike
        File to write.
    format : {"onnx", "torchscript"}, default="onnx"
        ONNX (opset 17, PyTorch's TorchScript-based exporter; the GRU is
        written as elementary ``MatMul``/``Sigmoid``/``Tanh`` operations of a
        ``GRUCell``, not as an ONNX ``GRU`` node) or a TorchScript archive for
        ``torch.jit.load``.
    dtype : {"float32", "float64"} or None, default=None
        Precision of the weights and of every floating input and output.
        None means "float64" for an estimator (the only precision of its
        whole step) and "float32" for a pipeline.

    Returns
    -------
    path : str
        The file written.
    """
    if isinstance(pipeline, OnlineEstimator):
        if dtype not in (None, "float64"):
            raise ValueError(
                "dtype must be 'float64' (or None) to export an OnlineEstimator's whole step, "
                f"which runs in float64; got {dtype!r}."
            )
        return export_step(pipeline, path, format)
    return _export_network(pipeline, path, format, "float32" if dtype is None else dtype)


def _export_network(pipeline, path, format, dtype):
    """:func:`export` of a fitted pipeline: its residual network's step."""
    if format not in FORMATS:
        raise ValueError(f"format must be one of {list(FORMATS)}; got {format!r}.")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64'; got {dtype!r}.")
    inputs, outputs = export_io(pipeline)
    _, residual = check_online_pipeline(pipeline)
    torch_dtype = getattr(torch, dtype)
    graph = _StepGraph(residual, torch_dtype)
    names = list(inputs)
    model = _wrapper(graph, names).eval()
    examples = []
    for name, shape in inputs.items():
        example = torch.zeros(shape, dtype=torch_dtype)
        if name == "rotation":
            example = torch.eye(3, dtype=torch_dtype)
        examples.append(example)
    path = os.fspath(path)
    with torch.no_grad():
        if format == "torchscript":
            traced = torch.jit.trace(model, tuple(examples))
            traced.save(path)
        else:
            torch.onnx.export(
                model,
                tuple(examples),
                path,
                input_names=names,
                output_names=list(outputs),
                opset_version=17,
                dynamo=False,
            )
    return path
