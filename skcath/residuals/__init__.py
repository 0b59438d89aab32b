"""Learned residuals: correct a backbone's nominal tip from motor history and sweep context."""

from ._estimators import GRUResidual, MLPResidual
from ._features import Standardizer, step_feature_names, sweep_feature_names
from ._modules import GRUResidualModule, MaskedNormalizedMSE, MLPResidualModule, SweepEncoder
from ._no_residual import NoResidual

__all__ = [
    "GRUResidual",
    "GRUResidualModule",
    "MLPResidual",
    "MLPResidualModule",
    "MaskedNormalizedMSE",
    "NoResidual",
    "Standardizer",
    "SweepEncoder",
    "step_feature_names",
    "sweep_feature_names",
]
