"""Residual learners as plain arrays and types, for the pickle-free persistence format.

skops builds only the types a user trusts, but a skorch net restores its torch
modules by unpickling bytes in its ``__setstate__``: trusting a residual
learner in skops would trust any code in the file. So before
:func:`skcath.persist.save` hands an estimator to skops, :func:`to_plain`
replaces every residual learner in it by a :class:`ResidualLearnerState`
holding its class, the parameters that differ from the class's defaults and
its fitted state as numpy arrays, numbers and strings: the ``state_dict`` of
the network, of the criterion and of the optimizer, the normalisation
statistics, and the training history as JSON. After skops has loaded the
file, :func:`from_plain` builds each learner again with its own ``__init__``
and ``initialize`` and loads that state into it. Nothing from the file is
unpickled, and the only code that runs is that of the types the user trusted.
"""

from __future__ import annotations

import json

import numpy as np
import torch
from sklearn.base import BaseEstimator
from skorch.history import History
from skorch.utils import get_map_location

from .online import OnlineEstimator
from .online._state import OnlineEstimatorState
from .residuals import GRUResidual, MLPResidual
from .residuals._features import Standardizer

__all__ = ["LEARNERS", "ResidualLearnerState", "from_plain", "to_plain"]

#: The classes (and their subclasses) that :class:`ResidualLearnerState` stores.
LEARNERS = (GRUResidual, MLPResidual)

#: torch components, stored through their ``state_dict``.
_TORCH = ("module_", "criterion_", "optimizer_")

#: What ``initialize`` builds again from the parameters: not stored.
_REBUILT = (
    "callbacks_",
    "cuda_dependent_attributes_",
    "history_",
    "init_context_",
    "initialized_",
    "prefixes_",
    "virtual_params_",
)


def _convert(value, kind, convert):
    """``value`` (nested dicts, lists and tuples) with ``convert`` applied to each ``kind`` leaf."""
    if isinstance(value, kind):
        return convert(value)
    if isinstance(value, dict):
        return {k: _convert(v, kind, convert) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_convert(v, kind, convert) for v in value)
    return value


def _to_arrays(state_dict):
    """A ``state_dict`` with its tensors as numpy arrays (on the CPU)."""
    return _convert(state_dict, torch.Tensor, lambda t: t.detach().cpu().numpy())


def _to_tensors(state_dict):
    """The inverse of :func:`_to_arrays`: numpy arrays become tensors (copies)."""
    return _convert(state_dict, np.ndarray, torch.tensor)


def _json_number(value):
    """Numpy scalars of a training history as Python numbers."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"the training history holds a {type(value).__name__}, not a number")


def _changed_params(learner):
    """The parameters of ``learner`` that differ from those of its class's default instance."""
    try:
        defaults = type(learner)().get_params(deep=False)
    except TypeError:  # a subclass without defaults for every argument: keep them all
        defaults = {}
    changed = {}
    for name, value in learner.get_params(deep=False).items():
        if name.startswith("_"):  # skorch's bookkeeping, set again by __init__
            continue
        default = defaults.get(name, object())
        if value is default:
            continue
        try:
            same = type(value) is type(default) and bool(value == default)
        except Exception:  # no boolean comparison (arrays, ...)
            same = False
        if not same:
            changed[name] = value
    return changed


class ResidualLearnerState:
    """A residual learner as plain data: what the pickle-free format stores of it.

    Built by :meth:`of`; :meth:`build` makes the learner again. Trusting this
    type when loading a file trusts no code: it holds only the learner's
    class (a type, which skops lists separately), a dict of parameters and
    numpy arrays, numbers and strings.

    Attributes
    ----------
    learner : type
        :class:`~skcath.residuals.GRUResidual`, :class:`~skcath.residuals.MLPResidual`
        or a subclass.
    params : dict
        Parameters that differ from the class's defaults.
    tensors : dict
        ``state_dict`` of ``module_``, ``criterion_`` and ``optimizer_``, by
        attribute, tensors as numpy arrays; empty for a learner that is not
        initialised.
    scalers : dict
        Normalisation statistics (``x_scaler_``, ``s_scaler_``) as
        ``{"mean": array, "scale": array}``.
    attributes : dict
        The other fitted attributes (``sigma_e_``, ``feature_names_in_``, ...).
    history : str or None
        The training history (``history_``) as JSON.
    """

    @classmethod
    def of(cls, learner):
        """The state of a residual learner (fitted or not); ``learner`` is left unchanged."""
        state = cls()
        state.learner = type(learner)
        state.params = _changed_params(learner)
        state.tensors, state.scalers, state.attributes, state.history = {}, {}, {}, None
        if not getattr(learner, "initialized_", False):
            return state
        state.tensors = {name: _to_arrays(getattr(learner, name).state_dict()) for name in _TORCH}
        state.history = json.dumps(learner.history_.to_list(), default=_json_number)
        for name, value in vars(learner).items():
            if not name.endswith("_") or name in _TORCH or name in _REBUILT:
                continue
            if isinstance(value, Standardizer):
                state.scalers[name] = {"mean": value.mean, "scale": value.scale}
            else:
                state.attributes[name] = value
        return state

    def build(self):
        """The residual learner this state was made of, with its weights and statistics.

        Raises
        ------
        ValueError
            The state names a class that is not a residual learner.
        """
        if not (isinstance(self.learner, type) and issubclass(self.learner, LEARNERS)):
            raise ValueError(
                f"the file stores a residual learner of class {self.learner!r}, which is not "
                f"one of {[c.__name__ for c in LEARNERS]} or a subclass"
            )
        params = dict(self.params)
        if "device" in params:  # a CUDA-trained learner loads on the CPU when there is no GPU
            device = get_map_location(params["device"])
            if device.type != torch.device(params["device"]).type:
                params["device"] = device.type
        learner = self.learner(**params)
        if not self.tensors:
            return learner
        if "n_motors_" in self.attributes:  # the network's input sizes follow it
            learner.n_motors_ = self.attributes["n_motors_"]
        with torch.random.fork_rng(devices=[]):  # the weights drawn here are replaced
            learner.initialize()
        module = self.tensors["module_"]
        floating = [v for v in module.values() if np.issubdtype(v.dtype, np.floating)]
        if floating:  # float64 after module_.double()
            learner.module_.to(dtype=torch.as_tensor(floating[0]).dtype)
        for name in ("module_", "criterion_"):
            getattr(learner, name).load_state_dict(_to_tensors(self.tensors[name]))
        learner.optimizer_.load_state_dict(_to_tensors(self.tensors["optimizer_"]))
        learner.history_ = History(json.loads(self.history))
        for name, value in self.scalers.items():
            setattr(learner, name, Standardizer(mean=value["mean"], scale=value["scale"]))
        for name, value in self.attributes.items():
            setattr(learner, name, value)
        return learner


def _walk(obj, convert, memo):
    """``obj`` with ``convert`` applied to what it returns a value for, copying containers.

    Descends into lists, tuples, dicts and scikit-learn estimators (their
    attributes); a container whose items are all unchanged is returned as is.
    """
    if id(obj) in memo:
        return memo[id(obj)]
    out = convert(obj)
    if out is not None:
        pass
    elif type(obj) in (list, tuple):
        items = [_walk(v, convert, memo) for v in obj]
        changed = any(a is not b for a, b in zip(items, obj))
        out = type(obj)(items) if changed else obj
    elif type(obj) is dict:
        items = {k: _walk(v, convert, memo) for k, v in obj.items()}
        out = items if any(items[k] is not v for k, v in obj.items()) else obj
    elif isinstance(obj, BaseEstimator) and hasattr(obj, "__dict__"):
        attributes = _walk(vars(obj), convert, memo)
        if attributes is vars(obj):
            out = obj
        else:  # a copy: the estimator given is left unchanged
            out = object.__new__(type(obj))
            out.__dict__.update(attributes)
    else:
        out = obj
    memo[id(obj)] = out
    return out


def _plain_learner(obj):
    if isinstance(obj, OnlineEstimator):
        return OnlineEstimatorState.of(obj, to_plain)
    if not isinstance(obj, LEARNERS):
        return None
    state = ResidualLearnerState.of(obj)
    state.params = to_plain(state.params)  # a pretrained learner among them
    return state


def _built_learner(obj):
    if isinstance(obj, OnlineEstimatorState):
        return obj.build(from_plain)
    if not isinstance(obj, ResidualLearnerState):
        return None
    obj.params = from_plain(obj.params)
    return obj.build()


def to_plain(estimator):
    """``estimator`` with each residual learner in it replaced by its :class:`ResidualLearnerState`.

    Each :class:`~skcath.online.OnlineEstimator` in it is replaced by its
    :class:`~skcath.online._state.OnlineEstimatorState` (whose DataFrames are
    stored as arrays, its residual learner as above).

    Parameters
    ----------
    estimator : object
        An estimator, a pipeline, or a meta-estimator holding residual
        learners (in its attributes, lists, tuples and dicts).

    Returns
    -------
    plain : object
        ``estimator`` itself when it holds no residual learner, else a copy
        of the estimators and containers on the way to each learner;
        ``estimator`` is left unchanged.
    """
    return _walk(estimator, _plain_learner, {})


def from_plain(estimator):
    """The inverse of :func:`to_plain`: every :class:`ResidualLearnerState` built again.

    And every :class:`~skcath.online._state.OnlineEstimatorState`.

    Raises
    ------
    ValueError
        A state names a class that is not a residual learner.
    """
    return _walk(estimator, _built_learner, {})
