"""The check that a pretrained residual learner has the network of the one it starts."""

from __future__ import annotations

import inspect

__all__ = ["check_same_network"]


def _module_arguments(learner):
    """The arguments the learner's network is built with: its defaults, then ``module__*``."""
    module = learner.module
    defaults = {}
    if isinstance(module, type):
        for name, p in inspect.signature(module.__init__).parameters.items():
            if p.default is not inspect.Parameter.empty:
                defaults[name] = p.default
    return {**defaults, **learner.get_params_for("module")}


def check_same_network(learner, source):
    """Raise a clear error unless ``source``'s network has the shape of ``learner``'s.

    Names each ``module__*`` argument that differs, with both values, or else
    each weight whose shape differs; called before the weights of
    ``pretrained`` are loaded.
    """
    mine, theirs = learner.module_.state_dict(), source.module_.state_dict()
    shapes = {k: tuple(v.shape) for k, v in mine.items()}
    their_shapes = {k: tuple(v.shape) for k, v in theirs.items()}
    if type(learner.module_) is type(source.module_) and shapes == their_shapes:
        return
    if type(learner.module_) is not type(source.module_):
        differences = [
            f"module={type(learner.module_).__name__} here, "
            f"{type(source.module_).__name__} in pretrained"
        ]
    else:
        here, there = _module_arguments(learner), _module_arguments(source)
        differences = [
            f"module__{k}={here.get(k)!r} here, {there.get(k)!r} in pretrained"
            for k in sorted(set(here) | set(there))
            if here.get(k) != there.get(k)
        ] or [
            f"weight {k!r} of shape {shapes.get(k)} here, {their_shapes.get(k)} in pretrained"
            for k in sorted(set(shapes) | set(their_shapes))
            if shapes.get(k) != their_shapes.get(k)
        ]
    raise ValueError(
        f"pretrained has another network than this {type(learner).__name__}: "
        f"{'; '.join(differences)}. Give this estimator the module and module__* "
        "parameters pretrained was fitted with."
    )
