"""What every estimator over recordings shares: the run-RMSE score and the input tags."""

import warnings

import numpy as np

from ._validation import check_target
from ._version import current_version
from .exceptions import InconsistentVersionWarning
from .metrics import mean_per_run_rmse

__all__ = ["RecordingsMixin"]


class RecordingsMixin:
    """Mixin of the estimators that take long-format recordings and predict tips.

    ``score`` is the negated mean per-run RMSE over motion rows, and the tags
    declare long-format input (strings, categories and NaN allowed) and a
    3-column target. Subclasses set ``_target_required``.

    Pickling stores the skcath version in the state (``_skcath_version``);
    unpickling under another version warns with
    :class:`skcath.exceptions.InconsistentVersionWarning`.
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
        if sample_weight is not None:
            raise ValueError("sample_weight is not supported: the metric weights runs equally.")
        y = check_target(y, len(X))
        return -mean_per_run_rmse(y, self.predict(X), X)

    def __getstate__(self):
        # the next class in the MRO (BaseEstimator, or skorch's NeuralNet that
        # serializes the torch modules) builds the state
        state = super().__getstate__()
        if state is None or not isinstance(state, dict):  # pragma: no cover - no __dict__
            return state
        return {**state, "_skcath_version": current_version()}

    def __setstate__(self, state):
        if isinstance(state, dict) and "_skcath_version" in state:
            state = dict(state)
            saved = state.pop("_skcath_version")
            if saved != current_version():
                warnings.warn(
                    InconsistentVersionWarning(
                        estimator_name=type(self).__name__,
                        original_version=saved,
                        current_version=current_version(),
                    ),
                    stacklevel=2,
                )
        parent = getattr(super(), "__setstate__", None)
        if parent is not None:
            parent(state)
        else:  # pragma: no cover - BaseEstimator and skorch NeuralNet both define it
            self.__dict__.update(state)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True
        tags.input_tags.string = True
        tags.input_tags.categorical = True
        tags.target_tags.required = self._target_required
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = False
        return tags
