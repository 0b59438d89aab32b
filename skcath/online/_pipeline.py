"""The check of the fitted pipeline a streaming estimator (or its export) steps."""

from sklearn.exceptions import NotFittedError
from sklearn.pipeline import Pipeline
from sklearn.utils.validation import check_is_fitted

from ..backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
from ..residuals import GRUResidual, GRUResidualModule, MLPResidual, MLPResidualModule, NoResidual

__all__ = ["STEP_BACKBONES", "check_online_pipeline"]


#: The backbones a streaming step evaluates.
STEP_BACKBONES = (PCCBackbone, PDLBackbone, PolynomialBackbone)


def check_online_pipeline(pipeline):
    """The backbone and the residual step (or None) of a fitted pipeline.

    Parameters
    ----------
    pipeline : sklearn.pipeline.Pipeline
        ``Pipeline([("backbone", PCCBackbone() | PDLBackbone() |
        PolynomialBackbone()), ("residual", NoResidual() | MLPResidual() |
        GRUResidual())])``, fitted; the residual step may be left out.

    Returns
    -------
    backbone : PCCBackbone, PDLBackbone or PolynomialBackbone
    residual : MLPResidual, GRUResidual or None
        None for a backbone alone or followed by :class:`NoResidual`.
    """
    if not isinstance(pipeline, Pipeline):
        raise TypeError(
            "pipeline must be a fitted sklearn Pipeline of a backbone and a residual "
            f"learner, got {type(pipeline).__name__}."
        )
    steps = [est for _, est in pipeline.steps if est is not None and est != "passthrough"]
    if not 1 <= len(steps) <= 2 or not isinstance(steps[0], STEP_BACKBONES):
        names = [type(est).__name__ for est in steps]
        raise ValueError(
            "pipeline must hold a backbone (PCCBackbone, PDLBackbone or PolynomialBackbone), "
            "optionally "
            "followed by NoResidual, MLPResidual or GRUResidual; got the steps "
            f"{names}."
        )
    backbone = steps[0]
    check_is_fitted(backbone)
    if len(steps) == 1:
        return backbone, None
    residual = steps[1]
    if isinstance(residual, NoResidual):
        check_is_fitted(residual)
        return backbone, None
    if not isinstance(residual, (GRUResidual, MLPResidual)):
        raise ValueError(
            "The last step of pipeline must be NoResidual, MLPResidual or GRUResidual; "
            f"got {type(residual).__name__}."
        )
    if not getattr(residual, "initialized_", False) or not hasattr(residual, "sigma_e_"):
        raise NotFittedError(
            f"The {type(residual).__name__} of pipeline is not fitted yet; fit the "
            "pipeline before streaming."
        )
    if not isinstance(residual.module_, (GRUResidualModule, MLPResidualModule)):
        raise ValueError(
            f"{type(residual).__name__} has a custom module "
            f"({type(residual.module_).__name__}); streaming supports GRUResidualModule "
            "and MLPResidualModule."
        )
    return backbone, residual
