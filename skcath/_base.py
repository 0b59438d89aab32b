"""What every estimator over recordings shares: the run-RMSE score and the input tags."""

import numpy as np

from ._validation import check_target

__all__ = ["RecordingsMixin"]


class RecordingsMixin:
    """Mixin of the estimators that take long-format recordings and predict tips.

    ``score`` is the negated mean per-run RMSE over motion rows, and the tags
    declare long-format input (strings, categories and NaN allowed) and a
    3-column target. Subclasses set ``_target_required``.
    """

    _target_required = False

    def _record_columns(self, X):
        """Remember the columns of the recordings seen in ``fit``."""
        self.feature_names_in_ = np.asarray(X.columns, dtype=object)
        self.n_features_in_ = X.shape[1]

    def score(self, X, y, sample_weight=None):
        """Negated mean per-run RMSE (mm) over motion rows (greater is better).

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format.
        y : array-like of shape (n_samples, 3)
            Measured tip positions (mm).
        sample_weight : None
            Not supported: runs have equal weights.

        Returns
        -------
        score : float
        """
        from .metrics import mean_per_run_rmse

        if sample_weight is not None:
            raise ValueError("sample_weight is not supported: the metric weights runs equally.")
        y = check_target(y, len(X))
        return -mean_per_run_rmse(y, self.predict(X), X)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True
        tags.input_tags.string = True
        tags.input_tags.categorical = True
        tags.target_tags.required = self._target_required
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = False
        return tags
