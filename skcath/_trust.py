"""What the pickle-free persistence format trusts, and the check of a file before it is built.

skops builds only the types a user trusts. :func:`skcath.persist.load`
trusts, besides skops' own defaults, the classes of skcath listed by
:func:`default_trusted`: those that :func:`skcath.persist.save` writes into a
file and whose loading runs skcath's code on numbers, strings and arrays
only. Anything else a file holds (a class of your own, a function) is refused
until it is named in ``trusted``.

One kind of object is refused even when its type is trusted: a skorch net
stored as itself. skorch's ``__setstate__`` unpickles bytes from its state,
so a file holding a residual learner as an object (rather than as the
:class:`~skcath._torch_state.ResidualLearnerState` that ``save`` writes)
could run any code. :func:`check_schema` reads the file's schema before skops
builds anything and refuses such an object; the learners' classes are
trusted only as classes, as ``ResidualLearnerState`` refers to them.
"""

from __future__ import annotations

import io
import json
import os
import zipfile

from skorch import NeuralNet

from ._torch_state import ResidualLearnerState
from .backbones import (
    PCCBackbone,
    PCCParams,
    PDLBackbone,
    PDLParams,
    PolynomialBackbone,
    PolynomialParams,
)
from .ensemble import SeedEnsembleRegressor
from .online import MotorRecalibration, ShaftChangeDetector
from .online._state import FrameState, OnlineEstimatorState
from .online._weights import StepWeights
from .residuals import GRUResidual, MLPResidual, NoResidual

__all__ = ["check_schema", "default_trusted", "read_schema"]


def _classes():
    """skcath's classes that a file written by ``persist.save`` may hold."""
    return (
        PCCBackbone, PCCParams, PDLBackbone, PDLParams, PolynomialBackbone, PolynomialParams,
        NoResidual, GRUResidual, MLPResidual, ResidualLearnerState,
        ShaftChangeDetector, MotorRecalibration, StepWeights, OnlineEstimatorState, FrameState,
        SeedEnsembleRegressor,
    )


def default_trusted() -> list[str]:
    """Fully qualified names of the skcath types that ``persist.load`` trusts by default.

    Returns
    -------
    names : list of str
    """
    return sorted(f"{c.__module__}.{c.__qualname__}" for c in _classes())


def _nodes(node):
    """Every node of a skops schema (nested dicts and lists), depth first."""
    if isinstance(node, dict):
        if "__loader__" in node:
            yield node
        for value in node.values():
            yield from _nodes(value)
    elif isinstance(node, list):
        for value in node:
            yield from _nodes(value)


def _is_net(module, name, trusted):
    """Whether the class ``module.name`` is a skorch net (only trusted classes are imported)."""
    if module.split(".")[0] in ("skorch", "torch"):
        return True
    if f"{module}.{name}" not in trusted:
        return False  # skops refuses it anyway, without importing it
    from skops.io._utils import gettype

    cls = gettype(module, name)
    return isinstance(cls, type) and issubclass(cls, NeuralNet)


def read_schema(payload):
    """The schema of a skops payload (``schema.json``), as nested dicts and lists.

    Raises
    ------
    zipfile.BadZipFile, KeyError, ValueError
        The payload is not a skops file.
    """
    with zipfile.ZipFile(io.BytesIO(payload)) as zf:
        return json.loads(zf.read("schema.json"))


def check_schema(schema, trusted, path):
    """Refuse a skops payload that holds a skorch net (or a torch object) as an object.

    Parameters
    ----------
    schema : dict
        The payload's schema (:func:`read_schema`).
    trusted : collection of str
        Names of the types the loading trusts.
    path : str or os.PathLike
        The file, for the message.

    Raises
    ------
    ValueError
        The payload holds such an object; it names the file and the class.
    """
    for node in _nodes(schema):
        if node["__loader__"] not in ("ObjectNode", "ReduceNode"):  # classes, functions, ...
            continue
        module, name = str(node.get("__module__")), str(node.get("__class__"))
        if _is_net(module, name, trusted):
            raise ValueError(
                f"{os.fspath(path)!r} holds a {module}.{name} stored as an object, which would "
                "unpickle bytes from the file (and so could run any code in it) when it is "
                "built. skcath.persist.save never writes one: it stores residual learners as "
                "their state (ResidualLearnerState). The file was forged or written by "
                "another tool; it is not loaded."
            )
