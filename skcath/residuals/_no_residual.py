"""The backbone alone as a final pipeline step: baselines in the same grid as the learners."""

from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import check_is_fitted

from .._base import RecordingsMixin
from .._validation import check_recordings
from ._backbone_columns import check_backbone_columns, nominal_tip

__all__ = ["NoResidual"]


class NoResidual(RecordingsMixin, RegressorMixin, BaseEstimator):
    """Predict the backbone's nominal tip ``b`` unchanged (residual ``r = 0``).

    The final step of a pipeline whose backbone appends ``b_x``, ``b_y``,
    ``b_z``; it lets the geometric baselines sit in the same parameter grid
    as the residual learners::

        GridSearchCV(pipe, {"residual": [NoResidual(), MLPResidual(), GRUResidual()]})

    Attributes
    ----------
    feature_names_in_ : ndarray of str
        Columns of ``X`` seen in ``fit``.
    n_features_in_ : int
        Number of columns of ``X`` seen in ``fit``.

    Examples
    --------
    >>> from sklearn.pipeline import Pipeline
    >>> from skcath.backbones import PDLBackbone
    >>> from skcath.residuals import NoResidual
    >>> pipe = Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())])
    >>> pipe.fit(X, y).predict(X)  # doctest: +SKIP
    """

    _parameter_constraints: dict = {}

    def _check_X(self, X, y=None):
        # no sweep is read: runs without a sweep phase are taken as they are
        X, y = check_recordings(X, y, require_sweep=False)
        check_backbone_columns(X, type(self).__name__)
        return X, y

    def predict(self, X):
        """Nominal tip position ``b`` of every row (mm), shape (n_samples, 3)."""
        check_is_fitted(self)
        X, _ = self._check_X(X)
        return nominal_tip(X)
